"""The training curves of a run, kept in memory: episodes, TD losses and gradient norms.

The final plots and ``summary.json`` read them; a training state saves them, so a resumed
run's plots cover the whole run.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field, fields
from typing import Any

import torch
from tensordict import TensorDictBase
from torch import Tensor

from trl_cartpole.report.plotting import FinalEvaluation, LearningCurves
from trl_cartpole.run.evaluation import EvalCurve
from trl_cartpole.run.learner import UpdateReport

__all__ = ["Episode", "History"]


@dataclass(frozen=True)
class Episode:
    """A training episode that ended: its return, its length and the frame it ended at."""

    episode_return: float
    length: int
    frame: int


@dataclass
class History:
    """The training curves the plots and the summary read."""

    episode_returns: list[float] = field(default_factory=list)  # in the order they ended
    episode_lengths: list[int] = field(default_factory=list)
    episode_frames: list[int] = field(default_factory=list)  # the frame each episode ended at
    update_frames: list[int] = field(default_factory=list)
    td_losses: list[float] = field(default_factory=list)
    grad_norms: list[float] = field(default_factory=list)
    epsilon_frames: list[int] = field(default_factory=list)  # after each batch, when epsilon-greedy
    epsilons: list[float] = field(default_factory=list)

    def record_episodes(self, batch: TensorDictBase, frames: int) -> list[Episode]:
        """Keep the episodes that finished in ``batch`` ``[rows, T]`` (or ``[T]``); return them.

        Episodes are kept in the order they ended (time-major over the envs), each with the
        frame it ended at; ``frames`` (the run's count) already counts this batch.
        """
        steps = batch.shape[-1]
        rows = batch.numel() // steps

        def time_major(key: tuple[str, str]) -> Tensor:  # [T, rows]
            return batch[key].reshape(rows, steps).T

        done = time_major(("next", "done"))  # [T, rows]
        if not done.any():
            return []
        returns = time_major(("next", "episode_reward"))[done].tolist()
        lengths = time_major(("next", "step_count"))[done].tolist()
        step_index = done.nonzero()[:, 0]  # [episodes]: the step of the batch each one ended at
        first_frame = frames - batch.numel()
        ended = (first_frame + (step_index + 1) * rows).tolist()
        episodes = [
            Episode(episode_return, length, frame)
            for episode_return, length, frame in zip(returns, lengths, ended, strict=True)
        ]
        for episode in episodes:
            self.episode_returns.append(episode.episode_return)
            self.episode_lengths.append(episode.length)
            self.episode_frames.append(episode.frame)
        return episodes

    def record_updates(self, report: UpdateReport, frames: int) -> None:
        """Keep the TD losses and gradient norms of one round of updates."""
        self.update_frames.extend([frames] * len(report))
        self.td_losses.extend(report.losses)
        self.grad_norms.extend(report.grad_norms)

    def record_epsilon(self, frames: int, epsilon: float) -> None:
        """Keep epsilon as it stands after a batch (the dashboard's exploration panel)."""
        self.epsilon_frames.append(frames)
        self.epsilons.append(epsilon)

    def curves(
        self,
        evaluations: EvalCurve,
        threshold: float | None,
        eval_episodes: int | None = None,
        final: FinalEvaluation | None = None,
        return_label: str = "Episode return",
    ) -> LearningCurves:
        """The training episodes so far, with ``evaluations`` (the evaluator's curve)."""
        return LearningCurves(
            self.episode_frames,
            self.episode_returns,
            evaluations.frames,
            evaluations.returns,
            threshold,
            eval_episodes=eval_episodes,
            final=final,
            return_label=return_label,
        )

    def state_dict(self) -> dict[str, Tensor]:
        """Each curve as one tensor, float64 or int64, so its values come back exactly: a
        checkpoint stores tensors as binary data, where a list went into its JSON schema, which
        Python's ``json.dump`` writes item by item (about a third of a second per save for a
        default CartPole run, seconds for an Atari run's tens of thousands of updates)."""
        return {
            name: torch.tensor(values, dtype=torch.float64 if name in _FLOATS else torch.int64)
            for name, values in asdict(self).items()
        }

    def load_state_dict(self, state: dict[str, Any]) -> None:
        """Read :meth:`state_dict`'s tensors."""
        for name, values in state.items():
            getattr(self, name)[:] = values.tolist()


# the curves of floats, by their annotation (the others, list[int], count frames and steps)
_FLOATS = {curve.name for curve in fields(History) if curve.type == "list[float]"}

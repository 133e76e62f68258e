"""Judging a policy: which episodes each evaluation plays, on which envs, and how many.

One rule for the seeds: an evaluation for ``purpose`` of a run seeded ``seed`` plays its i-th
episode on an env seeded ``seed + k * eval.seed_offset + i``, with k = 1 for the periodic
evaluations, 2 for the final one (and ``evaluate.py``'s default) and 3 for the candidates
played again (:mod:`trl_cartpole.run.best_policy`): three sets of episodes that never meet
each other or the training envs (seeded ``seed`` onward).

One memory rule for the envs: a pixel env is evaluated on Gymnasium's own frames
(:meth:`~trl_cartpole.run.env_kind.EnvKind.evaluation_env`), and each Gymnasium renderer holds
its own frames (about 30 MiB here), so no evaluation holds more than :data:`PIXEL_ENVS_AT_ONCE`
pixel envs: the final evaluation and the candidates build them a turn at a time, the periodic
evaluations keep one env of at most that many for the run (:class:`PeriodicEvaluation`).

The builder makes one :class:`EvalProtocol` from the config; the end of a run, the choice of
the best policy and ``evaluate.py`` ask it, and read no config themselves.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass

from tensordict.nn import TensorDictModuleBase
from torchrl.envs import TransformedEnv

from trl_cartpole.config.schema import Config, EnvConfig, EvalConfig
from trl_cartpole.run.env_kind import EnvKind
from trl_cartpole.run.envs import close_env, make_env_from_config
from trl_cartpole.run.evaluation import EvalResult, evaluate

__all__ = [
    "PIXEL_ENVS_AT_ONCE",
    "PURPOSES",
    "EvalProtocol",
    "PeriodicEvaluation",
    "cut_episodes_note",
    "evaluation_seed",
]

# k in seed + k * eval.seed_offset, for each evaluation's purpose.
PURPOSES = {"periodic": 1, "final": 2, "candidates": 3}
# Pixel envs one evaluation holds at once: each holds a Gymnasium renderer and its frames.
PIXEL_ENVS_AT_ONCE = 20


def evaluation_seed(seed: int, purpose: str, seed_offset: int = EvalConfig.seed_offset) -> int:
    """The seed of the first episode of an evaluation for ``purpose`` (:data:`PURPOSES`) in a
    run seeded ``seed``: ``seed + k * seed_offset`` (the benchmark's peers follow it too)."""
    return seed + PURPOSES[purpose] * seed_offset


def cut_episodes_note(result: EvalResult, max_steps: int, what: str = "episodes") -> str | None:
    """One line when episodes of ``result`` ran to ``max_steps`` and were cut there (an env
    with no time limit of its own): their returns are not whole episodes. None otherwise."""
    cut = sum(length >= max_steps for length in result.lengths)
    if not cut:
        return None
    return (
        f"{cut} of {len(result.lengths)} {what} ran {max_steps} steps and were cut there "
        "(eval.max_steps): their returns are not whole episodes; raise eval.max_steps or give "
        "the env a time limit (env.max_episode_steps)"
    )


@dataclass(frozen=True)
class EvalProtocol:
    """How a run's policies are evaluated: the env, the seeds, the episodes, the step limit."""

    env: EnvConfig  # the env evaluated on: a pixel env on Gymnasium's own frames
    device: str
    seed: int  # the run's seed
    seed_offset: int  # eval.seed_offset
    max_steps: int  # eval.max_steps: an episode longer than this is cut
    periodic_episodes: int  # eval.episodes
    final_episodes: int  # eval.final_episodes
    candidate_episodes: int  # eval.candidate_episodes
    observation_norm: Mapping[str, Sequence[float]] | None = None
    pixel_envs_at_once: int = PIXEL_ENVS_AT_ONCE

    @classmethod
    def from_config(
        cls, cfg: Config, observation_norm: Mapping[str, Sequence[float]] | None = None
    ) -> EvalProtocol:
        """The protocol of ``cfg``'s run (``observation_norm``: the statistics it trained with)."""
        return cls(
            env=EnvKind(cfg.env).evaluation_env(),
            device=cfg.device,
            seed=cfg.seed,
            seed_offset=cfg.eval.seed_offset,
            max_steps=cfg.eval.max_steps,
            periodic_episodes=cfg.eval.episodes,
            final_episodes=cfg.eval.final_episodes,
            candidate_episodes=cfg.eval.candidate_episodes,
            observation_norm=observation_norm,
        )

    def seed_for(self, purpose: str) -> int:
        """The seed of the first episode of an evaluation for ``purpose`` (:data:`PURPOSES`)."""
        return evaluation_seed(self.seed, purpose, self.seed_offset)

    def envs_at_once(self, episodes: int) -> int:
        """How many of ``episodes`` envs are built and played at a time."""
        return EnvKind(self.env).envs_at_once(episodes, self.pixel_envs_at_once)

    def make_envs(self, seed: int, count: int) -> TransformedEnv:
        """``count`` evaluation envs stepped together, seeded ``seed`` onward."""
        return make_env_from_config(
            self.env,
            seed,
            self.device,
            count,
            observation_norm=self.observation_norm,
            step_timeout=self.env.step_timeout,
        )

    def play(
        self,
        actor: TensorDictModuleBase,
        seed: int,
        episodes: int,
        epsilon: float = 0.0,
        on_turn: Callable[[int], None] | None = None,
    ) -> EvalResult:
        """``episodes`` greedy episodes of ``actor`` (epsilon-greedy with ``epsilon``), one per
        env seeded ``seed`` onward, :meth:`envs_at_once` at a time (the turn starting at
        episode i seeded ``seed + i``); ``on_turn`` is called with the episodes played after
        each turn."""
        at_once = self.envs_at_once(episodes)
        result = EvalResult()
        for start in range(0, episodes, at_once):
            env = self.make_envs(seed + start, min(at_once, episodes - start))
            try:
                turn = evaluate(actor, env, self.max_steps, epsilon)
            finally:
                close_env(env)
            result.extend(turn)
            if on_turn is not None:
                on_turn(len(result.returns))  # the episodes played so far
        return result

    def periodic(self) -> PeriodicEvaluation:
        """The periodic evaluations' env and player (:class:`PeriodicEvaluation`)."""
        return PeriodicEvaluation(self)

    def final(
        self, actor: TensorDictModuleBase, on_turn: Callable[[int], None] | None = None
    ) -> EvalResult:
        """The final evaluation: ``final_episodes`` episodes on the final seeds."""
        return self.play(actor, self.seed_for("final"), self.final_episodes, on_turn=on_turn)


class PeriodicEvaluation:
    """The periodic evaluations' env and player (``partial(periodic.play, actor)`` is the
    :class:`~trl_cartpole.run.evaluation.Evaluator`'s ``play``).

    One evaluation env of :meth:`EvalProtocol.envs_at_once` envs, seeded
    ``protocol.seed_for("periodic")`` onward, built once and kept for the run (its state is
    saved with a checkpoint, so a resumed run plays the same episodes). Each :meth:`play` plays
    ``protocol.periodic_episodes`` greedy episodes on it, one per env and turn, each turn
    continuing the envs' seeded random streams: every evaluation plays new episodes, and a pixel
    run's evaluations hold no more renderers than the final one."""

    def __init__(self, protocol: EvalProtocol) -> None:
        self.protocol = protocol
        self.episodes = protocol.periodic_episodes
        self.env = protocol.make_envs(
            protocol.seed_for("periodic"), protocol.envs_at_once(self.episodes)
        )

    def play(self, actor: TensorDictModuleBase) -> EvalResult:
        """One periodic evaluation of ``actor``."""
        result = EvalResult()
        while len(result.returns) < self.episodes:
            turn = evaluate(actor, self.env, self.protocol.max_steps)
            result.extend(turn, limit=self.episodes - len(result.returns))
        return result

    def close(self) -> None:
        close_env(self.env)

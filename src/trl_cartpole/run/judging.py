"""Judging a policy: which episodes each evaluation plays, on which envs, and how many.

One rule for the seeds: an evaluation for ``purpose`` of a run seeded ``seed`` plays its i-th
episode on an env seeded ``seed + k * eval.seed_offset + i``, with k = 1 for the periodic
evaluations, 2 for the final one (and ``evaluate.py``'s default) and 3 for the candidates
played again (:mod:`trl_cartpole.run.kept_policy`): three sets of episodes that never meet
each other or the training envs (seeded ``seed`` onward).

One memory rule for the envs: a pixel env is judged on Gymnasium's own frames
(:meth:`~trl_cartpole.run.env_kind.EnvKind.judged`), and each Gymnasium renderer holds its own
frames (about 30 MiB here), so episodes are played :data:`PIXEL_ENVS_AT_ONCE` at a time.

The builder makes one :class:`Judge` from the config; the end of a run, the kept-policy choice
and ``evaluate.py`` ask it, and read no config themselves.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass

from tensordict.nn import TensorDictModuleBase
from torchrl.envs import TransformedEnv

from trl_cartpole.config.schema import Config, EnvConfig
from trl_cartpole.run.env_kind import EnvKind
from trl_cartpole.run.envs import close_env, make_env_from_config
from trl_cartpole.run.evaluation import EvalResult, evaluate

__all__ = ["PIXEL_ENVS_AT_ONCE", "PURPOSES", "Judge"]

# k in seed + k * eval.seed_offset, for each evaluation's purpose.
PURPOSES = {"periodic": 1, "final": 2, "candidates": 3}
# Pixel envs one evaluation builds at once: 100 at once took the final evaluation to 3.1 GiB.
PIXEL_ENVS_AT_ONCE = 20


@dataclass(frozen=True)
class Judge:
    """How a run's policies are judged: the env, the seeds, the episodes, the step limit."""

    env: EnvConfig  # the env judged on: a pixel env on Gymnasium's own frames
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
    ) -> Judge:
        """The judge of ``cfg``'s run (``observation_norm``: the statistics it trained with)."""
        return cls(
            env=EnvKind(cfg.env).judged(),
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
        return self.seed + PURPOSES[purpose] * self.seed_offset

    def envs_at_once(self, episodes: int) -> int:
        """How many of ``episodes`` envs are built and played at a time."""
        return EnvKind(self.env).envs_at_once(episodes, self.pixel_envs_at_once)

    def make_envs(self, seed: int, count: int) -> TransformedEnv:
        """``count`` judging envs stepped together, seeded ``seed`` onward."""
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
            result.returns += turn.returns
            result.lengths += turn.lengths
            result.initial_values += turn.initial_values
            if on_turn is not None:
                on_turn(len(result.returns))  # the episodes played so far
        return result

    def final(
        self, actor: TensorDictModuleBase, on_turn: Callable[[int], None] | None = None
    ) -> EvalResult:
        """The final evaluation: ``final_episodes`` episodes on the final seeds."""
        return self.play(actor, self.seed_for("final"), self.final_episodes, on_turn=on_turn)

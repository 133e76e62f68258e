"""What re-creates an episode of an env whose state is not plain data: its start and actions.

A classic-control env's state is a few arrays a checkpoint stores as they are. Box2D's
LunarLander (or MuJoCo, or a user's env) holds its state in native objects instead. Such an
env is deterministic given its random generator and its actions, so :class:`EpisodeLog`
records, for the episode under way, how it began (the seed its reset was given, or the state
of its random generator just before a reset without one, and the reset's options) and every
action since. :meth:`EpisodeLog.replay` plays that record again on a fresh copy of the env and
checks that it reaches the same observation; True then means the state the record was taken in
for an env whose state lives in its episode (LunarLander builds a new Box2D world at every
reset; MuJoCo resets its data). State an env keeps across resets and does not show in its
observation (an episode counter, a curriculum) is not checked: such an env may replay to the
same observation and still go on differently.
"""

from __future__ import annotations

import copy
from typing import Any

import gymnasium as gym
import numpy as np

__all__ = ["MAX_LOGGED_STEPS", "PLAIN_STATE_MODULES", "EpisodeLog", "records_episodes"]

# envs whose whole state is plain data (stored as it is: trl_cartpole.store.env_state), or
# saved by their own means (ALE's cloneState): no log needed
PLAIN_STATE_MODULES = ("gymnasium.envs.classic_control", "ale_py")
MAX_LOGGED_STEPS = 100_000  # a longer episode is not logged (its resume starts a new one)


def records_episodes(env_id: str) -> bool:
    """Whether ``env_id``'s env needs :class:`EpisodeLog` for an exact resume: any env whose
    entry point is not in :data:`PLAIN_STATE_MODULES`."""
    entry_point = gym.spec(env_id).entry_point
    module = entry_point if isinstance(entry_point, str) else entry_point.__module__
    return not module.startswith(PLAIN_STATE_MODULES)


def _plain(value: Any) -> bool:
    if value is None or isinstance(value, (bool, int, float, str)):
        return True
    if isinstance(value, dict):
        return all(isinstance(k, str) and _plain(v) for k, v in value.items())
    return isinstance(value, (list, tuple)) and all(_plain(v) for v in value)


class EpisodeLog(gym.Wrapper):
    """Records the episode under way (module doc); ``record()`` is it as plain data (None when
    it cannot be replayed: options that are not plain data, or more than
    :data:`MAX_LOGGED_STEPS` steps)."""

    def __init__(self, env: gym.Env) -> None:
        super().__init__(env)
        self._start: dict[str, Any] | None = None  # how the episode began
        self._actions: list[np.ndarray] = []
        self._observation: np.ndarray | None = None

    def reset(self, *, seed: int | None = None, options: dict | None = None) -> Any:
        rng = (
            None
            if seed is not None
            else copy.deepcopy(self.unwrapped.np_random.bit_generator.state)
        )
        kept = copy.deepcopy(options)
        self._start = {"seed": seed, "rng": rng, "options": kept} if _plain(options) else None
        self._actions = []
        observation, info = self.env.reset(seed=seed, options=options)
        self._observation = np.array(observation, copy=True)
        return observation, info

    def step(self, action: Any) -> Any:
        if self._start is not None:
            if len(self._actions) < MAX_LOGGED_STEPS:
                self._actions.append(np.array(action, copy=True))
            else:
                self._start = None
        result = self.env.step(action)
        self._observation = np.array(result[0], copy=True)
        return result

    def record(self) -> dict[str, Any] | None:
        """The episode under way as plain data: its start, its actions ``[T, ...]`` and the
        observation it has reached; None if it cannot be replayed (class doc)."""
        if self._start is None or self._observation is None:
            return None
        actions = np.stack(self._actions) if self._actions else np.zeros((0,), dtype=np.int64)
        return {**self._start, "actions": actions, "observation": self._observation}

    def replay(self, record: dict[str, Any]) -> bool:
        """Play ``record`` again on this env (its reset, then every action): whether it reached
        the recorded observation (the env is then in the recorded state)."""
        if record["seed"] is None:
            self.unwrapped.np_random.bit_generator.state = copy.deepcopy(record["rng"])
        self.reset(seed=record["seed"], options=record["options"])
        for action in record["actions"]:
            self.step(action.item() if action.ndim == 0 else action)
        return self._observation is not None and np.array_equal(
            self._observation, record["observation"]
        )

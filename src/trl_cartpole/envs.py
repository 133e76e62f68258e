"""Environment factory: a Gymnasium env wrapped in TorchRL transforms, and the fit check.

DQN as built here needs a single observation vector and a finite set of actions. The check
runs on the TorchRL specs of the built env, so the message names what the env really has.
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import torch
from torchrl.data import Categorical, Composite, OneHot
from torchrl.envs import (
    DoubleToFloat,
    GymEnv,
    GymWrapper,
    RewardSum,
    StepCounter,
    TransformedEnv,
)

from trl_cartpole.config import ConfigError

__all__ = [
    "check_env_fits",
    "check_env_id",
    "make_env",
    "make_sync_vector_env",
    "solve_threshold",
]

OBSERVATION_KEY = "observation"


def check_env_id(env_id: str) -> None:
    """Raise :class:`ConfigError` if Gymnasium does not know ``env_id``."""
    try:
        gym.spec(env_id)
    except gym.error.Error as error:
        raise ConfigError(
            f"env.id={env_id!r} is not a registered Gymnasium env ({error}); "
            "check the spelling and version suffix, e.g. CartPole-v1"
        ) from None


def solve_threshold(env_id: str, override: float | None = None) -> float | None:
    """The return that counts as solved: ``override`` or Gymnasium's ``reward_threshold``."""
    if override is not None:
        return float(override)
    threshold = gym.spec(env_id).reward_threshold
    return None if threshold is None else float(threshold)


def check_env_fits(env: TransformedEnv | GymEnv, env_id: str) -> None:
    """Raise :class:`ConfigError` unless ``env`` has one vector observation and discrete actions."""
    action_spec = env.action_spec
    if not isinstance(action_spec, (OneHot, Categorical)):
        raise ConfigError(
            f"env {env_id!r} has a {type(action_spec).__name__} action space; "
            "DQN needs discrete actions (a Gymnasium Discrete space)"
        )
    observation_spec = env.observation_spec
    keys = list(observation_spec.keys(True, True))
    obs = observation_spec.get(OBSERVATION_KEY, None) if OBSERVATION_KEY in keys else None
    if obs is None or isinstance(obs, Composite) or len(keys) != 1:
        raise ConfigError(
            f"env {env_id!r} has observation entries {keys}; "
            "DQN here needs one vector observation (a Gymnasium Box of rank 1)"
        )
    obs_shape = tuple(obs.shape[len(env.batch_size) :])  # drop the batch dims of a vector env
    if len(obs_shape) != 1:
        raise ConfigError(
            f"env {env_id!r} has an observation of shape {obs_shape}; "
            "DQN here needs a vector (rank 1): flatten images or use a vector-state env"
        )


def make_sync_vector_env(env_id: str, num_envs: int, **make_kwargs: Any) -> gym.vector.VectorEnv:
    """``num_envs`` copies of ``env_id`` stepped in one process, with same-step autoreset.

    The Gymnasium env under a batched :func:`make_env`, and the evaluation envs of the
    benchmark's peers (``trl_cartpole.peers.protocol``), so both evaluate on the same envs.
    """
    return gym.make_vec(
        env_id,
        num_envs=num_envs,
        vectorization_mode="sync",
        vector_kwargs={"autoreset_mode": gym.vector.AutoresetMode.SAME_STEP},
        **make_kwargs,
    )


def make_env(
    env_id: str = "CartPole-v1",
    seed: int | None = None,
    device: str | torch.device = "cpu",
    max_episode_steps: int | None = None,
    num_envs: int = 1,
    render_mode: str | None = None,
) -> TransformedEnv:
    """Build ``GymEnv(env_id)`` wrapped in ``StepCounter``, ``RewardSum`` (+ ``DoubleToFloat``).

    With ``num_envs > 1`` the base env is a Gymnasium ``SyncVectorEnv`` (one process, same-step
    autoreset) in TorchRL's ``GymWrapper``, batch size ``[num_envs]``: evaluation plays all its
    episodes in one batched rollout.

    The returned env writes ``("next", "step_count")`` and ``("next", "episode_reward")`` so the
    training loop reads episode lengths and returns off the collected batch. Gymnasium's
    TimeLimit sets ``truncated`` (not ``terminated``) at the step limit, so the TD target keeps
    bootstrapping there.

    ``render_mode`` (``"rgb_array"`` or ``"human"``, single env only) is passed to
    ``gymnasium.make``; the Gymnasium env is ``env.base_env._env``.
    """
    check_env_id(env_id)
    make_kwargs: dict[str, Any] = {}
    if max_episode_steps is not None:
        make_kwargs["max_episode_steps"] = max_episode_steps
    if render_mode is not None:
        if num_envs != 1:
            raise ValueError("render_mode needs a single env (num_envs=1)")
        make_kwargs["render_mode"] = render_mode
    try:
        if num_envs == 1:
            base_env = GymEnv(env_id, device=device, **make_kwargs)
        else:
            base_env = GymWrapper(
                make_sync_vector_env(env_id, num_envs, **make_kwargs), device=device
            )
    except (ImportError, gym.error.DependencyNotInstalled) as error:
        raise ConfigError(
            f"env {env_id!r} needs a package that is not installed ({error})"
        ) from None
    try:
        check_env_fits(base_env, env_id)
    except ConfigError:
        base_env.close()
        raise
    transforms = [StepCounter(), RewardSum()]
    if base_env.observation_spec[OBSERVATION_KEY].dtype == torch.float64:
        transforms.append(DoubleToFloat())
    # append_transform wraps a plain env in a TransformedEnv and extends an existing one (the
    # GymWrapper of a vector env already is one, for its resets) instead of nesting them.
    env = base_env
    for transform in transforms:
        env = env.append_transform(transform)
    if seed is not None:
        env.set_seed(seed)
    return env

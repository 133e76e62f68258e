"""Environment factory: a Gymnasium env wrapped in TorchRL transforms, and the fit check.

DQN as built here needs a single observation vector and a finite set of actions. The check
runs on the TorchRL specs of the built env, so the message names what the env really has.

Env ids: any id Gymnasium has registered (``CartPole-v1``), ``module:Id`` (the module's import
registers ``Id``, Gymnasium's own convention), ``module:EnvClass`` (a ``gymnasium.Env``
subclass, registered here as ``module.EnvClass``), or an id registered by a module listed in
``env.imports``. :func:`resolve_env_id` turns each into a registered id.
"""

from __future__ import annotations

import importlib
from collections.abc import Mapping, Sequence
from typing import Any

import gymnasium as gym
import torch
from torchrl.envs import (
    DoubleToFloat,
    DTypeCastTransform,
    GymWrapper,
    ObservationNorm,
    RewardSum,
    StepCounter,
    TransformedEnv,
)

from trl_cartpole.config import EnvConfig
from trl_cartpole.errors import ConfigError

__all__ = [
    "check_env_fits",
    "estimate_observation_norm",
    "make_env",
    "make_env_from_config",
    "make_sync_vector_env",
    "resolve_env_id",
    "solve_threshold",
]

OBSERVATION_KEY = "observation"
# Gymnasium env families whose dependencies come with an extra of this project (pyproject.toml).
OPTIONAL_EXTRAS = {"gymnasium.envs.box2d": "box2d"}
# The smallest scale ObservationNorm divides by: a feature that stayed constant during the random
# rollouts (a flag random play never sets) must not be blown up by 1 / std once it moves.
MIN_OBSERVATION_SCALE = 1e-3


def _import_module(name: str, field: str) -> Any:
    try:
        return importlib.import_module(name)
    except ImportError as error:
        raise ConfigError(
            f"{field}: cannot import module {name!r} ({error}); install the package that "
            "provides it or add its folder to PYTHONPATH"
        ) from None


def resolve_env_id(env_id: str, imports: Sequence[str] = ()) -> str:
    """Import ``imports``, register a ``module:EnvClass`` entry point; return the registered id.

    Raises :class:`ConfigError` (one line) for a module that cannot be imported, an attribute
    that is not a ``gymnasium.Env`` subclass, or an id Gymnasium does not know.
    """
    for module_name in imports:
        _import_module(module_name, "env.imports")
    if ":" in env_id:
        module_name, name = env_id.split(":", 1)
        module = _import_module(module_name, f"env.id={env_id!r}")
        if name in gym.registry:  # registered by the import (Gymnasium's module:Id)
            env_id = name
        else:  # an env class, registered under its qualified name so two modules' classes differ
            target = getattr(module, name, None)
            if not (isinstance(target, type) and issubclass(target, gym.Env)):
                raise ConfigError(
                    f"env.id={env_id!r}: module {module_name!r} neither registers {name!r} nor "
                    "defines a gymnasium.Env subclass of that name"
                )
            qualified = f"{module_name}.{name}"
            if qualified not in gym.registry:
                gym.register(id=qualified, entry_point=env_id)
            env_id = qualified
    try:
        gym.spec(env_id)
    except gym.error.Error as error:
        raise ConfigError(
            f"env.id={env_id!r} is not a registered Gymnasium env ({error}); check the spelling "
            "and version suffix (e.g. CartPole-v1), or name the module that registers it in "
            "env.imports"
        ) from None
    return env_id


def solve_threshold(env_id: str, override: float | None = None) -> float | None:
    """The return that counts as solved: ``override`` or Gymnasium's ``reward_threshold``."""
    if override is not None:
        return float(override)
    threshold = gym.spec(resolve_env_id(env_id)).reward_threshold
    return None if threshold is None else float(threshold)


def _missing_dependency(env_id: str, error: Exception) -> ConfigError:
    """The one-line error for an env whose package is missing, naming the extra to install."""
    entry_point = str(gym.spec(env_id).entry_point)
    extra = next(
        (e for prefix, e in OPTIONAL_EXTRAS.items() if entry_point.startswith(prefix)), None
    )
    how = f'pip install -e ".[{extra}]"' if extra else "install the package the message names"
    reason = str(error).splitlines()[0] if str(error) else type(error).__name__
    return ConfigError(f"env {env_id!r} needs a package that is not installed ({reason}); {how}")


def check_env_fits(observation_space: gym.Space, action_space: gym.Space, env_id: str) -> None:
    """Raise :class:`ConfigError` unless the spaces are one vector and one discrete action.

    Checked on the Gymnasium spaces (of one env, ``single_*_space`` for a vector env) before
    TorchRL wraps the env, so a space TorchRL cannot batch fails here in one line too.
    """
    spaces = gym.spaces
    if not isinstance(action_space, spaces.Discrete):
        kind = "continuous" if isinstance(action_space, spaces.Box) else "multi-part"
        raise ConfigError(
            f"env {env_id!r} has {kind} actions (a Gymnasium {type(action_space).__name__}); "
            "DQN needs one discrete action (a Gymnasium Discrete space)"
        )
    if isinstance(observation_space, spaces.Dict | spaces.Tuple):
        parts = (
            list(observation_space.spaces)
            if isinstance(observation_space, spaces.Dict)
            else [type(part).__name__ for part in observation_space.spaces]
        )
        raise ConfigError(
            f"env {env_id!r} has observation entries {parts} (a Gymnasium "
            f"{type(observation_space).__name__} space); DQN here needs one vector observation "
            "(a Gymnasium Box of rank 1): flatten it (gymnasium.wrappers.FlattenObservation)"
        )
    if isinstance(observation_space, spaces.Discrete | spaces.MultiDiscrete | spaces.MultiBinary):
        raise ConfigError(
            f"env {env_id!r} has a discrete observation (a state index, e.g. Taxi or FrozenLake); "
            "DQN here needs a vector observation (a Gymnasium Box of rank 1)"
        )
    shape = tuple(observation_space.shape or ())
    if len(shape) == 3:
        raise ConfigError(
            f"env {env_id!r} has image observations of shape {shape}; DQN here needs one vector "
            "observation: use the env's vector-state version or flatten it in a Gymnasium wrapper"
        )
    if len(shape) != 1 or not isinstance(observation_space, spaces.Box):
        raise ConfigError(
            f"env {env_id!r} has an observation of shape {shape}; DQN here needs a vector "
            "(rank 1): flatten it (gymnasium.wrappers.FlattenObservation) or use a vector-state env"
        )


def make_sync_vector_env(env_id: str, num_envs: int, **make_kwargs: Any) -> gym.vector.VectorEnv:
    """``num_envs`` copies of ``env_id`` stepped in one process, with same-step autoreset.

    The Gymnasium env under a batched :func:`make_env`, and the evaluation envs of the
    benchmark's peers (``benchmarks.peers.protocol``), so both evaluate on the same envs.
    """
    return gym.make_vec(
        env_id,
        num_envs=num_envs,
        vectorization_mode="sync",
        vector_kwargs={"autoreset_mode": gym.vector.AutoresetMode.SAME_STEP},
        **make_kwargs,
    )


def make_env(
    env_name: str = "CartPole-v1",
    device: str | torch.device = "cpu",
    *,
    seed: int | None = None,
    max_episode_steps: int | None = None,
    num_envs: int = 1,
    render_mode: str | None = None,
    observation_norm: Mapping[str, Sequence[float]] | None = None,
) -> TransformedEnv:
    """Build the Gymnasium env in TorchRL's ``GymWrapper`` with ``StepCounter``, ``RewardSum``.

    The base env is ``GymWrapper(gymnasium.make(env_id))``: the env ``GymEnv(env_id)`` builds,
    made here because ``GymEnv`` first calls the env's constructor with ``frameskip=1``, which a
    custom env class whose ``__init__`` takes no arguments rejects. ``DoubleToFloat`` is added
    for float64 observations, ``DTypeCastTransform`` to float32 for other dtypes. ``env_name``
    (TorchRL's ``GymEnv`` name for it) is any id
    :func:`resolve_env_id` accepts; ``make_env(env_name, device)`` is the call of TorchRL's DQN
    example, the other arguments are keywords. With
    ``observation_norm`` (``{"loc": [...], "scale": [...]}``, from
    :func:`estimate_observation_norm`) a TorchRL ``ObservationNorm`` maps the observation to
    ``(obs - loc) / scale``.

    With ``num_envs > 1`` the base env is a Gymnasium ``SyncVectorEnv`` (one process, same-step
    autoreset) in TorchRL's ``GymWrapper``, batch size ``[num_envs]``: evaluation plays all its
    episodes in one batched rollout.

    The returned env writes ``("next", "step_count")`` and ``("next", "episode_reward")`` so the
    training loop reads episode lengths and returns off the collected batch. Gymnasium's
    TimeLimit sets ``truncated`` (not ``terminated``) at the step limit, so the TD target keeps
    bootstrapping there.

    ``render_mode`` (``"rgb_array"`` or ``"human"``, single env only) is passed to
    ``gymnasium.make``; the Gymnasium env is ``trl_cartpole.compat.gym_env(env)``.
    """
    env_id = resolve_env_id(env_name)
    make_kwargs: dict[str, Any] = {}
    if max_episode_steps is not None:
        make_kwargs["max_episode_steps"] = max_episode_steps
    if render_mode is not None:
        if num_envs != 1:
            raise ValueError("render_mode needs a single env (num_envs=1)")
        make_kwargs["render_mode"] = render_mode
    try:
        if num_envs == 1:
            gym_env = gym.make(env_id, **make_kwargs)
            spaces = gym_env.observation_space, gym_env.action_space
        else:
            gym_env = make_sync_vector_env(env_id, num_envs, **make_kwargs)
            spaces = gym_env.single_observation_space, gym_env.single_action_space
    except (ImportError, gym.error.DependencyNotInstalled) as error:
        raise _missing_dependency(env_id, error) from None
    try:
        check_env_fits(*spaces, env_id)
    except ConfigError:
        gym_env.close()
        raise
    base_env = GymWrapper(gym_env, device=device)
    transforms = [StepCounter(), RewardSum()]
    observation_dtype = base_env.observation_spec[OBSERVATION_KEY].dtype
    if observation_dtype == torch.float64:
        transforms.append(DoubleToFloat())
    elif observation_dtype != torch.float32:  # int or uint8 vectors: the network takes float32
        transforms.append(
            DTypeCastTransform(observation_dtype, torch.float32, in_keys=[OBSERVATION_KEY])
        )
    if observation_norm is not None:
        transforms.append(
            ObservationNorm(
                loc=torch.as_tensor(observation_norm["loc"], dtype=torch.float32),
                scale=torch.as_tensor(observation_norm["scale"], dtype=torch.float32),
                in_keys=[OBSERVATION_KEY],
                standard_normal=True,  # (obs - loc) / scale
            )
        )
    # append_transform wraps a plain env in a TransformedEnv and extends an existing one (the
    # GymWrapper of a vector env already is one, for its resets) instead of nesting them.
    env = base_env
    for transform in transforms:
        env = env.append_transform(transform)
    if seed is not None:
        env.set_seed(seed)
    return env


def make_env_from_config(
    env_cfg: EnvConfig,
    seed: int | None = None,
    device: str | torch.device = "cpu",
    num_envs: int | None = None,
    observation_norm: Mapping[str, Sequence[float]] | None = None,
    render_mode: str | None = None,
) -> TransformedEnv:
    """:func:`make_env` for the ``env`` section of a config (``num_envs`` overrides its own).

    ``observation_norm`` must be given when ``env_cfg.normalize_observations`` is on: the
    statistics belong to a run (:func:`estimate_observation_norm`, stored in its checkpoints).
    """
    if env_cfg.normalize_observations and observation_norm is None:
        raise ValueError("env.normalize_observations=true needs the run's observation_norm stats")
    return make_env(
        resolve_env_id(env_cfg.id, env_cfg.imports),
        device,
        seed=seed,
        max_episode_steps=env_cfg.max_episode_steps,
        num_envs=env_cfg.num_envs if num_envs is None else num_envs,
        render_mode=render_mode,
        observation_norm=observation_norm if env_cfg.normalize_observations else None,
    )


def estimate_observation_norm(env_cfg: EnvConfig, seed: int) -> dict[str, list[float]]:
    """Mean and std per observation feature over ``env_cfg.normalization_frames`` random frames.

    TorchRL's ``ObservationNorm.init_stats`` plays uniform random actions in one env; the torch
    RNG is forked, so estimating does not shift the run's random numbers. The scale is floored
    at ``MIN_OBSERVATION_SCALE``. Returns ``{"loc": [...], "scale": [...]}`` (JSON-ready).
    """
    env = make_env(
        resolve_env_id(env_cfg.id, env_cfg.imports),
        seed=seed,
        max_episode_steps=env_cfg.max_episode_steps,
    )
    norm = ObservationNorm(in_keys=[OBSERVATION_KEY], standard_normal=True)
    env.append_transform(norm)
    with torch.random.fork_rng():
        torch.manual_seed(seed)
        norm.init_stats(num_iter=env_cfg.normalization_frames, reduce_dim=0, cat_dim=0)
    env.close()
    return {
        "loc": norm.loc.tolist(),  # [obs_dim]
        "scale": norm.scale.clamp_min(MIN_OBSERVATION_SCALE).tolist(),  # [obs_dim]
    }

"""Environment factory: a Gymnasium env wrapped in TorchRL transforms, and the fit check.

DQN as built here needs a single observation vector and a finite set of actions. The check
runs on the TorchRL specs of the built env, so the message names what the env really has. The
ids accepted are :mod:`trl_cartpole.envs.ids`'s (:func:`~trl_cartpole.envs.ids.resolve_env_id`).
"""

from __future__ import annotations

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

from trl_cartpole.envs.episode_log import EpisodeLog, records_episodes
from trl_cartpole.envs.ids import check_env_fits, missing_dependency, resolve_env_id
from trl_cartpole.errors import ConfigError

__all__ = [
    "GYM_WRAPPER_KEYWORDS",
    "OBSERVATION_KEY",
    "make_env",
    "make_sync_vector_env",
]

OBSERVATION_KEY = "observation"
# The smallest scale ObservationNorm divides by: a feature that stayed constant during the random
# rollouts (a flag random play never sets) must not be blown up by 1 / std once it moves.
MIN_OBSERVATION_SCALE = 1e-3


def make_sync_vector_env(env_id: str, num_envs: int, **make_kwargs: Any) -> gym.vector.VectorEnv:
    """``num_envs`` copies of ``env_id`` stepped in one process, with same-step autoreset.

    The Gymnasium env under a batched :func:`make_env`, and the evaluation envs of the
    benchmark's peers (``benchmarks.peers.protocol``), so both evaluate on the same envs.

    :param env_id: a registered Gymnasium id (:func:`resolve_env_id` turns any accepted id
        into one).
    :param num_envs: how many copies of the env are stepped together.
    :param make_kwargs: passed on to ``gymnasium.make_vec``, which makes each copy with
        ``gymnasium.make(env_id, **make_kwargs)`` (``max_episode_steps``, an env's own options).
    :returns: Gymnasium's ``SyncVectorEnv`` (``vectorization_mode="sync"``, autoreset mode
        ``SAME_STEP``).
    """
    return gym.make_vec(
        env_id,
        num_envs=num_envs,
        vectorization_mode="sync",
        vector_kwargs={"autoreset_mode": gym.vector.AutoresetMode.SAME_STEP},
        # an env whose state is not plain data logs its episodes, for an exact resume
        wrappers=[EpisodeLog] if records_episodes(env_id) else None,
        **make_kwargs,
    )


# Keywords of TorchRL's GymWrapper (and the EnvBase under it); make_env passes every other
# keyword to gymnasium.make, as TorchRL's GymEnv does.
GYM_WRAPPER_KEYWORDS = frozenset(
    {
        "categorical_action_encoding",
        "from_pixels",
        "pixels_only",
        "frame_skip",
        "batch_size",
        "allow_done_after_reset",
        "convert_actions_to_numpy",
        "spec_locked",
        "auto_reset",
        "run_type_checks",
    }
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
    **kwargs: Any,
) -> TransformedEnv:
    """Return TorchRL's ``TransformedEnv(GymWrapper(gymnasium env), StepCounter, RewardSum)``.

    The arguments are TorchRL's ``GymEnv``'s: ``env_name`` and ``device`` (positional, as in
    TorchRL's DQN example's ``make_env(env_name, device)``), then keywords; every keyword goes
    to ``GymWrapper`` or to ``gymnasium.make``, as ``GymEnv`` does.

    The base env is ``GymWrapper(gymnasium.make(env_id))``: the env ``GymEnv(env_id)`` builds,
    made here because ``GymEnv`` first calls the env's constructor with ``frameskip=1``, which a
    custom env class whose ``__init__`` takes no arguments rejects. ``DoubleToFloat`` is added
    for float64 observations, ``DTypeCastTransform`` to float32 for other dtypes.

    The returned env writes ``("next", "step_count")`` and ``("next", "episode_reward")`` so the
    training loop reads episode lengths and returns off the collected batch. Gymnasium's
    TimeLimit sets ``truncated`` (not ``terminated``) at the step limit, so the TD target keeps
    bootstrapping there. The Gymnasium env is ``trl_cartpole.compat.gym_env(env)``.

    Example::

        >>> from trl_cartpole import make_env
        >>> env = make_env("CartPole-v1", seed=0, categorical_action_encoding=True)
        >>> env.rollout(3)["next", "step_count"].squeeze(-1).tolist()
        [1, 2, 3]

    :param env_name: the env id, any id :func:`resolve_env_id` accepts. Default: the default
        config's ``env.id``, CartPole-v1 (TorchRL's ``GymEnv``: required).
    :param device: the env's device, given to ``GymWrapper``. Default ``"cpu"`` (TorchRL's
        ``EnvBase``: None).
    :param seed: given to ``env.set_seed`` once the env is built; None: no seed is set here.
    :param max_episode_steps: the step limit (Gymnasium's ``TimeLimit``), given to
        ``gymnasium.make``; None: the env's registered limit.
    :param num_envs: with ``num_envs > 1`` the base env is a Gymnasium ``SyncVectorEnv`` (one
        process, same-step autoreset: :func:`make_sync_vector_env`) in TorchRL's
        ``GymWrapper``, batch size ``[num_envs]``: evaluation plays all its episodes in one
        batched rollout. Default 1: a single env.
    :param render_mode: given to ``gymnasium.make`` (a single env only: ``num_envs=1``).
        ``from_pixels=True`` sets ``render_mode="rgb_array"`` when it is None.
    :param observation_norm: ``{"loc": [...], "scale": [...]}``, from
        :func:`estimate_observation_norm`: a TorchRL ``ObservationNorm`` maps the observation
        to ``(obs - loc) / scale``. None: no normalisation.
    :param kwargs: any keyword of ``GymWrapper`` (``categorical_action_encoding``,
        ``from_pixels``, ``pixels_only``, ``frame_skip``, ``batch_size``... the set
        ``GYM_WRAPPER_KEYWORDS``) goes to it, with TorchRL's defaults
        (``categorical_action_encoding=False``: one-hot actions); every other keyword goes to
        ``gymnasium.make`` (an env's own options), as ``GymEnv`` does. ``from_pixels=True``
        renders frames into ``"pixels"``; ``make_q_actor(..., torso="cnn",
        in_keys=["pixels"])`` reads them (``trl_cartpole.envs.pixels`` has the transforms
        that crop, pool and stack the frames).
    :returns: TorchRL's ``TransformedEnv`` over the ``GymWrapper``, with ``StepCounter``,
        ``RewardSum``, the dtype cast where one is needed and ``ObservationNorm`` with
        ``observation_norm``.
    """
    # ids the config has resolved pass unchanged; a Python caller's error names env_name
    env_id = resolve_env_id(env_name, field="env_name", imports_field=None)
    wrapper_kwargs = {key: kwargs.pop(key) for key in list(kwargs) if key in GYM_WRAPPER_KEYWORDS}
    make_kwargs: dict[str, Any] = dict(kwargs)
    if max_episode_steps is not None:
        make_kwargs["max_episode_steps"] = max_episode_steps
    if wrapper_kwargs.get("from_pixels") and render_mode is None:
        render_mode = "rgb_array"  # what GymEnv sets for from_pixels
    if render_mode is not None:
        if num_envs != 1:
            raise ValueError("render_mode needs a single env (num_envs=1)")
        make_kwargs["render_mode"] = render_mode
    try:
        if num_envs == 1:
            gym_env = gym.make(env_id, **make_kwargs)
            if records_episodes(env_id):  # for an exact resume (envs/episode_log.py)
                gym_env = EpisodeLog(gym_env)
            spaces = gym_env.observation_space, gym_env.action_space
        else:
            gym_env = make_sync_vector_env(env_id, num_envs, **make_kwargs)
            spaces = gym_env.single_observation_space, gym_env.single_action_space
    except (ImportError, gym.error.DependencyNotInstalled) as error:
        raise missing_dependency(env_id, error) from None
    try:
        check_env_fits(*spaces, env_id, pixels=bool(wrapper_kwargs.get("from_pixels")))
    except ConfigError:
        gym_env.close()
        raise
    base_env = GymWrapper(gym_env, device=device, **wrapper_kwargs)
    transforms = [StepCounter(), RewardSum()]
    observation_dtype = (
        base_env.observation_spec[OBSERVATION_KEY].dtype
        if OBSERVATION_KEY in base_env.observation_spec.keys()  # noqa: SIM118 (a spec)
        else torch.float32  # pixels only: nothing to cast
    )
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

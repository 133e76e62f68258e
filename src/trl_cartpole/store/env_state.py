"""The state inside a run's TorchRL and Gymnasium envs, as data a checkpoint stores.

:class:`trl_cartpole.store.collection_state.EnvState` saves these (and the collector's carrier
and the n-step window) so that a run resumed from a checkpoint continues exactly as if never
stopped:

- the Gymnasium envs' internal state, as arrays and numbers, never pickled: for classic-control
  envs (CartPole, Acrobot, MountainCar...) every plain-data attribute of the env and of each
  wrapper around it (the physics ``state``, ``steps_beyond_terminated``, the time limit's
  ``_elapsed_steps``, the order and checker flags), its RNG's ``bit_generator.state``, and for a
  vector env its own arrays (``_autoreset_envs``, the last observations, rewards and flags);
- TorchRL's autoreset memo of the last vector-env step, which the next reset reads.

An Atari game's state is ALE's own: ``cloneState(include_rng=True)`` holds the emulator and
its random generator (sticky actions), stored as its serialized bytes (a uint8 array), with the
game's last action (which a sticky frame repeats and ALE's state leaves out: ``LastAction``),
the Gymnasium env's RNG (the NOOP starts) and the preprocessing's own state (the stacked
frames, the lives at the last step: the transforms' ``state_dict``), for each game of the env.

Other envs (Box2D's LunarLander, MuJoCo, a user's own) do not expose their state as data. Each
logs its episode under way (:class:`~trl_cartpole.envs.episode_log.EpisodeLog`: how it began
and every action since), and the resumed run plays that log again on its fresh envs, checking
that each reaches the saved observation; where one does not (an env that is not deterministic
given its random generator and actions), the resumed run resets them and says so. Where no
log is kept (an episode too long, an env not built by :func:`~trl_cartpole.parts.env.make_env`),
``checkpoint.trust_pickled_envs=true`` stores such envs pickled instead and loads them back
(not Gymnasium's ``EzPickle`` envs: below); unpickling runs any code the checkpoint holds, so
the setting is read from the command that loads, never from the checkpoint. Gymnasium's
``EzPickle`` envs (LunarLander, MuJoCo) pickle as their constructor arguments, i.e. as a fresh
env never reset, so they are reset even then. Collector worker processes snapshot their own
envs with the same functions (:mod:`trl_cartpole.store.worker_state`).

The private TorchRL names these live under are read through :mod:`trl_cartpole.compat`.
"""

from __future__ import annotations

import pickle
from typing import Any

import numpy as np
import torch
from gymnasium.utils import EzPickle
from gymnasium.vector import SyncVectorEnv
from tensordict import TensorDict, TensorDictBase
from torch.nn.parameter import is_lazy
from torchrl.envs import CatFrames, EnvBase, GymWrapper, SerialEnv, TransformedEnv

from trl_cartpole.compat import (
    ale_action_set,
    autoreset_state,
    gym_env,
    gym_generator,
    serial_envs,
    set_autoreset_state,
    set_gym_env,
)
from trl_cartpole.envs.atari import LastAction, ResizeFrame
from trl_cartpole.envs.episode_log import EpisodeLog

__all__ = [
    "autoreset_snapshot",
    "env_snapshot",
    "restore_autoreset",
    "restore_env_snapshot",
]

DATA_STATE_MODULE = "gymnasium.envs.classic_control"  # envs whose whole state is plain data
# Frames of a restored game's last action before its state is put back (_restore_atari)
LAST_ACTION_FRAMES = 32


def _is_plain(value: Any) -> bool:
    """Whether ``value`` is data a checkpoint stores without pickle (numbers, strings, arrays)."""
    if value is None or isinstance(value, (bool, int, float, str, np.generic)):
        return True
    if isinstance(value, np.ndarray):
        return value.dtype.kind in "biuf"
    if isinstance(value, (list, tuple)):
        return all(_is_plain(item) for item in value)
    return False


def _plain_attributes(obj: Any) -> dict[str, Any]:
    return {name: value for name, value in vars(obj).items() if _is_plain(value)}


def _layers(env: Any) -> list[Any]:
    """A Gymnasium env's wrappers from the outside in, then the env itself."""
    layers = [env]
    while hasattr(layers[-1], "env"):
        layers.append(layers[-1].env)
    return layers


def _single_env_snapshot(env: Any) -> dict[str, Any]:
    rng = gym_generator(env.unwrapped)  # None until the env is seeded
    return {
        "layers": [_plain_attributes(layer) for layer in _layers(env)],
        "rng": None if rng is None else rng.bit_generator.state,
    }


def _restore_single_env(env: Any, snapshot: dict[str, Any]) -> None:
    layers = _layers(env)
    if len(layers) != len(snapshot["layers"]):
        raise ValueError("the env's wrappers differ from the checkpoint's")
    for layer, attributes in zip(layers, snapshot["layers"], strict=True):
        for name, value in attributes.items():
            if name in vars(layer) and _is_plain(vars(layer)[name]):
                setattr(layer, name, value.copy() if isinstance(value, np.ndarray) else value)
    if snapshot["rng"] is not None:
        env.unwrapped.np_random.bit_generator.state = snapshot["rng"]


def _envs_of(gymnasium_env: Any) -> list[Any]:
    return gymnasium_env.envs if isinstance(gymnasium_env, SyncVectorEnv) else [gymnasium_env]


def _stores_its_state(env: EnvBase) -> bool:
    """Whether ``env`` is a Gymnasium env (or vector env) in a ``GymWrapper`` seen through its
    state: a state env, or pixels drawn from its state (``DrawCartPole``, whose stacked frames
    are stored with it: :func:`_frame_stacks`). Pixels Gymnasium renders are not (several
    rendered envs are a ``SerialEnv`` of renderers); a resumed run of them starts new
    episodes."""
    base = env.base_env if isinstance(env, TransformedEnv) else env
    return isinstance(base, GymWrapper) and not base.from_pixels


def _frame_stacks(env: EnvBase) -> dict[str, np.ndarray]:
    """The frames ``env``'s ``CatFrames`` hold stacked, as arrays on the CPU (none for an env
    without ``CatFrames``, and none yet for one never reset: :func:`_transform_buffers`)."""
    if not isinstance(env, TransformedEnv) or not any(
        isinstance(transform, CatFrames) for transform in env.transform
    ):
        return {}
    return {key: value for key, value in _transform_buffers(env).items() if "_cat_buffers" in key}


def _transform_buffers(env: TransformedEnv) -> dict[str, np.ndarray]:
    """The state of ``env``'s transforms (their ``state_dict``) as arrays on the CPU, without
    the buffers a transform makes at its first reset and has not made yet (``CatFrames``' of
    an evaluation env never played)."""
    state = env.transform.state_dict(keep_vars=True)
    return {
        key: value.detach().cpu().numpy().copy()
        for key, value in state.items()
        if not is_lazy(value)
    }


def _load_transform_buffers(env: TransformedEnv, buffers: dict[str, np.ndarray]) -> None:
    """Put :func:`_transform_buffers`' arrays back (onto the transforms' own device); an env
    whose stacks are not made yet is reset first (every state that moves is restored after)."""
    if not buffers:
        return
    if any(is_lazy(buffer) for buffer in env.transform.buffers()):
        env.reset()
    state = {key: torch.from_numpy(value.copy()) for key, value in buffers.items()}
    env.transform.load_state_dict(state, strict=False)


def _atari_games(env: EnvBase) -> list[TransformedEnv] | None:
    """The single-game envs of an Atari env (itself, or the games of its ``SerialEnv``), or
    None for another env."""
    base = env.base_env if isinstance(env, TransformedEnv) else env
    games = serial_envs(base) if isinstance(base, SerialEnv) else [env]
    if games and all(
        isinstance(game, TransformedEnv)
        and any(isinstance(transform, ResizeFrame) for transform in game.transform)
        for game in games
    ):
        return games
    return None


def _atari_snapshot(game: TransformedEnv) -> dict[str, Any]:
    unwrapped = gym_env(game).unwrapped
    state = unwrapped.ale.cloneState(include_rng=True).serialize()
    rng = gym_generator(unwrapped)
    wrapper = gym_env(game)
    last_action = wrapper.last_action if isinstance(wrapper, LastAction) else None
    return {
        "ale": np.frombuffer(state, dtype=np.uint8).copy(),
        "rng": None if rng is None else rng.bit_generator.state,
        # the action a sticky frame repeats, which ALE's state leaves out (-1: none yet)
        "last_action": -1 if last_action is None else last_action,
        # the preprocessing's state: the stacked frames, the lives at the last step
        "transforms": _transform_buffers(game),
    }


def _restore_atari(game: TransformedEnv, snapshot: dict[str, Any]) -> None:
    import ale_py

    _load_transform_buffers(game, snapshot["transforms"])  # first: it may reset the game
    unwrapped = gym_env(game).unwrapped
    state = ale_py.ALEState(snapshot["ale"].tobytes())
    last = snapshot.get("last_action")  # absent from a checkpoint written before it was kept
    if last is not None and isinstance(gym_env(game), LastAction):
        # frames of it, then the state again (which undoes them): ALE keeps it as the last
        # action. A frame is itself sticky (it keeps the previous action with probability 0.25),
        # so one frame could leave the old one; 32 leave it once in 0.25^32
        action = ale_action_set(unwrapped)[max(int(last), 0)]  # -1: NOOP, as after a reset
        for _ in range(LAST_ACTION_FRAMES):
            unwrapped.ale.act(action)
        gym_env(game).last_action = None if last < 0 else int(last)
    unwrapped.ale.restoreState(state)
    if snapshot["rng"] is not None:
        unwrapped.np_random.bit_generator.state = snapshot["rng"]


def _replay(gymnasium_env: Any, snapshot: dict[str, Any]) -> bool:
    """Play each env's logged episode again (:class:`EpisodeLog`), then put the vector env's
    own arrays back; False if an env is not logged or does not reach its logged state."""
    envs = _envs_of(gymnasium_env)
    if len(envs) != len(snapshot["envs"]) or not all(isinstance(e, EpisodeLog) for e in envs):
        return False
    reached = [env.replay(record) for env, record in zip(envs, snapshot["envs"], strict=True)]
    if not all(reached):
        return False
    for name, value in snapshot["vector"].items():
        setattr(gymnasium_env, name, value.copy() if isinstance(value, np.ndarray) else value)
    return True


def env_snapshot(env: EnvBase, trust_pickle: bool = False) -> dict[str, Any] | None:
    """The state of the Gymnasium env (or ``SyncVectorEnv``) behind ``env``, or None.

    ``{"data": ...}`` (nested dicts, lists, numbers and arrays) for classic-control envs, with
    the frames stacked by pixels drawn from their state;
    ``{"atari": [...]}`` (each game's ALE state as bytes, and its RNG) for Atari games;
    ``{"pickle": bytes}`` for other envs only with ``trust_pickle``; None where neither holds
    the env's state (and for pixels Gymnasium renders).
    """
    games = _atari_games(env)
    if games is not None:
        return {"atari": [_atari_snapshot(game) for game in games]}
    if not _stores_its_state(env):
        return None
    gymnasium_env = gym_env(env)
    envs = _envs_of(gymnasium_env)
    if all(type(e.unwrapped).__module__.startswith(DATA_STATE_MODULE) for e in envs):
        vector = _plain_attributes(gymnasium_env) if gymnasium_env is not envs[0] else {}
        envs_state = [_single_env_snapshot(e) for e in envs]
        return {"data": {"envs": envs_state, "vector": vector, "frames": _frame_stacks(env)}}
    records = [e.record() if isinstance(e, EpisodeLog) else None for e in envs]
    if all(record is not None for record in records):  # each episode, to play again
        vector = _plain_attributes(gymnasium_env) if gymnasium_env is not envs[0] else {}
        return {"replay": {"envs": records, "vector": vector}}
    if not trust_pickle or any(isinstance(e.unwrapped, EzPickle) for e in envs):
        return None
    try:  # a vector env made by gymnasium.make_vec holds local functions: pickle its envs
        return {"pickle": pickle.dumps(envs)}
    except Exception:  # native handles and other unpicklable state
        return None


def restore_env_snapshot(
    env: EnvBase, snapshot: dict[str, Any] | None, trust_pickle: bool = False
) -> bool:
    """Put a snapshot of :func:`env_snapshot` back into ``env``; False if it holds no state.

    A pickled snapshot is loaded only with ``trust_pickle``.
    """
    if snapshot is not None and "atari" in snapshot:
        games = _atari_games(env)
        if games is None or len(games) != len(snapshot["atari"]):
            return False
        for game, game_snapshot in zip(games, snapshot["atari"], strict=True):
            _restore_atari(game, game_snapshot)
        return True
    if snapshot is None or not _stores_its_state(env):
        return False
    gymnasium_env = gym_env(env)
    if "data" in snapshot:
        if snapshot["data"].get("frames"):  # first: it may reset an env never reset
            _load_transform_buffers(env, snapshot["data"]["frames"])
        envs = _envs_of(gymnasium_env)
        if len(envs) != len(snapshot["data"]["envs"]):
            return False
        for single_env, single_snapshot in zip(envs, snapshot["data"]["envs"], strict=True):
            _restore_single_env(single_env, single_snapshot)
        for name, value in snapshot["data"]["vector"].items():
            setattr(gymnasium_env, name, value.copy() if isinstance(value, np.ndarray) else value)
        return True
    if "replay" in snapshot:
        return _replay(gymnasium_env, snapshot["replay"])
    if not trust_pickle:
        return False
    envs = pickle.loads(snapshot["pickle"])  # a list: one Gymnasium env per env of the batch
    if any(isinstance(e.unwrapped, EzPickle) for e in envs):
        return False
    if isinstance(gymnasium_env, SyncVectorEnv):
        gymnasium_env.envs = envs
    else:
        set_gym_env(env, envs[0])
    return True


def autoreset_snapshot(env: EnvBase) -> dict[str, Any] | None:
    """TorchRL's autoreset memo (``done``: Tensor, ``saved_next``: TensorDict or None) as data."""
    if not _stores_its_state(env):
        return None
    memo = autoreset_state(env)
    if memo is None:
        return None
    return {
        key: {"tensordict": value.to_dict(), "batch_size": list(value.batch_size)}
        if isinstance(value, TensorDictBase)
        else value
        for key, value in memo.items()
    }


def restore_autoreset(env: EnvBase, snapshot: dict[str, Any]) -> None:
    memo = {
        key: TensorDict(value["tensordict"], batch_size=value["batch_size"])
        if isinstance(value, dict)
        else value
        for key, value in snapshot.items()
    }
    set_autoreset_state(env, memo)

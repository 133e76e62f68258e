"""The state a run keeps inside its envs, its collector and its n-step window, as a component.

``torchrl.checkpoint.Checkpoint`` saves every component through ``state_dict()`` /
``load_state_dict()``. The networks, optimizer, exploration module, replay buffer, collector
counters, global RNGs and the loop's own objects (progress, learner, evaluator, history) have
their own; :class:`EnvState` gathers what lives inside TorchRL and Gymnasium objects, so that a
run resumed from a checkpoint continues exactly as if never stopped:

- the Gymnasium envs' internal state, as arrays and numbers, never pickled: for classic-control
  envs (CartPole, Acrobot, MountainCar...) every plain-data attribute of the env and of each
  wrapper around it (the physics ``state``, ``steps_beyond_terminated``, the time limit's
  ``_elapsed_steps``, the order and checker flags), its RNG's ``bit_generator.state``, and for a
  vector env its own arrays (``_autoreset_envs``, the last observations, rewards and flags);
- TorchRL's autoreset memo of the last vector-env step, which the next reset reads;
- the collector's carrier (the last observation and the running step count and return);
- the n-step window the replay buffer's ``MultiStepTransform`` holds back.

Other envs (Box2D's LunarLander, MuJoCo, a user's own) do not expose their state as data: the
resumed run resets them and says so. ``checkpoint.trust_pickled_envs=true`` stores such envs
pickled instead and loads them back; unpickling runs any code the checkpoint holds, so the
setting is read from the command that loads, never from the checkpoint. Gymnasium's
``EzPickle`` envs (LunarLander, MuJoCo) pickle as their constructor arguments, i.e. as a fresh
env never reset, so they are reset even then. The training envs of worker processes or Ray
actors (``env=None``) are not saved: the resumed workers start new episodes.

The private TorchRL names these live under are read through :mod:`trl_cartpole.parts.compat`.
"""

from __future__ import annotations

import pickle
import warnings
from typing import Any

import numpy as np
from gymnasium.utils import EzPickle
from gymnasium.vector import SyncVectorEnv
from tensordict import TensorDict, TensorDictBase
from torchrl.envs import EnvBase, GymWrapper, TransformedEnv

from trl_cartpole.parts.compat import (
    autoreset_state,
    carrier_of,
    gym_env,
    n_step_window,
    set_autoreset_state,
    set_gym_env,
    set_n_step_window,
)

__all__ = ["EnvState", "env_snapshot", "restore_env_snapshot"]

DATA_STATE_MODULE = "gymnasium.envs.classic_control"  # envs whose whole state is plain data


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
    rng = env.unwrapped._np_random  # None until the env is seeded
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
    state. Pixel envs are not: the frames stacked by their transforms are not stored (and
    several of them are a ``SerialEnv``); a resumed pixel run starts new episodes."""
    base = env.base_env if isinstance(env, TransformedEnv) else env
    return isinstance(base, GymWrapper) and not base.from_pixels


def env_snapshot(env: EnvBase, trust_pickle: bool = False) -> dict[str, Any] | None:
    """The state of the Gymnasium env (or ``SyncVectorEnv``) behind ``env``, or None.

    ``{"data": ...}`` (nested dicts, lists, numbers and arrays) for classic-control envs;
    ``{"pickle": bytes}`` for other envs only with ``trust_pickle``; None where neither holds
    the env's state (and for pixel envs).
    """
    if not _stores_its_state(env):
        return None
    gymnasium_env = gym_env(env)
    envs = _envs_of(gymnasium_env)
    if all(type(e.unwrapped).__module__.startswith(DATA_STATE_MODULE) for e in envs):
        vector = _plain_attributes(gymnasium_env) if gymnasium_env is not envs[0] else {}
        return {"data": {"envs": [_single_env_snapshot(e) for e in envs], "vector": vector}}
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
    if snapshot is None or not _stores_its_state(env):
        return False
    gymnasium_env = gym_env(env)
    if "data" in snapshot:
        envs = _envs_of(gymnasium_env)
        if len(envs) != len(snapshot["data"]["envs"]):
            return False
        for single_env, single_snapshot in zip(envs, snapshot["data"]["envs"], strict=True):
            _restore_single_env(single_env, single_snapshot)
        for name, value in snapshot["data"]["vector"].items():
            setattr(gymnasium_env, name, value.copy() if isinstance(value, np.ndarray) else value)
        return True
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


def _autoreset_snapshot(env: EnvBase) -> dict[str, Any] | None:
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


def _restore_autoreset(env: EnvBase, snapshot: dict[str, Any]) -> None:
    memo = {
        key: TensorDict(value["tensordict"], batch_size=value["batch_size"])
        if isinstance(value, dict)
        else value
        for key, value in snapshot.items()
    }
    set_autoreset_state(env, memo)


class EnvState:
    """``state_dict`` / ``load_state_dict`` over the envs' and collector's state (module doc).

    ``trust_pickle`` (``checkpoint.trust_pickled_envs``) saves and loads envs that are not
    plain data with pickle.
    """

    def __init__(
        self, env: EnvBase | None, eval_env: EnvBase, collector, buffer, trust_pickle: bool = False
    ) -> None:
        self.env, self.eval_env = env, eval_env  # env: None when workers hold the training envs
        self.collector, self.buffer = collector, buffer
        self.trust_pickle = trust_pickle

    def state_dict(self) -> dict[str, Any]:
        window = n_step_window(self.buffer)
        in_process = self.env is not None  # else the training envs live in the workers
        return {
            "env": env_snapshot(self.env, self.trust_pickle) if in_process else None,
            "eval_env": env_snapshot(self.eval_env, self.trust_pickle),
            "env_autoreset": _autoreset_snapshot(self.env) if in_process else None,
            "eval_env_autoreset": _autoreset_snapshot(self.eval_env),
            "carrier": carrier_of(self.collector).to_dict() if in_process else None,
            "n_step_window": None if window is None else window.to_dict(),
            "n_step_window_size": None if window is None else list(window.batch_size),
        }

    def load_state_dict(self, state: dict[str, Any]) -> None:
        if self.env is None:
            warnings.warn(
                "collection runs in worker processes or Ray actors, whose envs are not saved: "
                "the resumed run's workers start new episodes (not an exact continuation)",
                stacklevel=2,
            )
        restored = {"env": False}
        for env, key in ((self.env, "env"), (self.eval_env, "eval_env")):
            if env is None:
                continue
            restored[key] = restore_env_snapshot(env, state[key], self.trust_pickle)
            if not restored[key]:  # a fresh env: new episodes, and a fresh autoreset memo
                warnings.warn(self._not_restored(key, state[key]), stacklevel=2)
                if key == "env":  # start a new episode from the restored RNG
                    carrier_of(self.collector).update(env.reset())
                continue
            memo = state[f"{key}_autoreset"]
            if memo is not None:
                _restore_autoreset(env, memo)
        # The carrier and the n-step window continue the training env's episodes: only with it.
        if restored["env"]:
            carrier = carrier_of(self.collector)
            carrier.update(TensorDict(state["carrier"], batch_size=carrier.batch_size))
            if state["n_step_window"] is not None:
                window = TensorDict(state["n_step_window"], batch_size=state["n_step_window_size"])
                set_n_step_window(self.buffer, window)

    def _not_restored(self, key: str, snapshot: Any) -> str:
        name = key.replace("_", " ")
        pickled = "pickle" in (snapshot or {})
        if pickled and not self.trust_pickle:
            return (
                f"the {name}'s state was stored pickled, and unpickling runs any code the "
                "checkpoint holds, so it was not loaded: the resumed run starts new episodes (not "
                "an exact continuation); pass checkpoint.trust_pickled_envs=true to load it if you "
                "wrote this checkpoint"
            )
        return (
            f"the {name}'s state is not stored as data (only classic-control envs are), so the "
            "resumed run starts new episodes (not an exact continuation)"
        )

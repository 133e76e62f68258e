"""The state a run keeps inside its envs, its collector and its n-step window, as a component.

``torchrl.checkpoint.Checkpoint`` saves every component through ``state_dict()`` /
``load_state_dict()``. The networks, optimizer, exploration module, replay buffer, collector
counters, global RNGs and the loop's own objects (progress, learner, evaluator, telemetry) have
their own; :class:`EnvState` gathers what lives inside TorchRL and Gymnasium objects, so that a
run resumed from a checkpoint continues exactly as if never stopped:

- the Gymnasium envs' internal state (physics, ``np_random``, time-limit counters), pickled:
  the training env mid-episode and the evaluation env, whose episodes follow one another
  (with TorchRL's autoreset memo of the last evaluation step, which the next reset reads);
- the collector's carrier (the last observation and the running step count and return);
- the n-step window the replay buffer's ``MultiStepTransform`` holds back.

The private TorchRL names these live under are read through :mod:`trl_cartpole.compat`.

An env whose state cannot be pickled is recorded as missing: the resumed run then resets it and
says so, the only case where a resume is not exact. That includes Gymnasium's ``EzPickle`` envs
(Box2D's LunarLander, MuJoCo): they pickle as their constructor arguments, so unpickling gives a
fresh env that was never reset, not the one mid-episode. The training envs of worker processes or
Ray actors (``env=None``) are not saved either: the resumed workers start new episodes.
"""

from __future__ import annotations

import pickle
import warnings
from typing import Any

from gymnasium.utils import EzPickle
from gymnasium.vector import SyncVectorEnv
from tensordict import TensorDict
from torchrl.envs import EnvBase

from trl_cartpole.compat import (
    autoreset_state,
    carrier_of,
    gym_env,
    n_step_window,
    set_autoreset_state,
    set_gym_env,
    set_n_step_window,
)

__all__ = ["EnvState"]


def _state_is_lost(envs: Any) -> bool:
    """Whether pickling ``envs`` (a Gymnasium env or a list of them) loses their state.

    Gymnasium's ``EzPickle`` envs (Box2D, MuJoCo) pickle as their constructor arguments:
    unpickled, they are fresh envs that were never reset.
    """
    return any(
        isinstance(e.unwrapped, EzPickle) for e in (envs if isinstance(envs, list) else [envs])
    )


def _pickled_env(env: EnvBase) -> bytes | None:
    """The Gymnasium env behind ``env`` pickled; for a ``SyncVectorEnv``, its list of envs.

    (A vector env made by ``gymnasium.make_vec`` holds local functions and cannot be pickled;
    between two evaluations its only state is that of its envs.) None where pickling would
    lose the env's state.
    """
    gymnasium_env = gym_env(env)
    envs = gymnasium_env.envs if isinstance(gymnasium_env, SyncVectorEnv) else gymnasium_env
    if _state_is_lost(envs):
        return None
    try:
        return pickle.dumps(envs)
    except Exception:  # native handles and other unpicklable state
        return None


def _pickled_autoreset_state(env: EnvBase) -> bytes | None:
    memo = autoreset_state(env)
    return None if memo is None else pickle.dumps(memo)


def _restore_env(env: EnvBase, payload: bytes | None) -> bool:
    """Put the pickled envs back into ``env``; False if there is no state to put back.

    (Checkpoints written before ``_state_is_lost`` hold ``EzPickle`` envs: those are refused.)
    """
    envs = None if payload is None else pickle.loads(payload)
    if envs is None or _state_is_lost(envs):
        return False
    gymnasium_env = gym_env(env)
    if isinstance(gymnasium_env, SyncVectorEnv):
        gymnasium_env.envs = envs
    else:
        set_gym_env(env, envs)
    return True


class EnvState:
    """``state_dict`` / ``load_state_dict`` over the envs' and collector's state (module doc)."""

    def __init__(self, env: EnvBase | None, eval_env: EnvBase, collector, buffer) -> None:
        self.env, self.eval_env = env, eval_env  # env: None when workers hold the training envs
        self.collector, self.buffer = collector, buffer

    def state_dict(self) -> dict[str, Any]:
        window = n_step_window(self.buffer)
        in_process = self.env is not None  # else the training envs live in the workers
        return {
            "env": _pickled_env(self.env) if in_process else None,
            "eval_env": _pickled_env(self.eval_env),
            "env_autoreset": _pickled_autoreset_state(self.env) if in_process else None,
            "eval_env_autoreset": _pickled_autoreset_state(self.eval_env),
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
            restored[key] = _restore_env(env, state[key])
            if not restored[key]:  # a fresh env: new episodes, and a fresh autoreset memo
                warnings.warn(
                    f"the {key.replace('_', ' ')}'s state could not be pickled when the "
                    "checkpoint was written, so the resumed run is not an exact continuation",
                    stacklevel=2,
                )
                if key == "env":  # start a new episode from the restored RNG
                    carrier_of(self.collector).update(env.reset())
                continue
            if state[f"{key}_autoreset"] is not None:
                set_autoreset_state(env, pickle.loads(state[f"{key}_autoreset"]))
        # The carrier and the n-step window continue the training env's episodes: only with it.
        if restored["env"]:
            carrier = carrier_of(self.collector)
            carrier.update(TensorDict(state["carrier"], batch_size=carrier.batch_size))
            if state["n_step_window"] is not None:
                window = TensorDict(state["n_step_window"], batch_size=state["n_step_window_size"])
                set_n_step_window(self.buffer, window)

"""The part of a run's state that no TorchRL component holds, as a checkpoint component.

``torchrl.checkpoint.Checkpoint`` saves every component through ``state_dict()`` /
``load_state_dict()``. The actor, loss (target network), optimizer, exploration module,
replay buffer, collector counters and global RNGs have their own; :class:`RunState` gathers
the rest, so that a run resumed from a checkpoint continues exactly as if never stopped:

- the loop's progress (frames, updates, best evaluation and its weights, solve point,
  training seconds) and the history the plots and summary read;
- the Gymnasium envs' internal state (physics, ``np_random``, time-limit counters), pickled:
  the training env mid-episode and the evaluation env, whose episodes follow one another
  (with TorchRL's autoreset memo of the last evaluation step, which the next reset reads);
- the collector's carrier (the last observation and the running step count and return);
- the n-step window the replay buffer's ``MultiStepTransform`` holds back;
- the hard target update's counter.

An env whose state cannot be pickled is recorded as missing: the resumed run then resets it and
says so, the only case where a resume is not exact. That includes Gymnasium's ``EzPickle`` envs
(Box2D's LunarLander, MuJoCo): they pickle as their constructor arguments, so unpickling gives a
fresh env that was never reset, not the one mid-episode. The training envs of worker processes or
Ray actors (``env=None``) are not saved either: the resumed workers start new episodes.
"""

from __future__ import annotations

import pickle
import warnings
from dataclasses import asdict
from typing import Any

from gymnasium.utils import EzPickle
from gymnasium.vector import SyncVectorEnv
from tensordict import TensorDict
from torchrl.envs import EnvBase
from torchrl.envs.transforms import VecGymEnvTransform

__all__ = ["RunState"]


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
    gym_env = env.base_env._env
    envs = gym_env.envs if isinstance(gym_env, SyncVectorEnv) else gym_env
    if _state_is_lost(envs):
        return None
    try:
        return pickle.dumps(envs)
    except Exception:  # native handles and other unpicklable state
        return None


def _autoreset_memo(env: EnvBase) -> VecGymEnvTransform | None:
    """TorchRL's transform that bridges a vector env's same-step autoreset, if ``env`` has one.

    Its ``_memo`` (the last step's done mask and observations) decides what the next
    ``reset()`` returns, so it is part of the evaluation env's state.
    """
    transform = getattr(env, "transform", None)
    for candidate in [] if transform is None else list(transform):
        if isinstance(candidate, VecGymEnvTransform):
            return candidate
    return None


def _pickled_memo(env: EnvBase) -> bytes | None:
    memo = _autoreset_memo(env)
    return None if memo is None else pickle.dumps(memo._memo)


def _restore_env(env: EnvBase, payload: bytes | None) -> bool:
    """Put the pickled envs back into ``env``; False if there is no state to put back.

    (Checkpoints written before ``_state_is_lost`` hold ``EzPickle`` envs: those are refused.)
    """
    envs = None if payload is None else pickle.loads(payload)
    if envs is None or _state_is_lost(envs):
        return False
    gym_env = env.base_env._env
    if isinstance(gym_env, SyncVectorEnv):
        gym_env.envs = envs
    else:
        env.base_env._env = envs
    return True


class RunState:
    """``state_dict`` / ``load_state_dict`` over the loop's own state (see the module doc)."""

    def __init__(self, progress, stopwatch, env, eval_env, collector, buffer, target_updater):
        self.progress = progress
        self.stopwatch = stopwatch
        self.env, self.eval_env = env, eval_env
        self.collector, self.buffer, self.target_updater = collector, buffer, target_updater

    def state_dict(self) -> dict[str, Any]:
        progress = self.progress
        n_step = getattr(self.buffer, "_transform", None)
        window = getattr(n_step[0], "_buffer", None) if n_step is not None and len(n_step) else None
        in_process = self.env is not None  # else the training envs live in the workers
        return {
            "frames": progress.frames,
            "updates": progress.updates,
            "best_eval": progress.best_eval,
            "best_state": progress.best_state,
            "frames_to_solve": progress.frames_to_solve,
            "seconds_to_solve": progress.seconds_to_solve,
            "last_eval_frame": progress.last_eval_frame,
            "collect_seconds": progress.collect_seconds,
            "update_seconds": progress.update_seconds,
            "history": asdict(progress.history),
            "train_seconds": self.stopwatch.seconds,
            "env": _pickled_env(self.env) if in_process else None,
            "eval_env": _pickled_env(self.eval_env),
            "env_memo": _pickled_memo(self.env) if in_process else None,
            "eval_env_memo": _pickled_memo(self.eval_env),
            "carrier": self.collector._carrier.to_dict() if in_process else None,
            "n_step_window": None if window is None else window.to_dict(),
            "n_step_window_size": None if window is None else list(window.batch_size),
            "hard_update_counter": getattr(self.target_updater, "counter", None),
        }

    def load_state_dict(self, state: dict[str, Any]) -> None:
        progress = self.progress
        for name in (
            "frames",
            "updates",
            "best_eval",
            "frames_to_solve",
            "seconds_to_solve",
            "last_eval_frame",
            "collect_seconds",
            "update_seconds",
        ):
            setattr(progress, name, state[name])
        progress.best_state = state["best_state"]
        for name, values in state["history"].items():
            getattr(progress.history, name)[:] = values
        self.stopwatch.elapsed = state["train_seconds"]
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
                    self.collector._carrier.update(env.reset())
                continue
            memo = _autoreset_memo(env)
            if memo is not None and state[f"{key}_memo"] is not None:
                memo._memo = pickle.loads(state[f"{key}_memo"])
        # The carrier and the n-step window continue the training env's episodes: only with it.
        if restored["env"]:
            carrier = self.collector._carrier
            carrier.update(TensorDict(state["carrier"], batch_size=carrier.batch_size))
            if state["n_step_window"] is not None:
                window = TensorDict(state["n_step_window"], batch_size=state["n_step_window_size"])
                self.buffer._transform[0]._buffer = window
        if state["hard_update_counter"] is not None:
            self.target_updater.counter = state["hard_update_counter"]

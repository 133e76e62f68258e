"""A misbehaving env named, not propagated: non-finite data and exceptions from its code.

A user's env (``env.id=my_module:MyEnv``) can return an observation or a reward that is NaN or
infinite, or raise in ``step`` or ``reset``. Left alone, the first surfaces later as
``TD loss is nan`` (naming neither the env nor the step) and the second as a long traceback
from inside the collector. :func:`check_finite_batch` looks at each collected batch and
:func:`env_fault` recognises an exception raised by the env's own code; both become one-line
:class:`~trl_cartpole.errors.TrainingFailed` errors naming the env, the fault and the frame.
"""

from __future__ import annotations

import traceback

import gymnasium as gym
import torch
from tensordict import TensorDictBase

from trl_cartpole.errors import TrainingFailed

__all__ = ["check_finite_batch", "env_fault"]

# Entries of a collected batch that the env did not write itself: the policy's outputs, and the
# return RewardSum sums from the rewards (a bad reward is named as the reward).
_NOT_THE_ENVS = ("action", "action_value", "chosen_action_value", "episode_reward")


def check_finite_batch(batch: TensorDictBase, env_id: str, frames: int) -> None:
    """Raise :class:`TrainingFailed` if a floating entry of ``batch`` ``[*B, T]`` that the env
    wrote (its observations and rewards) holds a NaN or an infinity. ``frames`` is the frame
    count before the batch; the message names the first bad step and its value."""
    keys = sorted(batch.keys(True, True), key=lambda k: not isinstance(k, tuple))  # next first
    for key in keys:
        name = key[-1] if isinstance(key, tuple) else key
        if name in _NOT_THE_ENVS:
            continue
        value = batch.get(key)
        if not torch.is_floating_point(value):
            continue
        bad = ~torch.isfinite(value.reshape(*batch.batch_size, -1)).all(-1)  # [*B, T]
        if bad.any():
            index = bad.nonzero()[0].tolist()  # [env, t] of a vector env's batch, or [t]
            where = value.reshape(*batch.batch_size, -1)[tuple(index)]
            shown = where[~torch.isfinite(where)][0].item()
            entry = ".".join(key) if isinstance(key, tuple) else key
            step = f"env {index[0]}, step {index[-1]}" if len(index) > 1 else f"step {index[0]}"
            raise TrainingFailed(
                f"env {env_id!r} returned a non-finite {entry} ({shown}) in the batch collected "
                f"after frame {frames} ({step} of the batch); check the env's step() and "
                "reset()"
            )


def env_fault(error: BaseException, env_id: str, frames: int) -> TrainingFailed | None:
    """A one-line :class:`TrainingFailed` if ``error`` was raised inside a Gymnasium env's
    ``step`` or ``reset`` (the innermost such frame of its traceback), else None."""
    method = None
    for frame, _ in traceback.walk_tb(error.__traceback__):
        owner = frame.f_locals.get("self")
        if frame.f_code.co_name in ("step", "reset") and isinstance(owner, gym.Env):
            method = f"{type(owner).__name__}.{frame.f_code.co_name}()"
    if method is None:
        return None
    reason = str(error).splitlines()[0] if str(error) else ""
    return TrainingFailed(
        f"env {env_id!r} raised {type(error).__name__} in {method} at frame {frames}"
        + (f": {reason}" if reason else "")
    )

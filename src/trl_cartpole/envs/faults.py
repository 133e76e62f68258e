"""A misbehaving env named, not propagated: bad data, exceptions, steps that never return.

A user's env (``env.id=my_module:MyEnv``) can return an observation or a reward that is NaN or
infinite, one TorchRL cannot read (the wrong shape, a reward that is not a number), raise in
``step`` or ``reset``, or never return from them. Left alone, the first surfaces later as
``TD loss is nan`` (naming neither the env nor the step), the others as long tracebacks from
inside the collector (or its worker processes), the last as a run that hangs.
:func:`check_finite_batch` looks at each collected batch; :class:`StepDeadline` (a TorchRL
transform) bounds each step and reset; :func:`env_fault` recognises an exception from the
env's code or from TorchRL reading its output, and :func:`worker_env_fault` the same in a
collector worker's log. Each becomes a one-line :class:`~trl_cartpole.errors.TrainingFailed`
naming the env, the fault and the frame.
"""

from __future__ import annotations

import re
import signal
import threading
import traceback
from pathlib import Path

import gymnasium as gym
import torch
from tensordict import TensorDictBase
from torchrl.envs import Transform

from trl_cartpole.errors import TrainingFailed

__all__ = [
    "EnvStepTimeout",
    "StepAlarm",
    "StepDeadline",
    "check_finite_batch",
    "disarm_step_deadline",
    "env_fault",
    "worker_env_fault",
]


class EnvStepTimeout(TimeoutError):
    """An env's ``step`` or ``reset`` did not return within its :class:`StepDeadline`."""


class StepAlarm:
    """A real-time alarm (``SIGALRM``) around one env call: ``with alarm: env.step(action)``.

    If the call has not returned ``seconds`` later, the handler raises :class:`EnvStepTimeout`
    where the env's code is stuck, so the traceback names the env's method. It exists only in a
    process's main thread, and only while no other real-time timer runs (a host's own alarm,
    pytest-timeout's, is left alone): elsewhere, and with ``seconds=None``, nothing is bounded.
    The handler it replaces is put back when it is cleared. An alarm a failed call left set
    raises nothing if it fires outside a Gymnasium env's ``step`` or ``reset``.
    """

    def __init__(self, seconds: float | None) -> None:
        self.seconds = seconds
        self.armed = False
        self._previous_handler = None

    def arm(self) -> None:
        global _ARMED
        if self.armed:  # a step that ended without clearing it (TorchRL skipped the hook)
            self.disarm()
        if not self.seconds or threading.current_thread() is not threading.main_thread():
            return
        if signal.getitimer(signal.ITIMER_REAL)[0] > 0:  # someone else's timer is running
            return
        self._previous_handler = signal.signal(signal.SIGALRM, self._expired)
        self.armed, _ARMED = True, self
        signal.setitimer(signal.ITIMER_REAL, self.seconds)

    def disarm(self) -> None:
        global _ARMED
        if not self.armed:
            return
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, self._previous_handler or signal.SIG_DFL)
        self.armed, _ARMED = False, None

    def _expired(self, signum, frame) -> None:
        if not self.armed:
            return
        self.disarm()
        if _inside_a_gymnasium_call(frame):
            raise EnvStepTimeout(f"did not return within {self.seconds:g} s (env.step_timeout)")

    def __enter__(self) -> StepAlarm:
        self.arm()
        return self

    def __exit__(self, *exc_info) -> None:
        self.disarm()


_ARMED: StepAlarm | None = None  # the alarm set now, if any (one timer per process)


def _inside_a_gymnasium_call(frame) -> bool:
    """Whether ``frame`` or a caller of it is a Gymnasium env's ``step`` or ``reset``."""
    while frame is not None:
        owner = frame.f_locals.get("self")
        if frame.f_code.co_name in ("step", "reset") and isinstance(
            owner, (gym.Env, gym.vector.VectorEnv)
        ):
            return True
        frame = frame.f_back
    return False


class StepDeadline(Transform):
    """A TorchRL transform that bounds each ``step`` and ``reset`` of the env below it.

    Before the base env steps (``_inv_call``, TorchRL's hook before a step) or resets
    (``_reset_env_preprocess``), its :class:`StepAlarm` is set ``seconds`` ahead; the
    transform's own step and reset, after the base env's, clear it. Appended last, it bounds the
    other transforms too.
    """

    def __init__(self, seconds: float | None) -> None:
        super().__init__(in_keys=[], out_keys=[])
        self.seconds = seconds
        self._alarm = StepAlarm(seconds)

    def _inv_call(self, tensordict: TensorDictBase) -> TensorDictBase:
        self._alarm.arm()  # the base env's step comes next
        return tensordict

    def _step(self, tensordict: TensorDictBase, next_tensordict: TensorDictBase):
        self._alarm.disarm()
        return next_tensordict

    def _reset_env_preprocess(self, tensordict: TensorDictBase | None):
        self._alarm.arm()  # the base env's reset comes next
        return tensordict

    def _reset(self, tensordict: TensorDictBase, tensordict_reset: TensorDictBase):
        self._alarm.disarm()
        return tensordict_reset


def disarm_step_deadline() -> None:
    """Clear the :class:`StepAlarm` an exception left set, if any (the run is ending)."""
    if _ARMED is not None:
        _ARMED.disarm()


# Entries of a collected batch that the env did not write itself: the policy's outputs, and the
# return RewardSum sums from the rewards (a bad reward is named as the reward).
_NOT_THE_ENVS = ("action", "action_value", "chosen_action_value", "episode_reward")


def check_finite_batch(batch: TensorDictBase, env_id: str, frames: int) -> None:
    """Raise :class:`TrainingFailed` if a floating entry of ``batch`` ``[*B, T]`` that the env
    wrote (its observations and rewards) holds a NaN or an infinity. ``frames`` is the frame
    count before the batch; the message names the first bad step and its value.

    The entries are checked together first, with one read of the result (the usual case: no
    bad value); only a batch that holds one is searched entry by entry for the message."""
    entries = [
        (key, value)
        for key, value in batch.items(include_nested=True, leaves_only=True)
        if (key[-1] if isinstance(key, tuple) else key) not in _NOT_THE_ENVS
        and torch.is_floating_point(value)
    ]
    if not entries or bool(torch.stack([torch.isfinite(v).all() for _, v in entries]).all()):
        return
    for key, value in sorted(entries, key=lambda entry: not isinstance(entry[0], tuple)):
        bad = ~torch.isfinite(value.reshape(*batch.batch_size, -1)).all(-1)  # [*B, T], next first
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
    """A one-line :class:`TrainingFailed` if ``error`` came from the env, else None: raised
    inside a Gymnasium env's ``step`` or ``reset`` (the innermost such frame of its traceback,
    a :class:`StepDeadline` timeout included), or raised by TorchRL reading what the env
    returned (an observation of the wrong shape, a reward that is not a number)."""
    method, reading = None, None
    for frame, _ in traceback.walk_tb(error.__traceback__):
        owner = frame.f_locals.get("self")
        name = frame.f_code.co_name
        if name in ("step", "reset") and isinstance(owner, gym.Env):
            method = f"{type(owner).__name__}.{name}()"
        elif name in _TORCHRL_READERS and _is_torchrl(frame.f_code.co_filename):
            reading = _TORCHRL_READERS[name]
    reason = str(error).splitlines()[0] if str(error) else ""
    if method is not None and isinstance(error, EnvStepTimeout):
        return TrainingFailed(f"env {env_id!r}: {method} {reason}, at frame {frames}")
    if method is not None:
        return _raised(env_id, type(error).__name__, method, frames, reason)
    if reading is not None:
        return _unreadable(env_id, reading, frames, f"{type(error).__name__}: {reason}")
    return None


# TorchRL's functions that read what a Gymnasium env returned: what each reads.
_TORCHRL_READERS = {
    "read_obs": "an observation",
    "_read_obs_eager": "an observation",
    "read_reward": "a reward",
    "read_done": "a done flag",
    "_step": "a step() result",
    "_reset": "a reset() result",
}


def _is_torchrl(filename: str) -> bool:
    """Whether ``filename`` is TorchRL's code that reads a Gymnasium env's output."""
    return (
        Path(filename)
        .as_posix()
        .endswith(("/torchrl/envs/gym_like.py", "/torchrl/envs/libs/gym.py"))
    )


def _raised(env_id: str, error_type: str, method: str, frames: int, reason: str):
    return TrainingFailed(
        f"env {env_id!r} raised {error_type} in {method} at frame {frames}"
        + (f": {reason}" if reason else "")
    )


def _unreadable(env_id: str, what: str, frames: int, reason: str) -> TrainingFailed:
    return TrainingFailed(
        f"env {env_id!r} returned {what} TorchRL cannot read at frame {frames} ({reason}); "
        "check what its step() and reset() return against its observation_space"
    )


# A frame line of a Python traceback: File "<path>", line <n>, in <function>
_TRACEBACK_FRAME = re.compile(r'^\s*File "(?P<file>[^"]+)", line (?P<line>\d+), in (?P<name>\S+)$')


def worker_env_fault(log_dir: Path, env_id: str, frames: int) -> TrainingFailed | None:
    """:func:`env_fault` for a collector worker process that died: read from the traceback in
    its log (``log_dir/worker-<pid>.log``, where :class:`WorkerEnvFactory` sends a worker's
    output; the run clears the folder when it starts its workers), the newest log first. None
    if no worker log holds a traceback from the env."""
    if not log_dir.is_dir():
        return None
    newest_first = sorted(log_dir.glob("worker-*.log"), key=lambda p: -p.stat().st_mtime)
    for log in newest_first:
        lines = log.read_text(encoding="utf-8", errors="replace").splitlines()
        starts = [i for i, line in enumerate(lines) if line.startswith("Traceback")]
        if not starts:
            continue
        block = lines[starts[-1] :]
        ending = next((line for line in reversed(block) if line and not line[0].isspace()), "")
        error_type, _, reason = ending.partition(": ")
        error_type = error_type.rsplit(".", 1)[-1]
        method, reading = None, None
        for line in block:
            match = _TRACEBACK_FRAME.match(line)
            if match is None:
                continue
            name, file = match["name"], match["file"]
            if name in ("step", "reset") and not _is_library(file):
                method = f"{name}() ({Path(file).name}, line {match['line']})"
            elif name in _TORCHRL_READERS and _is_torchrl(file):
                reading = _TORCHRL_READERS[name]
        where = f" (the worker's traceback: {log})"
        if method is not None and error_type == "EnvStepTimeout":
            return TrainingFailed(
                f"env {env_id!r}: {method} {reason} in a collector worker, in the batch after "
                f"frame {frames}{where}"
            )
        if method is not None:
            failure = _raised(env_id, error_type, f"{method} in a collector worker", frames, reason)
            return TrainingFailed(str(failure) + where)
        if reading is not None:
            failure = _unreadable(env_id, reading, frames, f"{error_type}: {reason}")
            return TrainingFailed(str(failure) + where)
    return None


def _is_library(filename: str) -> bool:
    """Whether ``filename`` is TorchRL's, TensorDict's or Gymnasium's wrappers' own code."""
    path = Path(filename).as_posix()
    return any(
        part in path
        for part in ("/torchrl/", "/tensordict/", "/gymnasium/wrappers/", "/gymnasium/vector/")
    )

"""A user's env that misbehaves is named in one line (exit status 1), with the run's failure
recorded in summary.json, instead of a NaN TD loss later or a traceback from the collector."""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import textwrap
import time

import pytest
import torch
from tensordict import TensorDict
from torchrl.envs import GymWrapper, TransformedEnv

from tests.conftest import CONFIG_DIR, SCRIPTS, SMOKE_OVERRIDES
from trl_cartpole.config.compose import compose_config
from trl_cartpole.envs.faults import check_finite_batch, env_fault, worker_env_fault
from trl_cartpole.errors import TrainingFailed
from trl_cartpole.run.training import train

FAULTY_ENVS = textwrap.dedent(
    """
    import numpy as np
    from gymnasium.envs.classic_control import CartPoleEnv


    class _AfterSteps(CartPoleEnv):
        def __init__(self, **kwargs):
            super().__init__(**kwargs)
            self.steps = 0


    class NaNCartPole(_AfterSteps):
        def step(self, action):
            self.steps += 1
            obs, reward, terminated, truncated, info = super().step(action)
            if self.steps > 150:
                obs = np.full_like(obs, np.nan)
            return obs, reward, terminated, truncated, info


    class InfiniteRewardCartPole(_AfterSteps):
        def step(self, action):
            self.steps += 1
            obs, reward, terminated, truncated, info = super().step(action)
            return obs, (np.inf if self.steps > 150 else reward), terminated, truncated, info


    class RaisingCartPole(_AfterSteps):
        def step(self, action):
            self.steps += 1
            if self.steps > 150:
                raise RuntimeError("the simulator lost its connection")
            return super().step(action)


    class WrongShapeCartPole(_AfterSteps):
        def step(self, action):
            self.steps += 1
            obs, reward, terminated, truncated, info = super().step(action)
            return (obs[:3] if self.steps > 150 else obs), reward, terminated, truncated, info


    class TextRewardCartPole(_AfterSteps):
        def step(self, action):
            self.steps += 1
            obs, reward, terminated, truncated, info = super().step(action)
            return obs, ("one" if self.steps > 150 else reward), terminated, truncated, info


    class HangingCartPole(_AfterSteps):
        def step(self, action):
            self.steps += 1
            if self.steps > 150:
                time.sleep(600)
            return super().step(action)


    class HangingResetCartPole(_AfterSteps):
        def reset(self, **kwargs):
            self.steps += 1  # resets here; building the env resets it too (unbounded)
            if self.steps > 8:
                time.sleep(600)
            return super().reset(**kwargs)
    """
).replace("import numpy as np", "import time\n\nimport numpy as np")


@pytest.mark.parametrize(
    ("env_class", "expected"),
    [
        ("NaNCartPole", r"returned a non-finite next\.observation \(nan\) in the batch"),
        ("InfiniteRewardCartPole", r"returned a non-finite next\.reward \(inf\)"),
        ("RaisingCartPole", r"raised RuntimeError in RaisingCartPole\.step\(\) at frame \d+: the"),
        (
            "WrongShapeCartPole",
            r"returned an observation TorchRL cannot read at frame \d+ \(RuntimeError: Shape "
            r"mismatch: the value has shape torch.Size\(\[3\]\) .*\[4\]",
        ),
        ("TextRewardCartPole", r"returned a step\(\) result TorchRL cannot read .*'str'"),
        (
            "HangingCartPole",
            r"HangingCartPole\.step\(\) did not return within 0\.5 s \(env\.step_timeout\), at "
            r"frame \d+",
        ),
        pytest.param(
            "HangingResetCartPole",
            r"HangingResetCartPole\.reset\(\) did not return within 0\.5 s",
            marks=pytest.mark.slow,  # a hang: seconds of waiting
        ),
    ],
)
def test_a_misbehaving_env_is_named_in_one_line(env_class, expected, tmp_path, monkeypatch):
    (tmp_path / "faulty_envs.py").write_text(FAULTY_ENVS)
    monkeypatch.syspath_prepend(str(tmp_path))
    run_dir = tmp_path / "run"
    cfg = compose_config(
        CONFIG_DIR,
        [
            *SMOKE_OVERRIDES,
            f"env.id=faulty_envs:{env_class}",
            "env.num_envs=1",
            "env.step_timeout=0.5",
            f"run_dir={run_dir}",
            "logger.plots=false",
        ],
    )
    started = time.monotonic()
    with pytest.raises(TrainingFailed, match=expected) as caught:
        train(cfg)
    assert time.monotonic() - started < 120  # a hang is cut, not waited out
    assert signal.getitimer(signal.ITIMER_REAL) == (0.0, 0.0)  # no alarm left behind
    assert "\n" not in str(caught.value) and f"faulty_envs:{env_class}" in str(caught.value)
    summary = json.loads((run_dir / "summary.json").read_text())
    assert summary["failed"] and "faulty_envs" in summary["failure"]


def test_the_finite_check_names_the_entry_the_step_and_the_value():
    batch = TensorDict(
        {
            "observation": torch.zeros(2, 5, 4),
            "action_value": torch.full((2, 5, 2), float("nan")),  # the policy's: not checked
            "next": {"reward": torch.ones(2, 5, 1), "done": torch.zeros(2, 5, 1, dtype=bool)},
        },
        batch_size=[2, 5],
    )
    check_finite_batch(batch, "Env-v0", 100)  # finite where the env wrote
    batch["next", "reward"][1, 3] = float("-inf")
    with pytest.raises(
        TrainingFailed, match=r"next\.reward \(-inf\) .* after frame 100 \(env 1, step 3"
    ):
        check_finite_batch(batch, "Env-v0", 100)


def test_a_step_deadline_raises_where_the_env_is_stuck_and_clears_itself():
    from gymnasium.envs.classic_control import CartPoleEnv

    from trl_cartpole.envs.faults import EnvStepTimeout, StepDeadline
    from trl_cartpole.parts.env import make_env

    class SlowCartPole(CartPoleEnv):
        delay = 0.0

        def step(self, action):
            time.sleep(self.delay)
            return super().step(action)

    env = make_env("CartPole-v1").append_transform(StepDeadline(0.2))
    env.rollout(5)  # fast steps: no alarm fires, none is left set
    assert signal.getitimer(signal.ITIMER_REAL) == (0.0, 0.0)
    slow = TransformedEnv(GymWrapper(SlowCartPole()), StepDeadline(0.2))
    SlowCartPole.delay = 5.0
    started = time.monotonic()
    with pytest.raises(EnvStepTimeout, match=r"did not return within 0\.2 s") as caught:
        slow.rollout(3)
    assert time.monotonic() - started < 2.0
    assert "SlowCartPole.step()" in str(env_fault(caught.value, "Slow-v0", 64))
    assert signal.getitimer(signal.ITIMER_REAL) == (0.0, 0.0)
    assert StepDeadline(None)._inv_call(TensorDict()) is not None  # no limit: nothing set


def test_a_worker_log_is_read_into_one_line(tmp_path):
    log = tmp_path / "worker-123.log"
    log.write_text(
        "Process _ProcessNoWarnSpawn-1:\n"
        "Traceback (most recent call last):\n"
        '  File "/x/site-packages/torchrl/collectors/_runner.py", line 9, in run\n'
        '  File "/x/site-packages/gymnasium/wrappers/common.py", line 125, in step\n'
        '  File "/home/me/my_envs.py", line 31, in step\n'
        "    raise RuntimeError('lost')\n"
        "RuntimeError: the simulator lost its connection\n"
    )
    failure = worker_env_fault(tmp_path, "my_envs:MyEnv", 288)
    assert str(failure) == (
        "env 'my_envs:MyEnv' raised RuntimeError in step() (my_envs.py, line 31) in a collector "
        f"worker at frame 288: the simulator lost its connection (the worker's traceback: {log})"
    )
    log.write_text("nothing went wrong\n")
    assert worker_env_fault(tmp_path, "my_envs:MyEnv", 288) is None


@pytest.mark.slow  # two worker processes per case
@pytest.mark.parametrize(
    ("env_class", "expected"),
    [
        (
            "RaisingCartPole",
            r"raised RuntimeError in step\(\) \(faulty_envs\.py, line \d+\) in a collector worker"
            r" at frame \d+: the simulator lost its connection \(the worker's traceback: ",
        ),
        (
            "HangingCartPole",
            r"step\(\) \(faulty_envs\.py, line \d+\) did not return within 1 s "
            r"\(env\.step_timeout\) in a collector worker",
        ),
    ],
)
def test_a_fault_in_a_worker_process_is_named_in_one_line(tmp_path, env_class, expected):
    (tmp_path / "faulty_envs.py").write_text(FAULTY_ENVS)
    run_dir = tmp_path / "run"
    proc = subprocess.run(
        [
            sys.executable,
            str(SCRIPTS / "train.py"),
            *SMOKE_OVERRIDES,
            f"env.id=faulty_envs:{env_class}",
            "env.num_envs=1",
            "collector.workers=2",
            "collector.total_frames=3000",
            "env.step_timeout=1",
            f"run_dir={run_dir}",
        ],
        capture_output=True,
        text=True,
        timeout=300,
        env={**os.environ, "PYTHONPATH": str(tmp_path)},
    )
    assert proc.returncode == 1, proc.stderr[-3000:]
    assert "Traceback" not in proc.stderr  # the workers' tracebacks are in their logs
    error = [line for line in proc.stderr.splitlines() if line.startswith("error:")]
    assert len(error) == 1 and re.search(expected, error[0]), proc.stderr[-3000:]
    assert json.loads((run_dir / "summary.json").read_text())["failed"]


def test_a_step_alarm_is_a_good_guest_of_the_process():
    from trl_cartpole.envs.faults import StepAlarm

    fired = []
    previous = signal.signal(signal.SIGALRM, lambda *_: fired.append(True))
    try:
        with StepAlarm(5.0):  # set while no other timer runs, its handler in place
            assert signal.getitimer(signal.ITIMER_REAL)[0] > 0
        assert signal.getitimer(signal.ITIMER_REAL) == (0.0, 0.0)
        signal.raise_signal(signal.SIGALRM)  # the host's handler is back
        assert fired == [True]
        signal.setitimer(signal.ITIMER_REAL, 30.0)  # the host's own timer is left alone
        with StepAlarm(0.1):
            time.sleep(0.3)
        assert signal.getitimer(signal.ITIMER_REAL)[0] > 20
        signal.setitimer(signal.ITIMER_REAL, 0)
        stale = StepAlarm(0.1)
        stale.arm()  # left set by a step that raised: it fires outside any env call
        time.sleep(0.3)  # and raises nothing here
        assert not stale.armed and signal.getsignal(signal.SIGALRM) is not stale._expired
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous)

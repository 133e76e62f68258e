"""A user's env that misbehaves is named in one line (exit status 1), with the run's failure
recorded in summary.json, instead of a NaN TD loss later or a traceback from the collector."""

from __future__ import annotations

import json
import textwrap

import pytest
import torch
from tensordict import TensorDict

from tests.conftest import CONFIG_DIR, SMOKE_OVERRIDES
from trl_cartpole.cli.main import compose_config
from trl_cartpole.errors import TrainingFailed
from trl_cartpole.run.env_faults import check_finite_batch
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
    """
)


@pytest.mark.parametrize(
    ("env_class", "expected"),
    [
        ("NaNCartPole", r"returned a non-finite next\.observation \(nan\) in the batch"),
        ("InfiniteRewardCartPole", r"returned a non-finite next\.reward \(inf\)"),
        ("RaisingCartPole", r"raised RuntimeError in RaisingCartPole\.step\(\) at frame \d+: the"),
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
            f"run_dir={run_dir}",
            "logger.plots=false",
        ],
    )
    with pytest.raises(TrainingFailed, match=expected) as caught:
        train(cfg)
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

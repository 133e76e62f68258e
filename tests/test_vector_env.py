"""Training on several envs stepped together (``env.num_envs``): batches, buffer, episode stats."""

from __future__ import annotations

import json

import torch

from trl_cartpole.parts.env import make_env
from trl_cartpole.parts.replay import NStepTransform, extend_with_batch, make_replay_buffer
from trl_cartpole.run.from_config import transition_keys
from trl_cartpole.run.training import train

from .conftest import SMOKE_OVERRIDES


def _rollout(num_envs: int, steps: int):
    env = make_env("CartPole-v1", seed=3, num_envs=num_envs)
    rollout = env.rollout(steps, break_when_any_done=False).select(*transition_keys())
    env.close()
    return rollout  # [num_envs, steps]


def test_uniform_buffer_stores_every_env_step_once():
    rollout = _rollout(3, 20)  # [3, 20]
    buffer = make_replay_buffer(max_size=100, batch_size=8, n_steps=1)
    extend_with_batch(buffer, rollout)
    assert len(buffer) == 60
    stored = buffer.storage[:60]
    assert torch.equal(stored["observation"], rollout["observation"].reshape(60, 4))


def test_nstep_windows_never_cross_from_one_env_into_another():
    rollout = _rollout(3, 40)  # [3, 40]: windows of 3 are complete for 37 steps of each env
    buffer = make_replay_buffer(max_size=500, batch_size=8, n_steps=3, gamma=0.9)
    extend_with_batch(buffer, rollout)
    assert len(buffer) == 3 * 37
    stored = buffer.storage[: 3 * 37].reshape(3, 37)
    for env_index in range(3):  # each env's windows equal those of the env processed alone
        alone = NStepTransform(3, 0.9).inv(rollout[env_index])
        assert torch.allclose(stored[env_index]["next", "reward"], alone["next", "reward"])
        assert torch.equal(stored[env_index]["next", "observation"], alone["next", "observation"])


def test_training_on_four_envs_counts_frames_and_episodes(compose, tmp_path):
    overrides = [o for o in SMOKE_OVERRIDES if not o.startswith("collector.frames_per_batch")]
    cfg = compose(
        *overrides,
        "env.num_envs=4",
        "collector.frames_per_batch=8",
        f"run_dir={tmp_path}",
        "logger.plots=false",
        "logger.live_plot=false",
    )
    summary = train(cfg)
    assert summary["frames"] == 304  # whole batches of 8 frames: 38 batches
    lengths = [
        float(line.split(",")[1])
        for line in (tmp_path / "metrics/scalars/train/episode_length.csv").read_text().split()
    ]
    # Every finished episode is one env's: 4 envs share 304 frames, 76 steps each, so the
    # finished episodes' lengths add up to at most 304 and each is at most 76 steps long.
    assert summary["episodes"] == len(lengths) > 4
    assert sum(lengths) <= 304 and max(lengths) <= 76
    assert json.loads((tmp_path / "summary.json").read_text())["frames"] == 304

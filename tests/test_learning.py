"""The default config solves CartPole-v1 within a frame budget (no wall-clock assertion)."""

from __future__ import annotations

import pytest

from trl_cartpole.run.training import train

pytestmark = pytest.mark.slow  # trains until CartPole is solved

FRAME_BUDGET = 40_000


def test_default_config_solves_cartpole(compose, tmp_path):
    cfg = compose(
        f"collector.total_frames={FRAME_BUDGET}",
        f"run_dir={tmp_path}",
        "logger.progress_bar=false",
        "logger.plots=false",
        "seed=0",
    )
    summary = train(cfg)
    assert summary["solved"], summary
    assert summary["frames_to_solve"] <= FRAME_BUDGET
    # The greedy mean over 20 eval episodes reached 475; the best policy holds up on 100 more.
    assert summary["best_eval_return_mean"] >= 475.0
    assert summary["final_eval_return_mean"] >= 400.0

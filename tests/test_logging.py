"""Logging backends for real: CSV rows and TensorBoard events read back; the live plot."""

from __future__ import annotations

import re

import pytest
from torchrl.checkpoint import Checkpoint

from trl_cartpole.errors import ConfigError
from trl_cartpole.report.loggers import make_logger
from trl_cartpole.report.plotting import LearningCurves, LiveDurationPlot, live_plot_target
from trl_cartpole.run.training import train
from trl_cartpole.store.checkpoint import resume_config

from .conftest import SMOKE_OVERRIDES

TRAIN_SCALARS = {
    "train/episode_return",
    "train/episode_length",
    "train/td_loss",
    "train/grad_norm",
    "train/q_max_mean",
    "train/frames_per_second",
    "eval/return_mean",
    "eval/final_return_mean",
}


def test_csv_backend_writes_every_scalar_with_frame_steps(compose, tmp_path):
    train(compose(*SMOKE_OVERRIDES, f"run_dir={tmp_path}", "algo=prioritized"))
    scalars = tmp_path / "metrics" / "scalars"
    written = {str(p.relative_to(scalars).with_suffix("")) for p in scalars.rglob("*.csv")}
    assert written >= TRAIN_SCALARS | {"train/epsilon", "train/mean_importance_weight"}
    rows = (scalars / "eval" / "return_mean.csv").read_text().split()
    assert [int(row.split(",")[0]) for row in rows] == [152, 300]  # first batch past 150, the end
    weights = (scalars / "train" / "mean_importance_weight.csv").read_text().split()
    assert all(0 < float(row.split(",")[1]) <= 1 for row in weights)


def test_tensorboard_backend_events_read_back(compose, tmp_path):
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    train(compose(*SMOKE_OVERRIDES, f"run_dir={tmp_path}", "logger.backend=tensorboard"))
    events = list((tmp_path / "metrics").rglob("events.out.tfevents.*"))
    assert len(events) == 1
    accumulator = EventAccumulator(str(events[0].parent))
    accumulator.Reload()
    assert set(accumulator.Tags()["scalars"]) >= TRAIN_SCALARS | {"train/epsilon"}
    evals = accumulator.Scalars("eval/return_mean")
    assert [event.step for event in evals] == [152, 300]
    assert not (tmp_path / "metrics" / "scalars").exists()  # no CSV files with TensorBoard


@pytest.mark.slow  # a run resumed
def test_tensorboard_events_after_the_checkpoint_are_not_doubled_by_a_resume(compose, tmp_path):
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    overrides = [*SMOKE_OVERRIDES, f"run_dir={tmp_path}", "logger.backend=tensorboard"]
    train(compose(*overrides, "checkpoint.interval_frames=100", "checkpoint.keep_last=5"))
    periodic = sorted(
        (tmp_path / "checkpoints" / "periodic").iterdir(),
        key=lambda p: Checkpoint.manifest(p)["metadata"]["counters"]["frames"],
    )[0]  # before the evaluation at frame 152: the resumed run logs that one again
    resumed_at = Checkpoint.manifest(periodic)["metadata"]["counters"]["frames"]
    assert resumed_at < 152
    (tmp_path / "summary.json").unlink()
    train(resume_config(periodic, [f"run_dir={tmp_path}"]), resume=periodic)
    accumulator = EventAccumulator(str(tmp_path / "metrics"))  # every events file in it
    accumulator.Reload()
    assert [event.step for event in accumulator.Scalars("eval/return_mean")] == [152, 300]
    losses = [event.step for event in accumulator.Scalars("train/td_loss")]
    assert losses == sorted(set(losses))  # each logged once, in order


def test_wandb_without_the_package_is_a_clear_error(tmp_path):
    try:
        import wandb  # noqa: F401

        pytest.skip("wandb is installed")
    except ImportError:
        pass
    with pytest.raises(ConfigError, match=re.escape('-e ".[wandb]" -c constraints.txt')):
        make_logger("wandb", tmp_path)


def test_headless_live_plot_rewrites_the_png_at_each_evaluation(compose, tmp_path):
    assert live_plot_target() == "file"  # the test machine has no display
    plot = LiveDurationPlot(tmp_path / "durations.png")
    plot.update(LearningCurves([32, 64, 96], [10, 20, 30], [64], [12.5], 475.0))
    first = (tmp_path / "durations.png").stat().st_mtime_ns
    plot.update(LearningCurves(list(range(32, 3872, 32)), [10, 20, 30, 40] * 30, [], [], None))
    assert (tmp_path / "durations.png").stat().st_mtime_ns >= first
    assert not list(tmp_path.glob(".*.tmp"))  # written atomically


def test_live_plot_skips_redraws_closer_than_its_interval(tmp_path):
    now = [100.0]
    plot = LiveDurationPlot(tmp_path / "durations.png", min_seconds=5.0, clock=lambda: now[0])
    curves = LearningCurves([32, 64], [10, 20], [64], [12.5], 475.0)
    assert plot.update(curves)  # the first update always draws
    now[0] = 104.9
    assert not plot.update(curves)
    now[0] = 105.0
    assert plot.update(curves)
    assert (tmp_path / "durations.png").exists()
    assert not plot.flush()  # nothing skipped since the last redraw
    now[0] = 106.0
    assert not plot.update(
        LearningCurves([32, 64, 96], [10, 20, 30], [64, 96], [12.5, 40.0], 475.0)
    )
    (tmp_path / "durations.png").unlink()
    assert plot.flush()  # the skipped update is drawn at the end of the run
    assert (tmp_path / "durations.png").exists()
    assert not plot.flush()


def test_a_resumed_run_rewinds_its_own_wandb_run_to_the_checkpoint(tmp_path, monkeypatch):
    """W&B's counterpart of purge_step: the same W&B run, rewound with ``resume_from`` to the
    W&B step the checkpoint recorded.

    (W&B applies the rewind on its server, at upload or ``wandb sync``: not testable here, so
    this checks what the logger asks of W&B.)
    """
    import sys
    import types

    from trl_cartpole.report import loggers

    created = []
    monkeypatch.setitem(sys.modules, "wandb", types.ModuleType("wandb"))
    monkeypatch.setattr(loggers, "WandbLogger", lambda **kwargs: created.append(kwargs))
    run_dir, other_dir = tmp_path / "0-CartPole-v1-dqn-seed0", tmp_path / "sweep2"
    run_dir.mkdir(), other_dir.mkdir()
    make_logger("wandb", run_dir)
    make_logger("wandb", run_dir, resumed_at=4096, logger_step=57)
    make_logger("wandb", run_dir, resumed_at=4096)  # a checkpoint without the W&B step
    (other_dir / "0-CartPole-v1-dqn-seed0").mkdir()
    make_logger("wandb", other_dir / "0-CartPole-v1-dqn-seed0")  # same name, other sweep
    fresh, rewound, continued, other = created
    assert fresh["id"] == rewound["id"] == continued["id"] != other["id"]
    assert fresh["resume"] == "never" and "resume_from" not in fresh
    assert rewound["resume_from"] == f"{fresh['id']}?_step=57" and rewound["resume"] is None
    assert continued["resume"] == "allow" and "resume_from" not in continued
    assert fresh["settings"] == {"silent": True}  # no W&B banner on the console

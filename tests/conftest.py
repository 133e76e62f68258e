"""Shared fixtures: the repository paths and a tiny, fast training config."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest
import torch

from trl_cartpole.config.compose import compose_config

ROOT = Path(__file__).resolve().parent.parent
CONFIG_DIR = ROOT / "configs"
SCRIPTS = ROOT / "scripts"

# A few hundred frames: enough to fill the buffer, update, evaluate and checkpoint, on four
# envs (the default steps 16) so a batch of 4 frames is one step of each.
SMOKE_OVERRIDES = [
    "env.num_envs=4",
    "collector.total_frames=300",
    "collector.init_random_frames=64",
    "collector.frames_per_batch=4",
    "collector.updates_per_batch=2",
    "buffer.batch_size=32",
    "eval.interval_frames=150",
    "eval.episodes=3",
    "eval.final_episodes=4",
    "logger.progress_bar=false",
]

# summary.json keys that differ between two runs of one config: timings, throughput, paths,
# the node ids of a Ray run.
TIMING_KEYS = {
    "train_seconds",
    "wall_seconds",
    "seconds_to_solve",
    "collect_frames_per_second",
    "updates_per_second",
    "peak_rss_mb",
    "phase_seconds",
    "run_dir",
    "checkpoint",
    "ray_nodes",
}


@pytest.fixture(autouse=True)
def _single_thread():
    torch.set_num_threads(1)


@pytest.fixture(autouse=True, scope="session")
def _no_machine_wide_ray_cluster():
    """Hermetic: RAY_ADDRESS (Ray's machine-wide pointer to a cluster) never reaches a test."""
    saved = os.environ.pop("RAY_ADDRESS", None)
    yield
    if saved is not None:
        os.environ["RAY_ADDRESS"] = saved


@pytest.fixture
def compose():
    def _compose(*overrides: str):
        return compose_config(CONFIG_DIR, list(overrides))

    return _compose


@pytest.fixture
def python() -> str:
    return sys.executable


@pytest.fixture(scope="session")
def smoke_checkpoint(tmp_path_factory) -> Path:
    """The best-policy checkpoint of a 300-frame default run (trained once per session)."""
    from trl_cartpole.run.training import train

    run_dir = tmp_path_factory.mktemp("smoke-checkpoint")
    train(
        compose_config(CONFIG_DIR, [*SMOKE_OVERRIDES, f"run_dir={run_dir}", "logger.plots=false"])
    )
    return run_dir / "checkpoints" / "best"


def run_script_in_process(name: str, *args: str) -> subprocess.CompletedProcess:
    """``scripts/<name>`` run by this process: its exit status and what it printed.

    The same entry (``cli.run_script``) as the script, so bad input still ends in one line and exit
    status 2, without a new interpreter importing torch (seconds a test). Tests of what only a
    process shows (signals, a traceback at exit, the import cost) use :func:`run_script`.
    """
    import contextlib
    import io

    from trl_cartpole.cli.main import run_script as run_script_entry
    from trl_cartpole.report.console import set_scripts_dir

    stdout, stderr = io.StringIO(), io.StringIO()
    saved_cwd = Path.cwd()
    os.chdir(ROOT)  # the scripts print paths relative to where they run
    try:
        with contextlib.redirect_stdout(stdout), contextlib.redirect_stderr(stderr):
            code = run_script_entry(Path(name).stem, SCRIPTS / name, list(args))
    finally:
        os.chdir(saved_cwd)
        set_scripts_dir(None)
    return subprocess.CompletedProcess([name, *args], code, stdout.getvalue(), stderr.getvalue())


def run_script(
    name: str, *args: str, timeout: float = 120, **kwargs
) -> subprocess.CompletedProcess:
    """Run ``scripts/<name>`` with this interpreter, from the repository root, capturing text."""
    kwargs.setdefault("cwd", ROOT)  # the scripts print paths relative to where they run
    return subprocess.run(
        [sys.executable, str(SCRIPTS / name), *args],
        capture_output=True,
        text=True,
        timeout=timeout,
        **kwargs,
    )


def summary_of(frames, seconds, final):
    """The keys of a run's ``summary.json`` that comparisons read."""
    return {
        "solved": frames is not None,
        "frames_to_solve": frames,
        "seconds_to_solve": seconds,
        "final_eval_return_mean": final,
        "wall_seconds": 10.0,
    }

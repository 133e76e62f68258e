"""Exact resume under repeated SIGKILLs at random moments, some aimed inside a checkpoint write.

A run on a preemptible machine is killed without warning, again and again, and resumed each
time from its newest complete checkpoint. Whatever the moments, the resumed run must end with
exactly the uninterrupted run's evaluations: the frames and return of every evaluation, and
the frames to solve, on two worker processes too (whose envs, carriers and RNGs the checkpoint
reads from the workers). Each life of the run completes one checkpoint of its own first (so the
run moves on), then is killed: three kills at a random moment after it, three aimed (at least
two must land inside the write): the test watches the checkpoint folder and kills the run as
soon as a training state is being staged (``torchrl.checkpoint.Checkpoint`` writes into
``.<name>.stage-<uuid>`` and renames it into place), and checks the staged folder was left
half-written.
"""

from __future__ import annotations

import json
import os
import random
import signal
import subprocess
import time
from pathlib import Path

import pytest

from trl_cartpole.run.training import train

from .conftest import SCRIPTS

KILLS = 6  # three at random moments, three inside a checkpoint write
RUN = [
    "collector.total_frames=20000",
    "collector.init_random_frames=64",
    "buffer.batch_size=32",
    "eval.interval_frames=1000",
    "eval.episodes=3",
    "eval.final_episodes=4",
    "eval.stop_when_solved=false",
    "checkpoint.interval_frames=256",
    "checkpoint.keep_last=2",
    "logger.progress_bar=false",
    "logger.live_plot=false",
    "logger.plots=false",
    "seed=5",
]
# an Atari preset's short budget
ATARI_RUN = [
    "buffer.max_size=2000",
    "collector.total_frames=1500",
    "collector.init_random_frames=64",
    "eval.interval_frames=500",
    "eval.max_steps=300",
    "eval.candidates=1",
    "checkpoint.interval_frames=128",
]
VARIANTS = {
    "default": [],
    "prioritized": ["algo=prioritized"],
    "two-workers": ["collector.workers=2", "env.num_envs=16"],
    # Box2D's state is not plain data: the envs play their logged episodes again
    "lunarlander": ["env=lunarlander", "collector.total_frames=8000", "eval.max_steps=300"],
    # two Ray actors on a Ray instance each life starts (the kill takes its session with it)
    "ray": [
        "collector.workers=2",
        "env.num_envs=16",
        "collector.backend=ray",
        "collector.total_frames=8000",
    ],
    # (Acrobot and MountainCar store their state as CartPole does: test_checkpoint_safety.py
    # continues each exactly from its stored data)
    # an Atari game (the preset's one game, its frames stored once): ALE's state with its RNG
    "breakout": [*ATARI_RUN, "env=breakout"],
    # a game whose restored state often plays on otherwise unless its last action comes back
    # with it (ALE's state leaves out the action a sticky frame repeats)
    "boxing": [*ATARI_RUN, "env=boxing"],
    # drawn frames stacked by CatFrames, a share painted by Gymnasium, a CNN: a short budget
    "pixels": [
        "env=cartpole_pixels",
        "env.num_envs=2",
        "env.pixels_rendered_share=0.5",
        "buffer.max_size=5000",
        "collector.total_frames=3000",
        "collector.init_random_frames=64",
        "eval.max_steps=100",
    ],
}


def _overrides(variant: str) -> list[str]:
    """The run's overrides, the variant's replacing the shared ones of the same keys."""
    own = VARIANTS[variant]
    keys = {override.split("=", 1)[0] for override in own}
    return [o for o in RUN if o.split("=", 1)[0] not in keys] + own


def _start(python: str, args: list[str], log: Path) -> subprocess.Popen:
    """``scripts/train.py args`` in a session of its own (a kill takes its workers too), its
    output to ``log`` (a file: a pipe no one reads could fill and stall the run)."""
    with log.open("w") as output:
        return subprocess.Popen(
            [python, str(SCRIPTS / "train.py"), *args],
            stdout=output,
            stderr=subprocess.STDOUT,
            start_new_session=True,
        )


def _stages(run_dir: Path) -> set[str]:
    """The checkpoint folders being staged right now (their temporary names)."""
    folder = run_dir / "checkpoints" / "periodic"
    try:
        return {entry.name for entry in os.scandir(folder) if ".stage-" in entry.name}
    except FileNotFoundError:
        return set()


def _kill(proc: subprocess.Popen) -> None:
    """SIGKILL the run and every process of its session (its collector workers)."""
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait(timeout=60)


def _complete(run_dir: Path) -> set[Path]:
    """The complete periodic checkpoints (an ``integrity.json`` is their last file)."""
    return {path.parent for path in (run_dir / "checkpoints" / "periodic").glob("*/integrity.json")}


def _wait_for_a_new_checkpoint(proc: subprocess.Popen, run_dir: Path, timeout: float = 180):
    """Wait until this process has completed a checkpoint of its own (the run moved on)."""
    known = _complete(run_dir)
    deadline = time.monotonic() + timeout
    while proc.poll() is None and not (_complete(run_dir) - known):
        assert time.monotonic() < deadline, "no checkpoint was written"
        time.sleep(0.01)


def _kill_inside_a_write(proc: subprocess.Popen, run_dir: Path, timeout: float = 180) -> bool:
    """SIGKILL the run as soon as a new checkpoint is being staged; True if one was caught
    half-written (its staging folder is left behind), False if the run ended first."""
    before = _stages(run_dir)  # stagings an earlier kill left behind
    deadline = time.monotonic() + timeout
    while proc.poll() is None:
        staging = _stages(run_dir) - before
        if staging:
            _kill(proc)
            return bool(_stages(run_dir) & staging)
        assert time.monotonic() < deadline, "no checkpoint was written"
        time.sleep(0.0005)
    return False


@pytest.mark.slow  # about 7 training processes per variant
@pytest.mark.parametrize("variant", list(VARIANTS))
def test_random_sigkills_then_resumes_end_as_the_uninterrupted_run(
    compose, python, tmp_path, variant
):
    needs = {"ray": ["ray"], "breakout": ["ale_py", "cv2"], "boxing": ["ale_py", "cv2"]}
    for module in needs.get(variant, []):  # the distributed and atari extras
        pytest.importorskip(module)
    overrides = _overrides(variant)
    run_dir = tmp_path / "killed"
    rng = random.Random(f"kills-{variant}")
    inside_a_write = 0
    args = [*overrides, f"run_dir={run_dir}"]
    for kill in range(KILLS):
        log = tmp_path / f"life-{kill}.log"
        proc = _start(python, args, log)
        _wait_for_a_new_checkpoint(proc, run_dir)  # each life moves the run on
        if kill % 2:  # aimed: inside the next checkpoint write
            inside_a_write += _kill_inside_a_write(proc, run_dir)
        else:  # a random moment: training, an evaluation or a write
            time.sleep(rng.uniform(0.0, 2.5))
            if proc.poll() is None:
                _kill(proc)
        output = log.read_text()
        assert proc.returncode == -signal.SIGKILL, f"exit {proc.returncode}: {output[-2000:]}"
        args = [f"resume={run_dir}"]  # from the newest complete checkpoint
    assert inside_a_write >= 2, f"only {inside_a_write} kills landed inside a write"

    resumed = subprocess.run(
        [python, str(SCRIPTS / "train.py"), *args], capture_output=True, text=True, timeout=600
    )
    assert resumed.returncode == 0, resumed.stderr[-2000:]
    got = json.loads((run_dir / "summary.json").read_text())
    expected = train(compose(*overrides, f"run_dir={tmp_path / 'whole'}"))
    assert got["eval_curve"]["frames"] == expected["eval_curve"]["frames"]
    assert got["eval_curve"]["returns"] == expected["eval_curve"]["returns"]
    assert got["frames_to_solve"] == expected["frames_to_solve"]
    total = int(next(o for o in overrides if o.startswith("collector.total_frames=")).split("=")[1])
    assert got["frames"] == expected["frames"] == total

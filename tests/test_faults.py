"""Fault injection: interrupts, exact resume, killed writes, numerical faults, bad input.

Each case is listed with what it proves in docs/reliability.md.
"""

from __future__ import annotations

import contextlib
import io
import json
import os
import re
import shutil
import signal
import subprocess
import time
import warnings
from importlib.util import find_spec
from pathlib import Path

import pytest
import torch
from torchrl.checkpoint import Checkpoint, CheckpointRotation

from trl_cartpole.errors import ConfigError, TrainingFailed
from trl_cartpole.run.training import train
from trl_cartpole.store.checkpoint import find_resume_checkpoint, resume_config

from .conftest import SCRIPTS, SMOKE_OVERRIDES, TIMING_KEYS, run_script, run_script_in_process

# 600 frames, an evaluation every 150, a training state every 200 (all of them kept).
RESUMABLE = [
    *SMOKE_OVERRIDES,
    "collector.total_frames=600",
    "checkpoint.interval_frames=200",
    "checkpoint.keep_last=10",
    "seed=2",
]


# Breakout's short resumable run, and the marks of a slow test that needs the atari extra
BREAKOUT_RESUMED = [
    "env=breakout",
    "buffer.max_size=1000",
    "eval.max_steps=300",  # an untrained policy's game can last its 27 000 steps
    "eval.candidates=1",
    "logger.plots=false",
]
ATARI_SLOW = [
    pytest.mark.slow,
    pytest.mark.skipif(find_spec("ale_py") is None, reason="the atari extra"),
]


def _comparable(summary: dict) -> dict:
    summary = {key: value for key, value in summary.items() if key not in TIMING_KEYS}
    measured = ("seconds", "rss_mb")  # timings and memory differ between two runs
    summary["eval_curve"] = {k: v for k, v in summary["eval_curve"].items() if k not in measured}
    return summary


def _weights(checkpoint: Path) -> dict[str, torch.Tensor]:
    from trl_cartpole.run.from_config import build_actor, build_env
    from trl_cartpole.store.checkpoint import (
        load_policy,
        read_checkpoint_config,
        read_observation_norm,
    )

    cfg = read_checkpoint_config(checkpoint)
    # the run's own kind of env: its state (with its statistics), or its pixels
    env = build_env(cfg, seed=0, observation_norm=read_observation_norm(checkpoint))
    actor = build_actor(cfg, env, "cpu")
    env.close()
    load_policy(checkpoint, actor)
    return actor.state_dict()


def _periodic_at(run_dir: Path, frames: int) -> Path:
    for path in CheckpointRotation(
        run_dir / "checkpoints" / "periodic", keep_last=10
    ).checkpoints():
        if Checkpoint.manifest(path)["metadata"]["counters"]["frames"] == frames:
            return path
    raise AssertionError(f"no periodic checkpoint at frame {frames}")


@pytest.mark.parametrize(
    "overrides",
    [
        ["algo=dqn"],
        pytest.param(["algo=rainbow"], marks=pytest.mark.slow),  # every Rainbow part: 17 s
        # The resumed run reads the observation statistics back from the checkpoint.
        pytest.param(
            ["env.normalize_observations=true", "env.normalization_frames=300"],
            marks=pytest.mark.slow,
        ),
        # The learning rate's taper goes on from the frames, its value read back with Adam's.
        pytest.param(["optim.lr_end=0.0002", "optim.lr_decay_frames=500"], marks=pytest.mark.slow),
        # The pixel preset: frames drawn from the state, a share painted by Gymnasium, stacked
        # by CatFrames; the stacks are stored with the envs' state.
        # LunarLander's Box2D state is not plain data: its envs play their logged episodes again
        pytest.param(["env=lunarlander", "logger.plots=false"], marks=pytest.mark.slow),
        # and in two worker processes: each worker's logged episodes, through its pipe
        pytest.param(
            ["env=lunarlander", "logger.plots=false", "collector.workers=2", "env.num_envs=2"],
            marks=pytest.mark.slow,
        ),
        pytest.param(
            [
                "env=cartpole_pixels",
                "env.num_envs=2",
                "env.pixels_rendered_share=0.5",
                "buffer.max_size=500",
                "buffer.batch_size=16",
                "eval.max_steps=50",
            ],
            marks=pytest.mark.slow,
        ),
        # and in two worker processes: each worker's state and stacks, through its pipe
        pytest.param(
            [
                "env=cartpole_pixels",
                "env.num_envs=2",
                "collector.workers=2",
                "env.pixels_rendered_share=0.5",
                "buffer.max_size=500",
                "buffer.batch_size=16",
                "eval.max_steps=50",
            ],
            marks=pytest.mark.slow,
        ),
        # An Atari game: ALE's cloneState (the emulator and its RNG), the NOOP starts' RNG and
        # the preprocessing's stacks and lives, each of 4 games, the frames stored once
        pytest.param([*BREAKOUT_RESUMED], marks=ATARI_SLOW),
        # the preset's one game, whose collector's own state is saved with it
        pytest.param([*BREAKOUT_RESUMED, "env.num_envs=1"], marks=ATARI_SLOW),
        # and in two worker processes, a batch of 2 games each
        pytest.param(
            [*BREAKOUT_RESUMED, "collector.workers=2", "env.num_envs=2"], marks=ATARI_SLOW
        ),
        # two Ray actors (a Ray instance started here): each actor's envs, carrier and RNG
        # through RayCollector's own remote calls, between two synchronous batches
        pytest.param(
            ["collector.workers=2", "env.num_envs=2", "collector.backend=ray"],
            marks=[
                pytest.mark.slow,
                pytest.mark.skipif(find_spec("ray") is None, reason="the distributed extra"),
            ],
        ),
    ],
    ids=[
        "dqn",
        "rainbow",
        "observation-norm",
        "lr-taper",
        "lunarlander",
        "lunarlander-workers",
        "pixels",
        "pixels-workers",
        "breakout",
        "breakout-one-game",
        "breakout-workers",
        "ray",
    ],
)
def test_resumed_run_equals_the_uninterrupted_one(compose, tmp_path, overrides):
    whole = tmp_path / "whole"
    expected = train(compose(*RESUMABLE, *overrides, f"run_dir={whole}"))
    resumed_dir = tmp_path / "resumed"
    shutil.copytree(whole, resumed_dir)
    (resumed_dir / "summary.json").unlink()
    checkpoint = _periodic_at(resumed_dir, 400)
    cfg = resume_config(checkpoint, [f"run_dir={resumed_dir}"])
    resumed = train(cfg, resume=checkpoint)
    assert _comparable(resumed) == _comparable(expected)
    for name in ("best", "last"):
        a, b = (_weights(d / "checkpoints" / name) for d in (whole, resumed_dir))
        assert a.keys() == b.keys() and all(torch.equal(a[k], b[k]) for k in a)
    td_loss = "metrics/scalars/train/td_loss.csv"
    assert (whole / td_loss).read_text() == (resumed_dir / td_loss).read_text()


@pytest.mark.parametrize(
    ("stopped_after", "overrides"),
    [
        ("last", []),
        # the end-of-run state removed: the periodic one at frame 600 predates the last
        # evaluation (evaluations every 250 frames: at 250, 500, then 600 after the loop)
        ("periodic", ["eval.interval_frames=250"]),
        # a solved run stops early: its end-of-run state has fewer frames than total_frames
        ("last", ["eval.stop_when_solved=true", "eval.solve_threshold=10"]),
        # workers: a collector whose state is not saved, rebuilt with no frames left to collect
        pytest.param("last", ["collector.workers=2", "env.num_envs=2"], marks=pytest.mark.slow),
    ],
    ids=["last", "periodic", "solved-early", "workers"],
)
def test_a_run_stopped_in_its_ending_finishes_on_resume(
    compose, tmp_path, stopped_after, overrides
):
    # Killed after its last training state but before summary.json: a resume with no override
    # goes straight to the ending, which equals the uninterrupted run's.
    whole = tmp_path / "whole"
    expected = train(compose(*RESUMABLE, *overrides, f"run_dir={whole}"))
    frames = expected["frames"]
    assert (frames < 600) == ("eval.stop_when_solved=true" in overrides)
    with pytest.raises(ConfigError, match="is a finished run"):  # its summary is written
        resume_config(find_resume_checkpoint(whole))
    stopped = tmp_path / "stopped"
    shutil.copytree(whole, stopped)
    (stopped / "summary.json").unlink()
    checkpoint = stopped / "checkpoints" / "last"
    if stopped_after == "periodic":
        shutil.rmtree(checkpoint)
        checkpoint = find_resume_checkpoint(stopped)
    assert Checkpoint.manifest(checkpoint)["metadata"]["counters"]["frames"] == frames
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        resumed = train(resume_config(checkpoint, [f"run_dir={stopped}"]), resume=checkpoint)
    # the same evaluations, best policy and final games, and no frame collected again
    assert _comparable(resumed) == _comparable(expected)
    # saved again before a write: TorchRL's "last_cursor is None" once warned here
    assert not [w for w in caught if "last_cursor" in str(w.message)]
    final = "metrics/scalars/eval/final_return_mean.csv"  # logged once, not twice
    assert (whole / final).read_text() == (stopped / final).read_text()
    with pytest.raises(ConfigError, match="leaves nothing to train"):  # a larger one trains on
        resume_config(checkpoint, [f"collector.total_frames={frames - 1}"])


def test_a_run_ends_at_its_training_seconds_and_a_resume_keeps_the_limit(compose, tmp_path):
    # collector.max_train_seconds ends the loop as its last frame would: the last evaluation,
    # the ending. Stopped in that ending, a resume under the same limits goes straight to it; a
    # larger limit trains on.
    budget = [o for o in RESUMABLE if not o.startswith("collector.total_frames")]
    limited = [*budget, "collector.total_frames=1000000", "collector.max_train_seconds=1.5"]
    whole = tmp_path / "whole"
    expected = train(compose(*limited, f"run_dir={whole}"))
    assert 0 < expected["frames"] < 1000000 and expected["train_seconds"] >= 1.5
    assert expected["eval_curve"]["frames"][-1] == expected["frames"]  # ended on an evaluation
    stopped = tmp_path / "stopped"
    shutil.copytree(whole, stopped)
    (stopped / "summary.json").unlink()
    last = stopped / "checkpoints" / "last"
    resumed = train(resume_config(last, [f"run_dir={stopped}"]), resume=last)
    assert _comparable(resumed) == _comparable(expected)
    more = train(
        resume_config(last, [f"run_dir={stopped}", "collector.max_train_seconds=3"]), resume=last
    )
    assert more["frames"] > expected["frames"] and more["train_seconds"] >= 3


@pytest.mark.slow  # a run resumed
def test_a_resumed_run_reads_its_observation_statistics_back(compose, tmp_path):
    # Statistics written into the checkpoint's manifest (and its integrity record) that no
    # estimate would give: the resumed run must build its envs with exactly those. (The
    # training env's ObservationNorm is also restored with the collector's state; the
    # evaluation env's comes from the manifest alone.)
    from torchrl.envs import ObservationNorm

    from trl_cartpole.run.build import build_components
    from trl_cartpole.store.checkpoint import write_integrity

    overrides = ["env.normalize_observations=true", "env.normalization_frames=300"]
    train(compose(*RESUMABLE, *overrides, f"run_dir={tmp_path}"))
    checkpoint = _periodic_at(tmp_path, 400)
    manifest = json.loads((checkpoint / "manifest.json").read_text())
    stored = manifest["metadata"]["observation_norm"]
    planted = {"loc": [v + 1.0 for v in stored["loc"]], "scale": [2.0] * len(stored["scale"])}
    manifest["metadata"]["observation_norm"] = planted
    (checkpoint / "manifest.json").write_text(json.dumps(manifest))
    write_integrity(checkpoint)
    cfg = resume_config(checkpoint, [f"run_dir={tmp_path}"])
    with build_components(cfg, resume=checkpoint) as components:
        (norm,) = [t for t in components.eval_env.transform if isinstance(t, ObservationNorm)]
        assert torch.allclose(norm.loc, torch.tensor(planted["loc"]))
        assert torch.allclose(norm.scale, torch.tensor(planted["scale"]))
        assert components.observation_norm == planted


@pytest.mark.slow  # a run resumed
def test_a_state_saved_before_the_nstep_buffer_holds_anything_resumes(compose, tmp_path):
    # 2 steps of each of 4 envs: a 3-step buffer has no complete window yet, so it is empty.
    overrides = [o for o in SMOKE_OVERRIDES if not o.startswith("collector.total_frames")]
    train(compose(*overrides, "collector.total_frames=8", f"run_dir={tmp_path}"))
    last = tmp_path / "checkpoints" / "last"
    assert "replay_buffer" not in Checkpoint.manifest(last)["components"]
    assert "policy" in Checkpoint.manifest(last)["components"]
    resumed = train(resume_config(last, ["collector.total_frames=100"]), resume=last)
    assert resumed["frames"] == 100 and resumed["updates"] > 0


# --- interrupts: SIGINT / SIGTERM, a second Ctrl-C, SIGKILL --------------------------------

LONG = [
    "collector.total_frames=4000",
    "collector.init_random_frames=64",
    "buffer.batch_size=32",
    "eval.interval_frames=1000",
    "eval.episodes=3",
    "eval.final_episodes=4",
    "checkpoint.interval_frames=0",
    "logger.progress_bar=false",
    "logger.live_plot=false",
    "seed=3",
]


def _resume(python: str, run_dir: Path) -> subprocess.CompletedProcess:
    """``scripts/train.py resume=run_dir`` in a new process, to its end."""
    return subprocess.run(
        [python, str(SCRIPTS / "train.py"), f"resume={run_dir}"],
        capture_output=True,
        text=True,
        timeout=300,
    )


def _start(python: str, run_dir: Path, *overrides: str) -> subprocess.Popen:
    return subprocess.Popen(
        [python, str(SCRIPTS / "train.py"), *overrides, f"run_dir={run_dir}"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )


def _wait_until_training(run_dir: Path, proc: subprocess.Popen, timeout: float = 120) -> None:
    """Wait for the first finished episode (its CSV row) of the run in ``proc``."""
    marker = run_dir / "metrics" / "scalars" / "train" / "episode_return.csv"
    deadline = time.monotonic() + timeout
    while not (marker.is_file() and marker.stat().st_size > 0):
        assert proc.poll() is None, proc.communicate()
        assert time.monotonic() < deadline, "training did not start"
        time.sleep(0.05)


@pytest.mark.slow  # a real signal to a training subprocess, four times
@pytest.mark.parametrize(
    ("signum", "code"),
    [(signal.SIGINT, 130), (signal.SIGTERM, 143), (signal.SIGHUP, 129), (signal.SIGUSR1, 138)],
)
def test_signal_checkpoints_and_the_resumed_run_equals_the_uninterrupted_one(
    compose, python, tmp_path, signum, code
):
    run_dir = tmp_path / "interrupted"
    proc = _start(python, run_dir, *LONG)
    _wait_until_training(run_dir, proc)
    time.sleep(0.5)
    proc.send_signal(signum)
    _, stderr = proc.communicate(timeout=120)
    assert proc.returncode == code, stderr[-2000:]
    lines = stderr.strip().splitlines()
    # the command names the interpreter that ran (here .venv/bin/python or python)
    assert re.search(rf"resume with: \S*python\S* scripts/train.py resume={run_dir}$", lines[-4])
    assert lines[-3] == "next:"  # the policy so far, evaluated and rendered
    for line, script in zip(lines[-2:], ("evaluate.py", "render.py"), strict=True):
        assert f"scripts/{script} checkpoint=" in line
        assert Path(line.split("checkpoint=")[1].split()[0]).is_dir()
    assert "Traceback" not in stderr
    assert not (run_dir / "summary.json").exists()  # the run is not over

    resumed = _resume(python, run_dir)
    assert resumed.returncode == 0, resumed.stderr[-2000:]
    expected = train(compose(*LONG, f"run_dir={tmp_path / 'whole'}"))
    got = json.loads((run_dir / "summary.json").read_text())
    assert _comparable(got) == _comparable(expected)
    a, b = (_weights(d / "checkpoints" / "last") for d in (run_dir, tmp_path / "whole"))
    assert all(torch.equal(a[k], b[k]) for k in a)


@pytest.mark.slow  # a signal to a training subprocess
def test_ctrl_c_saves_after_the_reader_of_a_tee_pipeline_died(python, tmp_path):
    # train.py ... 2>&1 | tee log, where tee is gone before Ctrl-C: every later write to the
    # pipe fails (EPIPE), and the save and its message must not be stopped by it.
    run_dir = tmp_path / "run"
    overrides = [o for o in LONG if not o.startswith("logger.progress_bar")]  # a line per eval
    proc = subprocess.Popen(
        [python, str(SCRIPTS / "train.py"), *overrides, f"run_dir={run_dir}"],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
    )
    tee = subprocess.Popen(["tee", str(tmp_path / "log")], stdin=proc.stdout)
    proc.stdout.close()  # only tee reads the pipe
    _wait_until_training(run_dir, proc)
    tee.kill()
    tee.wait()
    evaluations = run_dir / "metrics" / "scalars" / "eval" / "return_mean.csv"
    deadline = time.monotonic() + 120
    while not evaluations.is_file():  # an evaluation after tee died: its line hit the dead pipe
        assert proc.poll() is None and time.monotonic() < deadline
        time.sleep(0.05)
    time.sleep(0.3)
    proc.send_signal(signal.SIGINT)
    assert proc.wait(timeout=120) == 130
    checkpoint = find_resume_checkpoint(run_dir)
    frames = Checkpoint.manifest(checkpoint)["metadata"]["counters"]["frames"]
    assert frames >= 1000 and not (run_dir / "summary.json").exists()
    resumed = run_script("train.py", f"resume={run_dir}", timeout=300)
    assert resumed.returncode == 0, resumed.stderr[-2000:]
    assert json.loads((run_dir / "summary.json").read_text())["frames"] == 4000


@pytest.mark.slow  # two training subprocesses and a SIGKILL
def test_one_writer_per_run_directory_and_a_killed_one_blocks_nothing(python, tmp_path):
    run_dir = tmp_path / "run"
    endless = [o for o in LONG if not o.startswith(("collector.total_frames", "checkpoint."))]
    endless += ["collector.total_frames=1000000", "checkpoint.interval_frames=500"]
    proc = _start(python, run_dir, *endless, "eval.stop_when_solved=false")
    _wait_until_training(run_dir, proc)
    try:
        for args in ([f"run_dir={run_dir}", *SMOKE_OVERRIDES], [f"resume={run_dir}"]):
            second = run_script("train.py", *args)
            lines = [line for line in second.stderr.splitlines() if line.startswith("error:")]
            assert second.returncode == 2 and len(lines) == 1, second.stderr[-1500:]
            assert f"is being written by process {proc.pid} on " in lines[0]
    finally:
        proc.kill()  # SIGKILL: no chance to release anything itself
        proc.wait()
    after = run_script("train.py", f"run_dir={run_dir}", *SMOKE_OVERRIDES)
    assert after.returncode == 0, after.stderr[-1500:]
    assert f"process {os.getpid()}" not in (run_dir / ".lock").read_text()  # the new run's


@pytest.mark.slow  # a signal to a training subprocess
def test_second_ctrl_c_exits_at_once_and_corrupts_nothing(python, tmp_path):
    run_dir = tmp_path / "run"
    proc = _start(python, run_dir, *LONG, "checkpoint.interval_frames=100")
    _wait_until_training(run_dir, proc)
    time.sleep(0.3)
    proc.send_signal(signal.SIGINT)
    said = proc.stderr.readline()
    while said and "saving a checkpoint" not in said:  # the first signal was handled
        said = proc.stderr.readline()
    proc.send_signal(signal.SIGINT)
    _, stderr = proc.communicate(timeout=60)
    # ended by the signal's default action (a shell reports 130), no traceback
    assert proc.returncode == -signal.SIGINT and "Traceback" not in stderr, stderr[-3000:]
    checkpoint = find_resume_checkpoint(run_dir)  # the newest complete one loads
    resume_config(checkpoint)
    Checkpoint.manifest(checkpoint)


# A process that gets a stop signal, then spends minutes inside one C call on one thread (a
# matrix power of 2**40 on 3000x3000: 40 products of 54 GFLOP each), where no Python handler
# can run.
_BUSY_IN_C = """
import contextlib, sys, time, torch
from trl_cartpole.run import signals
torch.set_num_threads(1)
command_line = sys.argv[1] == "command-line"
with signals.second_signal_ends_process() if command_line else contextlib.nullcontext(), \\
        signals.StopRequest() as stop:
    print("ready", flush=True)
    while not stop.requested:
        time.sleep(0.01)
    print("busy", flush=True)
    try:
        torch.linalg.matrix_power(torch.rand(3000, 3000), 2**40)
    except KeyboardInterrupt:
        print("KeyboardInterrupt", flush=True)
        raise SystemExit(130)
    print("finished", flush=True)
"""


@pytest.mark.parametrize("caller", ["command-line", "python"])
def test_a_second_stop_signal_ends_a_command_line_process_inside_a_long_c_call(python, caller):
    proc = subprocess.Popen(
        [python, "-c", _BUSY_IN_C, caller],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        assert proc.stdout.readline() == "ready\n", proc.stderr.read()
        proc.send_signal(signal.SIGINT)  # the first: a request the loop would honour
        assert proc.stdout.readline() == "busy\n"
        time.sleep(0.5)  # inside the C call
        proc.send_signal(signal.SIGINT)
        if caller == "command-line":  # the OS's default action: at once, mid-call
            assert proc.wait(timeout=5) == -signal.SIGINT
            assert proc.stdout.read() == ""
        else:  # a notebook's kernel survives: KeyboardInterrupt once the call returns
            time.sleep(1.0)
            assert proc.poll() is None
    finally:
        proc.kill()
        proc.communicate()


@pytest.mark.slow  # SIGKILL mid-run, then a resume
def test_sigkill_mid_run_leaves_the_previous_checkpoint_loadable(python, tmp_path):
    run_dir = tmp_path / "run"
    for delay in (0.0, 0.37, 0.71):  # several moments, to land inside a write
        shutil.rmtree(run_dir, ignore_errors=True)
        proc = _start(
            python,
            run_dir,
            *LONG,
            "collector.total_frames=50000",
            "checkpoint.interval_frames=40",
            "env.num_envs=16",
            "collector.frames_per_batch=16",  # so that + 48 frames below is 3 whole batches
        )
        periodic = run_dir / "checkpoints" / "periodic"
        _wait_until_training(run_dir, proc)
        while not list(periodic.glob("*/integrity.json")):  # a first complete checkpoint
            assert proc.poll() is None, proc.communicate()
            time.sleep(0.02)
        time.sleep(delay)
        proc.kill()
        proc.communicate()
        checkpoint = find_resume_checkpoint(run_dir)
        frames = Checkpoint.manifest(checkpoint)["metadata"]["counters"]["frames"]
        resumed = subprocess.run(
            [
                python,
                str(SCRIPTS / "train.py"),
                f"resume={run_dir}",
                f"collector.total_frames={frames + 48}",
                "checkpoint.interval_frames=0",
            ],
            capture_output=True,
            text=True,
            timeout=300,
        )
        assert resumed.returncode == 0, resumed.stderr[-2000:]
        assert json.loads((run_dir / "summary.json").read_text())["frames"] == frames + 48


# --- numerical faults ---------------------------------------------------------------------


@pytest.mark.parametrize("buffer", ["uniform", "prioritized"])
def test_non_finite_loss_stops_with_the_update_named_and_keeps_the_last_good_checkpoint(
    compose, tmp_path, buffer
):
    from trl_cartpole.run.build import build_components

    def build_a_learner_that_fails_at_update_37(cfg, resume=None):
        components = build_components(cfg, resume)
        update, calls = components.learner.update, {"n": 0}
        first_weight = components.learner.optimizer.param_groups[0]["params"][0]

        def update_with_nan_weights(batch):  # a real divergence: loss and td_error NaN
            calls["n"] += 1
            if calls["n"] == 37:
                with torch.no_grad():
                    first_weight.fill_(float("nan"))
            return update(batch)

        components.learner.update = update_with_nan_weights
        return components

    run_dir = tmp_path / "run"
    overrides = [*SMOKE_OVERRIDES, "checkpoint.interval_frames=80", f"run_dir={run_dir}"]
    if buffer == "prioritized":  # the NaN must not reach the priorities the next draw reads
        overrides.append("buffer.prioritized=true")
    with pytest.raises(TrainingFailed, match=r"TD loss is nan at update 37 \(frame \d+\)"):
        train(compose(*overrides), build=build_a_learner_that_fails_at_update_37)
    summary = json.loads((run_dir / "summary.json").read_text())
    assert summary["failed"] is True and "update 37" in summary["failure"]
    assert summary["updates"] == 37  # the second update of that batch is not counted
    assert not (run_dir / "checkpoints" / "last").exists()  # no state with a NaN in it
    good = find_resume_checkpoint(run_dir)
    assert Checkpoint.manifest(good)["metadata"]["counters"]["updates"] < 37


# --- bad input: one line, exit 2, nothing trained ------------------------------------------


@pytest.fixture(scope="module")
def finished_run(tmp_path_factory) -> Path:
    from trl_cartpole.config.compose import compose_config

    from .conftest import CONFIG_DIR

    run_dir = tmp_path_factory.mktemp("finished") / "run"
    train(compose_config(CONFIG_DIR, [*RESUMABLE, f"run_dir={run_dir}"]))
    return run_dir


def _damaged_copy(run_dir: Path, target: Path, how: str) -> Path:
    shutil.copytree(run_dir, target)
    checkpoint = find_resume_checkpoint(target)
    if how == "truncated":
        files = [*checkpoint.rglob("*.memmap"), *checkpoint.rglob("*.bin")]  # the buffer: .bin
        biggest = max(files, key=lambda p: p.stat().st_size)
        biggest.write_bytes(biggest.read_bytes()[: biggest.stat().st_size // 2])
    elif how == "corrupt manifest":
        (checkpoint / "manifest.json").write_text("{ not json")
    elif how == "missing file":
        next(checkpoint.rglob("state.json")).unlink()
    return target


BAD_INPUTS = [
    ("unknown key", ["loss.gama=0.5"], "loss.gama is not a setting"),
    ("unknown group option", ["algo=nosuch"], "algo='nosuch' is not a preset"),
    ("wrong type", ["buffer.batch_size=big"], "buffer.batch_size='big' is not an integer"),
    ("impossible value", ["loss.gamma=1.5"], "loss.gamma=1.5 must lie in (0, 1]"),
    ("unknown env id", ["env.id=Nope-v0"], "is not a registered Gymnasium env"),
    ("continuous actions", ["env.id=Pendulum-v1"], "discrete"),
    ("discrete states, 32 envs", ["env.id=FrozenLake-v1"], "has a discrete observation"),
    ("tuple observation", ["env.id=Blackjack-v1"], "has observation entries"),
    pytest.param(
        "no cuda",
        ["device=cuda"],
        "has no usable CUDA GPU",
        marks=pytest.mark.skipif(torch.cuda.is_available(), reason="this machine has CUDA"),
    ),
    ("unwritable run dir", ["run_dir=/proc/trl_cartpole"], "is not writable"),
    ("a buffer beyond memory", ["buffer.max_size=1000000000000"], "lower buffer.max_size"),
    # 4 x 2**20 + 2**20, 2**40 + 2**20, 2 x 2**20 + 2 weights and biases
    (
        "networks beyond memory",
        ["network.num_cells=[1048576,1048576]"],
        "(1099520016386 parameters",
    ),
    ("a negative eval seed", ["eval.seed_offset=-1000001"], "eval.seed_offset=-1000001 must be"),
    # found by the fuzz test once buffer.storage was a field: Gymnasium's TimeLimit traceback
    ("episodes of no step", ["env.max_episode_steps=0"], "env.max_episode_steps=0 must be >= 1"),
    (
        "a step deadline beyond any timer",
        ["env.step_timeout=9223376706.0"],
        "env.step_timeout=9223376706.0 must be > 0 and at most 604800 seconds",
    ),
    ("a step deadline of no time", ["env.step_timeout=0"], "env.step_timeout=0.0 must be > 0"),
    ("no time to train", ["collector.max_train_seconds=0"], "max_train_seconds=0.0 must be > 0"),
    ("an AdamW without a floor", ["optim.eps=0"], "optim.eps=0.0 must be > 0 (AdamW's: 1e-08)"),
    ("a taper to nothing", ["optim.lr_end=0"], "optim.lr_end=0.0 must be > 0 (null: no taper)"),
    (
        "a taper a compiled update cannot follow",
        ["optim.lr_end=0.0001", "compile=true"],
        "holds fixed: pass compile=false, or optim.lr_end=null",
    ),
    ("a seed beyond 64 bits", ["seed=1180591620717411303424"], "integer settings stop at 2**62"),
    ("envs by the billion", ["eval.final_episodes=1000000000"], "at most 4096"),
    ("missing checkpoint", ["resume=/nonexistent/run"], "does not exist"),
]


@pytest.mark.parametrize(("case", "args", "message"), BAD_INPUTS)
def test_bad_training_input_is_one_line_and_exit_2(tmp_path, case, args, message):
    run_dir = tmp_path / "run"
    proc = run_script_in_process("train.py", f"run_dir={run_dir}", *args)
    lines = [line for line in proc.stderr.splitlines() if line.startswith("error:")]
    assert proc.returncode == 2 and len(lines) == 1 and message in lines[0], proc.stderr[-1500:]
    assert "Traceback" not in proc.stderr
    assert not run_dir.exists()  # nothing written


@pytest.mark.parametrize(
    ("how", "message"),
    [
        ("truncated", "is damaged"),
        ("corrupt manifest", "is damaged: manifest.json"),
        ("missing file", "is damaged"),
    ],
)
def test_damaged_checkpoint_is_refused_in_one_line(tmp_path, finished_run, how, message):
    damaged = _damaged_copy(finished_run, tmp_path / "damaged", how)
    before = sorted(p.relative_to(damaged) for p in damaged.rglob("*"))
    proc = run_script_in_process("train.py", f"resume={damaged}")
    lines = [line for line in proc.stderr.splitlines() if line.startswith("error:")]
    assert proc.returncode == 2 and len(lines) == 1 and message in lines[0], proc.stderr[-1500:]
    assert "Traceback" not in proc.stderr
    assert sorted(p.relative_to(damaged) for p in damaged.rglob("*")) == before  # untouched


@pytest.mark.parametrize("found", [5, 7])  # an earlier version's state, a later one's
def test_a_training_state_of_another_format_is_refused_naming_both(tmp_path, finished_run, found):
    from .test_checkpoint_safety import _rewrite_integrity

    other = tmp_path / "other"
    shutil.copytree(finished_run, other)
    for checkpoint in (other / "checkpoints").rglob("manifest.json"):
        manifest = json.loads(checkpoint.read_text())
        if manifest["metadata"]["kind"] == "training_state":
            manifest["metadata"]["format"] = found
            checkpoint.write_text(json.dumps(manifest))
            _rewrite_integrity(checkpoint.parent)
    proc = run_script_in_process("train.py", f"resume={other}", "collector.total_frames=900")
    lines = [line for line in proc.stderr.splitlines() if line.startswith("error:")]
    expected = f"is a training state of format {found}, and this version reads formats 6"
    assert proc.returncode == 2 and len(lines) == 1 and expected in lines[0], proc.stderr


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["env.id=Acrobot-v1"], "env.id cannot change"),
        (["network.num_cells=[64]"], "network.num_cells cannot change"),
        (["loss.gama=1"], "Key 'gama' not in"),
        (["logger.plots=512"], "logger.plots=512 is not a switch value"),
        ([], "is a finished run"),  # its summary.json is written
    ],
)
def test_resume_refuses_an_incompatible_config(finished_run, args, message):
    proc = run_script_in_process("train.py", f"resume={finished_run}", *args)
    assert proc.returncode == 2 and message in proc.stderr and "Traceback" not in proc.stderr


@pytest.mark.parametrize("script", ["evaluate.py", "render.py", "export.py"])
def test_a_directory_without_checkpoints_is_one_line_naming_what_to_pass(tmp_path, script):
    output = tmp_path / ("policy.pt2" if script == "export.py" else "out.gif")
    proc = run_script_in_process(script, f"checkpoint={tmp_path}", f"output={output}")
    lines = [line for line in proc.stderr.splitlines() if line.startswith("error:")]
    assert proc.returncode == 2 and len(lines) == 1, proc.stderr
    assert "is neither a checkpoint nor a run directory" in lines[0]
    assert "Traceback" not in proc.stderr and not output.exists()


def test_policy_checkpoint_cannot_be_resumed_and_a_foreign_one_cannot_be_evaluated(
    tmp_path, finished_run
):
    best = finished_run / "checkpoints" / "best"
    proc = run_script_in_process("train.py", f"resume={best}")
    assert proc.returncode == 2 and "without training state" in proc.stderr
    # A policy checkpoint whose stored config says another network shape.
    foreign = tmp_path / "foreign"
    shutil.copytree(best, foreign)
    manifest = json.loads((foreign / "manifest.json").read_text())
    manifest["metadata"]["config"]["network"]["hidden_sizes"] = [64, 64]
    (foreign / "manifest.json").write_text(json.dumps(manifest))
    proc = run_script_in_process("evaluate.py", f"checkpoint={foreign}", "episodes=2")
    assert proc.returncode == 2 and "is damaged: manifest.json" in proc.stderr
    assert "Traceback" not in proc.stderr
    proc = run_script_in_process("evaluate.py", "checkpoint=/nonexistent", "episodes=2")
    assert proc.returncode == 2 and "does not exist" in proc.stderr


def test_a_policy_checkpoint_loaded_into_another_network_shape_is_refused(finished_run):
    from trl_cartpole.parts.env import make_env
    from trl_cartpole.parts.models import make_q_actor
    from trl_cartpole.store.checkpoint import load_policy

    env = make_env("CartPole-v1")
    other = make_q_actor(env.observation_spec, env.action_spec, num_cells=[64])
    with pytest.raises(ConfigError, match="does not fit this policy"):
        load_policy(finished_run / "checkpoints" / "best", other)


def test_a_write_that_fails_halfway_leaves_the_previous_file(tmp_path):
    from trl_cartpole.store.files import write_atomic, write_json_atomic

    target = write_json_atomic(tmp_path / "summary.json", {"frames": 1})

    def crash_after_half(tmp: Path) -> None:
        tmp.write_text('{"frames": ')
        raise OSError("disk full")

    with pytest.raises(OSError, match="disk full"):
        write_atomic(target, crash_after_half)
    assert json.loads(target.read_text()) == {"frames": 1}
    assert [p.name for p in tmp_path.iterdir()] == ["summary.json"]  # no temporary left


@pytest.mark.slow  # a run resumed
def test_an_env_pickled_as_constructor_arguments_is_reset_on_resume(compose, tmp_path, monkeypatch):
    # LunarLander is a Gymnasium EzPickle env: unpickled, it is a fresh env never reset, so the
    # checkpoint records it as missing and the resumed run starts new episodes (it crashed in
    # LunarLander.step when the unpickled env was taken for the one mid-episode). Its episodes
    # are logged for a replay; here none is (every episode longer than the log holds).
    from trl_cartpole.envs import episode_log

    monkeypatch.setattr(episode_log, "MAX_LOGGED_STEPS", 0)
    run_dir = tmp_path / "run"
    train(compose(*RESUMABLE, "env=lunarlander", f"run_dir={run_dir}", "logger.plots=false"))
    checkpoint = _periodic_at(run_dir, 400)
    (run_dir / "summary.json").unlink()
    cfg = resume_config(checkpoint, [f"run_dir={run_dir}"])
    with pytest.warns(UserWarning, match="not an exact continuation"):
        summary = train(cfg, resume=checkpoint)
    assert summary["frames"] == 600 and summary["final_eval_episodes"] == 4


# --- a full disk -----------------------------------------------------------------------------

# 600 frames, a training state every 200: the first fits, the disk is full for the second.
FULL_DISK = [*SMOKE_OVERRIDES, "collector.total_frames=600", "checkpoint.interval_frames=200"]


def _leftover_stages(run_dir: Path) -> list[Path]:
    return [path for path in run_dir.rglob(".*") if ".stage-" in path.name]


def _build_with_a_full_disk(how: str):
    """A ``train(build=...)`` whose disk fills once the first training state is complete:
    the free space reads short (``how="free space short"``), or it reads fine and the write
    fails with ENOSPC inside TorchRL's staged write (``"ENOSPC mid-write"``: the progress
    component, saved after the envs, evaluator, history, learner, loss, optimizer and policy,
    cannot be written)."""
    import errno

    from trl_cartpole.run.build import build_components
    from trl_cartpole.store.checkpoint import find_complete_checkpoints

    def build(cfg, resume=None):
        run = build_components(cfg, resume)

        def disk_full() -> bool:
            return bool(find_complete_checkpoints(run.run_dir))

        if how == "free space short":
            free_bytes = run.checkpointer.free_bytes
            run.checkpointer.free_bytes = lambda path: 4096 if disk_full() else free_bytes(path)
        else:
            state_dict = run.progress.state_dict

            def state_dict_or_enospc():
                if disk_full():
                    raise OSError(errno.ENOSPC, "No space left on device", str(run.run_dir))
                return state_dict()

            run.progress.state_dict = state_dict_or_enospc
        return run

    return build


@pytest.mark.parametrize(
    "how", [pytest.param("free space short", marks=pytest.mark.slow), "ENOSPC mid-write"]
)
def test_a_full_disk_stops_the_run_and_keeps_the_previous_checkpoint(tmp_path, compose, how):
    from trl_cartpole.errors import DiskFull

    run_dir = tmp_path / "run"
    with pytest.raises(DiskFull) as stopped:
        train(compose(*FULL_DISK, f"run_dir={run_dir}"), build=_build_with_a_full_disk(how))
    line = str(stopped.value)
    assert "\n" not in line and "no space left for the checkpoint at" in line
    assert "MB is free" in line
    assert f"resume={run_dir}" in line or f"resume={run_dir.name}" in line
    assert _leftover_stages(run_dir) == []  # TorchRL's staged files are gone
    assert not (run_dir / "summary.json").exists()
    good = find_resume_checkpoint(run_dir)  # verified against its integrity record
    assert Checkpoint.manifest(good)["metadata"]["counters"]["frames"] == 200
    # space again: the resume finishes the run
    resumed = run_script_in_process("train.py", f"resume={run_dir}")
    assert resumed.returncode == 0, resumed.stderr[-2000:]
    assert json.loads((run_dir / "summary.json").read_text())["frames"] == 600


def test_the_first_checkpoint_not_fitting_says_there_is_nothing_to_resume(tmp_path, compose):
    from trl_cartpole.errors import DiskFull
    from trl_cartpole.run.build import build_components

    def build_on_a_full_disk(cfg, resume=None):
        run = build_components(cfg, resume)
        run.checkpointer.free_bytes = lambda path: 0
        return run

    run_dir = tmp_path / "run"
    with pytest.raises(DiskFull, match=r"0\.0 MB is free") as stopped:
        train(compose(*FULL_DISK, f"run_dir={run_dir}"), build=build_on_a_full_disk)
    assert "start the run again" in str(stopped.value)
    assert not (run_dir / "checkpoints").exists() or not any(
        (run_dir / "checkpoints").rglob("manifest.json")
    )


def test_a_full_disk_is_one_line_and_exit_status_74_at_the_command_line():
    from trl_cartpole.cli.main import run_cli
    from trl_cartpole.errors import DiskFull

    def command(argv):
        raise DiskFull("no space left for the checkpoint at runs/x: it needs about 2.0 MB")

    stderr = io.StringIO()
    with contextlib.redirect_stderr(stderr):
        code = run_cli(command, [])
    assert code == 74
    assert stderr.getvalue() == (
        "error: no space left for the checkpoint at runs/x: it needs about 2.0 MB\n"
    )


def _in_a_small_filesystem(
    mount_point: Path, megabytes: int, script: str, *args: str
) -> subprocess.CompletedProcess:
    """Run ``sh -c script`` with ``$1`` a fresh tmpfs of ``megabytes`` on ``mount_point``, in a
    private mount namespace (``unshare``: nothing is mounted on the machine, and the tmpfs
    vanishes with the process); skip where the machine allows no such namespace."""
    mount_point.mkdir()
    shell = ["unshare", "--user", "--map-root-user", "--mount", "sh", "-c"]
    mount = f'mount -t tmpfs -o size={megabytes}m tmpfs "$1"'
    if shutil.which("unshare") is None:
        pytest.skip("this machine has no unshare for a private tmpfs")
    if subprocess.run([*shell, mount, "sh", str(mount_point)], capture_output=True).returncode:
        pytest.skip("this machine allows no private tmpfs (unshare --user --mount)")
    return subprocess.run(
        [*shell, f"{mount} && {script}", "sh", str(mount_point), *args],
        capture_output=True,
        text=True,
        timeout=300,
    )


@pytest.mark.slow  # training subprocesses on a real full filesystem
@pytest.mark.parametrize(("megabytes", "resumable"), [(10, True), (3, False)])
def test_a_run_on_a_real_small_filesystem_stops_in_one_line(python, tmp_path, megabytes, resumable):
    # Before: at 10 MB the second periodic state died of SIGBUS (exit 135, the replay buffer's
    # memory-mapped writes), at 3 MB the first one did, with no word of the disk.
    copy = tmp_path / "copy"
    proc = _in_a_small_filesystem(
        tmp_path / "mount",
        # a training state here is about 6 MB: a 512x512 network, its target copy and AdamW's
        # moments (the replay buffer's checkpoint holds only its 1 000-3 000 transitions)
        megabytes,
        '"$2" "$3" run_dir="$1/run" collector.total_frames=3000 checkpoint.interval_frames=1000 '
        "network.num_cells=[512,512] "
        "eval.interval_frames=1000 eval.episodes=3 eval.final_episodes=4 "
        'logger.progress_bar=false; status=$?; cp -a "$1/run" "$4"; exit $status',
        python,
        str(SCRIPTS / "train.py"),
        str(copy),
    )
    lines = [line for line in proc.stderr.splitlines() if line.startswith("error:")]
    assert proc.returncode == 74 and len(lines) == 1, proc.stderr[-2000:]
    assert "no space left for the checkpoint at" in lines[0] and "Traceback" not in proc.stderr
    assert _leftover_stages(copy) == []
    if not resumable:
        assert "start the run again" in lines[0]
        return
    good = find_resume_checkpoint(copy)
    frames = Checkpoint.manifest(good)["metadata"]["counters"]["frames"]
    assert 1000 <= frames < 2000  # the first periodic state (whole batches of 32 frames)
    resumed = _resume(python, copy)
    assert resumed.returncode == 0, resumed.stderr[-2000:]
    assert json.loads((copy / "summary.json").read_text())["frames"] >= 3000


# --- the other tools on damaged input ------------------------------------------------------


def _damage_summary(summary_path: Path, how: str) -> None:
    text = summary_path.read_text()
    summary = json.loads(text)
    if how == "truncated":
        summary_path.write_text(text[: len(text) // 2])
        return
    if how == "a list":
        summary = [summary]
    elif how == "curve lengths differ":
        summary["eval_curve"]["returns"] = summary["eval_curve"]["returns"][:-1]
    elif how == "a string for a number":
        summary["frames_to_solve"] = "many"
    elif how == "a missing field":
        del summary["solve_threshold"]
    summary_path.write_text(json.dumps(summary))


@pytest.mark.parametrize(
    ("how", "message"),
    [
        ("truncated", "not JSON"),
        ("a list", "a JSON list, not an object"),
        ("curve lengths differ", "different lengths"),
        ("a string for a number", "'frames_to_solve' is 'many'"),
        ("a missing field", "no 'solve_threshold'"),
        ("damaged config.yaml", "config.yaml is damaged"),
    ],
)
def test_plot_refuses_a_damaged_run_in_one_line(tmp_path, finished_run, how, message):
    run_dir = tmp_path / "run"
    shutil.copytree(finished_run, run_dir)
    if how == "damaged config.yaml":
        (run_dir / "config.yaml").write_text("env: {id: [unclosed\n")
    else:
        _damage_summary(run_dir / "summary.json", how)
    out = tmp_path / "comparison"
    proc = run_script_in_process("plot.py", str(run_dir), f"out={out}")
    lines = [line for line in proc.stderr.splitlines() if line.startswith("error:")]
    assert proc.returncode == 2 and len(lines) == 1, proc.stderr[-2000:]
    assert message in lines[0] and str(run_dir) in lines[0], lines[0]
    assert "Traceback" not in proc.stderr
    assert not list(tmp_path.glob("comparison*"))  # nothing written


def test_plot_reads_no_metrics_csv_and_a_resume_drops_its_damaged_rows(
    tmp_path, finished_run, capsys
):
    from trl_cartpole.report.loggers import truncate_csv_metrics

    run_dir = tmp_path / "run"
    shutil.copytree(finished_run, run_dir)
    csv = run_dir / "metrics" / "scalars" / "eval" / "damaged.csv"
    # rows of a run, a write cut off by a kill, bytes that are no text, then later frames
    csv.write_bytes(b"100,1.5\n200,2.5\n30\xff\xfe,\n300,x\n\n400,4.5\n500,5")
    proc = run_script_in_process("plot.py", str(run_dir), f"out={tmp_path / 'comparison'}")
    assert proc.returncode == 0, proc.stderr[-2000:]  # the plot reads summary.json only
    truncate_csv_metrics(run_dir, 400)
    assert csv.read_text() == "100,1.5\n200,2.5\n400,4.5\n"
    assert f"dropped 2 damaged row(s) of {csv}" in capsys.readouterr().err


def test_evaluate_refuses_a_checkpoint_of_another_env_in_one_line(tmp_path, finished_run):
    from trl_cartpole.store.checkpoint import write_integrity

    # the manifest says Acrobot (6 observations, 3 actions), the weights are CartPole's, and the
    # integrity record is rewritten to match: the network built from the manifest does not fit
    foreign = tmp_path / "foreign"
    shutil.copytree(finished_run / "checkpoints" / "best", foreign)
    manifest = json.loads((foreign / "manifest.json").read_text())
    manifest["metadata"]["config"]["env"]["id"] = "Acrobot-v1"
    (foreign / "manifest.json").write_text(json.dumps(manifest))
    write_integrity(foreign)
    proc = run_script_in_process("evaluate.py", f"checkpoint={foreign}", "episodes=2")
    lines = [line for line in proc.stderr.splitlines() if line.startswith("error:")]
    assert proc.returncode == 2 and len(lines) == 1, proc.stderr[-2000:]
    assert "does not fit this policy" in lines[0] and "Traceback" not in proc.stderr
    assert not (tmp_path / "evaluation-foreign.json").exists()


def _foreign_database(path: Path) -> None:
    import sqlite3

    with sqlite3.connect(path) as db:
        db.execute("CREATE TABLE accounts (name TEXT, balance REAL)")
        db.execute("INSERT INTO accounts VALUES ('ada', 12.5)")
    db.close()


def _damaged_study(path: Path) -> None:
    optuna = pytest.importorskip("optuna")
    optuna.create_study(study_name="s", storage=f"sqlite:///{path}")
    data = bytearray(path.read_bytes())
    data[4096:8192] = b"\xa5" * 4096  # the second page overwritten
    path.write_bytes(bytes(data))


def _study_of_another_space(path: Path) -> None:
    optuna = pytest.importorskip("optuna")
    study = optuna.create_study(study_name="s", storage=f"sqlite:///{path}", direction="maximize")
    study.add_trial(
        optuna.trial.create_trial(
            params={"optim.weight_decay": 0.1},
            distributions={"optim.weight_decay": optuna.distributions.FloatDistribution(0, 1)},
            value=1.0,
        )
    )


@pytest.mark.parametrize(
    ("make", "message"),
    [
        (lambda path: path.write_bytes(b"not a database\n" * 100), "is not an SQLite database"),
        (_damaged_study, "is a damaged SQLite database"),
        (_foreign_database, "another program's SQLite database (tables accounts)"),
        (_study_of_another_space, "was tuned over optim.weight_decay; this search space is over"),
    ],
    ids=["not sqlite", "damaged", "another program's", "another search space"],
)
def test_tune_refuses_a_damaged_or_foreign_study_database_unchanged(tmp_path, make, message):
    pytest.importorskip("optuna")
    database = tmp_path / "study.db"
    make(database)
    before = database.read_bytes()
    proc = run_script_in_process(
        "tune.py",
        "trials=1",
        f"out={tmp_path / 'tuned.yaml'}",
        f"storage=sqlite:///{database}",
        "study=s",
    )
    lines = [line for line in proc.stderr.splitlines() if line.startswith("error:")]
    assert proc.returncode == 2 and len(lines) == 1, proc.stderr[-2000:]
    assert message in lines[0] and "Traceback" not in proc.stderr
    assert database.read_bytes() == before  # Optuna added no table to it
    assert not (tmp_path / "tuned.yaml").exists()


def test_the_run_lock_names_its_process_while_held_and_nothing_once_released(tmp_path):
    from trl_cartpole.store.run_lock import RunLock

    lock = RunLock(tmp_path)
    assert (tmp_path / ".lock").read_text().startswith(f"process {os.getpid()} on ")
    lock.release()
    assert (tmp_path / ".lock").read_text() == ""  # a finished run's lock reads as free
    RunLock(tmp_path).release()  # and is taken again at once


def test_a_run_directory_offers_its_best_policy_or_before_any_the_state_resume_takes(
    tmp_path, finished_run
):
    from trl_cartpole.policy.load import policy_checkpoint
    from trl_cartpole.run.checkpointer import play_commands

    with pytest.raises(ConfigError, match="is neither a checkpoint nor a run directory"):
        policy_checkpoint(tmp_path)  # nothing saved yet
    run = tmp_path / "run"
    shutil.copytree(finished_run, run)
    assert policy_checkpoint(run) == run / "checkpoints" / "best"
    shutil.rmtree(run / "checkpoints" / "best")  # stopped before its first evaluation
    last = run / "checkpoints" / "last"
    assert policy_checkpoint(run) == find_resume_checkpoint(run) == last
    periodic = run / "checkpoints" / "periodic" / "frames-999999"  # more frames than last's
    shutil.copytree(last, periodic)
    manifest = json.loads((periodic / "manifest.json").read_text())
    manifest["metadata"]["counters"]["frames"] += 1
    (periodic / "manifest.json").write_text(json.dumps(manifest))
    # (the manifest no longer matches the integrity record: the choice reads, the load refuses)
    with pytest.raises(ConfigError, match="frames-999999"):
        policy_checkpoint(run)
    assert policy_checkpoint(last) == last  # a checkpoint is itself

    lines = play_commands(run).splitlines()
    assert lines[0] == "next:"
    assert [line.split("checkpoint=")[1].split()[0] for line in lines[1:]] == [str(run)] * 2
    assert "evaluate" in lines[1] and "render" in lines[2]

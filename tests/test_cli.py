"""What a new user meets: --help, a quiet console, an ending that tells the truth."""

from __future__ import annotations

import dataclasses
import logging
import os
import re
import shutil
import subprocess
import sys
import warnings
from pathlib import Path

import pytest
import torch
from tensordict import TensorDict
from tqdm import tqdm

from tests.conftest import ROOT, SCRIPTS, SMOKE_OVERRIDES, run_script
from trl_cartpole.config.compose import compose_run_config
from trl_cartpole.config.help import field_help
from trl_cartpole.config.schema import Config
from trl_cartpole.report.console import (
    DYNAMO_PROFILER_LOGGER,
    ending,
    quiet_libraries,
    shown_path,
    solve_status,
    verdict,
)
from trl_cartpole.report.progress_bar import BAR_FORMAT
from trl_cartpole.run.history import History
from trl_cartpole.run.run_dir import prepare_run_dir

SCRIPT_NAMES = sorted(path.name for path in SCRIPTS.glob("*.py"))


@pytest.mark.parametrize("name", SCRIPT_NAMES)
def test_every_script_answers_help(name):
    proc = run_script(name, "--help", timeout=60)
    assert proc.returncode == 0, proc.stderr
    assert "usage" in proc.stdout.lower() and proc.stderr == ""


@pytest.mark.slow  # a fresh interpreter per subcommand
def test_benchmarks_answer_help():
    proc = subprocess.run(
        [sys.executable, "-m", "benchmarks", "--help"],
        capture_output=True,
        text=True,
        cwd=ROOT,
        timeout=60,
    )
    assert proc.returncode == 0 and "usage" in proc.stdout


def test_train_help_lists_presets_and_every_field_with_a_meaning():
    proc = run_script("train.py", "--help", timeout=60)
    for preset in ("algo=dqn", "algo=tutorial", "algo=rainbow", "env=cartpole", "env=acrobot"):
        assert preset in proc.stdout
    rows = field_help(Config)
    assert len(rows) > 60
    for key, _, default, meaning in rows:
        assert meaning, f"{key} has no comment in trl_cartpole/config/schema.py"
        assert f"  {key}={default} " in proc.stdout
    assert "  loss.gamma=0.995 (float)" in proc.stdout
    assert "  network.num_cells=[128,128] (list[int])" in proc.stdout


@pytest.mark.slow  # a run in a fresh interpreter
def test_a_run_prints_its_evaluations_and_ending_and_nothing_else(tmp_path):
    run_dir = tmp_path / "run"
    overrides = [o for o in SMOKE_OVERRIDES if not o.startswith("logger.progress_bar")]
    # 300 frames in batches of 4 do not divide into the 298 asked for: no warning about it.
    overrides = [o.replace("total_frames=300", "total_frames=298") for o in overrides]
    proc = run_script("train.py", *overrides, f"run_dir={run_dir}", timeout=300)
    assert proc.returncode == 0, proc.stderr
    output = proc.stdout + proc.stderr
    for noise in ("[INFO]", "Warning", "\x1b[", "Traceback"):
        assert noise not in output
    # stderr is not a terminal here: one line per evaluation instead of a redrawn bar, then a
    # line per long step of the end
    lines = proc.stderr.splitlines()
    steps = ["saving the last training state", "final evaluation: ", "drawing the plots"]
    evaluations = [line for line in lines if not line.startswith(tuple(steps))]
    assert evaluations and all(
        re.fullmatch(r"\d+ / 300 frames: greedy return -?[\d.]+ \(best -?[\d.]+\)", line)
        for line in evaluations
    ), proc.stderr
    ending = lines[len(evaluations) :]
    assert [line.split(":")[0].removesuffix(" ...") for line in ending] == [
        "saving the last training state",
        "final evaluation",
        "drawing the plots",
    ], proc.stderr
    lines = proc.stdout.splitlines()
    assert lines[0].startswith("CartPole-v1 [dqn, seed 0]: not solved in 300 frames")
    assert lines[1].startswith(f"run directory: {run_dir}")
    assert f"scripts/evaluate.py checkpoint={run_dir}" in proc.stdout
    command = lines[3].split()[0]  # the interpreter that ran, so the command works as printed
    found = Path(shutil.which(command) or command).absolute()
    assert found.parent == Path(sys.executable).absolute().parent  # its own bin, not the system's


def _summary(**changes) -> dict:
    summary = {
        "env_id": "CartPole-v1",
        "algo": "dqn",
        "seed": 3,
        "frames": 43008,
        "solved": True,
        "solve_threshold": 475.0,
        "frames_to_solve": 43008,
        "seconds_to_solve": 41.0,
        "final_eval_return_mean": 500.0,
        "final_eval_return_std": 0.0,
        "final_eval_episodes": 100,
        "best_eval_return_mean": 478.5,
        "eval_curve": {"frames": [1024 * i for i in range(1, 43)]},
        "run_dir": "runs/x",
        "checkpoint": "runs/x/checkpoints/best",
    }
    return {**summary, **changes}


def test_the_ending_never_says_solved_when_the_final_check_missed():
    missed = verdict(_summary(final_eval_return_mean=422.1, final_eval_return_std=129.7))
    assert "reached 475 once at 43008 frames" in missed
    assert "422.1 +/- 129.7 over 100 new episodes, below 475: not held" in missed
    assert "solved at" not in missed
    met = verdict(_summary())
    assert "solved at 43008 frames, 41.0 s of training" in met and "(>= 475)" in met
    assert "the best policy of 42 evaluations" in met
    scores = [{"frames": 1024, "eval_return_mean": 500.0, "replay_return_mean": 480.0}] * 3
    kept = verdict(_summary(candidates=scores))
    assert "the best policy (of the 3 best of 42 evaluations, the best over new episodes) " in kept


def test_the_ending_of_an_unsolved_run_and_of_an_env_without_threshold():
    unsolved = verdict(_summary(solved=False, frames_to_solve=None, frames=5000))
    assert "not solved in 5000 frames (threshold 475, best evaluation 478.5)" in unsolved
    one = verdict(_summary(solve_threshold=None, eval_curve={"frames": [5000]}))
    assert "no solve threshold" in one and "the best policy of 1 evaluation returned" in one
    assert "next:" in ending(_summary()) and "next:" not in ending(_summary(checkpoint=None))


def test_the_endings_export_command_writes_into_the_run_directory_not_the_clone():
    summary = _summary()
    (export,) = [line for line in ending(summary).splitlines() if "export" in line]
    output = export.split("output=")[1].split()[0]
    assert output == f"{shown_path(summary['run_dir'])}/policy.pt2"


def test_episodes_are_recorded_in_the_order_they_ended_with_their_frame():
    history = History()
    # 2 envs x 3 steps: env 0 ends at step 2, env 1 at step 0
    done = torch.tensor([[False, False, True], [True, False, False]]).unsqueeze(-1)
    batch = TensorDict(
        {
            "next": {
                "done": done,
                "episode_reward": torch.tensor([[1.0, 2.0, 30.0], [10.0, 1.0, 2.0]]).unsqueeze(-1),
                "step_count": torch.tensor([[1, 2, 30], [10, 1, 2]]).unsqueeze(-1),
            }
        },
        batch_size=[2, 3],
    )
    frames = 100 + batch.numel()  # the loop counts the batch before recording it
    episodes = history.record_episodes(batch, frames)
    assert [episode.frame for episode in episodes] == history.episode_frames
    assert history.episode_returns == [10.0, 30.0]  # env 1's episode ended first
    assert history.episode_lengths == [10, 30]
    assert history.episode_frames == [100 + 1 * 2, 100 + 3 * 2]


def test_the_bar_shows_eval_and_best_in_80_columns():
    bar = tqdm.format_meter(
        n=14_336,
        total=50_016,
        elapsed=21.0,
        ncols=80,
        prefix="LunarLander-v3",
        bar_format=BAR_FORMAT,
        unit_scale=True,
        postfix="eval -123 best -45.5 | ret -300 eps .05",
    )
    assert len(bar) <= 80 and "eval -123 best -45.5" in bar


@pytest.mark.parametrize(
    ("overrides", "name"),
    [
        ([], "runs/CartPole-v1-dqn-seed0-"),
        (["loss.double_dqn=true"], "runs/CartPole-v1-dqn-double_dqn=true-seed0-"),
        (["algo=double", "seed=2"], "runs/CartPole-v1-double-seed2-"),  # a preset names itself
        (["env=acrobot", "network.num_cells=[64,64]"], "-dqn-num_cells=64x64-seed0-"),
        (["seed=3", "buffer.batch_size=64", "optim.lr=5e-4"], "-batch_size=64,lr=0.0005-seed3-"),
        (["logger.backend=none", "checkpoint.keep_last=5"], "runs/CartPole-v1-dqn-seed0-"),
    ],
)
def test_a_run_directory_names_what_differs_from_its_presets(overrides, name):
    assert name in compose_run_config(ROOT / "configs", overrides).run_dir


def test_runs_latest_points_at_the_newest_run_and_survives_a_resume_through_it(tmp_path):
    runs = tmp_path / "runs"
    for name in ("first", "second"):
        prepare_run_dir(runs / name)
    assert (runs / "latest").resolve() == (runs / "second").resolve()
    prepare_run_dir(runs / "latest")  # resume=runs/latest writes through the link
    assert os.readlink(runs / "latest") == "second"
    prepare_run_dir(tmp_path / "elsewhere" / "run")  # not under runs/: no link
    assert not (tmp_path / "elsewhere" / "latest").exists()


@dataclasses.dataclass
class _BaseArgs:
    checkpoint: str = "???"  # a run directory


@dataclasses.dataclass
class _Args(_BaseArgs):
    colour: str = "#fff"  # a colour, not the comment "#fff"
    # the block above a field
    # that has no comment of its own
    width: int = 3
    height: int = 4  # trailing wins over the block above


def test_help_reads_each_fields_own_comment_inherited_fields_included():
    rows = {key: (kind, default, meaning) for key, kind, default, meaning in field_help(_Args)}
    assert rows["checkpoint"] == ("str", "???", "a run directory")
    assert rows["colour"] == ("str", "#fff", 'a colour, not the comment "#fff"')
    assert rows["width"] == ("int", "3", "the block above a field that has no comment of its own")
    assert rows["height"] == ("int", "4", "trailing wins over the block above")


def test_a_compiled_updates_habitual_notes_are_kept_off_the_console(caplog):
    """``compile=true`` made torch log "Profiler record function ... will be ignored" and
    tensordict warn that a Dynamo setting is deprecated, once per run; other warnings stay."""
    dynamo = logging.getLogger(DYNAMO_PROFILER_LOGGER)
    deprecated = "torch._dynamo.config.inline_inbuilt_nn_modules is deprecated and does nothing"
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        with quiet_libraries():
            dynamo.warning("Profiler record function %s will be ignored", "record_function")
            dynamo.warning("Graph break: something a user may need")
            warnings.warn(deprecated, FutureWarning, stacklevel=1)
            warnings.warn("a FutureWarning of another kind", FutureWarning, stacklevel=1)
    assert [r.getMessage() for r in caplog.records] == ["Graph break: something a user may need"]
    assert [str(w.message) for w in caught] == ["a FutureWarning of another kind"]
    dynamo.warning("Profiler record function %s will be ignored", "outside")  # filter removed
    assert caplog.records[-1].getMessage().endswith("outside will be ignored")
    # logger.verbose=true inside the script's quiet block (train() nests one): all shown
    caplog.clear()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        with quiet_libraries():
            with quiet_libraries(verbose=True):
                dynamo.warning("Profiler record function %s will be ignored", "verbose")
                warnings.warn(deprecated, FutureWarning, stacklevel=1)
            dynamo.warning("Profiler record function %s will be ignored", "outer again")
            warnings.warn(deprecated, FutureWarning, stacklevel=1)
    assert [r.getMessage() for r in caplog.records] == [
        "Profiler record function verbose will be ignored"
    ]
    assert [str(w.message) for w in caught] == [deprecated]


@pytest.mark.parametrize(
    "argv",
    [
        ["train", "loss.gama=0.9"],
        ["train", "loss.gamma=2"],
        ["train", "env=lunarlandr"],
        ["tune", "trials=1", "out=x.yaml", "optim.lr=-1"],
        ["evaluate", "checkpont=runs/x"],
    ],
    ids=lambda argv: " ".join(argv),
)
def test_a_typo_is_refused_before_torch_is_imported(argv, tmp_path):
    code = (
        "import sys\nfrom trl_cartpole.cli.main import main\n"
        f"code = main({argv!r})\n"
        "print('torch imported' if 'torch' in sys.modules else 'no torch', code)"
    )
    proc = subprocess.run(
        [sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True, timeout=120
    )
    assert proc.stdout.split() == ["no", "torch", "2"], proc.stdout + proc.stderr
    assert proc.stderr.startswith("error: ") and proc.stderr.count("\n") == 1


def test_an_error_whose_causes_loop_is_still_one_line():
    """A cause chain that loops (OmegaConf's errors can name each other) ends in one line."""
    from trl_cartpole.cli.main import one_line

    first, second = ValueError("first"), KeyError("second")
    first.__cause__, second.__cause__ = second, first
    assert one_line(first) == "first: 'second'"


def test_the_evaluate_command_an_ending_prints_plays_the_runs_own_episode_count():
    """evaluate plays the run's final evaluation's count (a Breakout run's 30 whole games), and
    the ending's comment says that count, not CartPole's 100."""
    (line,) = [
        line for line in ending(_summary(final_eval_episodes=30)).splitlines() if "evaluate" in line
    ]
    assert line.endswith("# 30 greedy episodes")


def test_a_run_that_trained_on_after_solving_says_how_long_it_trained_in_all():
    """Acrobot's preset trains its whole budget: "solved at ..., 33.5 s of training" alone read
    as the run's training time after 5.3 minutes of it."""
    line = verdict(_summary(seconds_to_solve=33.5, train_seconds=318.0))
    assert "solved at 43008 frames, 33.5 s of training (of 5.3 min in all);" in line
    assert "in all" not in verdict(_summary(seconds_to_solve=41.0, train_seconds=42.0))


@pytest.mark.parametrize(
    ("changes", "status"),
    [
        ({}, "solved"),
        ({"final_eval_return_mean": 474.9}, "not held"),  # reached once, not by the best policy
        ({"solved": False, "frames_to_solve": None}, "not solved"),
        ({"solve_threshold": None}, "no threshold"),
    ],
)
def test_one_verdict_in_the_ending_and_the_summary(changes, status):
    """The ending's words follow ``solve_status``, the value summary.json records."""
    summary = _summary(**changes)
    assert solve_status(summary) == status
    line = verdict(summary)
    said = {"solved": "solved at", "not held": ": not held", "not solved": "not solved in"}
    assert status == "no threshold" or said[status] in line

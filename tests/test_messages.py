"""Mistakes on the command line are answered in the project's words: the key or preset named,
the closest known name, the form that works; one line, exit status 2."""

from __future__ import annotations

import re
import subprocess
import sys

import pytest

from tests.conftest import run_script_in_process
from trl_cartpole.config.messages import did_you_mean


@pytest.mark.parametrize(
    ("args", "expected"),
    [
        (["seeed=1"], r"^seeed is not a setting \(did you mean 'seed'\?\); .* --help"),
        (["loss.gama=0.9"], r"^loss\.gama is not a setting \(did you mean 'loss\.gamma'\?\)"),
        (["--seed", "1"], r"^arguments are key=value here, without dashes: write seed=1$"),
        (["--seed=1"], r"write seed=1$"),
        (["algo=dobule"], r"^algo='dobule' is not a preset \(did you mean 'double'\?\); choose"),
        (["env=cartpol"], r"^env='cartpol' is not a preset \(did you mean 'cartpole'\?\)"),
        (["seed=abc"], r"^seed='abc' is not an integer; write seed=<an integer>$"),
        (["buffer.alpha=high"], r"^buffer\.alpha='high' is not a number"),
    ],
    ids=["typo", "nested typo", "dashes", "dashes with =", "algo", "env", "int", "float"],
)
def test_composition_mistakes_are_answered_in_the_projects_words(args, expected):
    done = run_script_in_process("train.py", *args)
    lines = done.stderr.strip().splitlines()
    assert done.returncode == 2 and len(lines) == 1, done.stderr
    assert re.search(expected, lines[0].removeprefix("error: ")), lines[0]
    assert "Hydra" not in lines[0] and "Exception" not in lines[0]


def test_no_suggestion_when_nothing_is_close():
    assert did_you_mean("zzz", ["seed", "env"]) == ""
    assert did_you_mean("sede", ["seed", "env"]) == " (did you mean 'seed'?)"


@pytest.mark.parametrize(
    ("args", "expected"),
    [
        ([], r"^checkpoint= is needed: add checkpoint=runs/latest"),
        (["checkpoint=runs/latest", "episodes=abc"], r"^episodes='abc' is not an integer"),
    ],
    ids=["no checkpoint", "episodes"],
)
def test_evaluate_names_the_missing_or_mistyped_key(args, expected):
    done = run_script_in_process("evaluate.py", *args)
    lines = done.stderr.strip().splitlines()
    assert done.returncode == 2 and len(lines) == 1, done.stderr
    assert re.search(expected, lines[0].removeprefix("error: ")), lines[0]


def _summary(env_id: str, solved: bool) -> dict:
    return {
        "run_dir": "runs/x",
        "env_id": env_id,
        "algo": "dqn",
        "seed": 0,
        "solve_threshold": -110.0,
        "solved": solved,
        "frames": 50_016,
        "frames_to_solve": 40_000 if solved else None,
        "seconds_to_solve": 60.0 if solved else None,
        "eval_curve": {"frames": [1000] * 49},
        "final_eval_return_mean": -100.0 if solved else -200.0,
        "final_eval_return_std": 0.0,
        "final_eval_episodes": 100,
        "best_eval_return_mean": -100.0 if solved else -200.0,
        "checkpoint": "runs/x/checkpoints/best",
    }


def test_a_run_that_ends_short_of_its_target_says_what_to_try():
    from trl_cartpole.report.console import ending

    def tries(summary, *args, **kwargs):
        lines = ending(summary, *args, **kwargs).splitlines()
        return lines[lines.index("try:") + 1 : lines.index("next:")]

    overrides = ["env.id=MountainCar-v0", "seed=0", "collector.total_frames=50000"]
    short = tries(_summary("MountainCar-v0", solved=False), overrides)
    assert short[0].endswith("train env=mountaincar algo=dqn   # tuned for MountainCar-v0")
    # the run's own command line, its budget doubled: a command, runnable as printed
    assert short[1].endswith(
        "train env.id=MountainCar-v0 seed=0 collector.total_frames=100032   # twice the frames"
    )
    # a run that used the preset, or learnt from pixels, is not sent to the state preset
    assert len(tries(_summary("MountainCar-v0", solved=False), ["env=mountaincar"])) == 1
    assert len(tries(_summary("MountainCar-v0", solved=False), (), pixels=True)) == 1
    no_preset = ending(_summary("Taxi-v3", solved=False)).splitlines()
    assert not any("env=" in line for line in no_preset)  # no preset to point at: more frames
    assert "try:" not in ending(_summary("MountainCar-v0", solved=True))


def test_a_run_that_saved_its_last_state_is_told_to_continue_it(tmp_path):
    from trl_cartpole.report.console import ending

    (tmp_path / "checkpoints" / "last").mkdir(parents=True)
    summary = _summary("MountainCar-v0", solved=False) | {"run_dir": str(tmp_path)}
    lines = ending(summary, ["env=mountaincar"]).splitlines()
    assert lines[lines.index("try:") + 1].endswith(
        f"train resume={tmp_path} collector.total_frames=100032"
        "   # this run, on to twice the frames"
    )


def test_the_ending_lists_the_plots_only_when_the_run_drew_them():
    from trl_cartpole.report.console import ending

    drawn = ending(_summary("MountainCar-v0", solved=True)).splitlines()[1]
    assert drawn.endswith("(durations.png, dashboard.png, summary.json, checkpoints/)")
    none = ending(_summary("MountainCar-v0", solved=True), plots=False).splitlines()[1]
    assert none.endswith("(summary.json, checkpoints/)")


def test_a_preset_of_ones_own_without_its_header_is_told_to_add_it(tmp_path):
    (tmp_path / "env").mkdir()
    (tmp_path / "env" / "tuned.yaml").write_text("env:\n  id: Acrobot-v1\n")
    done = run_script_in_process("train.py", f"presets={tmp_path}", "env=tuned")
    lines = done.stderr.strip().splitlines()
    assert done.returncode == 2 and len(lines) == 1, done.stderr
    assert "make '# @package _global_' its first line" in lines[0]
    (tmp_path / "env" / "tuned.yaml").write_text("# @package _global_\nenv:\n  id: Acrobot-v1\n")
    from trl_cartpole.config.compose import compose_config

    assert compose_config(overrides=[f"presets={tmp_path}", "env=tuned"]).env.id == "Acrobot-v1"


def _run_in_a_fresh_interpreter(command: str, *args: str) -> subprocess.CompletedProcess:
    """``trl-cartpole COMMAND ARGS`` in a new interpreter; its stdout: the exit code and whether
    torch had been imported by then."""
    script = (
        "import sys\n"
        "from trl_cartpole.cli.main import main\n"
        f"code = main([{command!r}, *{list(args)!r}])\n"
        "print(code, 'torch' in sys.modules)\n"
    )
    return subprocess.run([sys.executable, "-c", script], capture_output=True, text=True)


@pytest.mark.parametrize("command", ["evaluate", "render"])
def test_a_missing_checkpoint_is_answered_before_torch_is_imported(command, tmp_path):
    done = _run_in_a_fresh_interpreter(command, f"checkpoint={tmp_path / 'nope'}")
    assert done.stdout.split() == ["2", "False"], done.stderr
    assert "does not exist" in done.stderr


def test_an_env_dqn_cannot_play_is_refused_before_torch_is_imported():
    done = _run_in_a_fresh_interpreter("train", "env.id=Pendulum-v1")
    assert done.stdout.split() == ["2", "False"], done.stderr
    assert "has continuous actions" in done.stderr


def test_a_users_name_for_a_setting_suggests_the_schemas():
    known = ["optim.lr", "optim.lr_end", "optim.eps", "loss.gamma", "seed"]
    assert did_you_mean("optim.learning_rate", known) == " (did you mean 'optim.lr'?)"
    assert did_you_mean("loss.discount", known) == " (did you mean 'loss.gamma'?)"
    assert did_you_mean("optim.lr_ned", known) == " (did you mean 'optim.lr_end'?)"


@pytest.mark.parametrize(
    ("args", "expected"),
    [
        (
            ["--checkpoint", "runs/x"],
            "arguments are key=value here, without dashes: write checkpoint=runs/x",
        ),
        (["checkpont=runs/x"], "checkpont is not an argument of"),
        (["runs/x", "runs/y"], "'runs/y' is not key=value"),
    ],
)
def test_a_scripts_arguments_are_refused_in_the_projects_words(args, expected):
    proc = run_script_in_process("evaluate.py", *args)
    lines = [line for line in proc.stderr.splitlines() if line.startswith("error:")]
    assert proc.returncode == 2 and len(lines) == 1, proc.stderr
    assert expected in lines[0] and "EvaluateArgs" not in lines[0]
    if args == ["checkpont=runs/x"]:
        assert "(did you mean 'checkpoint'?)" in lines[0]


def test_a_lone_argument_is_the_checkpoint(tmp_path):
    from trl_cartpole.cli.commands.evaluate import EvaluateArgs
    from trl_cartpole.config.help import parse_args

    args = parse_args(
        EvaluateArgs, [str(tmp_path), "episodes=3"], "usage: x", positional="checkpoint"
    )
    assert args.checkpoint == str(tmp_path) and args.episodes == 3
    proc = run_script_in_process("evaluate.py", str(tmp_path / "nope"))
    assert proc.returncode == 2 and "does not exist" in proc.stderr


def test_a_warning_on_the_console_is_one_line_once_without_colour_codes():
    # a fresh interpreter: pytest records warnings instead of printing them
    script = (
        "import warnings\n"
        "from trl_cartpole.report.console import quiet_libraries\n"
        "with quiet_libraries():\n"
        "    for _ in range(4):  # Gymnasium's deprecation, once per env\n"
        "        warnings.warn('\\x1b[33mCartPole-v0 is old\\nmore\\x1b[0m', stacklevel=1)\n"
        "    warnings.warn('collector.total_frames=3000 ends before the first update')\n"
    )
    proc = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True)
    assert proc.returncode == 0 and proc.stdout == ""
    assert proc.stderr == (
        "warning: CartPole-v0 is old\n"
        "warning: collector.total_frames=3000 ends before the first update\n"
    )


def test_the_next_commands_carry_the_pythonpath_the_run_needed(monkeypatch):
    from trl_cartpole.report.console import ending

    monkeypatch.setenv("PYTHONPATH", "examples")  # where a user's env module lives
    lines = ending(_summary("MountainCar-v0", solved=False)).splitlines()
    commands = [line for line in lines if line.startswith("  ")]
    assert commands and all(line.startswith("  PYTHONPATH=examples ") for line in commands)
    monkeypatch.delenv("PYTHONPATH")
    assert "PYTHONPATH" not in ending(_summary("MountainCar-v0", solved=False))


def test_an_episode_cut_at_eval_max_steps_is_said():
    from trl_cartpole.run.eval_protocol import cut_episodes_note
    from trl_cartpole.run.evaluation import EvalResult

    whole = EvalResult(returns=[9.0, 20.0], lengths=[9, 20], initial_values=[0.0, 0.0])
    assert cut_episodes_note(whole, max_steps=50) is None
    cut = EvalResult(returns=[9707.3, 20.0, 50.0], lengths=[50, 20, 50], initial_values=[0.0] * 3)
    note = cut_episodes_note(cut, max_steps=50, what="final episodes")
    assert note.startswith("2 of 3 final episodes ran 50 steps and were cut there")
    assert "eval.max_steps" in note and "env.max_episode_steps" in note and "\n" not in note


@pytest.mark.parametrize(
    ("command", "args", "expected"),
    [
        ("evaluate", ["episodes=0"], "episodes=0 must be >= 1"),
        ("export", ["output=policy.tflite"], "end it in .onnx (ONNX) or .pt2"),
        ("render", ["episodes=0"], "episodes and fps must be >= 1"),
        ("render", ["output=agent.avi"], "choose a .gif or .mp4 file name"),
    ],
)
def test_a_bad_argument_of_a_policy_command_is_refused_before_torch_is_imported(
    command, args, expected, tmp_path
):
    done = _run_in_a_fresh_interpreter(command, f"checkpoint={tmp_path}", *args)
    assert done.stdout.split() == ["2", "False"], done.stderr
    assert expected in done.stderr


@pytest.mark.parametrize(
    ("overrides", "label"),
    [
        ([], "dqn"),
        (["env=cartpole_pixels"], "dqn + double DQN, dueling head"),  # its env preset's switches
        (["loss.double_dqn=true"], "dqn + double DQN"),
        (["algo=rainbow"], "rainbow"),
        (["algo=dueling", "buffer.n_steps=1"], "dueling + 1-step returns"),
    ],
)
def test_the_ending_names_the_variant_the_run_trained(overrides, label):
    from trl_cartpole.config.compose import compose_config, variant_label
    from trl_cartpole.config.schema import to_config
    from trl_cartpole.report.console import verdict

    assert variant_label(to_config(compose_config(overrides=overrides))) == label
    summary = _summary("MountainCar-v0", solved=True) | {"variant": label}
    assert verdict(summary).startswith(f"MountainCar-v0 [{label}, seed 0]: ")


def _interrupt(*args, **kwargs):
    raise KeyboardInterrupt


def test_ctrl_c_before_the_first_checkpoint_says_there_is_nothing_to_resume(
    tmp_path, monkeypatch, capsys
):
    """A Ctrl-C while torch still imports, before the run directory exists: no resume command
    that would fail (or resume another run through runs/latest)."""
    import trl_cartpole.run.training as training
    from trl_cartpole.cli.main import main

    monkeypatch.setattr(training, "train", _interrupt)
    assert main(["train", f"run_dir={tmp_path / 'new'}"]) == 130
    said = capsys.readouterr().err
    assert "nothing to resume" in said and "resume=" not in said


def test_ctrl_c_after_a_checkpoint_names_the_run_directory_to_resume(tmp_path, monkeypatch, capsys):
    import trl_cartpole.run.training as training
    import trl_cartpole.store.checkpoint as checkpoint
    from trl_cartpole.cli.main import main

    run_dir = tmp_path / "run"
    (run_dir / "checkpoints" / "last").mkdir(parents=True)
    (run_dir / "checkpoints" / "last" / checkpoint.INTEGRITY).write_text("{}")
    monkeypatch.setattr(training, "train", _interrupt)
    assert main(["train", f"run_dir={run_dir}"]) == 130
    said = capsys.readouterr().err
    assert f"resume={run_dir}" in said and "checkpoint is intact" in said

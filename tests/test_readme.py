"""The README and the guide run as written: their Python blocks, and the two commands CI runs."""

from __future__ import annotations

import re
import subprocess
import sys

import pytest
from torchrl.modules import DistributionalQValueActor, NoisyLinear, QValueActor
from torchrl.objectives import DistributionalDQNLoss, DQNLoss

from .conftest import ROOT

README = (ROOT / "README.md").read_text()
# Words of the project's own planning that a user has no way to know.
FORBIDDEN = re.compile(r"seeds'|shared/seeds|seed documents|\bbrief\b|\bissue(?:s|'s)?\b", re.I)


def _blocks(text: str, language: str) -> list[str]:
    return re.findall(rf"```{language}\n(.*?)```", text, re.DOTALL)


@pytest.mark.slow  # a run in a fresh interpreter
def test_readme_python_example_runs_on_its_own_and_prints_only_its_own_line():
    (code,) = _blocks(README, "python")
    proc = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=300, check=False
    )
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert re.fullmatch(r"last TD loss \d+\.\d{3}\n", proc.stdout)
    assert proc.stderr == ""  # no library's log line, warning or progress


def test_guide_variant_heads_example_runs_on_its_own():
    guide = (ROOT / "docs" / "guide.md").read_text()
    code = _blocks(guide.split("## DQN variants", 1)[1], "python")[0]
    namespace: dict = {}
    exec(compile(code, "docs/guide.md", "exec"), namespace)
    assert isinstance(namespace["actor"], QValueActor)
    assert any(isinstance(m, NoisyLinear) for m in namespace["actor"].modules())
    assert isinstance(namespace["loss"], DQNLoss) and namespace["loss"].double_dqn
    assert isinstance(namespace["c51"], DistributionalQValueActor)
    assert isinstance(namespace["c51_loss"], DistributionalDQNLoss)


def test_ci_runs_the_readme_quick_start_commands_as_written():
    ci = (ROOT / ".ci" / "run").read_text()
    install_and_train, tests = (block.strip() for block in _blocks(README, "bash")[:2])
    assert install_and_train in ci.splitlines()
    for half in tests.split(" && "):  # CI lints between the test install and the tests
        assert half in ci.splitlines()


USER_TEXTS = ["README.md", *sorted(f"docs/{p.name}" for p in (ROOT / "docs").glob("*.md"))]


@pytest.mark.parametrize("path", [*USER_TEXTS, "configs"])
def test_user_facing_text_uses_no_word_a_user_cannot_know(path):
    files = sorted((ROOT / path).rglob("*.yaml")) if path == "configs" else [ROOT / path]
    for file in files:
        found = FORBIDDEN.findall(file.read_text())
        assert not found, f"{file.relative_to(ROOT)}: {found}"


def test_the_readmes_expected_ending_is_what_a_run_prints(monkeypatch):
    """The quick start's ending, rebuilt by ``console.ending`` from the figures it quotes."""
    from trl_cartpole.report import console

    quoted = re.search(r"```\n(CartPole-v1 \[dqn.*?)```", README, re.DOTALL)[1].splitlines()
    numbers = re.match(
        r"CartPole-v1 \[dqn, seed 0\]: solved at (\d+) frames, ([\d.]+) s of training; the best "
        r"policy of (\d+) evaluations returned ([\d.]+) \+/- ([\d.]+) over (\d+) new episodes",
        quoted[0],
    )
    run_dir = re.search(r"run directory: (\S+)", quoted[1]).group(1)
    frames, seconds, evaluations, mean, std, episodes = numbers.groups()
    summary = {
        "env_id": "CartPole-v1",
        "algo": "dqn",
        "seed": 0,
        "solve_threshold": 475.0,
        "solved": True,
        "frames": int(frames),
        "frames_to_solve": int(frames),
        "seconds_to_solve": float(seconds),
        "eval_curve": {"frames": [0] * int(evaluations)},
        "final_eval_return_mean": float(mean),
        "final_eval_return_std": float(std),
        "final_eval_episodes": int(episodes),
        "best_eval_return_mean": float(mean),
        "run_dir": str(ROOT / run_dir),
        "checkpoint": "best",
    }
    monkeypatch.chdir(ROOT)
    monkeypatch.delenv("PYTHONPATH", raising=False)  # the README's run had none
    monkeypatch.setattr(console, "python_command", lambda: ".venv/bin/python")
    console.set_scripts_dir(ROOT / "scripts")
    try:
        assert console.ending(summary).splitlines() == quoted
    finally:
        console.set_scripts_dir(None)


def test_the_tutorials_python_runs_on_its_own(capsys):
    tutorial = (ROOT / "docs" / "tutorial.md").read_text()
    (code,) = _blocks(tutorial, "python")
    exec(compile(code, "docs/tutorial.md", "exec"), {})
    assert capsys.readouterr().out.strip() in ("tensor([1, 0])", "tensor([0, 1])")


def test_the_readme_is_short_enough_to_read_in_five_minutes():
    """The README is the front door: at most 150 lines, the rest lives in docs/."""
    assert len(README.splitlines()) <= 150

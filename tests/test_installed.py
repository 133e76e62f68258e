"""The package as a user installs it: a wheel in a fresh virtual environment, run elsewhere.

The wheel is built from this checkout and installed without its dependencies into a new
virtual environment whose only other path is this interpreter's site-packages (for torch,
TorchRL... already installed here); the editable install of the checkout is not visible there.
Everything then runs from an empty directory outside the repository: the documented API, the
``trl-cartpole`` command, the presets shipped in the wheel and a directory of the user's own.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import sysconfig
import venv
from pathlib import Path

import pytest

pytestmark = pytest.mark.slow  # builds a wheel and installs it in a fresh virtual environment

ROOT = Path(__file__).resolve().parent.parent
PIP = [sys.executable, "-m", "pip"]


@pytest.fixture(scope="module")
def installed(tmp_path_factory) -> Path:
    """A fresh virtual environment with the wheel of this checkout; returns its bin directory."""
    base = tmp_path_factory.mktemp("installed")
    source, wheels = base / "source", base / "wheels"  # built from a copy: the build/ is there
    shutil.copytree(ROOT / "src", source / "src", ignore=shutil.ignore_patterns("*.egg-info"))
    for name in ("pyproject.toml", "README.md"):
        shutil.copy(ROOT / name, source / name)
    subprocess.run(
        [*PIP, "wheel", "--no-deps", "--no-build-isolation", "-q", "-w", str(wheels), str(source)],
        check=True,
        capture_output=True,
        timeout=300,
    )
    (wheel,) = wheels.glob("trl_cartpole-*.whl")
    env_dir = base / "venv"
    venv.create(env_dir, with_pip=False)
    purelib = Path(
        sysconfig.get_paths(vars={"base": str(env_dir), "platbase": str(env_dir)})["purelib"]
    )
    # the dependencies come from this interpreter's site-packages (a path, not a site dir: its
    # .pth files, the checkout's editable install among them, are not read)
    (purelib / "dependencies.pth").write_text(sysconfig.get_paths()["purelib"] + "\n")
    subprocess.run(
        [
            *PIP,
            "--python",
            str(env_dir / "bin" / "python"),
            "install",
            "--no-deps",
            "--no-index",
            "-q",
            str(wheel),
        ],
        check=True,
        capture_output=True,
        timeout=300,
    )
    return env_dir / "bin"


def _run(bin_dir: Path, *args: str, cwd: Path, **env: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [str(bin_dir / args[0]), *args[1:]],
        cwd=cwd,
        capture_output=True,
        text=True,
        timeout=300,
        env={**os.environ, "PYTHONPATH": "", **env},
    )


def test_the_documented_api_works_from_the_installed_wheel(installed, tmp_path):
    code = (
        "import inspect, trl_cartpole\n"
        "from trl_cartpole import train, make_dqn_loss, make_env, make_q_actor\n"
        "assert inspect.isfunction(train), train\n"
        "print(trl_cartpole.__file__)\n"
        "env = make_env('CartPole-v1')\n"
        "actor = make_q_actor(env.observation_spec, env.action_spec, num_cells=[8])\n"
        "print(type(make_dqn_loss(value_network=actor, delay_value=True)).__name__)\n"
    )
    proc = _run(installed, "python", "-c", code, cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    module_file, loss = proc.stdout.split()
    assert Path(module_file).is_relative_to(installed.parent)  # the wheel's, not the checkout's
    assert loss == "DQNLoss"


def test_the_command_trains_a_shipped_preset_and_a_users_own_outside_the_repository(
    installed, tmp_path
):
    help_text = _run(installed, "trl-cartpole", "train", "--help", cwd=tmp_path)
    assert help_text.returncode == 0
    assert all(f"env={name}" in help_text.stdout for name in ("lunarlander", "acrobot"))
    typo = _run(installed, "trl-cartpole", "train", "loss.gama=0.9", cwd=tmp_path)
    assert typo.returncode == 2 and typo.stderr.count("\n") == 1 and "gama" in typo.stderr
    # a preset of the user's own, beside the shipped ones
    mine = tmp_path / "mine" / "env"
    mine.mkdir(parents=True)
    (mine / "tiny.yaml").write_text(
        "# @package _global_\n# Acrobot on a tiny budget\ndefaults:\n  - acrobot\n  - _self_\n"
        "collector:\n  total_frames: 256\n  init_random_frames: 64\n"
        "eval:\n  interval_frames: 128\n  episodes: 1\n  final_episodes: 1\n  max_steps: 50\n"
        "env:\n  num_envs: 2\n  max_episode_steps: 50\n"
        "buffer:\n  batch_size: 16\nlogger:\n  plots: false\n  live_plot: false\n"
    )
    run = _run(
        installed,
        "trl-cartpole",
        "train",
        "presets=mine",
        "env=tiny",
        "run_dir=runs/tiny",
        "collector.frames_per_batch=16",
        cwd=tmp_path,
    )
    assert run.returncode == 0, run.stderr
    assert "Acrobot-v1" in run.stdout and "trl-cartpole evaluate checkpoint=runs/tiny" in run.stdout
    assert (tmp_path / "runs" / "tiny" / "summary.json").exists()

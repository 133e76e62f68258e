"""The README's installs resolve the same on any day: they take ``-c constraints.txt``, the
versions CI tests, and this environment is those versions."""

from __future__ import annotations

import re
import sys
from importlib import metadata
from pathlib import Path

from tests.conftest import run_script_in_process

ROOT = Path(__file__).resolve().parent.parent


def _pins() -> dict[str, str]:
    lines = (ROOT / "constraints.txt").read_text().splitlines()
    return dict(line.split("==") for line in lines if line and not line.startswith("#"))


def test_every_pinned_distribution_installed_here_has_its_pinned_version():
    pins = _pins()
    assert "gymnasium" in pins and "tensordict" in pins and "torch" not in pins
    drifted = {}
    for name, pinned in pins.items():
        try:
            found = metadata.version(name)
        except metadata.PackageNotFoundError:
            continue  # an extra this environment lacks
        if found != pinned:
            drifted[name] = (pinned, found)
    assert not drifted, (
        f"installed versions differ from constraints.txt {drifted}: reinstall with "
        "-c constraints.txt, or regenerate it after a green CI run (python -m maintain lock)"
    )


def test_the_readme_installs_take_the_constraints():
    readme = (ROOT / "README.md").read_text()
    installs = [line for line in readme.splitlines() if "pip install torch==2.13.0 -e ." in line]
    assert installs and all("-c constraints.txt" in line for line in installs[:2])


def test_every_install_hint_names_an_extra_and_installs_as_the_readme_does():
    import tomllib

    from trl_cartpole.errors import install_hint

    extras = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"][
        "optional-dependencies"
    ]
    named = {
        match
        for path in (ROOT / "src" / "trl_cartpole").rglob("*.py")
        for match in re.findall(r"install_hint\(['\"](\w+)['\"]\)", path.read_text())
    }
    named |= {"box2d"}  # envs.ids.OPTIONAL_EXTRAS: the extra of an env family
    assert named and named <= set(extras), named - set(extras)
    hint = install_hint("tensorboard")
    pip = Path(sys.executable).with_name("pip").absolute()  # this interpreter's own pip
    assert Path(hint.split(" install ")[0]).absolute() == pip
    assert ' -e ".[tensorboard]" -c constraints.txt ' in hint
    assert f"torch=={metadata.version('torch').split('+')[0]} " in hint


def test_a_logger_without_its_package_is_refused_before_anything_is_written(tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "tensorboard", None)  # its import blocked: not installed
    run_dir = tmp_path / "run"
    proc = run_script_in_process("train.py", "logger.backend=tensorboard", f"run_dir={run_dir}")
    assert proc.returncode == 2 and "needs tensorboard" in proc.stderr
    assert '-e ".[tensorboard]" -c constraints.txt' in proc.stderr
    assert not run_dir.exists()

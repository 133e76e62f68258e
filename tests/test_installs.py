"""The README's installs resolve the same on any day: they take ``-c constraints.txt``, the
versions CI tests, and this environment is those versions."""

from __future__ import annotations

from importlib import metadata
from pathlib import Path

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

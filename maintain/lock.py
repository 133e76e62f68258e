"""Write ``constraints.txt``: the versions of this environment, which CI installs and tests.

Run after a green CI run, in its environment (``.venv`` with the test extras): the README's
install commands take ``-c constraints.txt``, so they resolve the same versions on any later
day; ``tests/test_installs.py`` checks the environment matches it. torch is left out (the
commands pin its CPU wheel themselves), and so are pip, setuptools, wheel and this project.
``--check`` writes nothing and exits 1 if the file differs from this environment.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
CONSTRAINTS = ROOT / "constraints.txt"
HEADER = """\
# The versions CI installs and tests, pinned so the README's commands resolve the same tomorrow
# (pip install ... -c constraints.txt). torch is pinned by the commands themselves (its CPU
# wheel); extras CI does not install (notebook, video, wandb) resolve freely. Regenerate after a
# green CI run: .venv/bin/python -m maintain lock (docs/choices.md).
"""
LEFT_OUT = ("torch", "pip", "setuptools", "wheel", "trl-cartpole", "trl_cartpole")


def pinned_lines() -> list[str]:
    """``name==version`` of every distribution installed here, but those left out."""
    frozen = subprocess.run(
        [sys.executable, "-m", "pip", "freeze", "--exclude-editable"],
        capture_output=True,
        text=True,
        check=True,
    ).stdout.splitlines()
    return [line for line in frozen if "==" in line and line.split("==")[0].lower() not in LEFT_OUT]


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--check", action="store_true", help="write nothing; exit 1 if stale")


def main(args: argparse.Namespace) -> None:
    text = HEADER + "\n".join(pinned_lines()) + "\n"
    if args.check:
        if CONSTRAINTS.read_text() != text:
            print("constraints.txt differs from this environment (python -m maintain lock)")
            sys.exit(1)
        print("constraints.txt is this environment")
        return
    CONSTRAINTS.write_text(text)
    print(f"wrote {CONSTRAINTS.relative_to(ROOT)}: {text.count('==')} pinned versions")

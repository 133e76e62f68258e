"""The ways a run ends other than by finishing; imported by every module that raises them.

They live in a module of their own, which imports nothing of the package, so that the schema
(``config``), the factories and the training loop can all raise them without importing one
another. :func:`install_hint` is the command their messages give for a missing extra.
"""

from __future__ import annotations

import sys
from importlib import metadata
from pathlib import Path

__all__ = [
    "ConfigError",
    "DiskFull",
    "TrainingFailed",
    "TrainingInterrupted",
    "WorkerLost",
    "install_hint",
]


def install_hint(extra: str) -> str:
    """The command that installs the project's ``extra`` as the README installs: this
    interpreter's pip, the torch version installed here pinned (its CPU wheel stays), the
    clone's ``constraints.txt``; and the form for an install from PyPI."""
    pip = Path(sys.executable).with_name("pip")
    try:
        shown = str(pip.absolute().relative_to(Path.cwd()))
    except ValueError:  # not under the current directory
        shown = str(pip.absolute())
    try:
        torch = f"torch=={metadata.version('torch').split('+')[0]} "
    except metadata.PackageNotFoundError:
        torch = ""
    return (
        f'{shown} install {torch}-e ".[{extra}]" -c constraints.txt (from a clone; '
        f'pip install "trl_cartpole[{extra}]" otherwise)'
    )


class ConfigError(ValueError):
    """A configuration that cannot run; the message is one line saying what to change."""


class TrainingFailed(Exception):
    """The run stopped on a numerical fault; ``summary.json`` records it."""


class TrainingInterrupted(Exception):
    """The run stopped on a signal after writing a checkpoint; the message says how to resume."""

    def __init__(self, message: str, signum: int) -> None:
        super().__init__(message)
        self.exit_code = 128 + signum  # the shell's convention: 130 for SIGINT, 143 for SIGTERM


class DiskFull(Exception):
    """The run stopped because a checkpoint did not fit on its disk; the message names the path,
    the space it needs and the resume command (the previous checkpoint is whole)."""


class WorkerLost(Exception):
    """A collector worker (a Ray actor) died; the run saved the batches trained so far and the
    message names the worker and the resume command."""

"""The three ways a run ends other than by finishing; imported by every module that raises them.

They live in a module of their own, which imports nothing of the package, so that the schema
(``config``), the factories and the training loop can all raise them without importing one
another.
"""

from __future__ import annotations

__all__ = ["ConfigError", "TrainingFailed", "TrainingInterrupted"]


class ConfigError(ValueError):
    """A configuration that cannot run; the message is one line saying what to change."""


class TrainingFailed(Exception):
    """The run stopped on a numerical fault; ``summary.json`` records it."""


class TrainingInterrupted(Exception):
    """The run stopped on a signal after writing a checkpoint; the message says how to resume."""

    def __init__(self, message: str, signum: int) -> None:
        super().__init__(message)
        self.exit_code = 128 + signum  # the shell's convention: 130 for SIGINT, 143 for SIGTERM

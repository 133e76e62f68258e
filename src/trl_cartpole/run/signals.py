"""How a run is stopped from outside: a stop signal becomes a request the loop honours.

:class:`StopRequest` turns the first SIGINT (Ctrl-C), SIGTERM (``kill``, a scheduler),
SIGHUP (the terminal or SSH connection closed) or SIGUSR1 (SLURM's ``--signal=USR1@60``
warning before preemption) into a flag the training loop reads at its next chance to save (the
end of a collected batch), where it writes a checkpoint and raises :class:`TrainingInterrupted`.
A second signal leaves at once (checkpoint writes are atomic, so that corrupts nothing): in a
command line's run (:func:`second_signal_ends_process`) the first signal hands the stop
signals back to the operating system's default action, so the second ends the process
whatever it is doing, inside a long C call (a batch, an allocation, a write) included, where
no Python handler could run; called from Python (a notebook's kernel must survive it), the
second signal raises ``KeyboardInterrupt`` at the interpreter's next step. The errors live in
:mod:`trl_cartpole.errors`.

Output must not stop a save: once the terminal is gone or the reader of a pipe (``| tee``)
has died, writing to stdout or stderr raises ``OSError``. :func:`unbreakable_console` makes
such writes silent, for the training (``StopRequest``) and for a whole command line run.
"""

from __future__ import annotations

import signal
import sys
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from types import FrameType
from typing import Any, TextIO

__all__ = [
    "StopRequest",
    "UnbreakableStream",
    "install_unbreakable_console",
    "second_signal_ends_process",
    "unbreakable_console",
]

# The stop signals this platform has (SIGHUP and SIGUSR1 are POSIX only).
STOP_SIGNALS = tuple(
    getattr(signal, name)
    for name in ("SIGINT", "SIGTERM", "SIGHUP", "SIGUSR1")
    if hasattr(signal, name)
)


# Inside a command line's run: the second stop signal takes the default action (the end).
_second_signal_ends_process = False


@contextmanager
def second_signal_ends_process() -> Iterator[None]:
    """Inside the block, a second stop signal ends the process at once, by the operating
    system's default action (exit status 128 + the signal as a shell reports it), whatever
    Python is doing. For a command line's run, not for a notebook's kernel."""
    global _second_signal_ends_process
    saved, _second_signal_ends_process = _second_signal_ends_process, True
    try:
        yield
    finally:
        _second_signal_ends_process = saved


class UnbreakableStream:
    """A text stream whose writes never raise: after the first failure they are dropped.

    Wraps ``sys.stdout`` / ``sys.stderr`` so that a closed terminal (``EIO``) or a pipe whose
    reader died (``EPIPE``) cannot end a run between a stop signal and its checkpoint.
    """

    def __init__(self, stream: TextIO) -> None:
        self.stream, self.broken = stream, False

    def write(self, text: str) -> int:
        if not self.broken:
            try:
                return self.stream.write(text)
            except (OSError, ValueError):  # EPIPE, EIO, or a closed file
                self.broken = True
        return len(text)

    def flush(self) -> None:
        if not self.broken:
            try:
                self.stream.flush()
            except (OSError, ValueError):
                self.broken = True

    def __getattr__(self, name: str) -> Any:  # isatty, fileno, encoding...: the stream's own
        return getattr(self.stream, name)


def install_unbreakable_console() -> None:
    """Make ``sys.stdout`` and ``sys.stderr`` :class:`UnbreakableStream` (if not already)."""
    if not isinstance(sys.stdout, UnbreakableStream):
        sys.stdout = UnbreakableStream(sys.stdout)
    if not isinstance(sys.stderr, UnbreakableStream):
        sys.stderr = UnbreakableStream(sys.stderr)


@contextmanager
def unbreakable_console() -> Iterator[None]:
    """Inside the block, ``sys.stdout`` and ``sys.stderr`` are :class:`UnbreakableStream`."""
    saved = sys.stdout, sys.stderr
    install_unbreakable_console()
    try:
        yield
    finally:
        sys.stdout, sys.stderr = saved


class StopRequest:
    """Catch the stop signals during training (a no-op outside the main thread).

    Inside it the console is unbreakable (:func:`unbreakable_console`).
    """

    SIGNALS = STOP_SIGNALS

    def __init__(self) -> None:
        self.signum: int | None = None
        self._previous: dict[int, object] = {}
        self._console = unbreakable_console()

    def __enter__(self) -> StopRequest:
        self._console.__enter__()
        if threading.current_thread() is threading.main_thread():
            for signum in self.SIGNALS:
                self._previous[signum] = signal.signal(signum, self._handle)
        return self

    def rearm(self) -> None:
        """Install the handlers again, over any a library set since (``ray.init`` installs a
        SIGTERM handler in C that prints a stack trace and kills the process)."""
        after_first = self.signum is not None and _second_signal_ends_process
        for signum in self._previous:  # after a first signal the next one still ends it
            signal.signal(signum, signal.SIG_DFL if after_first else self._handle)

    def __exit__(self, *exc_info: object) -> None:
        for signum, handler in self._previous.items():
            signal.signal(signum, handler)
        self._previous.clear()
        self._console.__exit__(*exc_info)

    def _handle(self, signum: int, frame: FrameType | None) -> None:
        if self.signum is not None:
            raise KeyboardInterrupt  # the second signal: leave now
        self.signum = signum
        if _second_signal_ends_process:  # the next one: the OS's default action, at once
            for stop_signal in self._previous:
                signal.signal(stop_signal, signal.SIG_DFL)
        print(
            f"\n{signal.Signals(signum).name}: saving a checkpoint at the end of this batch "
            "(send it again to exit at once; the newest complete checkpoint is kept)",
            file=sys.stderr,
            flush=True,
        )

    @property
    def requested(self) -> bool:
        return self.signum is not None

"""How a run is stopped from outside: SIGINT or SIGTERM become a request the loop honours.

:class:`StopRequest` turns the first SIGINT/SIGTERM into a flag the training loop reads at its
next safe point (the end of a collected batch), where it writes a checkpoint and raises
:class:`TrainingInterrupted`; a second signal raises ``KeyboardInterrupt`` at once (checkpoint
writes are atomic, so that corrupts nothing). The errors live in :mod:`trl_cartpole.errors`.
"""

from __future__ import annotations

import signal
import sys
import threading
from types import FrameType

__all__ = ["StopRequest"]


class StopRequest:
    """Catch SIGINT and SIGTERM during training (a no-op outside the main thread)."""

    SIGNALS = (signal.SIGINT, signal.SIGTERM)

    def __init__(self) -> None:
        self.signum: int | None = None
        self._previous: dict[int, object] = {}

    def __enter__(self) -> StopRequest:
        if threading.current_thread() is threading.main_thread():
            for signum in self.SIGNALS:
                self._previous[signum] = signal.signal(signum, self._handle)
        return self

    def __exit__(self, *exc_info: object) -> None:
        for signum, handler in self._previous.items():
            signal.signal(signum, handler)
        self._previous.clear()

    def _handle(self, signum: int, frame: FrameType | None) -> None:
        if self.signum is not None:
            raise KeyboardInterrupt  # the second signal: leave now
        self.signum = signum
        print(
            f"\n{signal.Signals(signum).name}: saving a checkpoint at the end of this batch "
            "(send it again to exit at once)",
            file=sys.stderr,
            flush=True,
        )

    @property
    def requested(self) -> bool:
        return self.signum is not None

"""One writer per run directory: a lock that a second process meets, and a dead one releases.

:class:`RunLock` holds an exclusive ``flock`` on ``RUN_DIR/.lock`` for as long as a run
writes there. A second ``train.py`` on the same ``run_dir``, or a ``resume=`` of a run that
another process is training, stops at once with a one-line :class:`ConfigError` naming that
process (its pid, host and start time, which the lock file records). The operating system
releases the lock when its process ends, however it ends, so a lock left by a killed run never
blocks the next one. Where ``fcntl`` does not exist (Windows) there is no lock.
"""

from __future__ import annotations

import os
import socket
import time
from pathlib import Path

from trl_cartpole.errors import ConfigError

try:
    import fcntl
except ImportError:  # pragma: no cover - not POSIX
    fcntl = None

__all__ = ["LOCK_NAME", "RunLock"]

LOCK_NAME = ".lock"


class RunLock:
    """The exclusive right to write ``run_dir``, taken on creation; :meth:`release` gives it up."""

    def __init__(self, run_dir: str | Path) -> None:
        self.path = Path(run_dir) / LOCK_NAME
        self._file = None
        if fcntl is None:
            return
        handle = open(self.path, "a+")  # noqa: SIM115 - held open for the run's lifetime
        try:
            fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            handle.seek(0)
            holder = handle.read().strip() or "another process"
            handle.close()
            raise ConfigError(
                f"run_dir={str(Path(run_dir))!r} is being written by {holder}; wait for it to "
                "end or stop it, or choose another run_dir"
            ) from None
        handle.seek(0)
        handle.truncate()
        started = time.strftime("%Y-%m-%d %H:%M:%S")
        handle.write(f"process {os.getpid()} on {socket.gethostname()} (since {started})\n")
        handle.flush()
        self._file = handle

    def release(self) -> None:
        """Give the directory up (closing the file releases the lock); safe to call twice.

        The holder's line is cleared first, so a finished run's ``.lock`` names no process."""
        if self._file is not None:
            self._file.seek(0)
            self._file.truncate()
            self._file.close()
            self._file = None

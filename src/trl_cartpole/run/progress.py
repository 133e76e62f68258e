"""How far a run is: frames, gradient updates, training seconds and where those seconds went.

``Progress`` is the loop's own counter, saved in every training state. Its clock is paused for
evaluation and checkpoints, so ``train_seconds`` and ``seconds_to_solve`` count training only.
``phase(name)`` times a block of the loop under a name the loop gives it (``collect``,
``update``...); the summary reports those seconds (``phase_seconds``), which is what
``python -m benchmarks profile`` prints. :func:`resident_mb` is the memory of the process and its
workers now, which each evaluation records.
"""

from __future__ import annotations

import time
from collections import defaultdict
from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any, TypeVar

__all__ = ["Progress", "Stopwatch", "resident_mb"]

T = TypeVar("T")


def resident_mb() -> float | None:
    """Resident memory now, in MiB, of this process and the processes it started (its collector
    workers, their children): the sum of each one's ``VmRSS`` in Linux's ``/proc``, so pages
    they share (the workers' copy of the policy weights) count once per process. Ray's actors
    are the Ray node's children, not this process's, and are not counted. None off Linux."""
    try:
        return round(sum(_resident_kib(pid) for pid in _process_tree("self")) / 1024, 1)
    except (OSError, IndexError, ValueError):
        return None


def _process_tree(pid: str) -> list[str]:
    """``pid`` and every live descendant, from ``/proc/PID/task/TID/children``."""
    tree, index = [pid], 0
    while index < len(tree):
        for children in Path(f"/proc/{tree[index]}/task").glob("*/children"):
            try:
                tree.extend(children.read_text().split())
            except OSError:  # the thread ended meanwhile
                continue
        index += 1
    return tree


def _resident_kib(pid: str) -> int:
    """``VmRSS`` of ``pid`` in KiB; 0 for a process that ended meanwhile (gone, or a zombie
    not yet reaped, whose status has no ``VmRSS`` line)."""
    try:
        status = Path(f"/proc/{pid}/status").read_text()
    except (FileNotFoundError, ProcessLookupError):
        return 0
    rss = (int(line.split()[1]) for line in status.splitlines() if line.startswith("VmRSS:"))
    return next(rss, 0)


class Stopwatch:
    """Wall time with pauses, so evaluation can be left out of the training time."""

    def __init__(self) -> None:
        self.elapsed = 0.0
        self._start: float | None = None

    def start(self) -> None:
        self._start = time.perf_counter()

    def pause(self) -> None:
        if self._start is not None:
            self.elapsed += time.perf_counter() - self._start
            self._start = None

    @property
    def running(self) -> bool:
        return self._start is not None

    @property
    def seconds(self) -> float:
        running = 0.0 if self._start is None else time.perf_counter() - self._start
        return self.elapsed + running


class Progress:
    """Frames collected, updates taken, the training clock and the seconds of each phase."""

    def __init__(self) -> None:
        self.frames = 0
        self.updates = 0
        self.clock = Stopwatch()
        self.phase_seconds: dict[str, float] = defaultdict(float)
        # the collector's total_frames and max_train_seconds under which the training loop
        # ended (None: it has not), at them or earlier (a solved run stops): a resume under the
        # same goes to the ending
        self.ended_under: dict[str, Any] | None = None

    @contextmanager
    def phase(self, name: str) -> Iterator[None]:
        """Add the time spent in the ``with`` block to ``phase_seconds[name]``."""
        start = time.perf_counter()
        try:
            yield
        finally:
            self.phase_seconds[name] += time.perf_counter() - start

    def timed(self, items: Iterable[T], name: str) -> Iterator[T]:
        """Yield from ``items``, adding the time spent producing each to ``phase_seconds``."""
        iterator = iter(items)
        while True:
            with self.phase(name):
                try:
                    item = next(iterator)
                except StopIteration:
                    return
            yield item

    def state_dict(self) -> dict[str, Any]:
        return {
            "frames": self.frames,
            "updates": self.updates,
            "train_seconds": self.clock.seconds,
            "phase_seconds": dict(self.phase_seconds),
            "ended_under": self.ended_under,
        }

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.frames, self.updates = state["frames"], state["updates"]
        self.clock.elapsed = state["train_seconds"]
        self.phase_seconds.clear()
        self.phase_seconds.update(state["phase_seconds"])
        self.ended_under = state["ended_under"]

"""The checkpointer of a run: the training state saved periodically, on a stop signal, on a
full disk or a lost worker, and at the end; the best policy as evaluations find it.

The format (manifests, integrity records, what loads how) is :mod:`trl_cartpole.store.checkpoint`.
"""

from __future__ import annotations

import errno
import math
import shlex
import signal
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

from torch import nn
from torchrl.checkpoint import Checkpoint

from trl_cartpole.compat import restore_last_written_row
from trl_cartpole.config.schema import Config
from trl_cartpole.errors import DiskFull, TrainingInterrupted, WorkerLost
from trl_cartpole.report.console import command, shown_path
from trl_cartpole.run.progress import Progress
from trl_cartpole.storage.chunked import confirm_chunked_writes
from trl_cartpole.store.checkpoint import (
    DISK_MARGIN_BYTES,
    DISK_MARGIN_FRACTION,
    check_training_state_format,
    find_complete_checkpoints,
    load_training_state,
    save_policy,
    save_training_state,
    state_bytes,
)
from trl_cartpole.store.collection_state import EnvState
from trl_cartpole.store.files import free_bytes, megabytes, tree_bytes

__all__ = ["Checkpointer"]


def _saved_bytes(name: str, component: Any) -> int:
    """The bytes a checkpoint stores of ``component``: its state dict's tensors, of a replay
    buffer only the filled share of its storage (the capacity is allocated at once)."""
    size = state_bytes(component.state_dict())
    if name != "replay_buffer":
        return size
    capacity = max(component.storage.max_size, 1)
    return size * min(len(component), capacity) // capacity


def play_commands(run_dir: Path) -> str:
    """The ``next:`` lines of a stopped run: evaluate and render the policy its directory offers
    (its best, or before its first evaluation its newest training state's)."""
    where = shlex.quote(shown_path(run_dir))
    return "\n".join(
        [
            "next:",
            f"  {command('evaluate')} checkpoint={where}   # greedy episodes of the policy so far",
            f"  {command('render')} checkpoint={where}     # a GIF of it",
        ]
    )


class Checkpointer:
    """Saves the training state: periodically, on a stop signal, and at the end of the run.

    ``components`` maps checkpoint names to objects with ``state_dict``/``load_state_dict``
    (TorchRL modules, the optimizer, the replay buffer, the collector, the loop's own state);
    they are saved together with the global RNG states, and loaded in their order.
    """

    def __init__(
        self,
        run_dir: Path,
        stored_config: Config,
        components: Mapping[str, Any],
        observation_norm: dict[str, list[float]] | None = None,
        metrics: Any = None,
        *,
        interval_frames: int,
        keep_last: int | None,
        save_best: bool,
        save_last: bool,
    ) -> None:
        self.run_dir = run_dir
        self.stored_config = stored_config  # written with every checkpoint: what rebuilds it
        self.components = dict(components)
        self.observation_norm = observation_norm
        self.metrics = metrics  # a MetricsLog: its W&B step goes into the counters
        self.free_bytes = free_bytes  # the disk's free space at a path (a test may replace it)
        self.interval = interval_frames or math.inf  # 0: no periodic state
        self.keep_last = keep_last  # periodic states kept (None: all)
        self.saves_best, self.saves_last = save_best, save_last
        self.last_saved_frame = 0
        # bytes the last training state wrote (its files linked from the one before not counted):
        # about what the next one writes
        self.state_size: int | None = None

    def load(self, path: str | Path, progress: Progress) -> None:
        """Restore every component from the training state at ``path``."""
        check_training_state_format(path)
        components = dict(self.components)
        if "replay_buffer" not in Checkpoint.manifest(path)["components"]:
            components.pop("replay_buffer", None)  # saved while an n-step buffer was empty
        load_training_state(path, **components)
        if "replay_buffer" in components:
            restore_last_written_row(components["replay_buffer"])
        self.last_saved_frame = progress.frames

    def save(self, path: Path, progress: Progress, keep_last: int | None = None) -> Path:
        counters = {"frames": progress.frames, "updates": progress.updates}
        if progress.ended_under is not None:  # the loop has ended: the ending is left
            counters["ended_under"] = progress.ended_under
        logger_step = None if self.metrics is None else self.metrics.logger_step()
        if logger_step is not None:
            counters["logger_step"] = logger_step  # a W&B resume rewinds to it
        buffer = self.components.get("replay_buffer")
        # An n-step buffer may still be empty (its windows are not complete yet): nothing to save.
        components = {
            name: component
            for name, component in self.components.items()
            if name != "replay_buffer" or len(buffer) > 0
        }
        # A training state is about as large as the one before it; the first is estimated from
        # its tensors, the replay buffer's for its filled rows (storage/chunked.py).
        expected = self.state_size or sum(
            _saved_bytes(name, component) for name, component in components.items()
        )
        saved = self._write_or_stop(
            path,
            expected,
            lambda: save_training_state(
                path,
                self.stored_config,
                counters,
                keep_last,
                observation_norm=self.observation_norm,
                **components,
            ),
        )
        if buffer is not None:  # its next checkpoint links the rows unchanged since this one
            confirm_chunked_writes(buffer, saved)
        self.state_size = tree_bytes(saved, new_only=True)
        return saved

    def _write_or_stop(self, path: Path, expected: int, write: Callable[[], Path]) -> Path:
        """``write()`` a checkpoint of about ``expected`` bytes at ``path``, or raise
        :class:`DiskFull` if it cannot fit: before the write when the free space is short,
        after it when the write fails with ENOSPC (TorchRL's staged files are then removed)."""
        needed = int(expected * (1 + DISK_MARGIN_FRACTION)) + DISK_MARGIN_BYTES
        if self.free_bytes(path) < needed:
            raise self._disk_full(path, needed)
        try:
            return write()
        except OSError as error:
            if error.errno != errno.ENOSPC:
                raise
            raise self._disk_full(path, needed) from None

    def _disk_full(self, path: Path, needed: int) -> DiskFull:
        free = self.free_bytes(path)
        if find_complete_checkpoints(self.run_dir):
            then = f"then resume with: {self.resume_command()}"
        else:
            then = "then start the run again (no training state was written before this one)"
        if free >= needed:  # the write failed all the same: something else fills the disk
            return DiskFull(
                f"no space left for the checkpoint at {shown_path(path)}: the write failed with "
                f"ENOSPC though {megabytes(free)} is free now (another writer on that disk?); "
                f"make room, {then}"
            )
        return DiskFull(
            f"no space left for the checkpoint at {shown_path(path)}: it needs about "
            f"{megabytes(needed)} and {megabytes(free)} is free; free "
            f"{megabytes(needed - free)} or more on that disk, {then}"
        )

    def maybe_save(self, progress: Progress, stop: Any) -> None:
        """Save a periodic state when one is due or a stop signal came (then stop the run).

        ``stop`` is the :class:`~trl_cartpole.run.signals.StopRequest` of the loop. After a
        signal, the state is saved and :class:`TrainingInterrupted` raised.
        """
        due = progress.frames - self.last_saved_frame >= self.interval
        if not (due or stop.requested):
            return
        self._save_periodic(progress)
        if stop.requested:
            raise TrainingInterrupted(
                f"stopped by {signal.Signals(stop.signum).name} at frame {progress.frames}; "
                f"checkpoint written; resume with: {self.resume_command()}\n"
                f"{play_commands(self.run_dir)}",
                stop.signum,
            )
        progress.clock.start()

    def stop_for_lost_worker(self, progress: Progress, lost: str) -> WorkerLost:
        """Save a periodic state of the batches trained so far; return the error that ends the
        run, naming the ``lost`` worker and the resume command. The workers' envs are left out
        of it (a lost worker never answers): a resume starts their episodes anew."""
        envs = self.components.get("envs")
        if isinstance(envs, EnvState):
            envs.forget_workers()
        self._save_periodic(progress)
        return WorkerLost(
            f"{lost}; the run stopped at frame {progress.frames} with a checkpoint; resume with: "
            f"{self.resume_command()}"
        )

    def _save_periodic(self, progress: Progress) -> None:
        """Stop the training clock and save a state under ``checkpoints/periodic``."""
        progress.clock.pause()
        self.save(self.run_dir / "checkpoints" / "periodic", progress, self.keep_last)
        self.last_saved_frame = progress.frames

    def resume_command(self) -> str:
        """The command that continues this run from its newest checkpoint."""
        return f"{command('train')} resume={shown_path(self.run_dir)}"

    def save_best(self, policy: nn.Module, frames: int, eval_return_mean: float) -> None:
        """The best policy so far (``checkpoints/best``), if ``checkpoint.save_best``."""
        if self.saves_best:
            path = self.run_dir / "checkpoints" / "best"
            self._write_or_stop(
                path,
                state_bytes(policy.state_dict()),
                lambda: save_policy(
                    path,
                    policy,
                    self.stored_config,
                    frames=frames,
                    eval_return_mean=eval_return_mean,
                    observation_norm=self.observation_norm,
                ),
            )

    def save_last(self, progress: Progress) -> None:
        """The end-of-run state (``checkpoints/last``), if ``checkpoint.save_last``."""
        if self.saves_last:
            self.save(self.run_dir / "checkpoints" / "last", progress)

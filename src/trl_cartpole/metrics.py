"""Metrics logging through TorchRL loggers, plus the in-memory history the plots read."""

from __future__ import annotations

import resource
import time
from dataclasses import dataclass, field
from pathlib import Path

from torchrl.record.loggers import CSVLogger, Logger, TensorboardLogger, WandbLogger

from trl_cartpole.config import ConfigError
from trl_cartpole.files import write_text_atomic

__all__ = ["History", "Stopwatch", "make_logger", "peak_rss_mb", "truncate_csv_metrics"]


def peak_rss_mb() -> float:
    """This process's peak resident memory in MiB (Linux reports ``ru_maxrss`` in KiB)."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


class Stopwatch:
    """Wall time with pauses, so evaluation can be left out of the training time.

    ``train()`` and the benchmark's peers (``trl_cartpole.peers.protocol``) time with it.
    """

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
    def seconds(self) -> float:
        running = 0.0 if self._start is None else time.perf_counter() - self._start
        return self.elapsed + running


def make_logger(
    backend: str,
    run_dir: str | Path,
    project: str = "trl_cartpole",
    wandb_offline: bool = True,
) -> Logger | None:
    """Return TorchRL's ``CSVLogger``, ``TensorboardLogger`` or ``WandbLogger`` for ``run_dir``.

    ``CSVLogger`` writes one ``metrics/scalars/<name>.csv`` per scalar, each row ``step,value``
    with ``step`` the frame count; ``TensorboardLogger`` writes event files under
    ``run_dir/metrics``; ``WandbLogger`` logs to ``project`` (offline by default, files under
    ``run_dir/wandb``). ``backend="none"`` returns ``None``.
    """
    if backend == "none":
        return None
    if backend == "csv":
        return CSVLogger(exp_name="metrics", log_dir=str(run_dir))
    if backend == "tensorboard":
        try:
            import tensorboard  # noqa: F401
        except ImportError:
            raise ConfigError(
                "logger.backend=tensorboard needs tensorboard: pip install -e '.[tensorboard]'"
            ) from None
        return TensorboardLogger(exp_name="metrics", log_dir=str(run_dir))
    if backend == "wandb":
        try:
            import wandb  # noqa: F401
        except ImportError:
            raise ConfigError(
                "logger.backend=wandb needs wandb: pip install -e '.[wandb]'"
            ) from None
        return WandbLogger(
            exp_name=Path(run_dir).name,
            offline=wandb_offline,
            save_dir=str(run_dir),
            project=project,
        )
    raise ConfigError(f"logger.backend={backend!r}; choose csv, tensorboard, wandb or none")


@dataclass
class History:
    """What the plots and the summary need from a run, kept in memory."""

    episode_returns: list[float] = field(default_factory=list)
    episode_lengths: list[int] = field(default_factory=list)
    update_frames: list[int] = field(default_factory=list)
    td_losses: list[float] = field(default_factory=list)
    grad_norms: list[float] = field(default_factory=list)
    eval_frames: list[int] = field(default_factory=list)
    eval_seconds: list[float] = field(default_factory=list)
    eval_returns: list[float] = field(default_factory=list)
    eval_initial_values: list[float] = field(default_factory=list)


def truncate_csv_metrics(run_dir: str | Path, frames: int) -> None:
    """Drop the CSV rows logged after ``frames`` (``run_dir/metrics/scalars/**.csv``).

    A resumed run logs those frames again; each file is rewritten atomically.
    """
    for path in (Path(run_dir) / "metrics" / "scalars").rglob("*.csv"):
        rows = path.read_text().splitlines(keepends=True)
        kept = [row for row in rows if row.strip() and int(row.split(",", 1)[0]) <= frames]
        write_text_atomic(path, "".join(kept))

"""Metrics logging through TorchRL loggers, plus the in-memory history the plots read."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from torchrl.record.loggers import CSVLogger, Logger, TensorboardLogger

from trl_cartpole.config import ConfigError

__all__ = ["History", "make_logger"]


def make_logger(backend: str, run_dir: str | Path) -> Logger | None:
    """Return TorchRL's ``CSVLogger`` or ``TensorboardLogger`` writing under ``run_dir/metrics``.

    ``CSVLogger`` writes one ``metrics/scalars/<name>.csv`` per scalar, each row ``step,value``
    with ``step`` the frame count. ``backend="none"`` returns ``None``.
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
    raise ConfigError(f"logger.backend={backend!r}; choose csv, tensorboard or none")


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

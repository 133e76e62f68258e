"""A run's directory: made (or refused) before anything is written, ``runs/latest`` pointed at
it, and the folder local worker processes write their output to."""

from __future__ import annotations

import os
import shutil
from pathlib import Path

from trl_cartpole.config.schema import Config
from trl_cartpole.errors import ConfigError

__all__ = ["fresh_worker_log_dir", "point_latest", "prepare_run_dir", "worker_log_dir"]


def point_latest(run_dir: Path) -> None:
    """Point ``runs/latest`` at ``run_dir`` when it lies in a ``runs`` directory (best effort).

    So a command can name the newest run without knowing its timestamp
    (``scripts/evaluate.py checkpoint=runs/latest``); the link is replaced atomically.
    """
    real = run_dir.resolve()
    if real.parent.name != "runs" or real.name == "latest":
        return
    temporary = real.parent / f".latest-{os.getpid()}"
    try:
        temporary.unlink(missing_ok=True)
        temporary.symlink_to(real.name)
        os.replace(temporary, real.parent / "latest")
    except OSError:  # a file system without symbolic links, or a real directory named latest
        temporary.unlink(missing_ok=True)


def prepare_run_dir(run_dir: str | Path) -> Path:
    """Create ``run_dir`` (and point ``runs/latest`` at it), or raise a one-line ConfigError."""
    path = Path(run_dir)
    try:
        path.mkdir(parents=True, exist_ok=True)
        probe = path / ".write-probe"
        probe.write_text("")
        probe.unlink()
    except OSError as error:
        raise ConfigError(
            f"run_dir={str(path)!r} is not writable ({error.strerror}); choose another run_dir"
        ) from None
    point_latest(path)
    return path


def worker_log_dir(cfg: Config, run_dir: Path) -> Path | None:
    """Where local collector worker processes write their output (None on Ray: Ray keeps it)."""
    return run_dir / "workers" if cfg.collector.backend == "local" else None


def fresh_worker_log_dir(cfg: Config, run_dir: Path) -> Path | None:
    """:func:`worker_log_dir`, emptied of an earlier session's logs (a resume, a rerun)."""
    log_dir = worker_log_dir(cfg, run_dir)
    if log_dir is not None:
        shutil.rmtree(log_dir, ignore_errors=True)
    return log_dir

"""Where a run's scalars go: a TorchRL logger, built for a run directory, behind one sink.

:func:`make_logger` returns TorchRL's ``CSVLogger``, ``TensorboardLogger`` or ``WandbLogger``
for a run directory, resumable (a resumed run logs its frames again without doubling them).
:class:`MetricsLog` is the sink the loop hands ready-made scalars to.
"""

from __future__ import annotations

import secrets
import sys
from pathlib import Path
from typing import Any

from torchrl.record.loggers import CSVLogger, Logger, TensorboardLogger, WandbLogger

from trl_cartpole.config.validation import check_logger_installed
from trl_cartpole.errors import ConfigError
from trl_cartpole.store.files import write_text_atomic

__all__ = ["MetricsLog", "make_logger", "truncate_csv_metrics"]


class ResumedTensorboardLogger(TensorboardLogger):
    """TorchRL's ``TensorboardLogger`` whose writer drops the events logged after ``purge_step``.

    A run resumed from a checkpoint at frame T logs frames T.. again; ``SummaryWriter``'s
    ``purge_step=T`` hides the events the stopped run wrote from T on, so none appears twice.
    ``_create_experiment`` is the hook TorchRL's ``Logger`` subclasses implement.
    """

    def __init__(self, exp_name: str, log_dir: str, purge_step: int) -> None:
        self.purge_step = purge_step
        super().__init__(exp_name=exp_name, log_dir=log_dir)

    def _create_experiment(self) -> Any:
        from torch.utils.tensorboard import SummaryWriter

        log_dir = str(Path(self.log_dir) / self.exp_name)
        return SummaryWriter(log_dir=log_dir, purge_step=self.purge_step)


WANDB_RUN_ID = "wandb-run-id"  # in the run directory: the W&B run its resumes continue


def wandb_run_id(run_dir: str | Path, resumed: bool) -> str:
    """The W&B run id of a run directory: new for a fresh run, the stored one when resumed."""
    path = Path(run_dir) / WANDB_RUN_ID
    if resumed and path.is_file():
        return path.read_text().strip()
    run_id = secrets.token_hex(8)
    write_text_atomic(path, run_id + "\n")
    return run_id


def make_logger(
    backend: str,
    run_dir: str | Path,
    project: str = "trl_cartpole",
    wandb_offline: bool = True,
    resumed_at: int | None = None,
    logger_step: int | None = None,
) -> Logger | None:
    """Return TorchRL's ``CSVLogger``, ``TensorboardLogger`` or ``WandbLogger`` for ``run_dir``.

    ``CSVLogger`` writes one ``metrics/scalars/<name>.csv`` per scalar, each row ``step,value``
    with ``step`` the frame count; ``TensorboardLogger`` writes event files under
    ``run_dir/metrics``; ``WandbLogger`` logs to ``project`` (offline by default, files under
    ``run_dir/wandb``, one W&B run per run directory, its id in ``run_dir/wandb-run-id``).
    ``backend="none"`` returns ``None``. ``resumed_at`` (the frame of the checkpoint a resumed
    run starts from) makes TensorBoard drop what was logged after it; ``logger_step`` (the W&B
    step the checkpoint recorded, :meth:`MetricsLog.logger_step`) rewinds the W&B run to it.
    """
    if backend == "none":
        return None
    if backend == "csv":
        return CSVLogger(exp_name="metrics", log_dir=str(run_dir))
    check_logger_installed(backend)
    if backend == "tensorboard":
        if resumed_at is not None:
            return ResumedTensorboardLogger("metrics", str(run_dir), purge_step=resumed_at)
        return TensorboardLogger(exp_name="metrics", log_dir=str(run_dir))
    if backend == "wandb":
        run_id = wandb_run_id(run_dir, resumed=resumed_at is not None)
        # A resumed run continues its W&B run, rewound (W&B's resume_from) to the W&B step the
        # checkpoint recorded, so the rows the stopped run logged after it are replaced.
        if resumed_at is None:
            resume = {"resume": "never"}
        elif logger_step is None:  # a checkpoint without it: continue, without a rewind
            resume = {"resume": "allow"}
        else:
            resume = {"resume": None, "resume_from": f"{run_id}?_step={logger_step}"}
        return WandbLogger(
            exp_name=Path(run_dir).name,
            offline=wandb_offline,
            save_dir=str(run_dir),
            project=project,
            id=run_id,
            settings={"silent": True},  # W&B's banner and run summary off: a quiet console
            **resume,
        )
    raise ConfigError(f"logger.backend={backend!r}; choose csv, tensorboard, wandb or none")


def truncate_csv_metrics(run_dir: str | Path, frames: int) -> None:
    """Drop the CSV rows logged after ``frames`` (``run_dir/metrics/scalars/**.csv``), and the
    ending's own (``final_*``: logged after the last training state, at its frames).

    A resumed run logs those frames again; each file is rewritten atomically. A row that is
    not ``step,value`` (a write cut off by a kill, a damaged file) is dropped with a line on
    stderr saying how many and where.
    """
    for path in (Path(run_dir) / "metrics" / "scalars").rglob("*.csv"):
        kept, damaged = [], 0
        last_kept = frames - 1 if path.stem.startswith("final_") else frames
        for row in path.read_text(errors="replace").splitlines():
            step = _csv_step(row)
            if step is None:
                damaged += bool(row.strip())
            elif step <= last_kept:
                kept.append(f"{row}\n")
        if damaged:
            print(f"dropped {damaged} damaged row(s) of {path} (not step,value)", file=sys.stderr)
        write_text_atomic(path, "".join(kept))


def _csv_step(row: str) -> int | None:
    """The step of a ``step,value`` CSV row, or None if the row is not one."""
    step, _, value = row.strip().partition(",")
    try:
        float(value)
        return int(step)
    except ValueError:
        return None


class MetricsLog:
    """The sink of ready-made scalars: ``log({name: value}, step)`` to a TorchRL logger."""

    def __init__(self, logger: Logger | None) -> None:
        self.logger = logger
        self._closed = False

    def log(self, scalars: dict[str, float], step: int) -> None:
        if self.logger is not None:
            for name, value in scalars.items():
                self.logger.log_scalar(name, float(value), step=step)

    def logger_step(self) -> int | None:
        """W&B's own step counter (its rows so far), for a resumed run's rewind; else None."""
        if not isinstance(self.logger, WandbLogger):
            return None
        return getattr(self.logger.experiment, "step", None)

    def close(self) -> None:
        """Close the logger once (flushes TensorBoard events, finishes a W&B run)."""
        if self.logger is not None and not self._closed:
            self.logger.close()
        self._closed = True

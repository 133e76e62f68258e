"""What a run reports while it trains: a TorchRL logger, the progress bar, the live plot.

:class:`Telemetry` is the one sink the loop reports to: finished episodes, gradient updates,
each batch and each evaluation. It writes them to a TorchRL logger (``CSVLogger``,
``TensorboardLogger`` or ``WandbLogger``), shows them on a tqdm bar, redraws the tutorial's
duration plot at each evaluation, and keeps the history the final plots and the summary read
(saved in training states, so a resumed run's plots cover the whole run).
"""

from __future__ import annotations

import resource
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from tensordict import TensorDictBase
from torch import nn
from torchrl.modules import EGreedyModule
from torchrl.record.loggers import CSVLogger, Logger, TensorboardLogger, WandbLogger
from tqdm.auto import tqdm

from trl_cartpole.errors import ConfigError
from trl_cartpole.files import write_text_atomic
from trl_cartpole.learner import UpdateReport
from trl_cartpole.models import expected_action_values
from trl_cartpole.plotting import LiveDurationPlot
from trl_cartpole.progress import Progress

__all__ = ["History", "Telemetry", "make_logger", "peak_rss_mb", "truncate_csv_metrics"]

UPDATE_LOG_INTERVAL = 100  # log TD loss, grad norm and epsilon once per this many updates


def peak_rss_mb() -> float:
    """This process's peak resident memory in MiB (Linux reports ``ru_maxrss`` in KiB)."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


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


def truncate_csv_metrics(run_dir: str | Path, frames: int) -> None:
    """Drop the CSV rows logged after ``frames`` (``run_dir/metrics/scalars/**.csv``).

    A resumed run logs those frames again; each file is rewritten atomically.
    """
    for path in (Path(run_dir) / "metrics" / "scalars").rglob("*.csv"):
        rows = path.read_text().splitlines(keepends=True)
        kept = [row for row in rows if row.strip() and int(row.split(",", 1)[0]) <= frames]
        write_text_atomic(path, "".join(kept))


@dataclass
class History:
    """The training curves the plots and the summary read, kept in memory."""

    episode_returns: list[float] = field(default_factory=list)
    episode_lengths: list[int] = field(default_factory=list)
    update_frames: list[int] = field(default_factory=list)
    td_losses: list[float] = field(default_factory=list)
    grad_norms: list[float] = field(default_factory=list)


class Telemetry:
    """The metrics sink: logger, progress bar and live plot behind one call per event."""

    def __init__(
        self,
        logger: Logger | None,
        live_plot: LiveDurationPlot | None = None,
        progress_bar: bool = True,
        description: str = "",
        total_frames: int | None = None,
    ) -> None:
        self.logger, self.live_plot = logger, live_plot
        self.history = History()
        self._bar_options = {
            "disable": not progress_bar,
            "total": total_frames,
            "unit": "frame",
            "dynamic_ncols": True,
            "desc": description,
        }
        self.bar: tqdm | None = None
        self.postfix: dict[str, str] = {}  # ep_return, eps, eval, best: shown together
        self._last_report = UpdateReport()
        self._closed = False

    def open_bar(self, frames: int) -> None:
        """Show the progress bar, starting at ``frames`` (a resumed run's count)."""
        self.bar = tqdm(initial=frames, **self._bar_options)

    def log(self, scalars: dict[str, float], step: int) -> None:
        if self.logger is not None:
            for name, value in scalars.items():
                self.logger.log_scalar(name, float(value), step=step)

    def episodes(self, batch: TensorDictBase, progress: Progress) -> None:
        """Record the episodes that finished in ``batch`` ``[rows, T]``."""
        done = batch["next", "done"].reshape(-1)  # [F]
        if not done.any():
            return
        returns = batch["next", "episode_reward"].reshape(-1)[done].tolist()
        lengths = batch["next", "step_count"].reshape(-1)[done].tolist()
        for episode_return, length in zip(returns, lengths, strict=True):
            self.history.episode_returns.append(episode_return)
            self.history.episode_lengths.append(length)
            self.log(
                {"train/episode_return": episode_return, "train/episode_length": length},
                progress.frames,
            )

    def updates(self, report: UpdateReport, progress: Progress) -> None:
        """Record the TD losses and gradient norms of one round of updates."""
        self.history.update_frames.extend([progress.frames] * len(report))
        self.history.td_losses.extend(report.losses)
        self.history.grad_norms.extend(report.grad_norms)
        self._last_report = report

    def batch(
        self,
        batch: TensorDictBase,
        progress: Progress,
        actor: nn.Module,
        exploration: EGreedyModule | None,
        updates_before: int,
    ) -> None:
        """Move the bar; every ``UPDATE_LOG_INTERVAL`` updates, log the training scalars."""
        if self.bar is not None:
            self.bar.update(batch.numel())
        if self.history.episode_returns:
            self.postfix.update(ep_return=f"{self.history.episode_returns[-1]:.0f}")
        if exploration is not None:
            self.postfix.update(eps=f"{exploration.eps.item():.3f}")
        self._show_postfix()
        if progress.updates // UPDATE_LOG_INTERVAL <= updates_before // UPDATE_LOG_INTERVAL:
            return
        history = self.history
        scalars = {
            "train/td_loss": history.td_losses[-1],
            "train/grad_norm": history.grad_norms[-1],
            "train/frames_per_second": progress.frames / max(progress.clock.seconds, 1e-9),
        }
        if batch.get("action_value", None) is not None:  # None in random warm-up batches
            q = expected_action_values(actor, batch["action_value"])  # [F, num_actions]
            scalars["train/q_max_mean"] = q.max(-1).values.mean().item()
        if exploration is not None:
            scalars["train/epsilon"] = exploration.eps.item()
        report = self._last_report
        if report.prioritized and report.last_sample is not None:
            weights = report.last_sample["priority_weight"]  # [batch_size]
            scalars["train/mean_importance_weight"] = weights.mean().item()
        self.log(scalars, progress.frames)

    def evaluation(self, result: Any, best: float, frames: int) -> None:
        """Record one greedy evaluation (an ``EvalResult``) and redraw the live plot."""
        self.log(
            {
                "eval/return_mean": result.mean,
                "eval/return_std": result.std,
                "eval/initial_value": result.initial_value,
            },
            frames,
        )
        self.postfix.update(eval=f"{result.mean:.1f}", best=f"{best:.1f}")
        self._show_postfix()

    def redraw_live_plot(self) -> None:
        if self.live_plot is not None:
            self.live_plot.update(self.history.episode_lengths)

    def _show_postfix(self) -> None:
        if self.bar is not None:
            self.bar.set_postfix(self.postfix, refresh=False)

    def close_bar(self) -> None:
        if self.bar is not None:
            self.bar.close()

    def close(self) -> None:
        """Close the bar and the logger (flushes TensorBoard events, finishes a wandb run)."""
        self.close_bar()
        if self.logger is not None and not self._closed:
            self.logger.close()
        self._closed = True

    def state_dict(self) -> dict[str, Any]:
        return asdict(self.history)

    def load_state_dict(self, state: dict[str, Any]) -> None:
        for name, values in state.items():
            getattr(self.history, name)[:] = values

"""What a run reports while it trains: a TorchRL logger, the progress bar, the live plot.

:class:`Telemetry` is the one sink the loop reports to: finished episodes, gradient updates,
each batch and each evaluation. It writes them to a TorchRL logger (``CSVLogger``,
``TensorboardLogger`` or ``WandbLogger``), shows them on a tqdm bar, redraws the tutorial's
duration plot at each evaluation, and keeps the history the final plots and the summary read
(saved in training states, so a resumed run's plots cover the whole run).
"""

from __future__ import annotations

import resource
import secrets
import sys
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from tensordict import TensorDictBase
from torch import Tensor, nn
from torchrl.modules import EGreedyModule
from torchrl.record.loggers import CSVLogger, Logger, TensorboardLogger, WandbLogger
from tqdm.auto import tqdm

from trl_cartpole.errors import ConfigError
from trl_cartpole.evaluation import EvalCurve
from trl_cartpole.files import write_text_atomic
from trl_cartpole.learner import UpdateReport
from trl_cartpole.models import expected_action_values
from trl_cartpole.plotting import LearningCurves, LiveDurationPlot, live_plot_target
from trl_cartpole.progress import Progress

__all__ = ["History", "Telemetry", "make_logger", "peak_rss_mb", "truncate_csv_metrics"]

UPDATE_LOG_INTERVAL = 100  # log TD loss, grad norm and epsilon once per this many updates
# 80 columns hold the bar with eval and best first: "CartPole-v1  29%|██▊   | 14.3k/50.0k 00:21,
# eval 500 best 500 | ret 134 eps .05"
BAR_FORMAT = "{desc} {percentage:3.0f}%|{bar}| {n_fmt}/{total_fmt} {elapsed}{postfix}"


def _short(value: float) -> str:
    """A return as the bar shows it: ``500``, ``-123``, ``10.5``."""
    return f"{value:.0f}" if abs(value) >= 100 else f"{value:.1f}"


def bar_mode(progress_bar: bool) -> str:
    """``bar`` on a terminal or in a notebook, ``lines`` (one per evaluation) when redirected."""
    if not progress_bar:
        return "off"
    return "bar" if sys.stderr.isatty() or live_plot_target() == "notebook" else "lines"


def peak_rss_mb() -> float:
    """This process's peak resident memory in MiB (Linux reports ``ru_maxrss`` in KiB)."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


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
    step the checkpoint recorded, :meth:`Telemetry.logger_step`) rewinds the W&B run to it.
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
        if resumed_at is not None:
            return ResumedTensorboardLogger("metrics", str(run_dir), purge_step=resumed_at)
        return TensorboardLogger(exp_name="metrics", log_dir=str(run_dir))
    if backend == "wandb":
        try:
            import wandb  # noqa: F401
        except ImportError:
            raise ConfigError(
                "logger.backend=wandb needs wandb: pip install -e '.[wandb]'"
            ) from None
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

    episode_returns: list[float] = field(default_factory=list)  # in the order they ended
    episode_lengths: list[int] = field(default_factory=list)
    episode_frames: list[int] = field(default_factory=list)  # the frame each episode ended at
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
        threshold: float | None = None,
    ) -> None:
        self.logger, self.live_plot, self.threshold = logger, live_plot, threshold
        self.history = History()
        self.mode = bar_mode(progress_bar)
        self.total_frames = total_frames
        self._bar_options = {
            "disable": self.mode != "bar",
            "total": total_frames,
            "unit": "frame",
            "unit_scale": True,
            "dynamic_ncols": True,
            "desc": description,
            "bar_format": BAR_FORMAT,
        }
        self.bar: tqdm | None = None
        self.postfix: dict[str, str] = {}  # eval, best, ret, eps: shown in this order
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
        """Record the episodes that finished in ``batch`` ``[rows, T]`` (or ``[T]``).

        Episodes are kept in the order they ended (time-major over the envs), each with the
        frame it ended at; ``progress.frames`` already counts this batch.
        """
        steps = batch.shape[-1]
        rows = batch.numel() // steps

        def time_major(key: tuple[str, str]) -> Tensor:  # [T, rows]
            return batch[key].reshape(rows, steps).T

        done = time_major(("next", "done"))  # [T, rows]
        if not done.any():
            return
        returns = time_major(("next", "episode_reward"))[done].tolist()
        lengths = time_major(("next", "step_count"))[done].tolist()
        step_index = done.nonzero()[:, 0]  # [episodes]: the step of the batch each one ended at
        first_frame = progress.frames - batch.numel()
        frames = (first_frame + (step_index + 1) * rows).tolist()
        for episode_return, length, frame in zip(returns, lengths, frames, strict=True):
            self.history.episode_returns.append(episode_return)
            self.history.episode_lengths.append(length)
            self.history.episode_frames.append(frame)
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
            self.postfix.update(ret=f"{self.history.episode_returns[-1]:.0f}")
        if exploration is not None:
            self.postfix.update(eps=f"{exploration.eps.item():.2f}".replace("0.", "."))
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
        self.postfix.update(eval=_short(result.mean), best=_short(best))
        self._show_postfix()
        if self.mode == "lines":  # output redirected: one line per evaluation, no redraws
            print(
                f"{frames} / {self.total_frames} frames: greedy return {result.mean:.1f} "
                f"(best {best:.1f})",
                file=sys.stderr,
                flush=True,
            )

    def curves(self, evaluations: EvalCurve) -> LearningCurves:
        """The training episodes so far, with ``evaluations`` (the evaluator's curve)."""
        history = self.history
        return LearningCurves(
            history.episode_frames,
            history.episode_returns,
            evaluations.frames,
            evaluations.returns,
            self.threshold,
        )

    def redraw_live_plot(self, evaluations: EvalCurve) -> None:
        if self.live_plot is not None:
            self.live_plot.update(self.curves(evaluations))

    def flush_live_plot(self) -> None:
        """Draw the live plot's last skipped redraw (the end of a run)."""
        if self.live_plot is not None:
            self.live_plot.flush()

    def _show_postfix(self) -> None:
        if self.bar is not None:
            shown = {key: f"{key} {value}" for key, value in self.postfix.items()}
            greedy = " ".join(shown[key] for key in ("eval", "best") if key in shown)
            training = " ".join(shown[key] for key in ("ret", "eps") if key in shown)
            self.bar.set_postfix_str(" | ".join(part for part in (greedy, training) if part))

    def close_bar(self) -> None:
        if self.bar is not None:
            self.bar.close()

    def close(self) -> None:
        """Close the bar and the logger (flushes TensorBoard events, finishes a wandb run)."""
        self.close_bar()
        if self.logger is not None and not self._closed:
            self.logger.close()
        self._closed = True

    def logger_step(self) -> int | None:
        """W&B's own step counter (its rows so far), for a resumed run's rewind; else None."""
        if not isinstance(self.logger, WandbLogger):
            return None
        return getattr(self.logger.experiment, "step", None)

    def state_dict(self) -> dict[str, Any]:
        return asdict(self.history)

    def load_state_dict(self, state: dict[str, Any]) -> None:
        for name, values in state.items():
            getattr(self.history, name)[:] = values

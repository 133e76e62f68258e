"""``train(cfg)``: the DQN loop (Mnih et al. 2015, algorithm 1) over TorchRL components.

Each collected batch: store it in the replay buffer, take ``updates_per_batch`` gradient steps
on replayed minibatches (moving the target network after each), step the schedules (epsilon,
network noise, the prioritized buffer's beta) and send the new weights to the collector, and
every ``eval.interval_frames`` play greedy episodes; checkpoints are written on a schedule and
on a stop signal. :func:`~trl_cartpole.run.build.build_components` builds the parts,
:func:`~trl_cartpole.run.summary.finish` ends the run; docs/architecture.md follows one frame
through them.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

from omegaconf import DictConfig
from tensordict import TensorDictBase

from trl_cartpole.config.schema import Config, to_config
from trl_cartpole.config.validation import validate
from trl_cartpole.envs.faults import (
    check_finite_batch,
    disarm_step_deadline,
    env_fault,
    worker_env_fault,
)
from trl_cartpole.errors import DiskFull, TrainingFailed, TrainingInterrupted, WorkerLost
from trl_cartpole.parts.collectors import lost_worker
from trl_cartpole.parts.models import expected_action_values
from trl_cartpole.parts.replay import extend_with_batch
from trl_cartpole.report.console import quiet_libraries
from trl_cartpole.run.build import Components, build_components
from trl_cartpole.run.evaluation import Evaluation
from trl_cartpole.run.progress import Progress
from trl_cartpole.run.signals import StopRequest
from trl_cartpole.run.summary import finish, record_failure

__all__ = ["train"]

UPDATE_LOG_INTERVAL = 100  # log TD loss, grad norm and epsilon once per this many updates


def train(
    cfg: Config | DictConfig | dict[str, Any],
    resume: str | Path | None = None,
    *,
    build: Callable[[Config, str | Path | None], Components] = build_components,
    on_evaluation: Callable[[Evaluation], None] | None = None,
) -> dict[str, Any]:
    """Train DQN as configured, write the run directory and return the summary dict.

    ``resume`` is a training-state checkpoint (``checkpoint.find_resume_checkpoint``) and
    ``cfg`` its stored config (``checkpoint.resume_config``): the run continues exactly where
    it stopped. A stop signal (SIGINT, SIGTERM, SIGHUP, SIGUSR1) writes a checkpoint and raises
    ``TrainingInterrupted``; a non-finite TD loss raises ``TrainingFailed``; a Ray collector
    actor that dies writes a checkpoint and raises ``WorkerLost``. ``build`` makes
    the components (a test may wrap it to inject a fault). ``on_evaluation(evaluation)`` gets
    each periodic :class:`~trl_cartpole.run.evaluation.Evaluation` after the run has recorded it
    (the tuner reports it to Optuna, which may stop the run by raising).
    """
    cfg = validate(to_config(cfg))
    # the stop request first: its unbreakable console is the one the progress bar writes to
    with quiet_libraries(cfg.logger.verbose), StopRequest() as stop, build(cfg, resume) as run:
        stop.rearm()  # a Ray collector's ray.init has just replaced the SIGTERM handler
        progress, phase = run.progress, run.progress.phase
        progress.clock.start()
        # a resumed run whose training was done when it stopped (killed in its ending) collects
        # nothing: it goes to its last evaluation and its ending, as the uninterrupted run did
        limits = _limits(cfg)
        done = progress.frames >= cfg.collector.total_frames or progress.ended_under == limits
        batches = () if done else run.collector
        try:
            # batch: [envs, T] ([workers, envs, T] from synchronous workers), envs * T frames
            for batch in progress.timed(batches, "collect"):
                batch = batch.reshape(-1, batch.shape[-1]) if batch.ndim > 2 else batch
                with phase("store"):
                    _store(run, batch)
                updates_before = progress.updates
                with phase("update"):  # gradient steps, priorities, target network
                    if len(run.buffer) >= run.learning_starts:
                        report = run.learner.step(run.updates_per_batch, progress)
                        run.history.record_updates(report, progress.frames)
                with phase("explore"):  # epsilon, network noise, beta, weight sync, the bar
                    run.schedules.step(batch.numel(), progress.frames)
                    if run.sync_policy_weights:
                        run.collector.update_policy_weights_()
                    _report_batch(run, batch, updates_before)
                if run.evaluator.due(progress):
                    evaluation = run.evaluator.run(progress)
                    _record_evaluation(run, evaluation, on_evaluation)
                    if evaluation.stop:
                        break
                if _out_of_time(cfg, progress):  # collector.max_train_seconds: end here
                    break
                run.checkpointer.maybe_save(progress, stop)  # after a signal: save, then raise
            progress.ended_under = limits
            if run.evaluator.last_eval_frame != progress.frames:  # end on an evaluation
                _record_evaluation(run, run.evaluator.run(progress), on_evaluation)
        except TrainingFailed as failure:
            raise record_failure(run, failure) from None
        except Exception as error:
            stop_as = _stop_for(run, error)
            if stop_as is None:
                raise
            raise stop_as from None
        return finish(run)


def _limits(cfg: Config) -> dict[str, Any]:
    """What ends the training loop: its frames and seconds (a resume under other ones trains
    on from a loop that ended)."""
    collector = cfg.collector
    return {
        "total_frames": collector.total_frames,
        "max_train_seconds": collector.max_train_seconds,
    }


def _out_of_time(cfg: Config, progress: Progress) -> bool:
    """Whether the run has trained its ``collector.max_train_seconds``."""
    limit = cfg.collector.max_train_seconds
    return limit is not None and progress.clock.seconds >= limit


# the loop's own ways to stop: never read as a worker's env fault
_OUR_STOPS = (TrainingInterrupted, DiskFull, WorkerLost)


def _store(run: Components, batch: TensorDictBase) -> None:
    """Check the batch ``[envs, T]``, count its frames, store it, log its finished episodes."""
    progress = run.progress
    check_finite_batch(batch, run.env_id, progress.frames)
    progress.frames += batch.numel()
    extend_with_batch(run.buffer, batch.select(*run.transition_keys))
    for episode in run.history.record_episodes(batch, progress.frames):
        run.metrics.log(
            {
                "train/episode_return": episode.episode_return,
                "train/episode_length": episode.length,
            },
            progress.frames,
        )


def _stop_for(run: Components, error: Exception) -> Exception | None:
    """What the run stops with after ``error`` escaped the loop (None: ``error`` itself).

    The env's own code raised, or a worker process's env died: the run's failure, recorded in
    the run directory. A Ray actor died: a checkpoint, then ``WorkerLost``. The loop's own
    stops (a signal, a full disk) and anything else go on as they are.
    """
    disarm_step_deadline()  # a step that raised left its alarm set
    frames = run.progress.frames
    fault = env_fault(error, run.env_id, frames)  # the env's own code raised
    ours = isinstance(error, _OUR_STOPS)
    if fault is None and run.worker_log_dir is not None and not ours:
        fault = worker_env_fault(run.worker_log_dir, run.env_id, frames)  # a worker died
    if fault is not None:
        return record_failure(run, fault)
    lost = None if ours else lost_worker(error, run.collector)  # a Ray actor died
    return None if lost is None else run.checkpointer.stop_for_lost_worker(run.progress, lost)


def _report_batch(run: Components, batch: TensorDictBase, updates_before: int) -> None:
    """Move the bar; every ``UPDATE_LOG_INTERVAL`` updates, log the training scalars."""
    progress, history, exploration = run.progress, run.history, run.exploration
    epsilon = None if exploration is None else exploration.eps.item()
    last_return = history.episode_returns[-1] if history.episode_returns else None
    run.progress_bar.advance(batch.numel(), last_return, epsilon)
    if epsilon is not None:
        history.record_epsilon(progress.frames, epsilon)
    if progress.updates // UPDATE_LOG_INTERVAL <= updates_before // UPDATE_LOG_INTERVAL:
        return
    scalars = {
        "train/td_loss": history.td_losses[-1],
        "train/grad_norm": history.grad_norms[-1],
        "train/frames_per_second": progress.frames / max(progress.clock.seconds, 1e-9),
    }
    if batch.get("action_value", None) is not None:  # None in random warm-up batches
        q = expected_action_values(run.actor, batch["action_value"])  # [F, num_actions]
        scalars["train/q_max_mean"] = q.max(-1).values.mean().item()
    if epsilon is not None:
        scalars["train/epsilon"] = epsilon
    report = run.learner.last_report
    if report.prioritized and report.last_sample is not None:
        weights = report.last_sample["priority_weight"]  # [batch_size]
        scalars["train/mean_importance_weight"] = weights.mean().item()
    run.metrics.log(scalars, progress.frames)


def _record_evaluation(
    run: Components, evaluation: Evaluation, on_evaluation: Callable[[Evaluation], None] | None
) -> None:
    """Log the evaluation, show it, redraw the live plot, save a new best; then the caller's."""
    result = evaluation.result
    scalars = {
        "eval/return_mean": result.mean,
        "eval/return_std": result.std,
        "eval/initial_value": result.initial_value,
    }
    rss_mb = run.evaluator.curve.rss_mb[-1]
    if rss_mb is not None:
        scalars["eval/rss_mb"] = rss_mb  # resident memory: a long run's leak shows here
    run.metrics.log(scalars, evaluation.frames)
    run.progress_bar.evaluation(result.mean, evaluation.best_return, evaluation.frames)
    if evaluation.new_best:
        run.checkpointer.save_best(run.actor, evaluation.frames, result.mean)
    if run.live_plot is not None:
        curves = run.history.curves(
            run.evaluator.curve,
            run.threshold,
            run.protocol.periodic_episodes,
            return_label=run.settings.return_label,
        )
        run.live_plot.update(curves)
    if on_evaluation is not None:
        on_evaluation(evaluation)

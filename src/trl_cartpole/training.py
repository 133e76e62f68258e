"""``train(cfg)``: the DQN loop (Mnih et al. 2015, algorithm 1) over TorchRL components.

Each collected batch: store it in the replay buffer, take ``updates_per_batch`` gradient steps
on replayed minibatches (moving the target network after each), step the exploration, and
every ``eval.interval_frames`` play greedy episodes; checkpoints are written on a schedule and
on a stop signal. :func:`~trl_cartpole.build.build_components` builds the parts,
:func:`~trl_cartpole.summary.finish` ends the run; docs/architecture.md follows one frame
through them.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

from omegaconf import DictConfig

from trl_cartpole.buffers import extend_with_batch
from trl_cartpole.build import TRANSITION_KEYS, Components, build_components
from trl_cartpole.config import Config, to_config
from trl_cartpole.console import quiet_libraries
from trl_cartpole.errors import TrainingFailed
from trl_cartpole.run_control import StopRequest
from trl_cartpole.summary import finish, record_failure
from trl_cartpole.validation import validate

__all__ = ["train"]


def train(
    cfg: Config | DictConfig | dict[str, Any],
    resume: str | Path | None = None,
    *,
    build: Callable[[Config, str | Path | None], Components] = build_components,
    on_evaluation: Callable[[int, float], None] | None = None,
) -> dict[str, Any]:
    """Train DQN as configured, write the run directory and return the summary dict.

    ``resume`` is a training-state checkpoint (``checkpoint.find_resume_checkpoint``) and
    ``cfg`` its stored config (``checkpoint.resume_config``): the run continues exactly where
    it stopped. A stop signal (SIGINT, SIGTERM, SIGHUP, SIGUSR1) writes a checkpoint and raises
    ``TrainingInterrupted``; a non-finite TD loss raises ``TrainingFailed``. ``build`` makes
    the components (a test may wrap it to inject a fault). ``on_evaluation(frames, mean)`` is
    called after each periodic evaluation (the tuner reports it to Optuna, which may stop the
    run by raising).
    """
    cfg = validate(to_config(cfg))
    # the stop request first: its unbreakable console is the one the progress bar writes to
    with quiet_libraries(cfg.logger.verbose), StopRequest() as stop, build(cfg, resume) as c:
        progress, phase = c.progress, c.progress.phase
        progress.clock.start()
        try:
            # batch: [envs, T] ([workers, envs, T] from synchronous workers), envs * T frames
            for batch in progress.timed(c.collector, "collect"):
                batch = batch.reshape(-1, batch.shape[-1]) if batch.ndim > 2 else batch
                with phase("store"):
                    progress.frames += batch.numel()
                    extend_with_batch(c.buffer, batch.select(*TRANSITION_KEYS))
                    c.telemetry.episodes(batch, progress)
                updates_before = progress.updates
                with phase("update"):  # gradient steps, priorities, target network
                    if len(c.buffer) >= c.learning_starts:
                        report = c.learner.step(cfg.collector.updates_per_batch, progress)
                        c.telemetry.updates(report, progress)
                with phase("explore"):  # epsilon, noise, beta, weight sync, progress bar
                    c.after_batch(batch, updates_before)
                if c.evaluator.due(progress):
                    evaluation = c.evaluator.run(progress)
                    if on_evaluation is not None:
                        on_evaluation(progress.frames, evaluation.result.mean)
                    if evaluation.stop:
                        break
                c.checkpointer.maybe_save(progress, stop)  # after a signal: save, then raise
        except TrainingFailed as failure:
            raise record_failure(c, failure) from None
        return finish(c)

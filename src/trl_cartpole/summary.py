"""How a run ends: the final evaluation of the best policy, the plots and ``summary.json``.

:func:`finish` runs after the loop: it saves the last training state, evaluates the best
policy (by periodic evaluation) over ``eval.final_episodes`` fresh episodes, draws the plots
and writes ``summary.json``, whose keys other tools rely on (docs/architecture.md).
:func:`record_failure` writes the summary of a run stopped by a numerical fault.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import gymnasium as gym
import tensordict
import torch
import torchrl

from trl_cartpole.build import Components, build_env, run_title
from trl_cartpole.errors import TrainingFailed
from trl_cartpole.evaluation import EvalResult, evaluate
from trl_cartpole.files import write_json_atomic
from trl_cartpole.plotting import plot_dashboard, plot_durations
from trl_cartpole.telemetry import peak_rss_mb

__all__ = ["finish", "record_failure"]


def finish(c: Components) -> dict[str, Any]:
    """Save the last state, evaluate the best policy, draw the plots, write ``summary.json``."""
    cfg, progress, evaluator = c.cfg, c.progress, c.evaluator
    progress.clock.pause()
    c.telemetry.close_bar()
    c.checkpointer.save_last(progress)
    c.release_collector()
    if evaluator.last_eval_frame != progress.frames:
        evaluator.run(progress, redraw=False)
    c.telemetry.flush_live_plot()
    evaluator.load_best()
    final_env = build_env(
        cfg, cfg.seed + 2 * cfg.eval.seed_offset, cfg.eval.final_episodes, c.observation_norm
    )
    final = evaluate(c.actor, final_env, cfg.eval.max_steps)
    final_env.close()
    c.telemetry.log({"eval/final_return_mean": final.mean}, progress.frames)
    c.telemetry.close()
    if cfg.logger.plots:
        history, curve = c.telemetry.history, evaluator.curve
        title = run_title(cfg)
        plot_durations(c.telemetry.curves(curve), c.run_dir / "durations.png", title)
        plot_dashboard(
            curve.frames,
            curve.returns,
            curve.initial_values,
            history.update_frames,
            history.td_losses,
            history.grad_norms,
            c.run_dir / "dashboard.png",
            title=title,
            threshold=c.threshold,
        )
    summary = _summary(c, final)
    write_json_atomic(c.run_dir / "summary.json", summary)
    return summary


def record_failure(c: Components, failure: TrainingFailed) -> TrainingFailed:
    """Write the failure to ``summary.json``; return the error to raise, naming that file.

    The last periodic checkpoint (written before the fault) stays the one to resume from.
    """
    periodic = c.run_dir / "checkpoints" / "periodic"
    progress, evaluator = c.progress, c.evaluator
    summary = {
        "env_id": c.cfg.env.id,
        "seed": c.cfg.seed,
        "algo": c.cfg.algo.name,
        "frames": progress.frames,
        "updates": progress.updates,
        "wall_seconds": round(time.perf_counter() - c.wall_start, 3),
        "solved": evaluator.frames_to_solve is not None,
        "frames_to_solve": evaluator.frames_to_solve,
        "failed": True,
        "failure": str(failure),
        "best_eval_return_mean": evaluator.best_return if evaluator.best_state else None,
        "last_good_checkpoint": str(periodic) if periodic.is_dir() else None,
        "run_dir": str(c.run_dir),
    }
    write_json_atomic(c.run_dir / "summary.json", summary)
    return TrainingFailed(f"{failure}; the failure is recorded in {c.run_dir / 'summary.json'}")


def _summary(c: Components, final: EvalResult) -> dict[str, Any]:
    cfg, progress, evaluator = c.cfg, c.progress, c.evaluator
    phases = progress.phase_seconds
    best = Path(c.run_dir) / "checkpoints" / "best"
    return {
        "env_id": cfg.env.id,
        "seed": cfg.seed,
        "algo": cfg.algo.name,
        "frames": progress.frames,
        "updates": progress.updates,
        "train_seconds": round(progress.clock.seconds, 3),
        "wall_seconds": round(time.perf_counter() - c.wall_start, 3),
        "solved": evaluator.frames_to_solve is not None,
        "solve_threshold": c.threshold,
        "frames_to_solve": evaluator.frames_to_solve,
        "seconds_to_solve": None
        if evaluator.seconds_to_solve is None
        else round(evaluator.seconds_to_solve, 3),
        "final_eval_return_mean": final.mean,
        "final_eval_return_std": final.std,
        "final_eval_episodes": len(final.returns),
        "final_eval_returns": final.returns,
        "best_eval_return_mean": evaluator.best_return,
        "episodes": len(c.telemetry.history.episode_returns),
        # Throughput of the two halves of the loop, and the process's peak resident memory.
        "collect_frames_per_second": round(progress.frames / max(phases["collect"], 1e-9)),
        "updates_per_second": round(progress.updates / max(phases["update"], 1e-9), 1),
        "phase_seconds": {name: round(seconds, 3) for name, seconds in phases.items()},
        "peak_rss_mb": round(peak_rss_mb(), 1),
        "eval_curve": {
            "frames": evaluator.curve.frames,
            "seconds": evaluator.curve.seconds,  # training seconds, evaluation excluded
            "returns": evaluator.curve.returns,
        },
        "checkpoint": str(best) if cfg.checkpoint.save_best else None,
        "run_dir": str(c.run_dir),
        "versions": {
            "torch": torch.__version__,
            "torchrl": torchrl.__version__,
            "tensordict": tensordict.__version__,
            "gymnasium": gym.__version__,
        },
    }

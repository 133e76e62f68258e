"""How a run ends: the final evaluation of the best policy, the plots and ``summary.json``.

:func:`finish` runs after the loop: it saves the last training state, chooses the policy to
keep (:mod:`trl_cartpole.run.best_policy`), evaluates it over the protocol's final episodes
(:mod:`trl_cartpole.run.eval_protocol`), draws the plots and writes ``summary.json``, whose keys
other tools rely on (docs/architecture.md). It reads the run's values (``run.settings``,
``run.protocol``), not its config.
:func:`record_failure` writes the summary of a run stopped by a numerical fault.
"""

from __future__ import annotations

import os
import resource
import shutil
import time
import warnings
from dataclasses import asdict
from pathlib import Path
from typing import Any

import gymnasium as gym
import tensordict
import torch
import torchrl

from trl_cartpole.compat import cpu_computes_bfloat16
from trl_cartpole.errors import TrainingFailed
from trl_cartpole.report.console import solve_status
from trl_cartpole.report.plotting import (
    DashboardData,
    FinalEvaluation,
    discounted_return_reference,
    plot_dashboard,
    plot_durations,
)
from trl_cartpole.run.best_policy import CandidateScore, choose_best_policy
from trl_cartpole.run.build import Components
from trl_cartpole.run.eval_protocol import cut_episodes_note
from trl_cartpole.run.evaluation import Candidate, EvalResult, Evaluator
from trl_cartpole.store.files import write_json_atomic

__all__ = ["ISA_LIMITS", "cpu_kernels", "finish", "peak_rss_mb", "record_failure", "run_summary"]

# environment variables that hold a library's CPU kernels below the processor's instructions
# (all three at AVX2 stand in for a processor without AVX-512: torch.compile's generated code
# and other libraries choose their own)
ISA_LIMITS = {
    "ONEDNN_MAX_CPU_ISA": "oneDNN",
    "ATEN_CPU_CAPABILITY": "ATen",
    "MKL_ENABLE_INSTRUCTIONS": "MKL",
}


def cpu_kernels() -> dict[str, Any]:
    """The vector instructions torch's CPU kernels use (``AVX512``, ``AVX2``...), whether oneDNN
    computes bfloat16 here, and the :data:`ISA_LIMITS` set (name: value), if any."""
    limits = {name: os.environ[name] for name in ISA_LIMITS if os.environ.get(name)}
    kernels = {
        "torch": torch.backends.cpu.get_cpu_capability(),
        "computes_bfloat16": cpu_computes_bfloat16(),
    }
    return {**kernels, "limits": limits} if limits else kernels


def peak_rss_mb() -> float:
    """This process's peak resident memory in MiB (Linux reports ``ru_maxrss`` in KiB)."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def finish(run: Components) -> dict[str, Any]:
    """Save the last state, choose and evaluate the best policy, draw the plots, write
    ``summary.json``."""
    _save_last_state(run)
    kept, scores = _choose_best_of_candidates(run)
    final = _final_evaluation(run)
    if run.settings.plots:
        run.progress_bar.status("drawing the plots")
        _draw_plots(run, final)
    progress, settings = run.progress, run.settings
    phases = progress.phase_seconds
    summary = run_summary(
        env_id=settings.env_id,
        seed=settings.seed,
        algo=settings.algo,
        frames=progress.frames,
        updates=progress.updates,
        train_seconds=progress.clock.seconds,
        wall_start=run.wall_start,
        threshold=run.threshold,
        evaluator=run.evaluator,
        final=final,
        run_dir=run.run_dir,
        variant=settings.variant,
        episodes=len(run.history.episode_returns),
        # Throughput of the two halves of the loop.
        collect_frames_per_second=round(progress.frames / max(phases["collect"], 1e-9)),
        updates_per_second=round(progress.updates / max(phases["update"], 1e-9), 1),
        phase_seconds={name: round(seconds, 3) for name, seconds in phases.items()},
        checkpoint=None if settings.best_checkpoint is None else str(settings.best_checkpoint),
        autocast=settings.autocast,
        num_threads=settings.num_threads,
        cpu_kernels=cpu_kernels(),
        best_policy_frames=None if kept is None else kept.frames,
        **({"candidates": [asdict(score) for score in scores]} if scores else {}),
        **({} if run.ray_nodes is None else {"ray_nodes": run.ray_nodes}),
        versions={
            "torch": torch.__version__,
            "torchrl": torchrl.__version__,
            "tensordict": tensordict.__version__,
            "gymnasium": gym.__version__,
        },
    )
    summary["solve_status"] = solve_status(summary)  # the ending's and the plots' verdict
    write_json_atomic(run.run_dir / "summary.json", summary)
    run.progress_bar.clear()
    return summary


def _save_last_state(run: Components) -> None:
    """Stop the clock, save the last training state, release the collector."""
    run.progress.clock.pause()
    run.progress_bar.close()
    run.progress_bar.status("saving the last training state")
    run.checkpointer.save_last(run.progress)
    run.release_collector()
    if run.settings.replay_files is not None:  # the training state just saved holds its own copy
        shutil.rmtree(run.settings.replay_files, ignore_errors=True)
    # a live plot to a file is the durations.png the end draws anew: no last redraw first
    if run.live_plot is not None and not (run.settings.plots and run.live_plot.target == "file"):
        run.live_plot.flush()


def _choose_best_of_candidates(run: Components) -> tuple[Candidate | None, list[CandidateScore]]:
    """The best policy, in the network and, when it is not the best periodic one, saved as
    ``checkpoints/best`` (:func:`~trl_cartpole.run.best_policy.choose_best_policy`)."""
    protocol, evaluator = run.protocol, run.evaluator
    kept, scores = choose_best_policy(
        protocol,
        evaluator,  # its network is run.actor: the candidates play through it
        on_candidate=lambda number, count: run.progress_bar.status(
            f"choosing the best policy: candidate {number} of {count} over "
            f"{protocol.candidate_episodes} new episodes"
        ),
    )
    if scores and kept is not evaluator.candidates[0]:  # checkpoints/best: the best policy
        run.checkpointer.save_best(run.actor, kept.frames, kept.eval_return_mean)
    return kept, scores


def _final_evaluation(run: Components) -> EvalResult:
    """The best policy over the protocol's final episodes, logged; the metrics log closed."""
    episodes = run.protocol.final_episodes
    say = f"final evaluation: the best policy over {episodes} new episodes"
    run.progress_bar.status(say)

    def show_played(played: int) -> None:  # pixel episodes are played 20 at a time
        if played < episodes:
            run.progress_bar.status(f"{say} ({played} played)")

    final = run.protocol.final(run.actor, on_turn=show_played)
    cut = cut_episodes_note(final, run.protocol.max_steps, "final episodes")
    if cut is not None:
        warnings.warn(cut, stacklevel=1)
    run.metrics.log({"eval/final_return_mean": final.mean}, run.progress.frames)
    run.metrics.close()
    return final


def _draw_plots(run: Components, final: EvalResult) -> None:
    """``durations.png`` (the PyTorch DQN tutorial's plot) and ``dashboard.png`` (the Practical
    RL DQN assignment's four panels)."""
    history, curve, settings = run.history, run.evaluator.curve, run.settings
    frames = run.progress.frames
    final_point = FinalEvaluation(frames, final.mean, final.std, len(final.returns))
    plot_durations(
        history.curves(
            curve, run.threshold, run.protocol.periodic_episodes, final_point, settings.return_label
        ),
        run.run_dir / "durations.png",
        settings.title,
    )
    dashboard = DashboardData(
        update_frames=history.update_frames,
        td_losses=history.td_losses,
        grad_norms=history.grad_norms,
        eval_frames=curve.frames,
        eval_initial_values=curve.initial_values,
        epsilon_frames=history.epsilon_frames,
        epsilons=history.epsilons,
        value_reference=discounted_return_reference(
            final.returns, final.lengths, settings.gamma, settings.time_limit
        ),
        max_grad_norm=settings.max_grad_norm,
    )
    plot_dashboard(dashboard, run.run_dir / "dashboard.png", title=settings.title)


def run_summary(
    *,
    env_id: str,
    seed: int,
    algo: str,
    frames: int,
    updates: int,
    train_seconds: float,
    wall_start: float,
    threshold: float | None,
    evaluator: Evaluator,
    final: EvalResult,
    run_dir: str | Path,
    **extra: Any,
) -> dict[str, Any]:
    """The ``summary.json`` of a finished run: ours, and a benchmark peer's under the protocol.

    ``evaluator`` holds the periodic evaluations (curve, best, solve point), ``final`` the
    best policy's evaluation on new episodes; ``extra`` keys (throughput, versions...) follow
    the shared ones, before ``peak_rss_mb``, ``run_dir`` and the end.
    """
    seconds_to_solve = evaluator.seconds_to_solve
    return {
        **_where_the_run_stands(env_id, seed, algo, frames, updates, wall_start, evaluator),
        "train_seconds": round(train_seconds, 3),
        "solve_threshold": threshold,
        "seconds_to_solve": None if seconds_to_solve is None else round(seconds_to_solve, 3),
        "final_eval_return_mean": final.mean,
        "final_eval_return_std": final.std,
        "final_eval_episodes": len(final.returns),
        "final_eval_returns": final.returns,
        "best_eval_return_mean": evaluator.best_return,
        "eval_curve": {
            "frames": evaluator.curve.frames,
            "seconds": evaluator.curve.seconds,  # training seconds, evaluation excluded
            "returns": evaluator.curve.returns,
            "rss_mb": evaluator.curve.rss_mb,  # resident memory (MiB) at each evaluation
        },
        **extra,
        # this process's peak, or more where its workers and it held more at an evaluation
        "peak_rss_mb": round(
            max([peak_rss_mb(), *(mb for mb in evaluator.curve.rss_mb if mb is not None)]), 1
        ),
        "run_dir": str(run_dir),
    }


def _where_the_run_stands(
    env_id: str,
    seed: int,
    algo: str,
    frames: int,
    updates: int,
    wall_start: float,
    evaluator: Evaluator,
) -> dict[str, Any]:
    """The keys every ``summary.json`` starts with, finished or failed."""
    return {
        "env_id": env_id,
        "seed": seed,
        "algo": algo,
        "frames": frames,
        "updates": updates,
        "wall_seconds": round(time.perf_counter() - wall_start, 3),
        "solved": evaluator.frames_to_solve is not None,
        "frames_to_solve": evaluator.frames_to_solve,
    }


def record_failure(run: Components, failure: TrainingFailed) -> TrainingFailed:
    """Write the failure to ``summary.json``; return the error to raise, naming that file.

    The last periodic checkpoint (written before the fault) stays the one to resume from.
    """
    periodic = run.run_dir / "checkpoints" / "periodic"
    progress, evaluator = run.progress, run.evaluator
    settings = run.settings
    summary = {
        **_where_the_run_stands(
            settings.env_id,
            settings.seed,
            settings.algo,
            progress.frames,
            progress.updates,
            run.wall_start,
            evaluator,
        ),
        "failed": True,
        "failure": str(failure),
        "best_eval_return_mean": evaluator.best_return if evaluator.best_state else None,
        "last_good_checkpoint": str(periodic) if periodic.is_dir() else None,
        "run_dir": str(run.run_dir),
    }
    write_json_atomic(run.run_dir / "summary.json", summary)
    return TrainingFailed(f"{failure}; the failure is recorded in {run.run_dir / 'summary.json'}")

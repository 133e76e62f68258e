"""Plots of a run: the tutorial's duration plot (also live) and the Practical RL dashboard.

File plots are drawn on ``matplotlib.figure.Figure`` objects, which need no pyplot backend, so
importing this module never changes the user's matplotlib backend; only a live window uses
pyplot.
"""

from __future__ import annotations

import io
import math
import os
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from trl_cartpole.store.files import write_atomic

__all__ = [
    "LearningCurves",
    "LiveDurationPlot",
    "draw_durations",
    "hold_last",
    "live_plot_target",
    "moving_average",
    "plot_comparison",
    "plot_dashboard",
    "plot_durations",
    "plot_seed_groups",
]


def moving_average(values: Sequence[float], window: int) -> np.ndarray:
    """Mean of the last ``window`` values at each point (fewer at the start), shape ``[N]``."""
    data = np.asarray(values, dtype=np.float64)
    if data.size == 0:
        return data
    cumsum = np.cumsum(np.insert(data, 0, 0.0))
    index = np.arange(1, data.size + 1)
    start = np.maximum(index - window, 0)
    return (cumsum[index] - cumsum[start]) / (index - start)


def _atomic_savefig(fig: Figure, path: Path) -> None:
    write_atomic(path, lambda tmp: fig.savefig(tmp, format="png", dpi=100))


@dataclass
class LearningCurves:
    """What the duration plot draws: training episodes and greedy evaluations, by frame."""

    episode_frames: Sequence[int]  # frame at which each training episode ended, in that order
    episode_returns: Sequence[float]  # its return (its duration on CartPole: +1 per step)
    eval_frames: Sequence[int]  # frame of each periodic greedy evaluation
    eval_returns: Sequence[float]  # its mean return over eval.episodes episodes
    threshold: float | None = None  # the solve threshold (475 on CartPole-v1), if any


def draw_durations(ax, curves: LearningCurves, title: str = "") -> None:
    """The PyTorch DQN tutorial's duration plot, against frames, with the greedy evaluations.

    Training episodes (epsilon-greedy, from all envs, ordered by the frame they ended at) are
    dots with their 100-episode mean, as the tutorial draws them; the greedy evaluations and
    the solve threshold show whether the policy itself is solved.
    """
    returns = np.asarray(curves.episode_returns, dtype=np.float64)
    frames = np.asarray(curves.episode_frames)
    if frames.size != returns.size:  # a run resumed from a state saved without their frames
        frames = np.linspace(0, curves.episode_frames[-1] if frames.size else 0, returns.size)
    ax.scatter(frames, returns, s=4, alpha=0.3, label="training episode (epsilon-greedy)")
    if returns.size >= 100:  # the tutorial draws the mean only once 100 episodes exist
        ax.plot(frames[99:], moving_average(returns, 100)[99:], label="100-episode mean")
    if len(curves.eval_frames):
        ax.plot(
            curves.eval_frames,
            curves.eval_returns,
            marker="o",
            linewidth=2,
            color="black",
            label="greedy evaluation (mean)",
        )
    if curves.threshold is not None:
        ax.axhline(
            curves.threshold, color="green", linestyle="--", label=f"solved ({curves.threshold:g})"
        )
    ax.set_xlabel("Frames")
    ax.set_ylabel("Episode return (= duration on CartPole)")
    ax.set_title(title or "Training episodes and greedy evaluations")
    ax.legend(loc="best", fontsize="small")
    ax.grid(alpha=0.3)


def plot_durations(curves: LearningCurves, path: str | Path, title: str = "") -> Path:
    """:func:`draw_durations` as a PNG file (written atomically)."""
    path = Path(path)
    fig = Figure(figsize=(8, 4.5))
    draw_durations(fig.subplots(), curves, title)
    _atomic_savefig(fig, path)
    return path


def live_plot_target() -> str:
    """Where a live plot can go: ``notebook`` (a Jupyter kernel), ``window`` or ``file``.

    ``window`` needs a display and an interactive matplotlib backend; anything else (a
    headless machine, CI) gets ``file``.
    """
    try:
        from IPython import get_ipython

        shell = get_ipython()
        if shell is not None and "IPKernelApp" in shell.config:
            return "notebook"
    except ImportError:
        pass
    if os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY") or sys.platform == "darwin":
        import matplotlib

        if matplotlib.get_backend().lower() not in NON_INTERACTIVE_BACKENDS:
            return "window"
    return "file"


NON_INTERACTIVE_BACKENDS = {"agg", "cairo", "pdf", "pgf", "ps", "svg", "template"}


class LiveDurationPlot:
    """The PyTorch DQN tutorial's live duration plot, redrawn by :meth:`update`.

    In a notebook the cell output is replaced by the new figure (``IPython.display``), with a
    display a matplotlib window is redrawn, and headless the PNG at ``path`` is rewritten.
    A redraw costs about 0.1 s (docs/choices.md): an update less than ``min_seconds`` (of
    ``clock``) after the last redraw is skipped and kept; :meth:`flush` (at the end of the run)
    draws the last one skipped, so the final picture is the same as without skipping.
    """

    def __init__(
        self,
        path: str | Path,
        title: str = "",
        target: str | None = None,
        min_seconds: float = 0.0,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.path, self.title = Path(path), title
        self.target = target or live_plot_target()
        self.min_seconds, self.clock = min_seconds, clock
        self._last_redraw: float | None = None
        self._skipped: LearningCurves | None = None  # the newest update not drawn yet
        self._window = None

    def update(self, curves: LearningCurves) -> bool:
        """Redraw with ``curves``, unless the last redraw is too recent; True if redrawn."""
        now = self.clock()
        if self._last_redraw is not None and now - self._last_redraw < self.min_seconds:
            self._skipped = curves
            return False
        self._last_redraw = now
        self._draw(curves)
        return True

    def flush(self) -> bool:
        """Draw the last skipped update, if any; True if drawn."""
        if self._skipped is None:
            return False
        self._last_redraw = self.clock()
        self._draw(self._skipped)
        return True

    def _draw(self, curves: LearningCurves) -> None:
        self._skipped = None
        if self.target == "file":
            plot_durations(curves, self.path, self.title)
        elif self.target == "notebook":
            from IPython import display

            fig = Figure(figsize=(8, 4.5))
            draw_durations(fig.subplots(), curves, self.title)
            buffer = io.BytesIO()
            fig.savefig(buffer, format="png", dpi=80)
            display.clear_output(wait=True)
            display.display(display.Image(data=buffer.getvalue()))
        else:
            import matplotlib.pyplot as plt

            if self._window is None:
                plt.ion()
                self._window = plt.figure(figsize=(8, 4.5))
            self._window.clf()
            draw_durations(self._window.subplots(), curves, self.title)
            plt.pause(0.001)


def plot_dashboard(
    eval_frames: Sequence[int],
    eval_returns: Sequence[float],
    eval_initial_values: Sequence[float],
    update_frames: Sequence[int],
    td_losses: Sequence[float],
    grad_norms: Sequence[float],
    path: str | Path,
    smoothing: int = 100,
    title: str = "",
    threshold: float | None = None,
) -> Path:
    """The Practical RL DQN assignment's 4 panels: eval return, TD loss, initial V, grad norm.

    TD loss and grad norm are smoothed with a moving average over ``smoothing`` updates; the
    eval panel shows the solve ``threshold`` when there is one.
    """
    path = Path(path)
    fig = Figure(figsize=(12, 8))
    axes = fig.subplots(2, 2)
    if title:
        fig.suptitle(title)
    if threshold is not None:
        axes[0, 0].axhline(threshold, color="green", linestyle="--", label="solved")
        axes[0, 0].legend(loc="lower right", fontsize="small")
    panels = [
        (axes[0, 0], eval_frames, eval_returns, "Mean greedy return (eval)", False),
        (axes[0, 1], update_frames, td_losses, "TD loss (smoothed)", True),
        (axes[1, 0], eval_frames, eval_initial_values, "Initial-state V = max_a Q(s0, a)", False),
        (axes[1, 1], update_frames, grad_norms, "Grad norm (smoothed)", True),
    ]
    for ax, x, y, title, smooth in panels:
        values = moving_average(y, smoothing) if smooth else np.asarray(y, dtype=np.float64)
        ax.plot(np.asarray(x), values)
        ax.set_title(title)
        ax.set_xlabel("Frames")
        ax.grid(alpha=0.3)
    fig.tight_layout()
    _atomic_savefig(fig, path)
    return path


def hold_last(frames: Sequence[int], values: Sequence[float], grid: np.ndarray) -> np.ndarray:
    """``[len(grid)]``: at each grid frame, the last value recorded at or before it.

    NaN before the first record; after the last one (a run that stopped once solved) the last
    value is held.
    """
    frames_arr = np.asarray(frames, dtype=np.float64)
    values_arr = np.asarray(values, dtype=np.float64)
    position = np.searchsorted(frames_arr, grid, side="right") - 1  # [G]
    held = values_arr[np.clip(position, 0, None)] if values_arr.size else np.full(grid.shape, 0.0)
    return np.where(position >= 0, held, np.nan)


def plot_seed_groups(
    curves: dict[str, list[tuple[Sequence[int], Sequence[float]]]],
    path: str | Path,
    threshold: float | None = None,
    ylabel: str = "Mean greedy return (eval)",
) -> Path:
    """One panel per group: each seed's curve, their median and interquartile band.

    ``curves`` maps a group name (a preset) to one ``(frames, values)`` per seed; every seed
    is held at its last value up to the longest run of the group (see :func:`hold_last`).
    """
    path = Path(path)
    columns = min(4, len(curves))
    rows = -(-len(curves) // columns)
    fig = Figure(figsize=(4 * columns, 3.2 * rows))
    axes = fig.subplots(rows, columns, squeeze=False, sharey=True)
    for ax, (name, seeds) in zip(axes.flat, curves.items(), strict=False):
        for frames, values in seeds:
            ax.step(frames, values, where="post", color="grey", alpha=0.35, linewidth=0.8)
        _median_band(ax, "median, interquartile band", seeds)
        if threshold is not None:
            ax.axhline(threshold, color="black", linestyle="--", linewidth=0.8)
        ax.set_title(name)
        ax.set_xlabel("Frames")
        ax.grid(alpha=0.3)
    for ax in axes[:, 0]:
        ax.set_ylabel(ylabel)
    for ax in list(axes.flat)[len(curves) :]:
        ax.set_visible(False)
    axes.flat[0].legend(loc="lower right", fontsize="small")
    fig.tight_layout()
    _atomic_savefig(fig, path)
    return path


def _median_band(ax, name: str, seeds: list[tuple[Sequence[float], Sequence[float]]]) -> None:
    """Draw the median over seeds of held curves and their interquartile band on ``ax``."""
    end = max(max(x) for x, _ in seeds if len(x))
    grid = np.linspace(0, end, 200)  # [G]
    held = np.stack([hold_last(x, y, grid) for x, y in seeds])  # [S, G]
    started = ~np.isnan(held).any(0)  # [G]
    low, median, high = np.percentile(held[:, started], [25, 50, 75], axis=0)
    (line,) = ax.plot(grid[started], median, linewidth=2, label=f"{name} ({len(seeds)} seeds)")
    ax.fill_between(grid[started], low, high, alpha=0.2, color=line.get_color())


def plot_comparison(
    panels: dict[str, dict[str, list[tuple[Sequence[float], Sequence[float]]]]],
    path: str | Path,
    threshold: float | None = None,
    ylabel: str = "Mean greedy return (eval)",
) -> Path:
    """Several configs on shared axes, one panel per x-axis (e.g. ``Frames``, ``Seconds``).

    ``panels`` maps an x-axis label to ``{config label: [(x, y) per seed]}``; each config is
    drawn as its median over seeds with an interquartile band (curves held as in
    :func:`hold_last`).
    """
    path = Path(path)
    fig = Figure(figsize=(6 * len(panels), 4.2))
    axes = fig.subplots(1, len(panels), squeeze=False)
    for ax, (xlabel, groups) in zip(axes.flat, panels.items(), strict=True):
        for name, seeds in groups.items():
            _median_band(ax, name, seeds)
        if threshold is not None:
            ax.axhline(threshold, color="black", linestyle="--", linewidth=0.8)
        ax.set_xlabel(xlabel)
        ax.set_ylabel(ylabel)
        ax.grid(alpha=0.3)
        ax.legend(loc="lower right", fontsize="small")
    fig.tight_layout()
    _atomic_savefig(fig, path)
    return path


def plot_profiles(
    solve_frames: dict[str, list[float | None]],
    final_returns: dict[str, list[float]],
    path: str | Path,
) -> Path:
    """Performance profiles (Agarwal et al. 2021) of each config over its runs, two panels.

    Left: the fraction of runs solved within F frames, for every F (unsolved runs never count).
    Right: the fraction of runs whose final greedy return exceeds tau, for every tau
    (:func:`trl_cartpole.report.interval_estimates.performance_profile`).
    """
    from trl_cartpole.report.interval_estimates import performance_profile

    path = Path(path)
    fig = Figure(figsize=(12, 4.2))
    left, right = fig.subplots(1, 2)
    solved = [f for runs in solve_frames.values() for f in runs if f is not None]
    frames = np.linspace(0, max(solved, default=1) * 1.05, 300)  # [G]
    for name, runs in solve_frames.items():
        finite = [math.inf if f is None else f for f in runs]
        left.step(
            frames,
            1 - performance_profile(finite, frames),
            where="post",
            label=f"{name} ({len(runs)} runs)",
        )
    left.set(xlabel="Frames", ylabel="Fraction of runs solved", ylim=(-0.02, 1.02))
    returns = [r for runs in final_returns.values() for r in runs]
    margin = 0.05 * ((max(returns) - min(returns)) or 1.0)  # start below every run
    taus = np.linspace(min(returns) - margin, max(returns), 300)  # [G]
    for name, runs in final_returns.items():
        right.step(taus, performance_profile(runs, taus), where="post", label=name)
    right.set(xlabel="Final greedy return tau", ylabel="Fraction of runs > tau", ylim=(-0.02, 1.02))
    for ax in (left, right):
        ax.grid(alpha=0.3)
        ax.legend(loc="best", fontsize="small")
    fig.tight_layout()
    _atomic_savefig(fig, path)
    return path

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
    "DashboardData",
    "FinalEvaluation",
    "LearningCurves",
    "LiveDurationPlot",
    "discounted_return_reference",
    "draw_durations",
    "draw_median_band",
    "hold_last",
    "live_plot_target",
    "moving_average",
    "plot_comparison",
    "plot_dashboard",
    "plot_durations",
    "savefig_atomic",
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


# the duration plot's margins: its legend sits under the axes (two columns, up to 3 rows)
DURATIONS_MARGINS = {"left": 0.09, "right": 0.97, "top": 0.93, "bottom": 0.3}


def savefig_atomic(fig: Figure, path: Path) -> None:
    write_atomic(path, lambda tmp: fig.savefig(tmp, format="png", dpi=100))


@dataclass(frozen=True)
class FinalEvaluation:
    """The end of a run's evaluation: the best policy over ``episodes`` new episodes."""

    frame: int  # where it is drawn: the run's last frame
    mean: float
    std: float
    episodes: int


@dataclass
class LearningCurves:
    """What the duration plot draws: training episodes and greedy evaluations, by frame."""

    episode_frames: Sequence[int]  # frame at which each training episode ended, in that order
    episode_returns: Sequence[float]  # its return (its duration on CartPole: +1 per step)
    eval_frames: Sequence[int]  # frame of each periodic greedy evaluation
    eval_returns: Sequence[float]  # its mean return over eval.episodes episodes
    threshold: float | None = None  # the solve threshold (475 on CartPole-v1), if any
    eval_episodes: int | None = None  # episodes per periodic evaluation, for the label
    final: FinalEvaluation | None = None  # the best policy's final evaluation, once run
    return_label: str = "Episode return"  # the y axis (CartPole's: "its length")


def draw_durations(ax, curves: LearningCurves, title: str = "") -> None:
    """The PyTorch DQN tutorial's duration plot, against frames, with the greedy evaluations.

    Training episodes (epsilon-greedy, from all envs, ordered by the frame they ended at) are
    dots with their 100-episode mean, as the tutorial draws them; the greedy evaluations, the
    final evaluation of the best policy and the solve threshold show whether the policy itself
    is solved. The legend says why the mean lags the greedy line: it averages exploring
    episodes played by older policies.
    """
    returns = np.asarray(curves.episode_returns, dtype=np.float64)
    frames = np.asarray(curves.episode_frames)
    if frames.size != returns.size:  # a run resumed from a state saved without their frames
        frames = np.linspace(0, curves.episode_frames[-1] if frames.size else 0, returns.size)
    ax.scatter(frames, returns, s=4, alpha=0.3, label="training episode (epsilon-greedy)")
    if returns.size >= 100:  # the tutorial draws the mean only once 100 episodes exist
        ax.plot(
            frames[99:],
            moving_average(returns, 100)[99:],
            label="mean of the last 100 training episodes\n"
            "(lags: they explore, and older policies played them)",
        )
    if len(curves.eval_frames):
        episodes = f"{curves.eval_episodes} episodes" if curves.eval_episodes else "episodes"
        ax.plot(
            curves.eval_frames,
            curves.eval_returns,
            marker="o",
            linewidth=2,
            color="black",
            label=f"greedy evaluation (mean of {episodes}, no exploration)",
        )
    if curves.final is not None:
        final = curves.final
        ax.errorbar(
            [final.frame],
            [final.mean],
            yerr=[final.std],
            fmt="D",
            markersize=8,
            capsize=5,
            color="tab:red",
            zorder=5,
            label=f"final: best policy, {final.episodes} new episodes: "
            f"{final.mean:.1f} +/- {final.std:.1f}",
        )
    if curves.threshold is not None:
        ax.axhline(
            curves.threshold, color="green", linestyle="--", label=f"solved ({curves.threshold:g})"
        )
    ax.set_xlabel("Frames (environment steps, all envs)")
    ax.set_ylabel(curves.return_label)
    ax.set_title(title or "Training episodes and greedy evaluations")
    # under the axes, two columns: never over the curves or the threshold line
    ax.legend(
        loc="upper center", bbox_to_anchor=(0.5, -0.14), ncol=2, fontsize="small", frameon=False
    )
    ax.grid(alpha=0.3)


def _durations_figure() -> Figure:
    """The duration plot's figure, its bottom margin holding the legend (fixed: no layout pass
    on each live redraw)."""
    fig = Figure(figsize=(8, 5.6))
    fig.subplots_adjust(**DURATIONS_MARGINS)
    return fig


def plot_durations(curves: LearningCurves, path: str | Path, title: str = "") -> Path:
    """:func:`draw_durations` as a PNG file (written atomically)."""
    path = Path(path)
    fig = _durations_figure()
    draw_durations(fig.subplots(), curves, title)
    savefig_atomic(fig, path)
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

            fig = _durations_figure()
            draw_durations(fig.subplots(), curves, self.title)
            buffer = io.BytesIO()
            fig.savefig(buffer, format="png", dpi=80)
            display.clear_output(wait=True)
            display.display(display.Image(data=buffer.getvalue()))
        else:
            import matplotlib.pyplot as plt

            if self._window is None:
                plt.ion()
                self._window = plt.figure(figsize=(8, 5.6))
            self._window.clf()
            self._window.subplots_adjust(**DURATIONS_MARGINS)
            draw_durations(self._window.subplots(), curves, self.title)
            plt.pause(0.001)


@dataclass
class DashboardData:
    """What the dashboard draws, by frame; empty sequences leave their panel with a note."""

    update_frames: Sequence[int]  # frame of each gradient update
    td_losses: Sequence[float]  # [updates]
    grad_norms: Sequence[float]  # [updates], before clipping
    eval_frames: Sequence[int]  # frame of each periodic greedy evaluation
    eval_initial_values: Sequence[float]  # mean max_a Q(s_0, a) at each evaluation
    epsilon_frames: Sequence[int] = ()  # after each batch; empty without epsilon-greedy
    epsilons: Sequence[float] = ()
    value_reference: float | None = None  # see :func:`discounted_return_reference`
    max_grad_norm: float | None = None  # the clipping norm, when gradients are clipped by norm


def discounted_return_reference(
    returns: Sequence[float], lengths: Sequence[int], gamma: float, time_limit: int | None
) -> float:
    """The initial-state value a policy's episodes earn, averaged over them.

    Each episode's return ``R`` over ``T`` steps is spread as an equal reward ``r = R / T`` per
    step (exact when every step earns the same, as on CartPole and MountainCar; near it on Acrobot,
    whose last step earns 0) and
    discounted: ``r (1 - gamma^T) / (1 - gamma)`` for an episode that ended, and
    ``r / (1 - gamma)`` for one cut by the ``time_limit``, since DQN's target bootstraps
    through a truncation (TorchRL stops it only at ``terminated``): 200 on CartPole at
    gamma = 0.995. ``max_a Q(s_0, a)`` approaches this value as the values converge.
    """
    values = []
    for episode_return, length in zip(returns, lengths, strict=True):
        if length <= 0:
            continue
        per_step = episode_return / length
        truncated = time_limit is not None and length >= time_limit
        horizon = 1.0 if truncated else 1 - gamma**length
        values.append(per_step * horizon / (1 - gamma))
    return float(np.mean(values)) if values else float("nan")


DASHBOARD_MARGINS = {
    "left": 0.06,
    "right": 0.985,
    "bottom": 0.075,
    "top": 0.865,
    "wspace": 0.18,
    "hspace": 0.3,
}


def plot_dashboard(
    data: DashboardData, path: str | Path, smoothing: int = 100, title: str = ""
) -> Path:
    """The Practical RL DQN assignment's 4 panels: exploration, TD loss, initial V, grad norm.

    TD loss and grad norm are smoothed with a moving average over ``smoothing`` updates. The
    greedy evaluations are on ``durations.png``; here the first panel is what the agent
    explored with (epsilon), and the initial-state value has its reference line.
    """
    path = Path(path)
    fig = Figure(figsize=(12, 8))
    axes = fig.subplots(2, 2)
    if title:
        fig.suptitle(title)
    exploration, loss, value, gradient = axes.flat
    _draw_panel(
        exploration,
        data.epsilon_frames,
        data.epsilons,
        "Exploration: epsilon after each batch",
        "Probability of a random action",
        empty_note="no epsilon-greedy: noisy layers explore, or none",
    )
    exploration.set_ylim(-0.02, 1.02)
    _draw_panel(
        loss,
        data.update_frames,
        moving_average(data.td_losses, smoothing),
        f"TD loss (mean of {smoothing} updates)\nrising while the values grow is normal",
        "TD loss",
        empty_note="no update yet",
    )
    _draw_panel(
        value,
        data.eval_frames,
        data.eval_initial_values,
        "Initial-state value at each greedy evaluation",
        "max_a Q(s0, a)",
        empty_note="no evaluation yet",
        label="the network's estimate",
    )
    if data.value_reference is not None and np.isfinite(data.value_reference):
        value.axhline(
            data.value_reference,
            color="green",
            linestyle="--",
            label="discounted return of the final evaluation's episodes: "
            f"{data.value_reference:.1f}",
        )
    if data.eval_frames:
        value.legend(loc="lower right", fontsize="small")
    _draw_panel(
        gradient,
        data.update_frames,
        moving_average(data.grad_norms, smoothing),
        f"Gradient norm before clipping (mean of {smoothing} updates)",
        "Gradient L2 norm",
        empty_note="no update yet",
    )
    if data.max_grad_norm is not None and len(data.update_frames):
        gradient.axhline(
            data.max_grad_norm,
            color="gray",
            linestyle="--",
            label=f"clipped to {data.max_grad_norm:g}",
        )
        gradient.legend(loc="upper right", fontsize="small")
    # the margins tight_layout() finds for this grid, with room for a 2-line title and an
    # offset label ("1e-4") over a panel; fixed, they cost nothing (tight_layout: about 0.2 s)
    fig.subplots_adjust(**DASHBOARD_MARGINS)
    savefig_atomic(fig, path)
    return path


def _draw_panel(ax, x, y, title: str, ylabel: str, empty_note: str, label: str = "") -> None:
    """One dashboard panel: ``y`` against frames, or ``empty_note`` when there is nothing."""
    if len(x):
        ax.plot(np.asarray(x), np.asarray(y, dtype=np.float64), label=label or None)
    else:
        ax.text(0.5, 0.5, empty_note, transform=ax.transAxes, ha="center", color="dimgray")
    ax.set_title(title)
    ax.set_xlabel("Frames")
    ax.set_ylabel(ylabel)
    ax.grid(alpha=0.3)


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


def draw_median_band(ax, name: str, seeds: list[tuple[Sequence[float], Sequence[float]]]) -> None:
    """Draw the median over seeds of held curves and their interquartile band on ``ax``."""
    end = max(max(x) for x, _ in seeds if len(x))
    grid = np.linspace(0, end, 200)  # [G]
    held = np.stack([hold_last(x, y, grid) for x, y in seeds])  # [S, G]
    started = ~np.isnan(held).any(0)  # [G]
    low, median, high = np.percentile(held[:, started], [25, 50, 75], axis=0)
    (line,) = ax.plot(
        grid[started],
        median,
        linewidth=2,
        label=f"{name} ({len(seeds)} seed{'s' if len(seeds) != 1 else ''})",
    )
    ax.fill_between(grid[started], low, high, alpha=0.2, color=line.get_color())


def plot_comparison(
    panels: dict[str, dict[str, list[tuple[Sequence[float], Sequence[float]]]]],
    path: str | Path,
    threshold: float | dict[str, float] | None = None,
    ylabel: str = "Mean greedy return (eval)",
) -> Path:
    """Several configs on shared axes, one panel per x-axis (e.g. ``Frames``, ``Seconds``).

    ``panels`` maps an x-axis label to ``{config label: [(x, y) per seed]}``; each config is
    drawn as its median over seeds with an interquartile band (curves held as in
    :func:`hold_last`). ``threshold``: one dashed line, or ``{env id: threshold}`` for runs of
    several envs, each line labelled with its env.
    """
    lines = {} if threshold is None else threshold
    if not isinstance(lines, dict):
        lines = {"": lines}
    path = Path(path)
    fig = Figure(figsize=(6 * len(panels), 4.2))
    axes = fig.subplots(1, len(panels), squeeze=False)
    for ax, (xlabel, groups) in zip(axes.flat, panels.items(), strict=True):
        for name, seeds in groups.items():
            draw_median_band(ax, name, seeds)
        for index, (env_id, value) in enumerate(lines.items()):
            label = f"{env_id} threshold" if len(lines) > 1 else None
            style = ("--", ":", "-.")[index % 3]
            ax.axhline(value, color="black", linestyle=style, linewidth=0.8, label=label)
        ax.set_xlabel(xlabel)
        ax.set_ylabel(ylabel)
        ax.grid(alpha=0.3)
        ax.legend(loc="lower right", fontsize="small")
    fig.tight_layout()
    savefig_atomic(fig, path)
    return path


def plot_profiles(
    solve_frames: dict[str, list[float | None]],
    final_returns: dict[str, list[float]],
    path: str | Path,
) -> Path:
    """Performance profiles (Agarwal et al. 2021) of each config over its runs, two panels.

    Left: the fraction of runs solved within F frames, for every F (unsolved runs never count).
    Right: the fraction of runs whose final greedy return exceeds x, for every return x
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
    right.set(
        xlabel="Final greedy return (the best policy's mean)",
        ylabel="Fraction of runs scoring above it",
        ylim=(-0.02, 1.02),
    )
    for ax in (left, right):
        ax.grid(alpha=0.3)
        ax.legend(loc="best", fontsize="small")
    fig.tight_layout()
    savefig_atomic(fig, path)
    return path

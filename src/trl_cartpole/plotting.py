"""PNG plots of a run: the tutorial's duration plot and the Practical RL 4-panel dashboard."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import matplotlib

matplotlib.use("Agg")  # headless: the plots are files
import matplotlib.pyplot as plt
import numpy as np

__all__ = ["moving_average", "plot_dashboard", "plot_durations"]


def moving_average(values: Sequence[float], window: int) -> np.ndarray:
    """Mean of the last ``window`` values at each point (fewer at the start), shape ``[N]``."""
    data = np.asarray(values, dtype=np.float64)
    if data.size == 0:
        return data
    cumsum = np.cumsum(np.insert(data, 0, 0.0))
    index = np.arange(1, data.size + 1)
    start = np.maximum(index - window, 0)
    return (cumsum[index] - cumsum[start]) / (index - start)


def _atomic_savefig(fig: plt.Figure, path: Path) -> None:
    tmp = path.with_name(f".{path.name}.tmp")
    fig.savefig(tmp, format="png", dpi=100)
    plt.close(fig)
    tmp.replace(path)


def plot_durations(episode_lengths: Sequence[int], path: str | Path, title: str = "") -> Path:
    """The tutorial's ``plot_durations``: episode duration and its 100-episode mean."""
    path = Path(path)
    fig, ax = plt.subplots(figsize=(8, 4.5))
    episodes = np.arange(1, len(episode_lengths) + 1)
    ax.plot(episodes, episode_lengths, label="duration", alpha=0.6)
    if len(episode_lengths) >= 100:
        # The tutorial draws the mean only once 100 episodes exist.
        means = moving_average(episode_lengths, 100)
        ax.plot(episodes[99:], means[99:], label="100-episode mean", linewidth=2)
    ax.set_xlabel("Episode")
    ax.set_ylabel("Duration")
    ax.set_title(title or "Training episode durations")
    ax.legend(loc="upper left")
    ax.grid(alpha=0.3)
    _atomic_savefig(fig, path)
    return path


def plot_dashboard(
    eval_frames: Sequence[int],
    eval_returns: Sequence[float],
    eval_initial_values: Sequence[float],
    update_frames: Sequence[int],
    td_losses: Sequence[float],
    grad_norms: Sequence[float],
    path: str | Path,
    smoothing: int = 100,
) -> Path:
    """The Practical RL seed's 4 panels: eval mean return, TD loss, initial-state V, grad norm.

    TD loss and grad norm are smoothed with a moving average over ``smoothing`` updates.
    """
    path = Path(path)
    fig, axes = plt.subplots(2, 2, figsize=(12, 8))
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

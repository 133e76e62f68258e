"""Aggregate scores over seeds with uncertainty: IQM, stratified bootstrap intervals, profiles.

The methods of Agarwal et al. 2021, "Deep reinforcement learning at the edge of the statistical
precipice" (NeurIPS), as their ``rliable`` library computes them, in NumPy:

- the interquartile mean (IQM): the mean of the middle 50 % of the scores, robust to an
  outlier seed yet less noisy than the median (``rliable.metrics.aggregate_iqm``, i.e.
  ``scipy.stats.trim_mean(scores, 0.25)``: ``floor(n / 4)`` scores cut at each end);
- a 95 % stratified bootstrap confidence interval: the runs of each task are resampled with
  replacement (tasks are the strata), the statistic recomputed, and the 2.5 and 97.5
  percentiles of those replicates taken (``rliable.library.get_interval_estimates``, percentile
  method);
- performance profiles: the fraction of runs whose score exceeds each threshold ``tau``
  (``rliable.library.create_performance_profile``).

``rliable`` itself is not a dependency: its 1.2.0 release needs ``arch``, which fails to import
beside pandas 3, and SciPy, pandas and seaborn for these few lines. Scores are ``[runs, tasks]``
arrays (one column for one env); an unsolved run's frames or seconds to solve are ``inf``.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

__all__ = ["Estimate", "interval_estimate", "iqm", "performance_profile"]


def iqm(scores: np.ndarray) -> float:
    """Interquartile mean of all scores (``scipy.stats.trim_mean(scores, 0.25, axis=None)``)."""
    flat = np.sort(np.asarray(scores, dtype=float), axis=None)  # [runs * tasks]
    cut = int(0.25 * flat.size)
    middle = flat[cut : flat.size - cut]
    if np.isinf(middle).any():
        return float(middle[np.isinf(middle)][0])  # inf: more than a quarter never solved
    return float(middle.mean())


@dataclass
class Estimate:
    """A point estimate and its confidence interval over ``runs`` runs."""

    value: float
    low: float
    high: float
    runs: int

    def __str__(self) -> str:
        return f"{_short(self.value)} [{_short(self.low)}, {_short(self.high)}]"


def _short(value: float) -> str:
    if np.isinf(value):
        return "inf"
    return f"{value:.0f}" if abs(value) >= 100 else f"{value:.1f}"


def interval_estimate(
    scores: Sequence[float] | np.ndarray,
    statistic: Callable[[np.ndarray], float] = iqm,
    reps: int = 2000,
    confidence: float = 0.95,
    seed: int = 0,
) -> Estimate:
    """``statistic`` of ``scores`` ([runs] or [runs, tasks]) with its stratified bootstrap CI.

    Each replicate resamples the runs of every task (column) independently, with replacement;
    the interval is the percentile interval of ``reps`` replicates (seeded: the same scores give
    the same interval).
    """
    scores = np.asarray(scores, dtype=float)
    scores = scores[:, None] if scores.ndim == 1 else scores  # [runs, tasks]
    runs, tasks = scores.shape
    rng = np.random.default_rng(seed)
    picks = rng.integers(0, runs, size=(reps, runs, tasks))  # [reps, runs, tasks]
    replicates = np.take_along_axis(scores[None], picks, axis=1)  # [reps, runs, tasks]
    values = np.array([statistic(replicate) for replicate in replicates])  # [reps]
    tail = (1 - confidence) / 2 * 100
    # linear interpolation (rliable's), or the nearest replicate where some are inf (unsolved)
    method = "linear" if np.isfinite(values).all() else "nearest"
    low, high = np.percentile(values, [tail, 100 - tail], method=method)
    return Estimate(statistic(scores), float(low), float(high), runs)


def performance_profile(
    scores: Sequence[float] | np.ndarray, taus: Sequence[float] | np.ndarray
) -> np.ndarray:
    """Fraction of runs with a score above each ``tau`` ([len(taus)])."""
    scores = np.asarray(scores, dtype=float).reshape(-1)  # [runs * tasks]
    taus = np.asarray(taus, dtype=float)
    return (scores[None, :] > taus[:, None]).mean(axis=1)

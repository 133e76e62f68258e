"""Interquartile means, stratified bootstrap intervals and performance profiles, by hand."""

from __future__ import annotations

import math

import numpy as np
import pytest

from trl_cartpole.report.interval_estimates import interval_estimate, iqm, performance_profile


def test_the_interquartile_mean_cuts_a_quarter_at_each_end():
    assert iqm([1, 2, 3, 4, 5, 6, 7, 8]) == 4.5  # mean of 3, 4, 5, 6
    assert iqm([7, 1, 100, 3, 2, 8, 4, 5, 6, -50]) == 4.5  # 10 scores: 2 cut each side
    assert iqm([1, 2, 3]) == 2.0  # fewer than 4: nothing cut
    assert iqm([[1, 10], [2, 20], [3, 30], [4, 40]]) == pytest.approx((3 + 4 + 10 + 20) / 4)
    assert math.isinf(iqm([1000, 2000, math.inf, math.inf]))  # half never solved


def test_the_interval_holds_the_estimate_and_narrows_with_more_runs():
    rng = np.random.default_rng(0)
    few, many = rng.normal(100, 10, 5), rng.normal(100, 10, 80)
    for scores in (few, many):
        estimate = interval_estimate(scores)
        assert estimate.low <= estimate.value <= estimate.high
    assert interval_estimate(many).high - interval_estimate(many).low < (
        interval_estimate(few).high - interval_estimate(few).low
    )
    assert str(interval_estimate([5.0] * 6)) == "5.0 [5.0, 5.0]"  # no spread, no interval
    assert interval_estimate(few).runs == 5
    assert interval_estimate(few, seed=3) == interval_estimate(few, seed=3)  # reproducible


def test_the_bootstrap_is_stratified_by_task():
    # Task 0 scores 0 on all 4 runs, task 1 scores 100: every replicate that resamples runs
    # within each task holds four 0s and four 100s, IQM (0 + 0 + 100 + 100) / 4 = 50, so the
    # interval is a point; pooled resampling would spread it.
    scores = np.array([[0.0, 100.0]] * 4)  # [runs, tasks]
    estimate = interval_estimate(scores)
    assert (estimate.value, estimate.low, estimate.high) == (50.0, 50.0, 50.0)


def test_a_performance_profile_is_the_fraction_of_runs_above_each_threshold():
    profile = performance_profile([1.0, 2.0, 3.0, 4.0], [0.0, 2.5, 4.0])
    assert profile.tolist() == [1.0, 0.5, 0.0]

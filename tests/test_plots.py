"""The plots explain themselves: labels, the final evaluation, reference lines."""

from __future__ import annotations

import math

import pytest
from matplotlib.figure import Figure

from trl_cartpole.report.plotting import (
    DashboardData,
    FinalEvaluation,
    LearningCurves,
    discounted_return_reference,
    draw_durations,
    plot_dashboard,
)


def test_reference_of_episodes_that_ended_is_their_discounted_return():
    # Acrobot-like: -1 per step for 80 steps, terminated: -(1 - 0.99^80) / 0.01
    expected = -(1 - 0.99**80) / 0.01
    assert discounted_return_reference([-80.0], [80], 0.99, time_limit=500) == pytest.approx(
        expected
    )
    assert expected == pytest.approx(-55.25, abs=0.01)


def test_reference_of_a_truncated_episode_bootstraps_forever():
    # CartPole at its time limit: +1 per step, the target bootstraps through truncation
    assert discounted_return_reference([500.0], [500], 0.995, time_limit=500) == pytest.approx(
        200.0
    )
    # the same episode with no time limit counts its 500 steps only
    assert discounted_return_reference([500.0], [500], 0.995, time_limit=None) == pytest.approx(
        (1 - 0.995**500) / 0.005
    )


def test_reference_averages_episodes_and_skips_empty_ones():
    both = discounted_return_reference([10.0, 500.0, 0.0], [10, 500, 0], 0.5, time_limit=500)
    assert both == pytest.approx(((1 - 0.5**10) / 0.5 + 2.0) / 2)
    assert math.isnan(discounted_return_reference([], [], 0.9, time_limit=None))


def _legend_texts(ax) -> list[str]:
    return [text.get_text() for text in ax.get_legend().get_texts()]


def test_duration_plot_names_each_curve_and_shows_the_final_evaluation():
    frames = list(range(10, 1510, 10))  # 150 episodes: the 100-episode mean is drawn
    curves = LearningCurves(
        frames,
        [float(f % 70) for f in frames],
        [500, 1000, 1500],
        [20.0, 80.0, 490.0],
        475.0,
        eval_episodes=20,
        final=FinalEvaluation(1500, 499.5, 1.25, 100),
    )
    ax = Figure().subplots()
    draw_durations(ax, curves)
    labels = _legend_texts(ax)
    assert labels[0] == "training episode (epsilon-greedy)"
    assert labels[1].startswith("mean of the last 100 training episodes") and "lags" in labels[1]
    assert labels[2] == "greedy evaluation (mean of 20 episodes, no exploration)"
    assert "solved (475)" in labels
    assert "final: best policy, 100 new episodes: 499.5 +/- 1.2" in labels
    assert ax.get_xlabel() and ax.get_ylabel()


def _dashboard_axes(tmp_path, monkeypatch, data: DashboardData):
    """Draw the dashboard to a file; return the axes of the figure it saved."""
    figures = []
    original = Figure.savefig

    def keep(self, *args, **kwargs):
        figures.append(self)
        return original(self, *args, **kwargs)

    monkeypatch.setattr(Figure, "savefig", keep)
    path = plot_dashboard(data, tmp_path / "dashboard.png")
    assert path.read_bytes()[:4] == b"\x89PNG"
    return list(figures[0].axes)


def test_dashboard_has_labels_everywhere_and_its_reference_lines(tmp_path, monkeypatch):
    data = DashboardData(
        update_frames=[100, 200, 300],
        td_losses=[1.0, 2.0, 3.0],
        grad_norms=[4.0, 5.0, 6.0],
        eval_frames=[100, 300],
        eval_initial_values=[1.0, 50.0],
        epsilon_frames=[100, 200, 300],
        epsilons=[1.0, 0.5, 0.05],
        value_reference=200.0,
        max_grad_norm=10.0,
    )
    axes = _dashboard_axes(tmp_path, monkeypatch, data)
    assert len(axes) == 4
    for ax in axes:
        assert ax.get_xlabel() == "Frames" and ax.get_ylabel() and ax.get_title()
    exploration, loss, value, gradient = axes
    assert "epsilon" in exploration.get_title()
    assert "is normal" in loss.get_title()
    assert any("200.0" in text for text in _legend_texts(value))
    assert [line.get_ydata()[0] for line in value.get_lines()][-1] == 200.0
    assert "clipped to 10" in _legend_texts(gradient)


def test_dashboard_without_epsilon_or_updates_says_so(tmp_path, monkeypatch):
    data = DashboardData(
        update_frames=[], td_losses=[], grad_norms=[], eval_frames=[500], eval_initial_values=[3]
    )
    exploration, loss, _, gradient = _dashboard_axes(tmp_path, monkeypatch, data)
    assert "noisy layers explore" in exploration.texts[0].get_text()
    assert loss.texts[0].get_text() == "no update yet"
    assert gradient.get_legend() is None


def test_the_duration_plot_names_its_axis_by_the_env_and_keeps_its_legend_off_the_curves():
    from matplotlib.figure import Figure

    from trl_cartpole.report.plotting import DURATIONS_MARGINS, LearningCurves, draw_durations

    curves = LearningCurves([10, 20], [-200.0, -150.0], [20], [-120.0], threshold=-100.0)
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    fig = Figure(figsize=(8, 5.6))
    canvas = FigureCanvasAgg(fig)
    fig.subplots_adjust(**DURATIONS_MARGINS)
    ax = fig.subplots()
    draw_durations(ax, curves, "Acrobot-v1 dqn seed 0")
    assert ax.get_ylabel() == "Episode return"  # no CartPole words on another env
    canvas.draw()
    legend = ax.get_legend().get_window_extent(canvas.get_renderer())
    axes = ax.get_window_extent(canvas.get_renderer())
    assert legend.y1 <= axes.y0  # under the axes: never over the threshold line
    assert legend.y0 >= 0 and legend.x0 >= 0 and legend.x1 <= fig.bbox.x1  # inside the image
    cartpole = LearningCurves([10], [9.0], [10], [9.0], return_label="Episode return (its length)")
    ax = Figure().subplots()
    draw_durations(ax, cartpole)
    assert ax.get_ylabel() == "Episode return (its length)"


def test_the_profiles_axes_are_labelled_in_words(tmp_path, monkeypatch):
    """The profiles' axes say what they show: no symbol a reader cannot know (was "tau")."""
    from trl_cartpole.report import plotting

    saved = []
    monkeypatch.setattr(plotting, "savefig_atomic", lambda fig, path: saved.append(fig))
    plotting.plot_profiles({"a": [1000, None]}, {"a": [500.0, 120.0]}, tmp_path / "p.png")
    labels = [(ax.get_xlabel(), ax.get_ylabel()) for ax in saved[0].axes]
    assert labels[1] == (
        "Final greedy return (the best policy's mean)",
        "Fraction of runs scoring above it",
    )
    assert not any("tau" in text for pair in labels for text in pair)


def test_runs_of_two_envs_draw_each_envs_threshold(tmp_path, monkeypatch):
    """Mixed envs: one dashed line per env, each labelled, not the first run's alone."""
    from trl_cartpole.report import plotting

    saved = []
    monkeypatch.setattr(plotting, "savefig_atomic", lambda fig, path: saved.append(fig))
    panels = {"Frames": {"a": [([0, 1000], [10.0, 500.0])], "b": [([0, 1000], [-500.0, -90.0])]}}
    thresholds = {"CartPole-v1": 475.0, "Acrobot-v1": -100.0}
    plotting.plot_comparison(panels, tmp_path / "c.png", thresholds)
    (ax,) = saved[0].axes
    drawn = {line.get_label(): line.get_ydata()[0] for line in ax.get_lines()}
    assert drawn["CartPole-v1 threshold"] == 475.0 and drawn["Acrobot-v1 threshold"] == -100.0

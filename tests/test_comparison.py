"""Comparing runs: medians over seeds, the comparison table, the plot of seed groups, ``plot``."""

from __future__ import annotations

import json
import math
import subprocess

import numpy as np

from trl_cartpole.report.plotting import hold_last
from trl_cartpole.tools.comparison import markdown_table, median_to_solve

from .conftest import SCRIPTS, summary_of


def test_median_to_solve_counts_unsolved_seeds_as_infinitely_slow():
    assert median_to_solve([3000, 1000, 2000]) == 2000
    assert median_to_solve([3000, None, 1000, 2000, None]) == 3000  # 3/5 solved: finite
    assert math.isinf(median_to_solve([3000, None, None]))  # most seeds unsolved


def test_hold_last_steps_through_evaluations_and_holds_after_the_run_ends():
    grid = np.array([0, 500, 1000, 1500, 2000, 3000])
    held = hold_last([1000, 2000], [10.0, 475.0], grid)
    assert np.isnan(held[:2]).all()  # before the first evaluation
    assert held[2:].tolist() == [10.0, 10.0, 475.0, 475.0]


def test_markdown_table_rows():
    results = {
        "a": [
            summary_of(1000, 2.0, 500.0),
            summary_of(3000, 6.0, 490.0),
            summary_of(None, None, 20),
        ],
        "b": [summary_of(None, None, 10.0)],
    }
    results["a"][0] |= {"collect_frames_per_second": 900, "updates_per_second": 250.0}
    results["a"][1] |= {"collect_frames_per_second": 1100, "updates_per_second": 150.0}
    results["a"][2] |= {"collect_frames_per_second": 1000, "updates_per_second": 200.0}
    for run, rss in zip(results["a"], (400.0, 500.0, 450.0), strict=True):
        run["peak_rss_mb"] = rss
    lines = markdown_table(results).splitlines()
    # Frames and seconds: IQM (3 seeds: no cut, one unsolved: inf), median, slowest. Final
    # return: IQM = mean of 500, 490, 20 = 336.7; each of 20 and 500 thrice drawn has p = 1/27
    # > 2.5 %, so the bootstrap interval's ends are 20 and 500.
    assert lines[2] == (
        "| a | 2/3 | not solved | 3000 | not solved | not solved | 6.0 | not solved | "
        "337 [20.0, 500] | 10.0 | 1000 | 200 | 450 |"
    )
    # A peer's summary has no throughput figures: dashes.
    assert lines[3] == (
        "| b | 0/1 | not solved | not solved | not solved | not solved | not solved | not solved "
        "| 10.0 [10.0, 10.0] | 10.0 | - | - | - |"
    )
    # Each seed's figures in a table of their own, after a blank line.
    assert lines[4] == ""
    assert lines[7:] == ["| a | 1000, 3000, - | 2.0, 6.0, - |", "| b | - | - |"]


def test_plot_script_groups_seeds_of_one_config(python, tmp_path):
    # named as the project names runs with an override: "=" in a run directory's name
    for seed in (0, 1, 2):
        _fake_run(
            tmp_path, f"CartPole-v1-dqn-optim.lr=0.001-seed{seed}", seed, 1e-3, 1000 * (seed + 1)
        )
    for seed in (0, 1):
        _fake_run(
            tmp_path,
            f"CartPole-v1-dqn-optim.lr=0.0005-seed{seed}",
            seed,
            5e-4,
            None if seed else 4000,
        )
    (tmp_path / "unfinished").mkdir()
    out = tmp_path / "cmp" / "comparison"
    proc = subprocess.run(
        [
            python,
            str(SCRIPTS / "plot.py"),
            *map(str, sorted(tmp_path.iterdir())),
            f"out={out}",
        ],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert proc.returncode == 0, proc.stderr
    assert "skipped" in proc.stderr and "unfinished" in proc.stderr
    table = out.with_suffix(".md").read_text()
    # frames_to_solve 1000, 2000, 3000: IQM (nothing cut from 3) 2000, interval [1000, 3000]
    # (each end thrice drawn: p = 1/27 > 2.5 %), median 2000, slowest 3000.
    assert "| CartPole-v1 dqn optim.lr=0.001 | 3/3 | 2000 [1000, 3000] | 2000 | 3000 |" in table
    assert "| CartPole-v1 dqn optim.lr=0.0005 | 1/2 | not solved |" in table
    assert out.with_suffix(".png").stat().st_size > 1000
    assert out.with_name("comparison-profiles.png").stat().st_size > 1000


def _fake_run(root, name, seed, lr, frames_to_solve):
    from omegaconf import OmegaConf

    from trl_cartpole.config.schema import Config

    run_dir = root / name
    run_dir.mkdir()
    config = Config(seed=seed, run_dir=str(run_dir))
    config.optim.lr = lr
    OmegaConf.save(OmegaConf.structured(config), run_dir / "config.yaml")
    summary = {
        "solved": frames_to_solve is not None,
        "frames_to_solve": frames_to_solve,
        "seconds_to_solve": None if frames_to_solve is None else frames_to_solve / 1000,
        "final_eval_return_mean": 500.0,
        "wall_seconds": 3.0,
        "solve_threshold": 475.0,
        "eval_curve": {"frames": [1000, 2000], "seconds": [1.0, 2.0], "returns": [20.0, 480.0]},
    }
    (run_dir / "summary.json").write_text(json.dumps(summary))
    return run_dir


def test_the_solved_column_says_how_many_solved_runs_did_not_hold_it():
    held = summary_of(1000, 2.0, 500.0) | {"solve_threshold": 475.0}
    dropped = summary_of(2000, 4.0, 460.2) | {"solve_threshold": 475.0}  # "not held"
    never = summary_of(None, None, 20.0) | {"solve_threshold": 475.0}
    table = markdown_table({"a": [held, dropped, never], "b": [held]}, label="config")
    assert "| a | 2/3 (1 not held) |" in table and "| b | 1/1 |" in table


def test_a_run_of_an_env_without_a_solve_threshold_is_read(tmp_path):
    """An own env has no threshold: its summary says ``solve_threshold: null``, as training
    wrote it, and the comparison reads it (the solved column counts none)."""
    from trl_cartpole.tools.comparison import read_summary

    run_dir = _fake_run(tmp_path, "my_env-seed0", 0, 1e-3, None)
    path = run_dir / "summary.json"
    path.write_text(json.dumps(json.loads(path.read_text()) | {"solve_threshold": None}))
    summary = read_summary(path)
    assert summary["solve_threshold"] is None
    assert "| runs | 0/1 | not solved |" in markdown_table({"runs": [summary]}, label="config")


def test_a_seed_run_twice_counts_once_in_its_group(tmp_path, capsys):
    """A repeat of a run (the same config and seed) is one seed, not two: the newest directory
    is kept and the other named on stderr."""
    from trl_cartpole.tools.comparison import group_runs, load_runs

    first = _fake_run(tmp_path, "CartPole-v1-dqn-seed0-20261201-000000", 0, 1e-3, 1000)
    again = _fake_run(tmp_path, "CartPole-v1-dqn-seed0-20261202-000000", 0, 1e-3, 2000)
    other = _fake_run(tmp_path, "CartPole-v1-dqn-seed1-20261201-000000", 1, 1e-3, 3000)
    (runs,) = group_runs(load_runs([first, again, other])).values()
    assert [run["run_dir"] for run in runs] == [again, other]
    assert f"skipped {first}: seed 0" in capsys.readouterr().err

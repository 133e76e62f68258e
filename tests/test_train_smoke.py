"""A few hundred frames through scripts/train.py: every file and summary key; determinism."""

from __future__ import annotations

import json
import re
import subprocess
from pathlib import Path

import pytest
import torch

from trl_cartpole.parts.env import make_env
from trl_cartpole.run.from_config import build_actor
from trl_cartpole.run.training import train
from trl_cartpole.store.checkpoint import load_policy

from .conftest import SCRIPTS, SMOKE_OVERRIDES, TIMING_KEYS, run_script

SUMMARY_KEYS = {
    "autocast",
    "num_threads",
    "cpu_kernels",
    "solve_status",
    "env_id",
    "seed",
    "algo",
    "frames",
    "updates",
    "train_seconds",
    "wall_seconds",
    "collect_frames_per_second",
    "updates_per_second",
    "peak_rss_mb",
    "solved",
    "solve_threshold",
    "frames_to_solve",
    "seconds_to_solve",
    "final_eval_return_mean",
    "final_eval_return_std",
    "final_eval_episodes",
    "best_eval_return_mean",
    "eval_curve",
    "checkpoint",
    "versions",
}


@pytest.fixture(scope="module")
def smoke_run(tmp_path_factory):
    run_dir = tmp_path_factory.mktemp("smoke") / "run"
    proc = subprocess.run(
        [
            __import__("sys").executable,
            str(SCRIPTS / "train.py"),
            *SMOKE_OVERRIDES,
            f"run_dir={run_dir}",
            "seed=1",
        ],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert proc.returncode == 0, proc.stderr[-2000:]
    return run_dir, proc


def test_run_directory_holds_every_artefact(smoke_run):
    run_dir, proc = smoke_run
    for name in [
        "summary.json",
        "config.yaml",
        "durations.png",
        "dashboard.png",
        "checkpoints/best/manifest.json",
        "checkpoints/last/manifest.json",
    ]:
        assert (run_dir / name).is_file(), name
    scalars = run_dir / "metrics" / "scalars"
    for name in [
        "train/episode_return",
        "train/episode_length",
        "train/td_loss",
        "eval/return_mean",
        "eval/rss_mb",
        "eval/final_return_mean",
    ]:
        assert (scalars / f"{name}.csv").is_file(), name
    assert (run_dir / "durations.png").read_bytes()[:4] == b"\x89PNG"
    assert f"run directory: {run_dir}" in proc.stdout


def test_summary_has_every_key_with_consistent_values(smoke_run):
    run_dir, _ = smoke_run
    summary = json.loads((run_dir / "summary.json").read_text())
    assert summary.keys() >= SUMMARY_KEYS
    assert summary["env_id"] == "CartPole-v1" and summary["seed"] == 1
    assert summary["algo"] == "dqn"
    assert summary["frames"] == 300
    # the kernels this process's torch runs (the run was a subprocess of the same interpreter)
    assert summary["cpu_kernels"]["torch"] == torch.backends.cpu.get_cpu_capability()
    # Updates start once the buffer holds init_random_frames=64 (> batch 32) transitions. A
    # batch of 4 frames is one step of each of the 4 envs, and the 3-step buffer stores a step
    # once the 3 after it are in: after k batches it holds 4 * (k - 3) transitions, >= 64 from
    # k = 19. So batches 19..75 update, 2 updates each.
    assert summary["updates"] == 57 * 2
    assert summary["solve_threshold"] == 475.0
    assert summary["final_eval_episodes"] == 4 == len(summary["final_eval_returns"])
    curve = summary["eval_curve"]
    assert len(curve["rss_mb"]) == len(curve["frames"]) == 2  # memory at each evaluation
    assert all(0 < mb <= summary["peak_rss_mb"] for mb in curve["rss_mb"])
    assert summary["final_eval_return_mean"] == pytest.approx(
        sum(summary["final_eval_returns"]) / 4, rel=1e-5
    )
    assert summary["solved"] is (summary["frames_to_solve"] is not None)
    assert 0 < summary["train_seconds"] <= summary["wall_seconds"]
    assert summary["collect_frames_per_second"] > 0 and summary["updates_per_second"] > 0
    assert 100 < summary["peak_rss_mb"] < 4096
    assert set(summary["versions"]) == {"torch", "torchrl", "tensordict", "gymnasium"}


@pytest.mark.slow  # evaluates the smoke run twice
def test_best_checkpoint_loads_and_evaluates(smoke_run, compose):
    run_dir, _ = smoke_run
    env = make_env("CartPole-v1")
    actor = build_actor(compose(*SMOKE_OVERRIDES), env)  # the run's network
    before = [p.clone() for p in actor.parameters()]
    load_policy(run_dir / "checkpoints" / "best", actor)
    assert any(not torch.equal(a, b) for a, b in zip(before, actor.parameters(), strict=True))

    out = run_dir / "eval.json"
    proc = run_script(
        "evaluate.py",
        f"checkpoint={run_dir / 'checkpoints' / 'best'}",
        "episodes=7",
        f"output={out}",
    )
    assert proc.returncode == 0, proc.stderr[-2000:]
    report = json.loads(out.read_text())
    assert report["episodes"] == 7 == len(report["returns"])
    assert min(report["returns"]) == report["min"] and max(report["returns"]) == report["max"]
    assert "greedy return over 7 episodes" in proc.stdout
    # without episodes=: as many as the run's own final evaluation (eval.final_episodes=4)
    proc = run_script("evaluate.py", str(run_dir), f"output={out}")
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert json.loads(out.read_text())["episodes"] == 4


@pytest.mark.slow  # two runs
def test_same_seed_same_figures(compose, tmp_path):
    summaries = []
    for name in ("a", "b"):
        cfg = compose(*SMOKE_OVERRIDES, "seed=4", f"run_dir={tmp_path / name}")
        summaries.append(train(cfg))
    for summary in summaries:
        assert len(summary["eval_curve"].pop("seconds")) == 2  # timings differ between runs
        assert len(summary["eval_curve"].pop("rss_mb")) == 2  # and so does memory
    first, second = ({k: v for k, v in s.items() if k not in TIMING_KEYS} for s in summaries)
    assert first == second
    losses = [(tmp_path / n / "metrics/scalars/train/td_loss.csv").read_text() for n in "ab"]
    assert losses[0] == losses[1] and losses[0].count("\n") >= 1
    env = make_env("CartPole-v1")
    actors = [build_actor(cfg, env) for _ in "ab"]
    for actor, name in zip(actors, "ab", strict=True):
        load_policy(tmp_path / name / "checkpoints" / "best", actor)
    for p_a, p_b in zip(actors[0].parameters(), actors[1].parameters(), strict=True):
        assert torch.equal(p_a, p_b)


def test_update_metrics_logged_whenever_100_updates_pass(compose, tmp_path):
    """With 3 updates per batch the counter never lands on a multiple of 100 after a batch."""
    overrides = [o for o in SMOKE_OVERRIDES if not o.startswith("collector.updates_per_batch")]
    cfg = compose(
        *overrides,
        "collector.updates_per_batch=3",
        "logger.plots=false",
        "checkpoint.save_last=false",
        f"run_dir={tmp_path}",
    )
    summary = train(cfg)
    assert summary["updates"] == 57 * 3  # 171 updates: the 100th falls inside a batch
    rows = (tmp_path / "metrics/scalars/train/td_loss.csv").read_text().splitlines()
    assert len(rows) == 1


def test_the_guide_names_every_key_a_run_writes_to_its_summary(smoke_run):
    """docs/guide.md's summary.json row lists each key of a real run's summary.json."""
    run_dir, _ = smoke_run
    summary = json.loads((run_dir / "summary.json").read_text())
    guide = (Path(__file__).resolve().parent.parent / "docs" / "guide.md").read_text()
    row = next(line for line in guide.splitlines() if line.startswith("| `summary.json` |"))
    named = set(re.findall(r"`([a-z_]+)`", row))
    assert sorted(set(summary) - named) == []

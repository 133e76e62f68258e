"""The peers of ``python -m benchmarks run``: the shared evaluation protocol and short runs."""

from __future__ import annotations

import json

import gymnasium as gym
import pytest
import torch

from benchmarks.harness import run_peer
from benchmarks.peers.protocol import GreedyEvaluation


def _always_left(obs: torch.Tensor) -> torch.Tensor:  # obs [E, 4] -> action values [E, 2]
    return torch.tensor([1.0, 0.0]).expand(len(obs), 2)


def test_greedy_evaluation_scores_each_envs_first_episode():
    evaluation = GreedyEvaluation("CartPole-v1", episodes=3, seed=11)
    returns = evaluation(_always_left).returns
    evaluation.close()
    expected = []  # by hand: env i of the vector env is seeded 11 + i
    for index in range(3):
        env = gym.make("CartPole-v1")
        env.reset(seed=11 + index)
        steps, done = 0, False
        while not done:
            _, _, terminated, truncated, _ = env.step(0)
            steps, done = steps + 1, terminated or truncated
        expected.append(float(steps))
    assert returns == expected
    assert all(8 <= r <= 12 for r in returns)  # pushing left topples the pole in about 10 steps


def test_later_evaluations_play_new_episodes():
    evaluation = GreedyEvaluation("CartPole-v1", episodes=4, seed=0)
    first, second = evaluation(_always_left).returns, evaluation(_always_left).returns
    evaluation.close()
    assert first != second  # the envs' RNGs moved on: new start states


@pytest.mark.parametrize(
    "peer",
    # tianshou_dqn and sbx_dqn make their own virtual environments on first use: minutes
    [
        "tutorial_loop",
        "sb3_dqn",
        pytest.param("tianshou_dqn", marks=pytest.mark.slow),
        pytest.param("sbx_dqn", marks=pytest.mark.slow),
    ],
)
@pytest.mark.slow  # a peer's run in a subprocess
def test_peer_runs_under_the_protocol_and_writes_a_summary(tmp_path, peer):
    if peer == "sb3_dqn":
        pytest.importorskip("stable_baselines3")
    protocol = ["--total-frames=1500", "--eval-interval=500", "--eval-episodes=3"]
    summary = run_peer(peer, 1, tmp_path, [*protocol, "--final-episodes=4"])
    assert summary == json.loads((tmp_path / f"{peer}-seed1" / "summary.json").read_text())
    assert summary["algo"] == peer and summary["seed"] == 1
    evaluated = summary["eval_curve"]["frames"]
    assert evaluated == (
        [500, 1000, 1500][: len(evaluated)] if summary["solved"] else [500, 1000, 1500]
    )
    assert summary["final_eval_episodes"] == 4
    assert summary["updates"] > 0 and summary["frames"] >= 1500
    assert 0 < summary["train_seconds"] < summary["wall_seconds"]
    assert summary["best_eval_return_mean"] == max(summary["eval_curve"]["returns"])


@pytest.mark.slow  # two runs of a peer
def test_tutorial_loop_repeats_itself_with_the_same_seed(tmp_path):
    protocol = ["--total-frames=600", "--eval-interval=300", "--eval-episodes=2"]
    summaries = [
        run_peer("tutorial_loop", 2, tmp_path / name, [*protocol, "--final-episodes=2"])
        for name in ("a", "b")
    ]
    first, second = (s["eval_curve"]["returns"] + [s["final_eval_return_mean"]] for s in summaries)
    assert first == second

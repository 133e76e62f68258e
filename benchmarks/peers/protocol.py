"""The benchmark protocol for peers: greedy evaluation on seeded envs, training time without it.

Mirrors what ``train()`` does, so a peer's figures compare with a trl_cartpole run's:
``episodes`` greedy episodes on a Gymnasium ``SyncVectorEnv`` seeded ``seed + seed_offset``
(one episode per env, the first of each), every ``interval_frames`` frames; the training clock
stops while evaluating; the run is solved when the greedy mean first reaches Gymnasium's
``reward_threshold``; the policy with the best evaluation gets a final evaluation over
``final_episodes`` episodes on envs seeded ``seed + 2 * seed_offset``.
"""

from __future__ import annotations

import argparse
import copy
import statistics
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import torch

from trl_cartpole.envs import make_sync_vector_env, solve_threshold
from trl_cartpole.files import write_json_atomic
from trl_cartpole.progress import Stopwatch
from trl_cartpole.telemetry import peak_rss_mb

__all__ = ["GreedyEvaluation", "PeerRun", "greedy_act", "parse_peer_args", "weights_snapshot"]

SEED_OFFSET = 1_000_000  # as EvalConfig.seed_offset

# obs [E, obs_dim] float32 -> greedy actions [E] int
Act = Callable[[np.ndarray], np.ndarray]


def greedy_act(q_values: Callable[[torch.Tensor], torch.Tensor]) -> Act:
    """The greedy policy of ``q_values`` (observations [E, obs_dim] -> action values [E, A])."""

    @torch.no_grad()
    def act(obs: np.ndarray) -> np.ndarray:  # obs [E, obs_dim] -> greedy actions [E]
        return q_values(torch.from_numpy(obs)).argmax(1).numpy()

    return act


def weights_snapshot(network: torch.nn.Module) -> Callable[[], dict[str, torch.Tensor]]:
    """A copy of ``network``'s weights, taken when called (the best evaluation's, for a peer)."""
    return lambda: copy.deepcopy(network.state_dict())


class GreedyEvaluation:
    """Greedy episodes on ``episodes`` envs stepped together; each env's first episode counts."""

    def __init__(self, env_id: str, episodes: int, seed: int, max_steps: int = 10_000) -> None:
        self.env = make_sync_vector_env(env_id, episodes)
        self.seed: int | None = seed  # used by the first reset only; later ones continue
        self.max_steps = max_steps

    def __call__(self, act: Act) -> list[float]:
        obs, _ = self.env.reset(seed=self.seed)  # obs: [E, obs_dim]
        self.seed = None
        episodes = self.env.num_envs
        returns = np.zeros(episodes)  # [E]
        running = np.ones(episodes, dtype=bool)  # [E] still in its first episode
        for _ in range(self.max_steps):
            obs, reward, terminated, truncated, _ = self.env.step(act(obs.astype(np.float32)))
            returns += reward * running
            running &= ~(terminated | truncated)
            if not running.any():
                break
        return returns.tolist()

    def close(self) -> None:
        self.env.close()


class PeerRun:
    """Training clock, periodic greedy evaluation, solve point and ``summary.json`` of a peer."""

    def __init__(self, name: str, args: argparse.Namespace) -> None:
        self.name, self.args = name, args
        threshold = solve_threshold(args.env_id)
        if threshold is None:
            raise SystemExit(f"error: {args.env_id} has no reward_threshold to count a solve at")
        self.threshold = threshold
        self.evaluation = GreedyEvaluation(args.env_id, args.eval_episodes, args.seed + SEED_OFFSET)
        self.wall_start = time.perf_counter()
        self.clock = Stopwatch()  # training time: paused while evaluating
        self.clock.start()
        self.eval_frames: list[int] = []
        self.eval_seconds: list[float] = []
        self.eval_returns: list[float] = []
        self.best_return = -float("inf")
        self.best_weights: Any = None
        self.frames_to_solve: int | None = None
        self.seconds_to_solve: float | None = None

    def evaluate(self, frames: int, act: Act, snapshot: Callable[[], Any]) -> bool:
        """Evaluate greedily with the clock stopped; keep the best weights; return solved."""
        self.clock.pause()
        mean = statistics.fmean(self.evaluation(act))
        self.eval_frames.append(frames)
        self.eval_seconds.append(round(self.clock.seconds, 3))
        self.eval_returns.append(mean)
        if mean > self.best_return:
            self.best_return, self.best_weights = mean, snapshot()
        solved = mean >= self.threshold
        if solved and self.frames_to_solve is None:
            self.frames_to_solve, self.seconds_to_solve = frames, self.clock.seconds
        self.clock.start()
        return solved

    def finish(self, frames: int, updates: int, act: Act, load: Callable[[Any], None]) -> dict:
        """Evaluate the best weights over ``final_episodes`` and write ``summary.json``."""
        self.clock.pause()
        self.evaluation.close()
        load(self.best_weights)
        final = GreedyEvaluation(
            self.args.env_id, self.args.final_episodes, self.args.seed + 2 * SEED_OFFSET
        )
        returns = final(act)
        final.close()
        summary = {
            "env_id": self.args.env_id,
            "seed": self.args.seed,
            "algo": self.name,
            "frames": frames,
            "updates": updates,
            "train_seconds": round(self.clock.seconds, 3),
            "wall_seconds": round(time.perf_counter() - self.wall_start, 3),
            "solved": self.frames_to_solve is not None,
            "solve_threshold": self.threshold,
            "frames_to_solve": self.frames_to_solve,
            "seconds_to_solve": None
            if self.seconds_to_solve is None
            else round(self.seconds_to_solve, 3),
            "final_eval_return_mean": statistics.fmean(returns),
            "final_eval_episodes": len(returns),
            "best_eval_return_mean": self.best_return,
            "eval_curve": {
                "frames": self.eval_frames,
                "seconds": self.eval_seconds,
                "returns": self.eval_returns,
            },
            "peak_rss_mb": round(peak_rss_mb(), 1),
            "run_dir": str(self.args.run_dir),
        }
        self.args.run_dir.mkdir(parents=True, exist_ok=True)
        write_json_atomic(self.args.run_dir / "summary.json", summary)
        return summary


def parse_peer_args(description: str) -> argparse.Namespace:
    """The command line every peer shares (``python -m benchmarks.peers.<peer> ...``)."""
    parser = argparse.ArgumentParser(description=description)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--run-dir", type=Path, required=True)
    parser.add_argument("--env-id", default="CartPole-v1")
    parser.add_argument("--total-frames", type=int, default=150_000)
    parser.add_argument("--eval-interval", type=int, default=1000)
    parser.add_argument("--eval-episodes", type=int, default=20)
    parser.add_argument("--final-episodes", type=int, default=100)
    return parser.parse_args()

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
import time
from collections.abc import Callable
from pathlib import Path

import torch

from trl_cartpole.envs.ids import solve_threshold
from trl_cartpole.parts.env import make_sync_vector_env
from trl_cartpole.run.eval_protocol import evaluation_seed
from trl_cartpole.run.evaluation import EvalResult, Evaluator, play_greedy_episodes
from trl_cartpole.run.progress import Progress
from trl_cartpole.run.summary import run_summary
from trl_cartpole.store.files import write_json_atomic

__all__ = ["GreedyEvaluation", "PeerRun", "parse_peer_args"]


# observations [E, obs_dim] float32 -> action values [E, A]
QValues = Callable[[torch.Tensor], torch.Tensor]


class GreedyEvaluation:
    """Greedy episodes on ``episodes`` envs stepped together; each env's first episode counts.

    The run's own protocol (:func:`trl_cartpole.run.evaluation.play_greedy_episodes`) on a
    Gymnasium ``SyncVectorEnv`` seeded ``seed`` at its first reset; later calls continue it.
    """

    def __init__(self, env_id: str, episodes: int, seed: int, max_steps: int = 10_000) -> None:
        self.env = make_sync_vector_env(env_id, episodes)
        self.seed: int | None = seed  # used by the first reset only; later ones continue
        self.max_steps = max_steps

    def __call__(self, q_values: QValues) -> EvalResult:
        result = play_greedy_episodes(self.env, q_values, self.max_steps, seed=self.seed)
        self.seed = None
        return result

    def close(self) -> None:
        self.env.close()


class PeerRun:
    """Training clock, periodic greedy evaluation, solve point and ``summary.json`` of a peer.

    The evaluation is the run's own :class:`~trl_cartpole.run.evaluation.Evaluator` and the
    summary the run's own :func:`~trl_cartpole.run.summary.run_summary`: a peer's figures read
    like a trl_cartpole run's. :meth:`watch` names the peer's Q-network once it is built.
    """

    def __init__(self, name: str, args: argparse.Namespace) -> None:
        self.name, self.args = name, args
        threshold = solve_threshold(args.env_id)
        if threshold is None:
            raise SystemExit(f"error: {args.env_id} has no reward_threshold to count a solve at")
        self.threshold = threshold
        self.wall_start = time.perf_counter()
        self.progress = Progress()  # its clock is the training time: paused while evaluating
        self.progress.clock.start()
        self.evaluator: Evaluator | None = None  # set by watch()
        self.q_values: QValues | None = None
        self._periodic: GreedyEvaluation | None = None

    def watch(self, network: torch.nn.Module, q_values: QValues | None = None) -> None:
        """Evaluate ``network`` (``q_values``: its observations -> action values, if not itself)."""
        self.q_values = network if q_values is None else q_values
        evaluation = GreedyEvaluation(
            self.args.env_id, self.args.eval_episodes, evaluation_seed(self.args.seed, "periodic")
        )
        self._periodic = evaluation
        self.evaluator = Evaluator(
            lambda: evaluation(self.q_values), network, self.args.eval_interval, self.threshold
        )

    def evaluate(self, frames: int) -> bool:
        """Evaluate greedily with the clock stopped; keep the best weights; return solved."""
        self.progress.frames = frames
        return self.evaluator.run(self.progress).solved

    def finish(self, frames: int, updates: int) -> dict:
        """Evaluate the best weights over ``final_episodes`` and write ``summary.json``."""
        self.progress.clock.pause()
        self._periodic.close()
        self.evaluator.load_best()
        final_evaluation = GreedyEvaluation(
            self.args.env_id, self.args.final_episodes, evaluation_seed(self.args.seed, "final")
        )
        final = final_evaluation(self.q_values)
        final_evaluation.close()
        summary = run_summary(
            env_id=self.args.env_id,
            seed=self.args.seed,
            algo=self.name,
            frames=frames,
            updates=updates,
            train_seconds=self.progress.clock.seconds,
            wall_start=self.wall_start,
            threshold=self.threshold,
            evaluator=self.evaluator,
            final=final,
            run_dir=self.args.run_dir,
        )
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

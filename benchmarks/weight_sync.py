"""Do the collector's workers act with the learner's weights and epsilon? One line per batch.

    python -m benchmarks weight-sync --backend local|ray [--batches 6]

Two workers of 4 CartPole envs. After every batch the learner moves its network's weights and,
from the second batch on, sets epsilon to 0, then calls ``update_policy_weights_()`` as the
training loop does. Each line says which learner weights the batch's action values came from
(``current``, or ``k batches old``) and how many actions were greedy: with a working sync, the
values are ``current`` and, once epsilon is 0, every action is greedy.
"""

from __future__ import annotations

import argparse
import copy
from pathlib import Path

import torch
from tensordict.nn import TensorDictSequential

from trl_cartpole.config.compose import compose_config
from trl_cartpole.config.schema import to_config
from trl_cartpole.parts.collectors import (
    make_collector,
    needs_weight_sync,
    shutdown_collector,
)
from trl_cartpole.run.envs import worker_env_constructors
from trl_cartpole.run.from_config import build_actor, build_env, build_exploration

SEEDS = [0]  # the config's seed: the harness's common arguments
OUT = Path("runs/bench/weight_sync")


def _source(batch, actors: list) -> str:
    """Which of the learner's past networks (newest last) gave ``batch``'s action values."""
    observations = batch.select("observation").clone()
    for age, actor in enumerate(reversed(actors)):
        with torch.no_grad():
            values = actor(observations)["action_value"]  # [frames, actions]
        if torch.allclose(values, batch["action_value"], atol=1e-5):
            return "current" if age == 0 else f"{age} batches old"
    return "unknown"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--backend", choices=["local", "ray"], default="local")
    parser.add_argument("--batches", type=int, default=6)


def main(args: argparse.Namespace) -> None:
    overrides = ["env.num_envs=4", "collector.workers=2", f"collector.backend={args.backend}"]
    cfg = to_config(compose_config("configs", [*overrides, *args.overrides]))
    env = build_env(cfg, cfg.seed)
    actor, exploration = build_actor(cfg, env), build_exploration(cfg, env)
    policy = TensorDictSequential(actor, exploration)
    collector = make_collector(
        worker_env_constructors(cfg),
        policy,
        frames_per_batch=32,
        total_frames=32 * args.batches,
        backend=args.backend,
    )
    history = [copy.deepcopy(actor)]  # the weights each batch was asked to use
    try:
        for index, batch in enumerate(collector):
            flat = batch.reshape(-1)  # [frames]
            greedy = (flat["action"].argmax(-1) == flat["action_value"].argmax(-1)).float()
            print(
                f"batch {index}: learner epsilon {exploration.eps.item():.2f}, "
                f"action values from the learner's {_source(flat, history)} weights, "
                f"greedy actions {greedy.mean().item():.2f}",
                flush=True,
            )
            with torch.no_grad():
                for parameter in actor.parameters():
                    parameter.add_(0.1 * torch.randn_like(parameter))
            exploration.eps.fill_(0.0)
            history.append(copy.deepcopy(actor))
            if needs_weight_sync(collector, policy):
                collector.update_policy_weights_()
    finally:
        shutdown_collector(collector)

"""Stable-Baselines3 DQN with rl-zoo3's tuned settings for the env, under the benchmark protocol.

    pip install -e ".[bench]"
    python -m benchmarks.peers.sb3_dqn --seed 0 --run-dir runs/peers/sb3_dqn-seed0
        [--env-id Acrobot-v1]

The settings are those rl-zoo3 2.9.2's ``hyperparams/dqn.yml`` gives ``--env-id``
(:mod:`benchmarks.peers.zoo_settings` reads them from its wheel); for CartPole-v1: lr 2.3e-3,
batch 64, buffer 100 000, learning_starts 1 000, gamma 0.99, target_update_interval 10 (env
steps), train_freq 256, gradient_steps 128, exploration_fraction 0.16, exploration_final_eps
0.04, net_arch [256, 256], over n_timesteps 50 000. SB3 scales the epsilon schedule to the
``learn()`` budget, so with another budget the fraction is rescaled to keep zoo's decay over
``exploration_fraction * n_timesteps`` steps (8 000 for CartPole). A callback runs the
protocol's greedy evaluation every ``--eval-interval`` steps (training clock stopped) and stops
the run once solved.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable
from typing import Any

import torch

from benchmarks.peers.protocol import PeerRun, parse_peer_args
from benchmarks.peers.zoo_settings import zoo_dqn_settings


def train_with_zoo_settings(
    name: str, dqn_class: type, args: argparse.Namespace, watch: Callable[[PeerRun, Any], None]
) -> dict:
    """Train ``dqn_class`` (Stable-Baselines3's ``DQN``, or one that takes its arguments) with
    rl-zoo3's settings for ``args.env_id`` under the protocol; ``watch(run, model)`` shows the
    run the model's Q-network. Returns the run's summary."""
    from stable_baselines3.common.callbacks import BaseCallback

    run = PeerRun(name, args)
    settings, timesteps = zoo_dqn_settings(args.env_id)
    fraction = settings.get("exploration_fraction", 0.1)  # SB3's default where zoo sets none
    settings["exploration_fraction"] = fraction * timesteps / args.total_frames  # zoo's, in steps
    model = dqn_class("MlpPolicy", args.env_id, seed=args.seed, device="cpu", verbose=0, **settings)
    watch(run, model)

    class ProtocolCallback(BaseCallback):
        def _on_step(self) -> bool:
            if self.num_timesteps % args.eval_interval:
                return True
            return not run.evaluate(self.num_timesteps)

    model.learn(total_timesteps=args.total_frames, callback=ProtocolCallback())
    return run.finish(model.num_timesteps, model._n_updates)


def main() -> None:
    args = parse_peer_args(__doc__.splitlines()[0])
    try:
        from stable_baselines3 import DQN
    except ImportError:
        raise SystemExit(
            "error: stable-baselines3 is not installed; pip install -e '.[bench]'"
        ) from None
    torch.set_num_threads(1)
    train_with_zoo_settings("sb3_dqn", DQN, args, lambda run, model: run.watch(model.q_net))


if __name__ == "__main__":
    main()

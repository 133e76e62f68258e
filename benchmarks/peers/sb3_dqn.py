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

import torch

from benchmarks.peers.protocol import parse_peer_args
from benchmarks.peers.zoo_settings import train_with_zoo_settings


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

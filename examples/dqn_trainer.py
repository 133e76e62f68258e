"""The factories inside TorchRL's own ``torchrl.trainers`` ``DQNTrainer``, on CartPole-v1.

Every keyword ``DQNTrainer`` takes for a part is a factory's object as it comes: the
``Collector``, ``DQNLoss``, AdamW, a one-step ``TensorDictReplayBuffer``, ``HardUpdate`` and
``EGreedyModule``. No glue: the trainer samples, steps the optimizer, the target updater and
epsilon itself. At the end the greedy policy plays 20 episodes: after the default 20 000
frames it returned 136.4 +/- 5.7 here (seed 0; a random policy returns about 22). The trainer
updates from its first batch on and the buffer holds one-step transitions, so it learns slower
than ``scripts/train.py`` (solved at 11 000 to 15 000 frames).

    python examples/dqn_trainer.py                   # 20 000 frames, about 1 min here
    python examples/dqn_trainer.py --frames 2000
"""

from __future__ import annotations

import argparse
import logging
import warnings
from typing import Any

import torch
from tensordict.nn import TensorDictSequential
from torchrl.trainers.algorithms import DQNTrainer

from trl_cartpole import (
    evaluate,
    make_collector,
    make_dqn_loss,
    make_env,
    make_exploration,
    make_optimizer,
    make_q_actor,
    make_replay_buffer,
    make_target_updater,
)


def main(argv: list[str] | None = None) -> dict[str, Any]:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=20_000, help="frames to collect")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    logging.getLogger("torchrl").setLevel(logging.WARNING)  # TorchRL's INFO lines off
    torch.manual_seed(args.seed)

    env = make_env("CartPole-v1", seed=args.seed, num_envs=16)  # a batch is [16, 2]
    # the default run's CartPole values (its config's sections, given by name; left out, each
    # factory takes the defaults of the TorchRL class it builds)
    actor = make_q_actor(
        env.observation_spec, env.action_spec, num_cells=[128, 128], activation_class="relu"
    )
    exploration = make_exploration(env.action_spec, 1.0, 0.05, 3_000)  # EGreedyModule's order
    collector = make_collector(
        env,
        TensorDictSequential(actor, exploration),
        frames_per_batch=32,
        total_frames=args.frames,
        init_random_frames=1_000,
    )
    loss = make_dqn_loss(actor, gamma=0.995, loss_function="smooth_l1")  # Huber
    with warnings.catch_warnings():  # DQNTrainer says it is a prototype, its hooks will move
        warnings.simplefilter("ignore", UserWarning)
        warnings.simplefilter("ignore", FutureWarning)
        trainer = DQNTrainer(
            collector=collector,
            total_frames=args.frames,
            frame_skip=1,
            optim_steps_per_batch=6,
            loss_module=loss,
            optimizer=make_optimizer(actor.parameters(), 4e-3, amsgrad=True, weight_decay=0.0),
            # one-step, 50 000 transitions, batches of 512
            replay_buffer=make_replay_buffer(max_size=50_000, batch_size=512),
            # HardUpdate: a copy every 50 updates (TorchRL counts interval + 1)
            target_net_updater=make_target_updater(loss, value_network_update_interval=49),
            greedy_module=exploration,
            clip_norm=10.0,
            progress_bar=False,
            logger=None,
            enable_logging=False,
            save_trainer_file=None,
            episode_reward_key="episode_reward",  # make_env's RewardSum writes this key
        )
        trainer.train()
    collector.shutdown()

    eval_env = make_env("CartPole-v1", seed=args.seed + 1_000, num_envs=20)
    result = evaluate(actor, eval_env, max_steps=500)
    eval_env.close()
    print(f"greedy return over 20 episodes: {result.mean:.1f} +/- {result.std:.1f}")
    return {
        "trainer": trainer,
        "actor": actor,
        "exploration": exploration,
        "loss": loss,
        "greedy_return": result.mean,
    }


if __name__ == "__main__":
    main()

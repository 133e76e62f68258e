"""An Atari game in your own TorchRL loop: the preprocessed game, the CNN actor, the frame-once
storage and the learner's view of a lost life, each a factory or class you can take alone.

- ``make_atari_env`` (``trl_cartpole.envs.atari``): TorchRL's ``TransformedEnv`` of an ALE id
  with the standard preprocessing (84x84 gray, 4 frames under ``"pixels"``, frame skip 4,
  NOOP starts, FIRE after a reset and a lost life);
- ``make_q_actor(..., torso="cnn")``: a ``QValueActor`` on the Nature CNN that finds the
  frames in the spec without being told where they are;
- ``FrameStackStorage`` (``trl_cartpole.storage.frames``): TorchRL's ``LazyTensorStorage``
  keeping each 84x84 frame once (0.8 GB for 100 000 transitions, not 5.6 GB);
- ``LearnerView`` (``trl_cartpole.envs.atari``): a replay buffer transform, so the learner sees
  a lost life as the end of its episode and rewards clipped to their sign, while the score the
  env reports is the game's.

This is the Breakout preset's recipe by hand, shortened: ``python scripts/train.py
env=breakout`` is the whole of it (docs/atari.md).

    python examples/atari_breakout.py                # 5 000 agent steps, an update every 4
    python examples/atari_breakout.py --steps 200
"""

from __future__ import annotations

import argparse
import logging
from typing import Any

import torch
from tensordict.nn import TensorDictSequential

from trl_cartpole import (
    make_collector,
    make_dqn_loss,
    make_exploration,
    make_optimizer,
    make_q_actor,
    make_replay_buffer,
    make_target_updater,
    make_update,
)
from trl_cartpole.envs.atari import LearnerView, make_atari_env
from trl_cartpole.storage.frames import FrameStackStorage

RANDOM_STEPS = 100  # agent steps of random play before the first update


def main(argv: list[str] | None = None) -> dict[str, Any]:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=5_000, help="agent steps to collect")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    logging.getLogger("torchrl").setLevel(logging.WARNING)  # TorchRL's INFO lines off
    torch.manual_seed(args.seed)

    env = make_atari_env("ALE/Breakout-v5", seed=args.seed)  # "pixels": [4, 84, 84] uint8
    actor = make_q_actor(  # the Nature CNN (Mnih et al. 2015) with a dueling head
        env.observation_spec,
        env.action_spec,
        torso="cnn",
        num_cells=[512],
        head="dueling",
        activation_class="relu",
    )
    exploration = make_exploration(env.action_spec, eps_end=0.01, annealing_num_steps=args.steps)
    buffer = make_replay_buffer(
        storage=FrameStackStorage(10_000),  # each frame of a stack stored once
        transform=LearnerView(),  # a lost life ends the learner's episode; rewards clipped
        batch_size=32,
        n_steps=3,
        gamma=0.99,
    )
    loss = make_dqn_loss(actor, loss_function="smooth_l1", replay_buffer=buffer)
    target = make_target_updater(loss, kind="hard", value_network_update_interval=100)
    optimizer = make_optimizer(actor.parameters(), lr=1e-4, eps=1.5e-4)
    update = make_update(loss, optimizer)
    collector = make_collector(
        env,
        TensorDictSequential(actor, exploration),
        frames_per_batch=4,  # agent steps: 4 game frames each
        total_frames=args.steps,
        init_random_frames=RANDOM_STEPS,
    )

    losses, scores = [], []
    for batch in collector:  # [4] steps
        buffer.extend(batch)
        exploration.step(batch.numel())
        scores += batch["next", "episode_reward"][batch["next", "done"]].tolist()  # the game's
        if len(buffer) >= RANDOM_STEPS:
            losses.append(update(buffer.sample())["loss"].item())
            target.step()
    collector.shutdown()
    print(f"{len(losses)} updates; {len(scores)} games ended, scores {scores[-5:]}")
    return {"actor": actor, "buffer": buffer, "losses": losses, "scores": scores}


if __name__ == "__main__":
    main()

"""Your own DQN loop on Acrobot-v1: a dueling head, double DQN and a soft target network.

Nothing of the project's training loop is used: the factories build stock TorchRL objects
(``QValueActor`` with a dueling head, ``EGreedyModule``, an n-step ``TensorDictReplayBuffer``,
``DQNLoss(double_dqn=True)``, ``SoftUpdate``, a ``Collector``) and the loop is the ten lines
below. The loss takes its discount from the n-step buffer (``replay_buffer=``), so the two
cannot disagree. At the end the greedy policy plays 10 episodes (Acrobot: -500 is a policy that
never swings up; -100 is Gymnasium's "solved").

    python examples/dueling_double_acrobot.py               # 40 000 frames, 71 s here
    python examples/dueling_double_acrobot.py --frames 2000
"""

from __future__ import annotations

import argparse
import logging
import time
from typing import Any

import torch
from tensordict.nn import TensorDictSequential

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
    make_update,
)


def main(argv: list[str] | None = None) -> dict[str, Any]:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=40_000, help="frames to collect")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    logging.getLogger("torchrl").setLevel(logging.WARNING)  # TorchRL's INFO lines off
    torch.manual_seed(args.seed)
    start = time.perf_counter()

    env = make_env("Acrobot-v1", seed=args.seed, num_envs=8)  # 8 envs stepped together
    actor = make_q_actor(
        env.observation_spec, env.action_spec, num_cells=[128, 128], head="dueling"
    )
    exploration = make_exploration(env.action_spec, 1.0, 0.05, annealing_num_steps=20_000)
    buffer = make_replay_buffer(max_size=50_000, batch_size=128, n_steps=3, gamma=0.99)
    loss = make_dqn_loss(actor, double_dqn=True, replay_buffer=buffer)  # gamma: the buffer's
    target = make_target_updater(loss, tau=0.01)  # SoftUpdate
    update = make_update(loss, make_optimizer(actor.parameters(), lr=5e-4))
    collector = make_collector(
        env,
        TensorDictSequential(actor, exploration),
        frames_per_batch=16,  # 2 steps of the 8 envs: a batch is [8, 2]
        total_frames=args.frames,
        init_random_frames=1_000,
    )
    initial_target = [p.clone() for p in loss.target_value_network_params.values(True, True)]

    frames, losses = 0, []
    for batch in collector:  # batch: [envs, T]
        buffer.extend(batch)  # n-step windows per env, in time order
        frames += batch.numel()
        if len(buffer) >= 1_000:
            for _ in range(4):  # four gradient steps per batch of 16 frames
                losses.append(update(buffer.sample())["loss"].item())
                target.step()
        exploration.step(batch.numel())
    collector.shutdown()

    greedy = evaluate(actor, make_env("Acrobot-v1", seed=args.seed + 1_000, num_envs=10), 500)
    seconds = time.perf_counter() - start
    print(
        f"Acrobot-v1, {frames} frames in {seconds:.0f} s: greedy return {greedy.mean:.1f} "
        f"+/- {greedy.std:.1f} over {len(greedy.returns)} episodes"
    )
    return {
        "actor": actor,
        "exploration": exploration,
        "buffer": buffer,
        "loss": loss,
        "target": target,
        "initial_target": initial_target,
        "frames": frames,
        "losses": losses,
        "greedy_return": greedy.mean,
        "seconds": seconds,
    }


if __name__ == "__main__":
    main()

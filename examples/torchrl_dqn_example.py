"""TorchRL's own DQN example, ``sota-implementations/dqn/dqn_cartpole.py``, on our factories.

The structure and names are the example's (``make_env``, ``make_dqn_model``, ``greedy_module``,
``model_explore``, ``replay_buffer``, ``loss_module``, ``target_net_updater``, its loop); each
TorchRL constructor is swapped for the factory that returns the same class, called with the
same argument names. Its settings are the example's CartPole config (``num_cells`` 120, 84;
``l2`` loss; gamma 0.99; a hard target copy every 50 updates; batch 128; lr 2.5e-4; eps 1.0 to
0.05), but for a shorter budget: 50 000 frames (the example's 500 100), eps annealed over 10 000
frames (250 000) after 1 000 random frames (10 000), and AdamW without weight decay
(``make_optimizer``), which is Adam's update. On seed 0 its greedy test returns were 83, 60,
225, 294 and 500 at 10 000 to 50 000 frames (AMD EPYC): these settings learn CartPole slowly
and unevenly (``trl-cartpole train`` solves it in about 15 000 frames; docs/performance.md).

    python examples/torchrl_dqn_example.py              # 86 s here
    python examples/torchrl_dqn_example.py --frames 2000
"""

from __future__ import annotations

import argparse
import logging
from typing import Any

import torch
from tensordict.nn import TensorDictSequential
from torch import nn
from torchrl.envs import ExplorationType, set_exploration_type

from trl_cartpole import (
    make_collector,
    make_dqn_loss,
    make_env,
    make_exploration,
    make_optimizer,
    make_q_actor,
    make_replay_buffer,
    make_target_updater,
)


def make_dqn_model(env_name: str = "CartPole-v1", device: str = "cpu"):
    """The example's ``make_dqn_model``: an MLP Q-network in a ``QValueActor``."""
    proof_environment = make_env(env_name, device)
    return make_q_actor(
        proof_environment.observation_spec,
        proof_environment.action_spec,
        num_cells=[120, 84],
        activation_class=nn.ReLU,
        device=device,
    )


def main(argv: list[str] | None = None) -> dict[str, Any]:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=50_000, help="frames to collect")
    parser.add_argument("--init-random-frames", type=int, default=1_000)
    parser.add_argument("--annealing-frames", type=int, default=10_000)
    parser.add_argument("--test-interval", type=int, default=10_000, help="frames between tests")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    logging.getLogger("torchrl").setLevel(logging.WARNING)  # TorchRL's INFO lines off
    torch.manual_seed(args.seed)
    device, env_name = "cpu", "CartPole-v1"

    # Make the components
    model = make_dqn_model(env_name, device)
    greedy_module = make_exploration(
        model.spec, eps_init=1.0, eps_end=0.05, annealing_num_steps=args.annealing_frames
    )
    model_explore = TensorDictSequential(model, greedy_module).to(device)
    collector = make_collector(
        create_env_fn=make_env(env_name, device, seed=args.seed),
        policy=model_explore,
        frames_per_batch=10,
        total_frames=args.frames,
        device=device,
        storing_device=device,
        max_frames_per_traj=-1,
        init_random_frames=args.init_random_frames,
    )
    replay_buffer = make_replay_buffer(
        max_size=10_000, batch_size=128, n_steps=1, device=device, pin_memory=False
    )
    loss_module = make_dqn_loss(value_network=model, gamma=0.99, loss_function="l2")
    target_net_updater = make_target_updater(loss_module, value_network_update_interval=50)
    optimizer = make_optimizer(loss_module.parameters(), lr=2.5e-4, weight_decay=0.0)  # Adam's
    test_env = make_env(env_name, device, seed=args.seed + 1_000)
    initial_target = [p.clone() for p in loss_module.target_value_network_params.values(True, True)]

    # Main loop
    collected_frames, losses, test_returns = 0, [], []
    for data in collector:
        greedy_module.step(data.numel())  # epsilon follows the frames seen
        data = data.reshape(-1)
        collected_frames += data.numel()
        replay_buffer.extend(data)
        if collected_frames < args.init_random_frames:
            continue
        sampled_tensordict = replay_buffer.sample()
        q_loss = loss_module(sampled_tensordict)["loss"]
        optimizer.zero_grad()
        q_loss.backward()
        nn.utils.clip_grad_norm_(loss_module.parameters(), max_norm=10.0)
        optimizer.step()
        target_net_updater.step()
        losses.append(q_loss.item())
        if collected_frames % args.test_interval < data.numel():  # the example's test
            with set_exploration_type(ExplorationType.DETERMINISTIC), torch.no_grad():
                rollout = test_env.rollout(500, model, auto_cast_to_device=True)
            test_returns.append(rollout["next", "reward"].sum().item())
            print(f"frames {collected_frames}: test return {test_returns[-1]:.0f}")
    collector.shutdown()
    print(f"{collected_frames} frames, last TD loss {losses[-1]:.3f}")
    return {
        "model": model,
        "greedy_module": greedy_module,
        "collector": collector,
        "replay_buffer": replay_buffer,
        "loss_module": loss_module,
        "target_net_updater": target_net_updater,
        "initial_target": initial_target,
        "frames": collected_frames,
        "losses": losses,
        "test_returns": test_returns,
    }


if __name__ == "__main__":
    main()

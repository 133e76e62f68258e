"""TorchRL's own ``sota-implementations/dqn/dqn_cartpole.py`` loop, built from our factories.

The example's names are TorchRL's (``env_name``, ``eps_init``, ``annealing_num_steps``,
``max_size``, ``create_env_fn``, ``storing_device``...), so porting it means swapping its
constructors for our factories and nothing else. A few hundred frames: it runs, the target
network follows the online one, and epsilon anneals.
"""

from __future__ import annotations

import pytest
import torch
from tensordict.nn import TensorDictSequential
from torchrl.collectors import Collector
from torchrl.data import LazyTensorStorage, TensorDictReplayBuffer
from torchrl.modules import EGreedyModule, QValueActor
from torchrl.objectives import DQNLoss, HardUpdate

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

FRAMES, FRAMES_PER_BATCH, INIT_RANDOM_FRAMES, UPDATES = 400, 10, 100, 2


def test_the_torchrl_dqn_example_trains_on_our_factories():
    torch.manual_seed(0)
    # Make the components (the example's make_dqn_model / EGreedyModule / SyncDataCollector...)
    env = make_env("CartPole-v1", "cpu")
    model = make_q_actor(env.observation_spec, env.action_spec, in_keys=["observation"])
    greedy_module = make_exploration(
        env.action_spec, annealing_num_steps=200, eps_init=1.0, eps_end=0.05
    )
    model_explore = TensorDictSequential(model, greedy_module)
    collector = make_collector(
        create_env_fn=make_env("CartPole-v1", "cpu"),
        policy=model_explore,
        frames_per_batch=FRAMES_PER_BATCH,
        total_frames=FRAMES,
        device="cpu",
        storing_device="cpu",
        max_frames_per_traj=-1,
        init_random_frames=INIT_RANDOM_FRAMES,
    )
    replay_buffer = make_replay_buffer(max_size=1000, batch_size=32, n_steps=1, pin_memory=False)
    loss_module = make_dqn_loss(model, gamma=0.99, loss_function="l2")
    target_net_updater = make_target_updater(loss_module, value_network_update_interval=9)
    optimizer = make_optimizer(loss_module.parameters(), lr=2.5e-4)
    for built, kind in [
        (model, QValueActor),
        (greedy_module, EGreedyModule),
        (collector, Collector),
        (replay_buffer, TensorDictReplayBuffer),
        (replay_buffer._storage, LazyTensorStorage),
        (loss_module, DQNLoss),
        (target_net_updater, HardUpdate),
    ]:
        assert isinstance(built, kind)

    # The example's loop
    collected_frames, losses, batches = 0, [], 0
    for data in collector:
        batches += 1
        greedy_module.step(data.numel())
        data = data.reshape(-1)
        collected_frames += data.numel()
        replay_buffer.extend(data)
        if collected_frames < INIT_RANDOM_FRAMES:
            continue
        for _ in range(UPDATES):
            sampled_tensordict = replay_buffer.sample()
            loss_td = loss_module(sampled_tensordict)
            q_loss = loss_td["loss"]
            optimizer.zero_grad()
            q_loss.backward()
            torch.nn.utils.clip_grad_norm_(list(loss_module.parameters()), max_norm=10.0)
            optimizer.step()
            target_net_updater.step()
            losses.append(q_loss.item())
    collector.shutdown()

    assert collected_frames == FRAMES and batches == FRAMES // FRAMES_PER_BATCH
    updates = UPDATES * (FRAMES - INIT_RANDOM_FRAMES) // FRAMES_PER_BATCH + UPDATES
    assert len(losses) == updates and all(torch.isfinite(torch.tensor(losses)))
    assert greedy_module.eps.item() == pytest.approx(0.05)  # 400 frames: past the 200 of annealing
    # 62 updates, a hard copy every 10: the target equals the online net after update 60, and
    # two optimizer steps since moved the online net away from it.
    online = loss_module.value_network_params.flatten_keys()
    target = loss_module.target_value_network_params.flatten_keys()
    assert any(not torch.equal(online[k], target[k]) for k in online.keys())  # noqa: SIM118

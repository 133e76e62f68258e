"""Tianshou 2 DQN with the settings of its own CartPole example, under the benchmark protocol.

    python -m benchmarks run --algos dqn --peers tianshou_dqn --seeds 0 1 2
    runs/peer-venvs/tianshou_dqn/bin/python -m benchmarks.peers.tianshou_dqn --seed 0 \\
        --run-dir runs/peers/tianshou_dqn-seed0          # one run, once that venv exists

Tianshou 2.0.1 pins ``pandas<3`` and needs numba, so it runs from a virtual environment of its
own (``benchmarks.harness.PEER_VENVS``), which ``python -m benchmarks run --peers tianshou_dqn``
creates on first use. The settings are those of Tianshou's ``examples/discrete/discrete_dqn.py``:
an MLP 128-128-128 (``tianshou.utils.net.common.Net``), Adam with lr 1e-3, batch 64, 10 training
envs (``DummyVectorEnv``), gamma 0.9, 3-step returns, the target network copied every 320
gradient steps, a ``VectorReplayBuffer`` of 20 000, epsilon 0.1 while training, and collection
steps of 10 env steps, each followed by one gradient step (``update_step_num_gradient_steps_
per_sample = 0.1``). Tianshou's trainer loop (collect, then update) is run here step by step so
that the protocol's greedy evaluation takes the place of Tianshou's test collector.
"""

from __future__ import annotations

import numpy as np
import torch

from benchmarks.peers.protocol import PeerRun, parse_peer_args

EXAMPLE = {  # examples/discrete/discrete_dqn.py
    "lr": 1e-3,
    "batch_size": 64,
    "train_envs": 10,
    "gamma": 0.9,
    "n_step": 3,
    "target_update_freq": 320,
    "buffer_size": 20_000,
    "eps_train": 0.1,
    "hidden_sizes": [128, 128, 128],
    "collection_steps": 10,  # env steps per collection step; one gradient step after each
}


def main() -> None:
    args = parse_peer_args(__doc__.splitlines()[0])
    try:
        import gymnasium as gym
        import tianshou as ts
        from tianshou.algorithm.modelfree.dqn import DiscreteQLearningPolicy
        from tianshou.algorithm.optim import AdamOptimizerFactory
        from tianshou.data import CollectStats
        from tianshou.utils.net.common import Net
        from tianshou.utils.torch_utils import policy_within_training_step
    except ImportError:
        raise SystemExit(
            "error: tianshou is not installed here; run this peer with the interpreter of "
            "runs/peer-venvs/tianshou_dqn, which python -m benchmarks run --peers tianshou_dqn "
            "makes"
        ) from None
    torch.set_num_threads(1)
    torch.manual_seed(args.seed)
    np.random.seed(args.seed)  # noqa: NPY002 (Tianshou's epsilon-greedy draws from it)
    run = PeerRun("tianshou_dqn", args)
    train_envs = ts.env.DummyVectorEnv(
        [lambda: gym.make(args.env_id) for _ in range(EXAMPLE["train_envs"])]
    )
    train_envs.seed(args.seed)
    space = gym.make(args.env_id)
    net = Net(
        state_shape=space.observation_space.shape,
        action_shape=space.action_space.n,
        hidden_sizes=EXAMPLE["hidden_sizes"],
    )
    policy = DiscreteQLearningPolicy(
        model=net, action_space=space.action_space, eps_training=EXAMPLE["eps_train"]
    )
    algorithm = ts.algorithm.DQN(
        policy=policy,
        optim=AdamOptimizerFactory(lr=EXAMPLE["lr"]),
        gamma=EXAMPLE["gamma"],
        n_step_return_horizon=EXAMPLE["n_step"],
        target_update_freq=EXAMPLE["target_update_freq"],
    )
    buffer = ts.data.VectorReplayBuffer(EXAMPLE["buffer_size"], EXAMPLE["train_envs"])
    collector = ts.data.Collector[CollectStats](
        algorithm, train_envs, buffer, exploration_noise=True
    )
    collector.reset()

    # Tianshou's Net returns (action values, hidden state)
    run.watch(net, lambda obs: net(obs)[0])

    frames = updates = 0
    next_eval = args.eval_interval
    while frames < args.total_frames:
        with policy_within_training_step(policy):
            frames += collector.collect(n_step=EXAMPLE["collection_steps"]).n_collected_steps
            algorithm.update(sample_size=EXAMPLE["batch_size"], buffer=collector.buffer)
        updates += 1
        if frames >= next_eval:
            next_eval += args.eval_interval
            if run.evaluate(frames):
                break
    run.finish(frames, updates)


if __name__ == "__main__":
    main()

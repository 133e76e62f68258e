"""The PyTorch DQN tutorial's training loop, in plain PyTorch, under the benchmark protocol.

    python -m benchmarks.peers.tutorial_loop --seed 0 --run-dir runs/peers/tutorial_loop-seed0

The training code is the tutorial's (pytorch.org, reinforcement_q_learning), kept as written:
``deque`` replay memory of ``Transition`` tuples, ``random.sample``, ``torch.cat`` batching, a
non-final mask, Huber loss, gradient value clipping at 100, AdamW(amsgrad) lr 1e-4, and the
soft target update through ``state_dict`` after every step. Batch 128, gamma 0.99,
epsilon 0.9 -> 0.05 with exponential decay 1000, tau 0.005, memory 10 000, MLP 128-128. The
only additions are the seeds (the action space's too), one torch thread (as ``train()``),
and the protocol's periodic greedy evaluation with the clock stopped.
"""

from __future__ import annotations

import math
import random
from collections import deque, namedtuple

import gymnasium as gym
import numpy as np
import torch
from torch import nn, optim

from benchmarks.peers.protocol import PeerRun, parse_peer_args

BATCH_SIZE = 128
GAMMA = 0.99
EPS_START = 0.9
EPS_END = 0.05
EPS_DECAY = 1000
TAU = 0.005
LR = 1e-4

Transition = namedtuple("Transition", ("state", "action", "next_state", "reward"))


class ReplayMemory:
    def __init__(self, capacity: int) -> None:
        self.memory: deque[Transition] = deque(maxlen=capacity)

    def push(self, *args) -> None:
        self.memory.append(Transition(*args))

    def sample(self, batch_size: int) -> list[Transition]:
        return random.sample(self.memory, batch_size)

    def __len__(self) -> int:
        return len(self.memory)


class DQN(nn.Module):
    def __init__(self, n_observations: int, n_actions: int) -> None:
        super().__init__()
        self.layer1 = nn.Linear(n_observations, 128)
        self.layer2 = nn.Linear(128, 128)
        self.layer3 = nn.Linear(128, n_actions)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        x = torch.relu(self.layer1(x))
        x = torch.relu(self.layer2(x))
        return self.layer3(x)


def main() -> None:
    args = parse_peer_args(__doc__.splitlines()[0])
    torch.set_num_threads(1)
    random.seed(args.seed)
    np.random.seed(args.seed)  # noqa: NPY002
    torch.manual_seed(args.seed)
    run = PeerRun("tutorial_loop", args)

    env = gym.make(args.env_id)
    n_actions = env.action_space.n
    state, _ = env.reset(seed=args.seed)
    env.action_space.seed(args.seed)  # the tutorial leaves it unseeded; seeded, runs repeat
    policy_net = DQN(len(state), n_actions)
    target_net = DQN(len(state), n_actions)
    target_net.load_state_dict(policy_net.state_dict())
    optimizer = optim.AdamW(policy_net.parameters(), lr=LR, amsgrad=True)
    memory = ReplayMemory(10_000)
    steps_done = 0
    updates = 0

    def select_action(state: torch.Tensor) -> torch.Tensor:
        nonlocal steps_done
        eps_threshold = EPS_END + (EPS_START - EPS_END) * math.exp(-1.0 * steps_done / EPS_DECAY)
        sample = random.random()
        steps_done += 1
        if sample > eps_threshold:
            with torch.no_grad():
                return policy_net(state).max(1)[1].view(1, 1)
        return torch.tensor([[env.action_space.sample()]], dtype=torch.long)

    def optimize_model() -> None:
        nonlocal updates
        if len(memory) < BATCH_SIZE:
            return
        transitions = memory.sample(BATCH_SIZE)
        batch = Transition(*zip(*transitions, strict=True))
        non_final_mask = torch.tensor(
            tuple(s is not None for s in batch.next_state), dtype=torch.bool
        )
        non_final_next_states = torch.cat([s for s in batch.next_state if s is not None])
        state_batch = torch.cat(batch.state)
        action_batch = torch.cat(batch.action)
        reward_batch = torch.cat(batch.reward)
        state_action_values = policy_net(state_batch).gather(1, action_batch)
        next_state_values = torch.zeros(BATCH_SIZE)
        with torch.no_grad():
            next_state_values[non_final_mask] = target_net(non_final_next_states).max(1)[0]
        expected_state_action_values = (next_state_values * GAMMA) + reward_batch
        criterion = nn.SmoothL1Loss()
        loss = criterion(state_action_values, expected_state_action_values.unsqueeze(1))
        optimizer.zero_grad()
        loss.backward()
        torch.nn.utils.clip_grad_value_(policy_net.parameters(), 100)
        optimizer.step()
        updates += 1

    run.watch(policy_net)

    frames = 0
    state = torch.tensor(state, dtype=torch.float32).unsqueeze(0)
    while frames < args.total_frames:
        action = select_action(state)
        observation, reward, terminated, truncated, _ = env.step(action.item())
        reward = torch.tensor([reward])
        next_state = (
            None if terminated else torch.tensor(observation, dtype=torch.float32).unsqueeze(0)
        )
        memory.push(state, action, next_state, reward)
        state = next_state
        optimize_model()
        target_net_state_dict = target_net.state_dict()
        policy_net_state_dict = policy_net.state_dict()
        for key in policy_net_state_dict:
            target_net_state_dict[key] = policy_net_state_dict[key] * TAU + target_net_state_dict[
                key
            ] * (1 - TAU)
        target_net.load_state_dict(target_net_state_dict)
        frames += 1
        if terminated or truncated:
            state, _ = env.reset()
            state = torch.tensor(state, dtype=torch.float32).unsqueeze(0)
        if frames % args.eval_interval == 0 and run.evaluate(frames):
            break
    env.close()
    run.finish(frames, updates)


if __name__ == "__main__":
    main()

"""n-step returns: rewards, next states and bootstrap discounts across episode ends."""

from __future__ import annotations

import torch
from tensordict import TensorDict
from torch import nn
from torchrl.data import OneHot
from torchrl.modules import QValueActor

from trl_cartpole.parts.losses import make_dqn_loss
from trl_cartpole.parts.replay import make_replay_buffer

GAMMA, N = 0.5, 3


def _trajectory() -> TensorDict:
    """9 steps: an episode terminated at step 2, one truncated at step 4, one still running.

    Observation s_t = t, reward r_t = t + 1, action 0; the next observation is the next
    step's, t + 1, except where an episode ends: there the last state is t + 0.5.
    """
    steps = 9
    obs = torch.arange(steps, dtype=torch.float32).unsqueeze(-1)  # [9, 1]
    terminated = torch.zeros(steps, 1, dtype=torch.bool)
    truncated = torch.zeros(steps, 1, dtype=torch.bool)
    terminated[2] = True
    truncated[4] = True
    return TensorDict(
        {
            "observation": obs,
            "action": nn.functional.one_hot(torch.zeros(steps, dtype=torch.long), 2),
            "next": {
                "observation": torch.where(terminated | truncated, obs + 0.5, obs + 1.0),
                "reward": obs + 1.0,
                "done": terminated | truncated,
                "terminated": terminated,
                "truncated": truncated,
            },
        },
        batch_size=[steps],
    )


# By hand, R_t = sum_{j<k} 0.5^j r_{t+j}, k = min(3, steps to the episode's end):
#   t=0: 1 + .5*2 + .25*3 = 2.75, k=3, s'=2.5, terminated (the window ends at the termination)
#   t=1: 2 + .5*3 = 3.5, k=2;  t=2: 3, k=1           (both end at the termination too)
#   t=3: 4 + .5*5 = 6.5, k=2, s'=4.5, NOT terminated (the truncation keeps the bootstrap)
#   t=4: 5, k=1, s'=4.5;  t=5: 6 + .5*7 + .25*8 = 11.5, k=3, s'=8 (s_8)
# t = 6, 7, 8 wait for later frames: their windows are not complete yet.
RETURNS = [2.75, 3.5, 3.0, 6.5, 5.0, 11.5]
STEPS = [3, 2, 1, 2, 1, 3]
NEXT_OBS = [2.5, 2.5, 2.5, 4.5, 4.5, 8.0]
TERMINATED = [True, True, True, False, False, False]


def _filled_buffer():
    buffer = make_replay_buffer(max_size=32, batch_size=4, n_steps=N, gamma=GAMMA)
    trajectory = _trajectory()
    buffer.extend(trajectory[:2])  # windows cross the collector's batches
    buffer.extend(trajectory[2:])
    return buffer


def test_n_step_transitions_match_the_hand_computed_reference():
    stored = _filled_buffer()[:]
    assert len(stored) == 6
    assert stored["observation"].squeeze(-1).tolist() == [0.0, 1.0, 2.0, 3.0, 4.0, 5.0]
    assert stored["next", "reward"].squeeze(-1).tolist() == RETURNS
    assert stored["steps_to_next_obs"].squeeze(-1).tolist() == STEPS
    assert stored["next", "observation"].squeeze(-1).tolist() == NEXT_OBS
    assert stored["next", "terminated"].squeeze(-1).tolist() == TERMINATED
    assert stored["steps_to_next_obs"].shape == stored["next", "reward"].shape  # [6, 1]


def test_td_target_bootstraps_with_gamma_to_the_window_length():
    net = nn.Linear(1, 2, bias=False)  # Q(s) = [s, 2 s]: max_a Q(s', a) = 2 s'
    with torch.no_grad():
        net.weight.copy_(torch.tensor([[1.0], [2.0]]))
    loss = make_dqn_loss(
        QValueActor(net, in_keys=["observation"], spec=OneHot(2)), gamma=GAMMA, loss_function="l2"
    )
    stored = _filled_buffer()[:]
    loss(stored)
    # y_t = R_t + gamma^k (1 - terminated) 2 s'; the taken action 0 has Q(s_t, 0) = t.
    discount = [GAMMA**k * (not term) for k, term in zip(STEPS, TERMINATED, strict=True)]
    assert discount == [0.0, 0.0, 0.0, 0.25, 0.5, 0.125]
    targets = [r + d * 2 * s for r, d, s in zip(RETURNS, discount, NEXT_OBS, strict=True)]
    squared = [(t - y) ** 2 for t, y in enumerate(targets)]
    assert torch.allclose(stored["td_error"].squeeze(-1), torch.tensor(squared))


def test_the_held_back_frames_arrive_with_the_next_batch():
    buffer = _filled_buffer()
    continuation = _trajectory()[:3].clone()  # three more steps of the running episode
    continuation["observation"] += 9
    continuation["next", "observation"] += 9
    continuation["next", "reward"] += 9
    for key in ("done", "terminated", "truncated"):
        continuation["next", key].zero_()
    buffer.extend(continuation)
    stored = buffer[:]
    assert stored["observation"].squeeze(-1).tolist()[6:] == [6.0, 7.0, 8.0]
    # t=6: 7 + .5*8 + .25*9 = 13.25 (r_8 = 9), then the continuation's rewards 10, 11, ...
    assert stored["next", "reward"].squeeze(-1).tolist()[6] == 13.25

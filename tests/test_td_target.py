"""The DQN loss on a hand-made batch: a TD target worked out by hand, including a terminated
transition (no bootstrap) and a truncated one (bootstrap kept)."""

from __future__ import annotations

import pytest
import torch
from tensordict import TensorDict
from torch import nn
from torchrl.data import OneHot
from torchrl.modules import QValueActor

from trl_cartpole.parts.losses import make_dqn_loss


def _linear_actor() -> QValueActor:
    """Q(s) = W s with W = [[1, 0], [0, 2]]: Q(s, 0) = s_0, Q(s, 1) = 2 s_1."""
    net = nn.Linear(2, 2, bias=False)
    with torch.no_grad():
        net.weight.copy_(torch.tensor([[1.0, 0.0], [0.0, 2.0]]))
    return QValueActor(net, in_keys=["observation"], spec=OneHot(2))


def _batch() -> TensorDict:
    # Three copies of s = [3, 0], a = 0, r = 1, s' = [1, 1]: Q(s, a) = 3, max_a Q(s', a) = 2.
    # Row 0: running; row 1: terminated; row 2: truncated by a time limit.
    done = torch.tensor([[False], [True], [True]])
    terminated = torch.tensor([[False], [True], [False]])
    return TensorDict(
        {
            "observation": torch.tensor([[3.0, 0.0]] * 3),
            "action": torch.tensor([[1, 0]] * 3),
            "next": {
                "observation": torch.tensor([[1.0, 1.0]] * 3),
                "reward": torch.ones(3, 1),
                "done": done,
                "terminated": terminated,
                "truncated": done & ~terminated,
            },
        },
        batch_size=[3],
    )


# gamma = 0.5. Targets y = r + gamma * (1 - terminated) * max_a Q(s', a):
#   running: 1 + 0.5 * 2 = 2  -> delta = 3 - 2 = 1
#   terminated: 1             -> delta = 3 - 1 = 2
#   truncated: 1 + 0.5 * 2 = 2 -> delta = 1 (truncation must not stop bootstrapping)
DELTAS = torch.tensor([1.0, 2.0, 1.0])


def test_l2_loss_equals_hand_computed_td_errors():
    loss = make_dqn_loss(_linear_actor(), gamma=0.5, loss_function="l2")
    batch = _batch()
    value = loss(batch)["loss"]
    assert value.item() == pytest.approx((DELTAS**2).mean().item())  # (1 + 4 + 1) / 3 = 2
    # The per-sample squared TD error is written back for prioritized replay.
    assert torch.allclose(batch["td_error"].flatten(), DELTAS**2)


def test_huber_loss_equals_hand_computed_values():
    # smooth_l1 (beta=1): 0.5 d^2 if |d| < 1 else |d| - 0.5 -> [0.5, 1.5, 0.5]
    loss = make_dqn_loss(_linear_actor(), gamma=0.5, loss_function="smooth_l1")
    assert loss(_batch())["loss"].item() == pytest.approx(2.5 / 3)


def test_treating_truncation_as_termination_would_change_the_loss():
    """Guards the batch itself: if the truncated row were terminal its delta would be 2."""
    batch = _batch()
    batch["next", "terminated"] = batch["next", "done"].clone()
    loss = make_dqn_loss(_linear_actor(), gamma=0.5, loss_function="l2")
    assert loss(batch)["loss"].item() == pytest.approx((1 + 4 + 4) / 3)


def test_target_network_is_used_for_bootstrap():
    """Changing the online weights after construction leaves max_a Q_target(s', a) unchanged."""
    actor = _linear_actor()
    loss = make_dqn_loss(actor, gamma=0.5, loss_function="l2")
    params = loss.value_network_params
    params.apply(lambda t: t.data.mul_(2.0))  # online Q doubles: Q(s, a) = 6
    # Target still gives max Q(s') = 2: deltas = 6 - [2, 1, 2] = [4, 5, 4].
    assert loss(_batch())["loss"].item() == pytest.approx((16 + 25 + 16) / 3)

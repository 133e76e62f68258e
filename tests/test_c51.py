"""C51: the projected target distribution by hand, and distributions that sum to one."""

from __future__ import annotations

import pytest
import torch
from tensordict import TensorDict
from torch import nn
from torchrl.data import OneHot
from torchrl.modules import DistributionalQValueActor
from torchrl.objectives import DistributionalDQNLoss

from trl_cartpole.config.schema import Config, NetworkConfig
from trl_cartpole.parts.env import make_env
from trl_cartpole.parts.losses import make_dqn_loss
from trl_cartpole.parts.models import expected_action_values
from trl_cartpole.run.from_config import build_actor

SUPPORT = torch.tensor([0.0, 1.0, 2.0])  # z, delta_z = 1
P_S = torch.tensor([[0.25, 1 / 3], [0.25, 1 / 3], [0.5, 1 / 3]])  # p(s, .): [atoms, actions]
P_NEXT = torch.tensor([[0.2, 0.6], [0.5, 0.3], [0.3, 0.1]])  # p(s', .): E = [1.1, 0.5]


def _actor() -> DistributionalQValueActor:
    """States are one-hot: s = [1, 0], s' = [0, 1]; the network's logits are log p."""
    net = nn.Sequential(nn.Linear(2, 6, bias=False), nn.Unflatten(-1, (3, 2)))
    with torch.no_grad():
        net[0].weight.copy_(torch.stack([P_S.log().flatten(), P_NEXT.log().flatten()], -1))
    return DistributionalQValueActor(net, support=SUPPORT, in_keys=["observation"], spec=OneHot(2))


def _batch() -> TensorDict:
    terminated = torch.tensor([[False], [True]])
    return TensorDict(
        {
            "observation": torch.tensor([[1.0, 0.0], [1.0, 0.0]]),
            "action": torch.tensor([[1, 0], [1, 0]]),
            "next": {
                "observation": torch.tensor([[0.0, 1.0], [0.0, 1.0]]),
                "reward": torch.tensor([[0.5], [0.5]]),
                "done": terminated,
                "terminated": terminated,
                "truncated": torch.zeros_like(terminated),
            },
        },
        batch_size=[2],
    )


def test_projected_target_distribution_of_a_hand_worked_example():
    # Not terminated: a* = argmax_a E[Z(s', a)] = 0 (1.1 > 0.5); Tz = 0.5 + 0.5 z = [.5, 1, 1.5].
    #   Tz=0.5 splits p=0.2 half-half onto z0, z1; Tz=1 puts p=0.5 on z1; Tz=1.5 splits 0.3
    #   onto z1, z2  ->  m = [0.1, 0.75, 0.15].
    # Terminated: Tz = r = 0.5 for every atom  ->  m = [0.5, 0.5, 0].
    m = torch.tensor([[0.1, 0.75, 0.15], [0.5, 0.5, 0.0]])
    log_p = P_S[:, 0].log()  # the online distribution of the taken action 0 at s
    cross_entropy = -(m * log_p).sum(-1)  # [2]
    loss = make_dqn_loss(_actor(), gamma=0.5)
    assert isinstance(loss, DistributionalDQNLoss)
    batch = _batch()
    value = loss(batch)["loss"]
    assert torch.allclose(batch["td_error"].squeeze(-1), cross_entropy, atol=1e-6)
    assert value.item() == pytest.approx(cross_entropy.mean().item(), rel=1e-6)
    assert m.sum(-1).tolist() == pytest.approx([1.0, 1.0])


def test_distributions_sum_to_one_and_the_greedy_action_maximises_their_mean():
    env = make_env("CartPole-v1", seed=0)
    network = NetworkConfig(distributional=True, atoms=11, v_min=0.0, v_max=10.0, head="dueling")
    torch.manual_seed(0)
    actor = build_actor(Config(network=network), env)
    td = actor(env.reset().expand(7).clone())  # 7 copies of the first state
    log_p = td["action_value"]  # [7, atoms, actions]
    assert log_p.shape == (7, 11, 2)
    assert torch.allclose(log_p.exp().sum(-2), torch.ones(7, 2), atol=1e-6)
    q = expected_action_values(actor, log_p)  # [7, 2]
    assert torch.allclose(q, (log_p.exp() * torch.linspace(0, 10, 11).unsqueeze(-1)).sum(-2))
    assert torch.equal(td["action"].argmax(-1), q.argmax(-1))


def test_tied_expected_values_give_one_greedy_action():
    """TorchRL marks every tied maximum in a one-hot action; a two-hot one broke the C51 loss."""
    from trl_cartpole.parts.models import make_q_actor

    env = make_env("CartPole-v1", seed=0)
    support = torch.linspace(0, 100, 51)
    actor = make_q_actor(env.observation_spec, env.action_spec, num_cells=[8], support=support)
    with torch.no_grad():
        for parameter in actor.parameters():
            parameter.zero_()  # every action gets the same distribution: an exact tie
    td = actor(TensorDict(observation=torch.randn(6, 4), batch_size=[6]))
    assert td["action"].tolist() == [[1, 0]] * 6

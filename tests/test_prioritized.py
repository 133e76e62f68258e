"""Prioritized replay: priorities written back from the TD error, weights applied in the loss."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from tensordict import TensorDict
from torch import nn
from torchrl.data import OneHot
from torchrl.modules import QValueActor

from trl_cartpole.parts.losses import make_dqn_loss
from trl_cartpole.parts.optim import make_update
from trl_cartpole.parts.replay import annealed_beta, make_replay_buffer

ALPHA, BETA, EPS, GAMMA = 0.5, 0.4, 1e-6, 0.5
W = torch.tensor([[1.0, -1.0], [0.5, 2.0]])  # Q(s) = W s: [*B, 2] -> [*B, 2]


def _transitions() -> TensorDict:
    obs = torch.tensor([[1.0, 0.0], [0.0, 1.0], [2.0, 1.0], [1.0, 1.0], [0.0, 3.0], [3.0, 0.0]])
    next_obs = torch.tensor(
        [[0.0, 1.0], [1.0, 1.0], [0.0, 0.0], [2.0, 0.0], [1.0, 0.0], [0.0, 2.0]]
    )
    action = torch.tensor([0, 1, 1, 0, 0, 1])
    terminated = torch.tensor([False, False, True, False, False, False]).unsqueeze(-1)
    return TensorDict(
        {
            "observation": obs,
            "action": nn.functional.one_hot(action, 2),
            "next": {
                "observation": next_obs,
                "reward": torch.tensor([1.0, 0.0, 2.0, -1.0, 0.5, 3.0]).unsqueeze(-1),
                "done": terminated,
                "terminated": terminated,
                "truncated": torch.zeros_like(terminated),
            },
        },
        batch_size=[6],
    )


def _td_errors_by_hand(data: TensorDict) -> torch.Tensor:
    """delta = Q(s, a) - (r + gamma * (1 - terminated) * max_a' Q(s', a')), weights W."""
    q = data["observation"] @ W.T  # [N, 2]
    q_taken = (q * data["action"]).sum(-1)  # [N]
    next_max = (data["next", "observation"] @ W.T).max(-1).values  # [N]
    not_terminated = 1.0 - data["next", "terminated"].float().squeeze(-1)
    return q_taken - (data["next", "reward"].squeeze(-1) + GAMMA * not_terminated * next_max)


def _seed(seed: int) -> None:
    torch.manual_seed(seed)
    np.random.seed(seed)  # noqa: NPY002 (TorchRL's CPU PrioritizedSampler draws from it)


def _setup():
    _seed(0)
    net = nn.Linear(2, 2, bias=False)
    with torch.no_grad():
        net.weight.copy_(W)
    actor = QValueActor(net, in_keys=["observation"], spec=OneHot(2))
    loss = make_dqn_loss(actor, gamma=GAMMA, loss_function="l2")
    buffer = make_replay_buffer(
        max_size=16, batch_size=4, prioritized=True, alpha=ALPHA, beta=BETA, eps=EPS, n_steps=1
    )
    buffer.extend(_transitions())
    # lr = 0: the weights stay W, so every TD error can be checked against the hand values.
    update = make_update(loss, torch.optim.SGD(net.parameters(), lr=0.0), grad_clip="none")
    return loss, buffer, update


def test_priorities_written_torchrls_way_are_squared_td_error_plus_eps_to_the_alpha():
    """TorchRL's rule, which the pipeline's Learner follows: DQNLoss writes td_error = delta ** 2
    and update_tensordict_priority stores (td_error + eps) ** alpha."""
    _, buffer, update = _setup()
    delta = _td_errors_by_hand(_transitions())  # [6]
    sample = buffer.sample()  # [4]
    update(sample)
    buffer.update_tensordict_priority(sample)  # as Learner.step does
    index = sample["index"]
    stored = buffer.sampler._sum_tree[index]  # the sampler's p_i ** alpha
    expected = (delta[index] ** 2 + EPS) ** ALPHA
    assert torch.allclose(torch.as_tensor(stored, dtype=torch.float32), expected, rtol=1e-5)


def test_loss_is_the_importance_weighted_mean_of_squared_td_errors():
    loss, buffer, update = _setup()
    delta = _td_errors_by_hand(_transitions())
    everything = buffer[:]  # give all six transitions their priority once
    loss(everything)
    buffer.update_tensordict_priority(everything)

    _seed(3)
    sample = buffer.sample()  # [4]
    index, weights = sample["index"], sample["priority_weight"]  # [4], [4]
    priorities = (delta**2 + EPS) ** ALPHA  # [6]
    # TorchRL's weights: (N P(i)) ** -beta / max_k (N P(k)) ** -beta = (p_i / min_k p_k) ** -beta
    assert torch.allclose(weights, (priorities[index] / priorities.min()) ** -BETA, rtol=1e-5)
    assert not torch.allclose(weights, weights[0].expand(4))  # non-uniform, so the test can bite

    squared = delta[index] ** 2  # l2 loss per sample
    weighted = (weights * squared).sum() / weights.sum()
    metrics = update(sample)
    assert metrics["loss"].item() == pytest.approx(weighted.item(), rel=1e-5)
    assert metrics["loss"].item() != pytest.approx(squared.mean().item(), rel=1e-3)


def test_higher_priority_transitions_are_sampled_more_often():
    loss, buffer, _ = _setup()
    everything = buffer[:]
    loss(everything)
    buffer.update_tensordict_priority(everything)
    _seed(0)
    counts = torch.bincount(buffer.sample(6000)["index"], minlength=6).float()  # [6]
    priorities = (_td_errors_by_hand(_transitions()) ** 2 + EPS) ** ALPHA
    assert torch.allclose(counts / 6000, priorities / priorities.sum(), atol=0.02)


@pytest.mark.parametrize(("frames", "expected"), [(0, 0.4), (500, 0.7), (1000, 1.0), (5000, 1.0)])
def test_beta_is_annealed_linearly_to_one(frames, expected):
    assert annealed_beta(0.4, frames, anneal_frames=1000) == pytest.approx(expected)


def test_the_configs_alpha_is_torchrls_and_the_presets_are_schauls_exponent():
    """buffer.alpha is TorchRL's, on DQNLoss's delta ** 2: the prioritized preset's 0.3 is
    Schaul et al.'s 0.6 on |delta|; Rainbow's C51 priority (a cross-entropy) takes 0.6 as is."""
    from trl_cartpole.config.compose import compose_run_config
    from trl_cartpole.config.schema import to_config
    from trl_cartpole.run.from_config import build_replay_buffer

    cfg = to_config({"buffer": {"prioritized": True, "alpha": 0.45}})
    assert build_replay_buffer(cfg).sampler.alpha == pytest.approx(0.45)  # as given
    assert to_config(
        compose_run_config(overrides=["algo=prioritized"])
    ).buffer.alpha == pytest.approx(0.3)
    assert to_config(compose_run_config(overrides=["algo=rainbow"])).buffer.alpha == pytest.approx(
        0.6
    )

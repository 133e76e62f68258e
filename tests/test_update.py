"""One gradient step: gradient clipping by value and by norm, and the loss going down."""

from __future__ import annotations

import pytest
import torch
from tensordict import TensorDict
from torch import nn
from torchrl.data import OneHot
from torchrl.modules import QValueActor

from trl_cartpole.parts.losses import make_dqn_loss
from trl_cartpole.parts.optim import make_optimizer, make_update


def _setup(scale: float = 100.0):
    torch.manual_seed(0)
    net = nn.Linear(4, 2)
    actor = QValueActor(net, in_keys=["observation"], spec=OneHot(2))
    loss = make_dqn_loss(actor, gamma=0.9, loss_function="l2")
    batch = TensorDict(
        {
            "observation": torch.randn(16, 4) * scale,
            "action": nn.functional.one_hot(torch.randint(2, (16,)), 2),
            "next": {
                "observation": torch.randn(16, 4),
                "reward": torch.full((16, 1), scale),
                "done": torch.zeros(16, 1, dtype=torch.bool),
                "terminated": torch.zeros(16, 1, dtype=torch.bool),
                "truncated": torch.zeros(16, 1, dtype=torch.bool),
            },
        },
        batch_size=[16],
    )
    return actor, loss, batch


def _params(actor) -> torch.Tensor:
    return torch.cat([p.detach().flatten().clone() for p in actor.parameters()])


@pytest.mark.parametrize("max_grad", [0.5, 2.0])
def test_value_clipping_bounds_each_gradient_element(max_grad):
    actor, loss, batch = _setup()
    sgd = torch.optim.SGD(actor.parameters(), lr=1.0)  # step = -grad: the clipped grad shows
    update = make_update(loss, sgd, grad_clip="value", max_grad=max_grad)
    before = _params(actor)
    metrics = update(batch)
    step = _params(actor) - before
    assert step.abs().max().item() == pytest.approx(max_grad)
    assert metrics["grad_norm"].item() > max_grad  # measured before clipping


def test_norm_clipping_bounds_the_gradient_norm():
    actor, loss, batch = _setup()
    sgd = torch.optim.SGD(actor.parameters(), lr=1.0)
    update = make_update(loss, sgd, grad_clip="norm", max_grad=3.0)
    before = _params(actor)
    metrics = update(batch)
    assert (_params(actor) - before).norm().item() == pytest.approx(3.0, rel=1e-4)
    assert metrics["grad_norm"].item() > 3.0


def test_adamw_updates_lower_the_loss_on_a_fixed_batch():
    actor, loss, batch = _setup(scale=1.0)
    optimizer = make_optimizer(actor.parameters(), lr=1e-2)
    assert isinstance(optimizer, torch.optim.AdamW)
    assert optimizer.defaults["amsgrad"] is True
    update = make_update(loss, optimizer, grad_clip="value", max_grad=100.0)
    first = update(batch.clone())["loss"].item()
    for _ in range(50):
        last = update(batch.clone())["loss"].item()
    assert last < 0.5 * first


@pytest.mark.slow  # torch.compile: 25 s
def test_update_compiles_whole_and_matches_eager():
    """``make_update`` is pure enough for ``torch.compile``: same losses and weights as eager."""
    results = []
    for compiled in (False, True):
        actor, loss, batch = _setup(scale=1.0)
        optimizer = make_optimizer(actor.parameters(), lr=1e-2)
        update = make_update(loss, optimizer, grad_clip="norm", max_grad=1.0)
        if compiled:
            update = torch.compile(update)
        losses = [update(batch.clone())["loss"].item() for _ in range(3)]
        results.append((losses, _params(actor)))
    (eager_losses, eager_params), (compiled_losses, compiled_params) = results
    assert compiled_losses == pytest.approx(eager_losses, rel=1e-4)
    assert torch.allclose(eager_params, compiled_params, atol=1e-5)

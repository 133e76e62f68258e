"""One gradient step: gradient clipping by value and by norm, and the loss going down."""

from __future__ import annotations

import os
import subprocess

import pytest
import torch
from tensordict import TensorDict
from torch import nn
from torchrl.data import OneHot
from torchrl.modules import QValueActor

from trl_cartpole.parts.losses import make_dqn_loss
from trl_cartpole.parts.optim import make_optimizer, make_update
from trl_cartpole.report.console import quiet_libraries


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
    optimizer = make_optimizer(actor.parameters(), lr=1e-2, amsgrad=True, weight_decay=0.0)
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
        with quiet_libraries():  # as a run compiles: tensordict's note on a Dynamo setting off
            losses = [update(batch.clone())["loss"].item() for _ in range(3)]
        results.append((losses, _params(actor)))
    (eager_losses, eager_params), (compiled_losses, compiled_params) = results
    assert compiled_losses == pytest.approx(eager_losses, rel=1e-4)
    assert torch.allclose(eager_params, compiled_params, atol=1e-5)


@pytest.mark.parametrize(
    ("frames", "expected"), [(0, 1e-3), (2_500, 7.75e-4), (10_000, 1e-4), (30_000, 1e-4)]
)
def test_the_learning_rate_tapers_linearly_then_holds(frames, expected):
    from trl_cartpole.parts.optim import tapered_lr

    # 1e-3 + (1e-4 - 1e-3) * 2500 / 10000 = 1e-3 - 2.25e-4
    assert tapered_lr(1e-3, 1e-4, frames, decay_frames=10_000) == pytest.approx(expected)


@pytest.mark.parametrize("lr_end", [None, pytest.param(2e-4, marks=pytest.mark.slow)])
def test_a_run_updates_at_the_learning_rate_of_the_frames_collected(compose, tmp_path, lr_end):
    """Each update uses the lr set after the batch before it: 1e-3 until the first batch's
    schedules have run, then 1e-3 + (lr_end - 1e-3) * frames / 400 (none: 1e-3 throughout)."""
    from tests.conftest import SMOKE_OVERRIDES
    from trl_cartpole.run.build import build_components
    from trl_cartpole.run.training import train

    seen: list[tuple[int, float]] = []  # (frames collected, lr) at each update

    def build_with_a_spy(cfg, resume=None):
        components = build_components(cfg, resume)
        update, optimizer = components.learner.update, components.learner.optimizer

        def recording_update(batch):
            seen.append((components.progress.frames, optimizer.param_groups[0]["lr"]))
            return update(batch)

        components.learner.update = recording_update
        return components

    taper = [] if lr_end is None else [f"optim.lr_end={lr_end}", "optim.lr_decay_frames=400"]
    overrides = [*SMOKE_OVERRIDES, "optim.lr=0.001", *taper, f"run_dir={tmp_path / 'run'}"]
    train(compose(*overrides), build=build_with_a_spy)
    assert len(seen) > 100 and seen[-1][0] >= 296  # updates through the 300 frames
    previous_batch = 4  # collector.frames_per_batch: the schedules ran on the frames before
    for frames, lr in seen:
        end = 1e-3 if lr_end is None else lr_end
        expected = 1e-3 + (end - 1e-3) * min(1.0, (frames - previous_batch) / 400)
        assert lr == pytest.approx(expected, rel=1e-9), (frames, lr)


def test_the_config_sets_adamws_eps(compose, tmp_path):
    """``optim.eps`` reaches AdamW: 1e-8 (AdamW's own) unless set, data-efficient Rainbow's
    1.5e-4 when asked."""
    from tests.conftest import SMOKE_OVERRIDES
    from trl_cartpole.config.schema import to_config
    from trl_cartpole.run.build import build_components

    for overrides, expected in (([], 1e-8), (["optim.eps=0.00015"], 1.5e-4)):
        cfg = to_config(compose(*SMOKE_OVERRIDES, *overrides, f"run_dir={tmp_path / 'run'}"))
        with build_components(cfg) as components:
            optimizer = components.learner.optimizer
        assert isinstance(optimizer, torch.optim.AdamW)
        assert optimizer.param_groups[0]["eps"] == pytest.approx(expected, rel=1e-12)


def test_auto_autocast_is_bfloat16_only_where_the_cpu_computes_it(monkeypatch):
    from trl_cartpole.parts import optim

    monkeypatch.setattr(optim, "cpu_computes_bfloat16", lambda: True)
    chosen, line = optim.choose_autocast("auto", "cpu")
    assert chosen == "bfloat16" and "runs in bfloat16" in line
    assert optim.choose_autocast("bfloat16", "cpu") == ("bfloat16", None)  # native: nothing said
    monkeypatch.setattr(optim, "cpu_computes_bfloat16", lambda: False)
    chosen, line = optim.choose_autocast("auto", "cpu")
    assert chosen == "none" and "runs in float32" in line
    chosen, line = optim.choose_autocast("bfloat16", "cpu")  # asked for: kept, and warned about
    assert chosen == "bfloat16" and "emulates bfloat16" in line and "auto picks float32" in line
    assert optim.choose_autocast("none", "cpu") == ("none", None)


@pytest.mark.slow  # a fresh interpreter importing torch (5 s)
def test_an_avx2_only_cpu_is_given_float32(python):
    """``ONEDNN_MAX_CPU_ISA=AVX2 ATEN_CPU_CAPABILITY=avx2`` stand in for a CPU without AVX-512:
    there oneDNN reports no bfloat16, and ``auto`` is float32 whatever this machine has."""
    code = "from trl_cartpole.parts.optim import choose_autocast; print(choose_autocast('auto'))"
    env = {**os.environ, "ONEDNN_MAX_CPU_ISA": "AVX2", "ATEN_CPU_CAPABILITY": "avx2"}
    proc = subprocess.run(
        [python, "-c", code], capture_output=True, text=True, env=env, timeout=120
    )
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert proc.stdout.startswith("('none', 'optim.autocast=auto: the update runs in float32")
    assert "AVX2" in proc.stdout

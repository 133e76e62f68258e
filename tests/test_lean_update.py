"""The compiled whole update is the eager update within float rounding, on the same objects."""

from __future__ import annotations

import pytest
import torch

from trl_cartpole import (
    make_dqn_loss,
    make_env,
    make_optimizer,
    make_q_actor,
    make_replay_buffer,
    make_update,
)
from trl_cartpole.fast.compiled_update import make_lean_update
from trl_cartpole.fast.loss import fuse_dqn_loss
from trl_cartpole.parts.replay import extend_with_batch

from .conftest import SMOKE_OVERRIDES

UPDATES = 40


def _buffer(n_steps: int, categorical: bool, prioritized: bool):
    env = make_env("CartPole-v1", seed=0, num_envs=4, categorical_action_encoding=categorical)
    buffer = make_replay_buffer(
        max_size=2000,
        batch_size=64,
        n_steps=n_steps,
        **({"gamma": 0.97} if n_steps > 1 else {}),
        **({"prioritized": True, "alpha": 0.6, "beta": 0.4} if prioritized else {}),
    )
    extend_with_batch(buffer, env.rollout(200, break_when_any_done=False))  # [4, 200]
    return make_env("CartPole-v1", categorical_action_encoding=categorical), buffer


def _learner(env, buffer, *, double: bool, amsgrad: bool, weight_decay: float):
    torch.manual_seed(3)  # the same initial weights for both updates
    actor = make_q_actor(env.observation_spec, env.action_spec, num_cells=[64, 64])
    loss = make_dqn_loss(actor, gamma=0.97, double_dqn=double, replay_buffer=buffer)
    with torch.no_grad():  # a target a few updates behind the online network
        for target in loss.target_value_network_params.values(True, True):
            target.mul_(0.9).add_(0.01)
    optimizer = make_optimizer(
        actor.parameters(), lr=3e-3, amsgrad=amsgrad, weight_decay=weight_decay
    )
    return actor, loss, optimizer


VARIANTS = {  # (n_steps, categorical, prioritized, double, amsgrad, weight decay, clip)
    "default": (3, False, False, False, True, 0.0, "norm"),
    # a large decoupled weight decay: an update that left it out would drift apart at once
    "double-prioritized-categorical": (1, True, True, True, False, 0.5, "value"),
}


@pytest.mark.parametrize("variant", list(VARIANTS))
def test_the_compiled_update_follows_the_eager_one_within_float_rounding(variant):
    n_steps, categorical, prioritized, double, amsgrad, decay, clip = VARIANTS[variant]
    env, buffer = _buffer(n_steps, categorical, prioritized)
    eager_actor, eager_loss, eager_optimizer = _learner(
        env, buffer, double=double, amsgrad=amsgrad, weight_decay=decay
    )
    lean_actor, lean_loss, lean_optimizer = _learner(
        env, buffer, double=double, amsgrad=amsgrad, weight_decay=decay
    )
    eager = make_update(fuse_dqn_loss(eager_loss), eager_optimizer, clip, 1.0)
    lean = make_lean_update(lean_loss, lean_optimizer, clip, 1.0)
    assert lean is not None
    start = [p.detach().clone() for p in lean_actor.parameters()]
    for update in range(UPDATES):
        if update % 10 == 5:  # from the same state again: each update is compared on its own
            _copy_state(eager_actor, eager_optimizer, lean_actor, lean_optimizer)
        sample = buffer.sample()
        eager_sample, lean_sample = sample.clone(), sample.clone()
        theirs, ours = eager(eager_sample), lean(lean_sample)
        torch.testing.assert_close(ours["loss"], theirs["loss"], rtol=1e-3, atol=1e-6)
        torch.testing.assert_close(ours["grad_norm"], theirs["grad_norm"], rtol=1e-3, atol=1e-6)
        torch.testing.assert_close(  # a squared difference: rounding shows at small values
            lean_sample["td_error"], eager_sample["td_error"], rtol=1e-3, atol=1e-5
        )
        assert lean_sample["td_error"].shape == (64, 1)
    for ours, theirs, before in zip(
        lean_actor.parameters(), eager_actor.parameters(), start, strict=True
    ):
        assert not torch.equal(ours, before)  # the actor's own parameters were stepped
        torch.testing.assert_close(ours, theirs, rtol=1e-3, atol=1e-5)
    # the optimizer's state is the stock AdamW's: the same entries, the same values
    ours_state, theirs_state = lean_optimizer.state_dict(), eager_optimizer.state_dict()
    assert ours_state["param_groups"] == theirs_state["param_groups"]
    for index, theirs in theirs_state["state"].items():
        assert sorted(ours_state["state"][index]) == sorted(theirs)
        assert ours_state["state"][index]["step"].item() == UPDATES
        for key in theirs:
            torch.testing.assert_close(
                ours_state["state"][index][key], theirs[key], rtol=1e-3, atol=1e-6
            )


def _copy_state(from_actor, from_optimizer, to_actor, to_optimizer) -> None:
    """The parameters and AdamW moments of one learner written into the other's tensors."""
    with torch.no_grad():
        for source, destination in zip(from_actor.parameters(), to_actor.parameters(), strict=True):
            destination.copy_(source)
            for key, value in from_optimizer.state[source].items():
                to_optimizer.state[destination][key].copy_(value)


def test_two_updates_built_differently_in_one_process_each_keep_their_own_graph():
    # Dynamo's graphs are kept per code object and the guards on constants are left out:
    # each built update must compile its own (another clip bound, double DQN, activation)
    env, buffer = _buffer(1, False, False)
    samples = [buffer.sample() for _ in range(3)]
    for double, max_grad, activation in ((False, 0.5, "relu"), (True, 5.0, "tanh")):
        results = []
        for make in ("eager", "lean"):
            torch.manual_seed(3)
            actor = make_q_actor(
                env.observation_spec,
                env.action_spec,
                num_cells=[32],
                activation_class=torch.nn.ReLU if activation == "relu" else torch.nn.Tanh,
            )
            loss = make_dqn_loss(actor, gamma=0.97, double_dqn=double)
            optimizer = make_optimizer(actor.parameters(), lr=1e-2)
            if make == "eager":
                update = make_update(fuse_dqn_loss(loss), optimizer, "norm", max_grad)
            else:
                update = make_lean_update(loss, optimizer, "norm", max_grad)
            for sample in samples:
                update(sample.clone())
            results.append([p.detach().clone() for p in actor.parameters()])
        for ours, theirs in zip(results[1], results[0], strict=True):
            torch.testing.assert_close(ours, theirs, rtol=1e-4, atol=1e-6)


def test_a_new_learning_rate_is_used_without_compiling_again():
    env, buffer = _buffer(1, False, False)
    actor, loss, optimizer = _learner(env, buffer, double=False, amsgrad=False, weight_decay=0.0)
    lean = make_lean_update(loss, optimizer)
    torch._dynamo.reset()
    torch._dynamo.utils.counters.clear()
    lean(buffer.sample())
    before = [p.detach().clone() for p in actor.parameters()]
    optimizer.param_groups[0]["lr"] = 0.0  # a taper's last value: nothing moves
    lean(buffer.sample())
    assert all(torch.equal(p, q) for p, q in zip(actor.parameters(), before, strict=True))
    optimizer.param_groups[0]["lr"] = 1e-2
    lean(buffer.sample())
    assert not all(torch.equal(p, q) for p, q in zip(actor.parameters(), before, strict=True))
    assert torch._dynamo.utils.counters["stats"]["unique_graphs"] == 1


def test_an_optimizer_loaded_from_its_state_dict_continues_as_if_never_saved():
    env, buffer = _buffer(1, False, False)
    samples = [buffer.sample() for _ in range(4)]
    runs = []
    for reload in (False, True):
        actor, loss, optimizer = _learner(env, buffer, double=False, amsgrad=True, weight_decay=0.0)
        lean = make_lean_update(loss, optimizer)
        for index, sample in enumerate(samples):
            if reload and index == 3:  # new state tensors, as a resume makes them
                optimizer.load_state_dict(optimizer.state_dict())
            lean(sample.clone())
        runs.append([p.detach().clone() for p in actor.parameters()])
        assert all(state["step"].item() == 4 for state in optimizer.state.values())
    assert all(torch.equal(a, b) for a, b in zip(*runs, strict=True))


def test_eager_and_compiled_updates_take_turns_on_one_optimizer_as_eager_alone():
    # the same AdamW state either way: the eager update's state read by the compiled one and
    # the other way round, as the library's two functions may share an optimizer
    env, buffer = _buffer(3, False, False)
    samples = [buffer.sample() for _ in range(6)]
    runs = []
    for mixed in (False, True):
        actor, loss, optimizer = _learner(env, buffer, double=False, amsgrad=True, weight_decay=0.1)
        eager = make_update(fuse_dqn_loss(loss), optimizer, "norm", 10.0)
        lean = make_lean_update(loss, optimizer, "norm", 10.0)
        for index, sample in enumerate(samples):
            (lean if mixed and index % 2 else eager)(sample.clone())
        runs.append([p.detach().clone() for p in actor.parameters()])
        assert all(state["step"].item() == 6 for state in optimizer.state.values())
    for mixed, alone in zip(runs[1], runs[0], strict=True):
        torch.testing.assert_close(mixed, alone, rtol=1e-4, atol=1e-6)


def test_a_changed_optimizer_setting_or_sample_kind_is_refused_not_ignored():
    env, buffer = _buffer(1, False, False)
    _, loss, optimizer = _learner(env, buffer, double=False, amsgrad=False, weight_decay=0.0)
    lean = make_lean_update(loss, optimizer)
    sample = buffer.sample()
    lean(sample.clone())
    weighted = sample.clone()
    weighted.set("priority_weight", torch.ones(64))  # importance weights the first had not
    with pytest.raises(ValueError, match="one update serves samples of one kind"):
        lean(weighted)
    optimizer.param_groups[0]["weight_decay"] = 0.1
    with pytest.raises(ValueError, match="call make_lean_update again"):
        lean(sample.clone())


def test_what_it_does_not_cover_is_left_to_the_eager_update():
    env, _ = _buffer(1, False, False)
    noisy = make_q_actor(env.observation_spec, env.action_spec, noisy=True)
    loss = make_dqn_loss(noisy, gamma=0.9)
    assert make_lean_update(loss, make_optimizer(noisy.parameters())) is None
    actor = make_q_actor(env.observation_spec, env.action_spec, num_cells=[16])
    loss = make_dqn_loss(actor, gamma=0.9)
    sgd = torch.optim.SGD(actor.parameters(), lr=0.1)
    assert make_lean_update(loss, sgd) is None
    two_groups = make_optimizer([{"params": [p]} for p in actor.parameters()])
    assert make_lean_update(loss, two_groups) is None
    with pytest.raises(ValueError, match="grad_clip='clip'"):
        make_lean_update(loss, make_optimizer(actor.parameters()), grad_clip="clip")


def test_a_run_with_compile_true_trains_with_the_compiled_update_and_follows_a_taper(
    compose, tmp_path
):
    from trl_cartpole import train
    from trl_cartpole.run.build import build_components

    seen = {}

    def build_and_watch(cfg, resume=None):
        components = build_components(cfg, resume)
        seen["update"] = components.learner.update
        seen["optimizer"] = components.learner.optimizer
        return components

    overrides = [
        *SMOKE_OVERRIDES,
        "fast=true",
        "compile=true",
        "optim.lr_end=0.0001",
        "logger.plots=false",
    ]
    summary = train(compose(*overrides, f"run_dir={tmp_path / 'run'}"), build=build_and_watch)
    assert summary["updates"] > 0
    assert seen["update"].__qualname__ == "make_lean_update.<locals>.update"
    assert seen["optimizer"].param_groups[0]["lr"] == pytest.approx(1e-4)  # tapered to the end


def test_bfloat16_autocast_runs_the_products_in_bfloat16_and_keeps_float32_state():
    env, buffer = _buffer(3, False, False)
    samples = [buffer.sample() for _ in range(5)]
    results = {}
    for name in ("float32", "bfloat16 eager", "bfloat16 compiled"):
        actor, loss, optimizer = _learner(env, buffer, double=True, amsgrad=True, weight_decay=0.0)
        dtype = None if name == "float32" else torch.bfloat16
        if name == "bfloat16 compiled":
            update = make_lean_update(loss, optimizer, "norm", 10.0, autocast_dtype=dtype)
        else:
            update = make_update(fuse_dqn_loss(loss), optimizer, "norm", 10.0, autocast_dtype=dtype)
        losses = [update(sample.clone())["loss"] for sample in samples]
        assert all(value.dtype == torch.float32 for value in losses)
        assert all(p.dtype == torch.float32 for p in actor.parameters())
        results[name] = torch.stack(losses)
    # bfloat16 keeps 8 bits of mantissa: the losses differ from float32's, by about that much
    assert not torch.equal(results["bfloat16 eager"], results["float32"])
    torch.testing.assert_close(results["bfloat16 eager"], results["float32"], rtol=5e-2, atol=1e-3)
    torch.testing.assert_close(
        results["bfloat16 compiled"], results["bfloat16 eager"], rtol=2e-2, atol=1e-3
    )
    # the compiled update ran under autocast too: nearer bfloat16's losses than float32's
    to_eager = (results["bfloat16 compiled"] - results["bfloat16 eager"]).abs().sum()
    to_float32 = (results["bfloat16 compiled"] - results["float32"]).abs().sum()
    assert to_eager < to_float32


def test_autocast_is_refused_where_the_fused_loss_is_not_used(compose):
    from trl_cartpole import ConfigError, validate
    from trl_cartpole.config.schema import to_config

    assert (
        validate(to_config(compose("fast=true", "optim.autocast=bfloat16"))).optim.autocast
        == "bfloat16"
    )
    with pytest.raises(ConfigError, match=r"or optim\.autocast=none"):
        validate(to_config(compose("fast=true", "optim.autocast=bfloat16", "network.noisy=true")))
    with pytest.raises(ConfigError, match="choose one of"):
        validate(to_config(compose("optim.autocast=float16")))

"""The fused DQN loss is DQNLoss's arithmetic: bitwise the same loss, gradients and td_error."""

from __future__ import annotations

import pytest
import torch

from trl_cartpole import make_dqn_loss, make_env, make_q_actor, make_replay_buffer
from trl_cartpole.fast.loss import FusedDQNLoss, fuse_dqn_loss
from trl_cartpole.parts.replay import extend_with_batch


def _sample(n_steps: int = 1, categorical: bool = False, prioritized: bool = False):
    env = make_env("CartPole-v1", seed=0, num_envs=4, categorical_action_encoding=categorical)
    one_env = make_env("CartPole-v1", categorical_action_encoding=categorical)  # its specs
    buffer = make_replay_buffer(
        max_size=1000,
        batch_size=64,
        n_steps=n_steps,
        **({"gamma": 0.9} if n_steps > 1 else {}),
        **({"prioritized": True, "alpha": 0.6, "beta": 0.4} if prioritized else {}),
    )
    extend_with_batch(buffer, env.rollout(100, break_when_any_done=False))  # [4, 100]
    return one_env, buffer


def _compare(loss, buffer, batches: int = 3) -> None:
    fused = fuse_dqn_loss(loss)
    assert isinstance(fused, FusedDQNLoss)
    # the target network a few updates behind the online one: targets differ from Q
    with torch.no_grad():
        for target in loss.target_value_network_params.values(True, True):
            target.mul_(0.9).add_(0.01)
    params = list(loss.value_network_params.values(True, True))
    for _ in range(batches):
        sample = buffer.sample()
        results = []
        for compute in (loss, fused):
            for param in params:
                param.grad = None
            copy = sample.clone()
            value = compute(copy)["loss"]
            value.backward()
            results.append((value, copy["td_error"], [p.grad.clone() for p in params]))
        (theirs, their_error, their_grads), (ours, our_error, our_grads) = results
        assert torch.equal(theirs, ours) and torch.equal(their_error, our_error)
        assert all(torch.equal(a, b) for a, b in zip(their_grads, our_grads, strict=True))
        assert their_error.shape == (64, 1)


@pytest.mark.parametrize(
    "variant",
    ["dqn", "double", "dueling", "n-step", "prioritized", "categorical", "l2"],
)
def test_the_fused_loss_equals_dqnloss_bitwise(variant):
    env, buffer = _sample(
        n_steps=3 if variant == "n-step" else 1,
        categorical=variant == "categorical",
        prioritized=variant == "prioritized",
    )
    actor = make_q_actor(
        env.observation_spec,
        env.action_spec,
        num_cells=[32, 32],
        head="dueling" if variant == "dueling" else "plain",
    )
    loss = make_dqn_loss(
        actor,
        gamma=0.9,
        double_dqn=variant == "double",
        loss_function="l2" if variant == "l2" else "smooth_l1",
        **({"replay_buffer": buffer} if variant == "n-step" else {}),
    )
    if variant == "prioritized":  # importance weights in the sample: the weighted mean
        assert buffer.sample().get("priority_weight", None) is not None
    _compare(loss, buffer)


def test_the_fused_loss_updates_the_actors_own_parameters():
    env, buffer = _sample()
    actor = make_q_actor(env.observation_spec, env.action_spec, num_cells=[16])
    fused = fuse_dqn_loss(make_dqn_loss(actor, gamma=0.9))
    fused(buffer.sample())["loss"].backward()
    assert all(p.grad is not None for p in actor.parameters())


def test_losses_it_does_not_cover_are_left_to_the_loss_module():
    env, _ = _sample()
    noisy = make_q_actor(env.observation_spec, env.action_spec, noisy=True)
    assert fuse_dqn_loss(make_dqn_loss(noisy, gamma=0.9)) is None
    support = torch.linspace(0, 10, 11)
    c51 = make_q_actor(env.observation_spec, env.action_spec, support=support)
    assert fuse_dqn_loss(make_dqn_loss(c51, gamma=0.9)) is None


def test_the_loss_modules_pre_hooks_run_first_so_its_checks_still_hold():
    # make_dqn_loss without replay_buffer checks the first batch's n-step discount
    env, buffer = _sample(n_steps=3)  # the buffer discounts with 0.9
    actor = make_q_actor(env.observation_spec, env.action_spec, num_cells=[16])
    loss = make_dqn_loss(actor, gamma=0.99)
    fused = fuse_dqn_loss(make_dqn_loss(actor, gamma=0.99))  # the check runs once per loss
    with pytest.raises(ValueError) as theirs:
        loss(buffer.sample())
    with pytest.raises(ValueError) as ours:
        fused(buffer.sample())
    assert str(ours.value) == str(theirs.value)

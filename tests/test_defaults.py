"""Two sets of defaults: TorchRL's for a call made of TorchRL's arguments, this project's tuned
ones with ``tuned=True``.

A factory called with TorchRL's arguments alone behaves as the TorchRL class it builds
(checked here against that class, called the same way); ``tuned=True`` builds what the default
config builds (checked against ``trl_cartpole.run.build``), and the tuned values are the
schema's, one source for both.
"""

from __future__ import annotations

import inspect

import pytest
import torch
from tensordict.nn import TensorDictSequential
from torch import nn
from torchrl.collectors import Collector
from torchrl.data import LazyTensorStorage, TensorDictReplayBuffer
from torchrl.modules import MLP, EGreedyModule, QValueActor
from torchrl.objectives import DQNLoss, HardUpdate

from trl_cartpole.config.schema import Config
from trl_cartpole.parts.collectors import make_collector
from trl_cartpole.parts.env import make_env
from trl_cartpole.parts.exploration import make_exploration
from trl_cartpole.parts.losses import make_dqn_loss, make_target_updater
from trl_cartpole.parts.models import ACTIVATIONS, make_q_actor
from trl_cartpole.parts.optim import make_optimizer
from trl_cartpole.parts.replay import make_replay_buffer
from trl_cartpole.parts.tuned import TORCHRL, TUNED
from trl_cartpole.run.from_config import (
    build_actor,
    build_env,
    build_exploration,
    build_replay_buffer,
    torchrl_priority_exponent,
)


@pytest.fixture(scope="module")
def env():
    env = make_env("CartPole-v1", seed=0)
    yield env
    env.close()


def _default(cls, argument):
    return inspect.signature(cls).parameters[argument].default


# --- the TorchRL set is TorchRL's -----------------------------------------------------------


def test_the_torchrl_defaults_are_read_off_the_torchrl_classes(env):
    egreedy = TORCHRL["make_exploration"]
    for ours, theirs in (
        ("eps_init", "eps_init"),
        ("eps_end", "eps_end"),
        ("annealing_num_steps", "annealing_num_steps"),
    ):
        assert egreedy[ours] == _default(EGreedyModule, theirs)
    for argument in ("lr", "amsgrad", "weight_decay", "eps"):
        assert TORCHRL["make_optimizer"][argument] == _default(torch.optim.AdamW, argument)
    assert TORCHRL["make_target_updater"]["value_network_update_interval"] == _default(
        HardUpdate, "value_network_update_interval"
    )
    for argument in ("total_frames", "init_random_frames", "device"):
        assert TORCHRL["make_collector"][argument] == _default(Collector, argument)
    assert TORCHRL["make_dqn_loss"]["loss_function"] == _default(DQNLoss, "loss_function")
    stock = DQNLoss(QValueActor(MLP(in_features=4, out_features=2), spec=env.action_spec))
    td0_gamma = pytest.approx(stock.value_estimator.gamma.item())  # made on first use
    assert TORCHRL["make_dqn_loss"]["gamma"] == TORCHRL["make_replay_buffer"]["gamma"] == td0_gamma
    assert TORCHRL["make_q_actor"]["activation_class"] is _default(MLP, "activation_class")
    assert TORCHRL["make_q_actor"]["num_cells"] is _default(MLP, "num_cells")


def test_a_collector_from_torchrls_arguments_runs_as_torchrls_collector(env):
    actor = make_q_actor(env.observation_spec, env.action_spec)
    ours = make_collector(env, actor, frames_per_batch=50)
    theirs = Collector(env, actor, frames_per_batch=50, auto_register_policy_transforms=False)
    try:
        assert ours.total_frames == theirs.total_frames == float("inf")  # -1: endless
        assert ours.init_random_frames == theirs.init_random_frames  # the policy from frame 0
    finally:
        ours.shutdown()
        theirs.shutdown()
    with pytest.raises(TypeError, match=r"needs frames_per_batch= .* or tuned=True"):
        make_collector(env, actor)
    tuned = make_collector(env, actor, tuned=True)
    try:
        assert (tuned.frames_per_batch, tuned.total_frames) == (32, 50_016)  # whole batches
        assert tuned.init_random_frames == 1_024
    finally:
        tuned.shutdown()


def test_a_buffer_from_torchrls_arguments_samples_as_torchrls(env):
    rollout = env.rollout(20, break_when_any_done=False)
    ours = make_replay_buffer(storage=LazyTensorStorage(100))
    theirs = TensorDictReplayBuffer(storage=LazyTensorStorage(100))
    ours.extend(rollout)
    theirs.extend(rollout)
    assert ours.batch_size is theirs.batch_size is None
    for buffer in (ours, theirs):  # no batch size: TorchRL asks for one at sample()
        with pytest.raises(RuntimeError, match="batch_size"):
            buffer.sample()
    assert ours.sample(8).shape == (8,)
    assert make_replay_buffer()._storage.max_size == 1_000  # TorchRL's default capacity
    with pytest.raises(TypeError, match=r"needs alpha= and beta= .* or tuned=True"):
        make_replay_buffer(prioritized=True)


def test_exploration_from_torchrls_arguments_anneals_as_egreedy_module(env):
    ours, theirs = make_exploration(env.action_spec), EGreedyModule(env.action_spec)
    ours.step(1000)
    theirs.step(1000)
    assert ours.eps.item() == theirs.eps.item() == pytest.approx(0.1, rel=1e-3)
    tuned = make_exploration(env.action_spec, tuned=True)
    tuned.step(1000)
    assert tuned.eps.item() == pytest.approx(1.0 - 0.95 / 3, rel=1e-4)  # 1.0 -> 0.05 over 3 000


def test_a_loss_from_torchrls_arguments_is_dqnloss_with_its_defaults(env):
    torch.manual_seed(0)
    actor = make_q_actor(env.observation_spec, env.action_spec)
    ours, theirs = make_dqn_loss(actor), DQNLoss(actor)
    batch = env.rollout(16, actor, break_when_any_done=False)
    assert ours(batch.clone())["loss"].item() == pytest.approx(theirs(batch.clone())["loss"].item())
    assert ours.loss_function == theirs.loss_function == "l2"
    assert ours.value_estimator.gamma.item() == pytest.approx(0.99)
    # left to TorchRL's discount, the state loads strictly into a stock DQNLoss made the same way
    fresh_ours, fresh_theirs = make_dqn_loss(actor), DQNLoss(actor)
    fresh_theirs.load_state_dict(fresh_ours.state_dict())
    tuned = make_dqn_loss(actor, tuned=True)
    assert tuned.loss_function == "smooth_l1"
    assert tuned.value_estimator.gamma.item() == pytest.approx(0.995)


def test_target_updater_and_optimizer_from_torchrls_arguments(env):
    loss = make_dqn_loss(make_q_actor(env.observation_spec, env.action_spec))
    assert make_target_updater(loss).value_network_update_interval == (
        HardUpdate(loss).value_network_update_interval
    )
    with pytest.raises(TypeError, match=r"needs tau= or eps= .* or tuned=True"):
        make_target_updater(loss, kind="soft")
    assert make_target_updater(loss, kind="soft", tuned=True).eps == pytest.approx(0.98)
    params = list(nn.Linear(2, 2).parameters())
    ours, theirs = make_optimizer(params).defaults, torch.optim.AdamW(params).defaults
    for argument in ("lr", "betas", "eps", "weight_decay", "amsgrad"):
        assert ours[argument] == theirs[argument], argument


def test_an_actor_from_mlps_arguments_is_mlps(env):
    torch.manual_seed(0)
    ours = make_q_actor(env.observation_spec, env.action_spec, num_cells=[16])
    torch.manual_seed(0)
    theirs = QValueActor(MLP(in_features=4, out_features=2, num_cells=[16]), spec=env.action_spec)
    assert {type(m) for m in ours.modules()} & {nn.Tanh, nn.ReLU} == {nn.Tanh}
    a, b = ours.state_dict(), theirs.state_dict()
    assert a.keys() == b.keys() and all(torch.equal(a[k], b[k]) for k in a)


# --- the tuned set is the default config's ----------------------------------------------------


def test_the_tuned_values_are_the_default_configs():
    cfg = Config()
    expected = {
        "make_q_actor": {
            "num_cells": list(cfg.network.hidden_sizes),
            "activation_class": ACTIVATIONS[cfg.network.activation],
        },
        "make_exploration": {
            "eps_init": cfg.exploration.eps_start,
            "eps_end": cfg.exploration.eps_end,
            "annealing_num_steps": cfg.exploration.decay_frames,
        },
        "make_replay_buffer": {
            "max_size": cfg.buffer.size,
            "batch_size": cfg.buffer.batch_size,
            "alpha": torchrl_priority_exponent(cfg.buffer.alpha, False),
            "beta": cfg.buffer.beta,
            "eps": cfg.buffer.priority_eps,
            "gamma": cfg.loss.gamma,
        },
        "make_dqn_loss": {"gamma": cfg.loss.gamma, "loss_function": cfg.loss.loss_function},
        "make_target_updater": {
            "value_network_update_interval": cfg.loss.hard_update_interval - 1,
            "tau": cfg.loss.tau,
        },
        "make_optimizer": {
            "lr": cfg.optim.lr,
            "amsgrad": cfg.optim.amsgrad,
            "weight_decay": cfg.optim.weight_decay,
            "eps": cfg.optim.eps,
        },
        "make_collector": {
            "frames_per_batch": cfg.collector.frames_per_batch,
            "total_frames": cfg.collector.total_frames,
            "init_random_frames": cfg.collector.init_random_frames,
            "device": cfg.device,
        },
    }
    assert expected == TUNED
    assert cfg.loss.target_update == "hard" and not cfg.loss.double_dqn


def test_tuned_factories_build_the_default_configs_actor_exploration_and_buffer():
    cfg = Config()
    env = build_env(cfg, seed=0, num_envs=1)
    torch.manual_seed(0)
    from_config = build_actor(cfg, env)
    torch.manual_seed(0)
    tuned = make_q_actor(env.observation_spec, env.action_spec, tuned=True)
    a, b = from_config.state_dict(), tuned.state_dict()
    assert a.keys() == b.keys() and all(torch.equal(a[k], b[k]) for k in a)

    configured, default = build_exploration(cfg, env), make_exploration(env.action_spec, tuned=True)
    assert type(configured) is type(default)
    assert (configured.eps_init, configured.eps_end, configured.annealing_num_steps) == (
        default.eps_init,
        default.eps_end,
        default.annealing_num_steps,
    )
    configured = build_replay_buffer(cfg)
    tuned = make_replay_buffer(n_steps=cfg.buffer.n_steps, tuned=True)  # n_steps: 1 unless asked
    assert type(configured) is type(tuned)
    assert configured._storage.max_size == tuned._storage.max_size == cfg.buffer.size
    assert configured.batch_size == tuned.batch_size == cfg.buffer.batch_size
    assert configured._transform[0].gamma == tuned._transform[0].gamma == cfg.loss.gamma
    prioritized = make_replay_buffer(prioritized=True, tuned=True)
    assert prioritized.sampler.alpha == pytest.approx(
        build_replay_buffer(Config(buffer=type(cfg.buffer)(prioritized=True))).sampler.alpha
    )


def test_an_argument_given_wins_over_tuned(env):
    explore = make_exploration(env.action_spec, eps_end=0.2, tuned=True)
    assert explore.eps_end.item() == pytest.approx(0.2)
    assert explore.annealing_num_steps == 3000
    policy = TensorDictSequential(make_q_actor(env.observation_spec, env.action_spec))
    collector = make_collector(env, policy, frames_per_batch=8, total_frames=16, tuned=True)
    try:
        assert collector.total_frames == 16 and collector.init_random_frames == 1_000 // 8 * 8
    finally:
        collector.shutdown()

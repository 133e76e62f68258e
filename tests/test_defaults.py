"""One home for each default: a factory's are the TorchRL class's, the default run's are the
schema's, and a config section's keys are its factory's keywords.

A factory called with TorchRL's arguments alone behaves as the TorchRL class it builds (checked
here against that class, called the same way); called with its config section
(``make_x(**cfg.x)``), it builds what the pipeline builds.
"""

from __future__ import annotations

import inspect
from dataclasses import asdict

import pytest
import torch
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
from trl_cartpole.parts.models import make_q_actor
from trl_cartpole.parts.optim import make_optimizer
from trl_cartpole.parts.replay import make_replay_buffer
from trl_cartpole.run.from_config import (
    build_actor,
    build_exploration,
    build_learner,
    build_replay_buffer,
)


@pytest.fixture(scope="module")
def env():
    env = make_env("CartPole-v1", seed=0)
    yield env
    env.close()


def _default(function, argument):
    return inspect.signature(function).parameters[argument].default


# --- a factory's defaults are the TorchRL class's ----------------------------------------------


def test_the_factories_defaults_are_read_off_the_torchrl_classes():
    for argument in ("eps_init", "eps_end", "annealing_num_steps"):
        assert _default(make_exploration, argument) == _default(EGreedyModule, argument)
    for argument in ("lr", "amsgrad", "weight_decay", "eps"):
        assert _default(make_optimizer, argument) == _default(torch.optim.AdamW, argument)
    for argument in ("total_frames", "init_random_frames", "device"):
        assert _default(make_collector, argument) == _default(Collector, argument)
    assert _default(make_q_actor, "activation_class") is _default(MLP, "activation_class")
    assert _default(make_q_actor, "num_cells") is _default(MLP, "num_cells")


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
    with pytest.raises(TypeError, match="frames_per_batch"):
        make_collector(env, actor)


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
    with pytest.raises(TypeError, match=r"needs alpha= and beta="):
        make_replay_buffer(prioritized=True)


def test_exploration_from_torchrls_arguments_anneals_as_egreedy_module(env):
    ours, theirs = make_exploration(env.action_spec), EGreedyModule(env.action_spec)
    ours.step(1000)
    theirs.step(1000)
    assert ours.eps.item() == theirs.eps.item() == pytest.approx(0.1, rel=1e-3)


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


def test_target_updater_and_optimizer_from_torchrls_arguments(env):
    loss = make_dqn_loss(make_q_actor(env.observation_spec, env.action_spec))
    assert make_target_updater(loss).value_network_update_interval == (
        HardUpdate(loss).value_network_update_interval
    )
    with pytest.raises(TypeError, match=r"needs tau= or eps="):
        make_target_updater(loss, kind="soft")
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


# --- a config section is its factory's keywords -------------------------------------------------

# the keys of each section that are the run's, not its factory's (the schema marks them)
RUN_KEYS = {
    "network": {"distributional", "atoms", "v_min", "v_max"},  # make_q_actor's support=
    "exploration": set(),
    "buffer": {"storage", "beta_anneal_frames", "pixels_shift"},
    "loss": set(),
    "target_updater": set(),
    "optim": {"grad_clip", "max_grad", "lr_end", "lr_decay_frames", "autocast"},
    "collector": {
        "max_train_seconds",
        "updates_per_batch",
        "learning_starts",
        "workers",
        "ray_resources",
        "ray_runtime_env",
    },
}
FACTORIES = {
    "network": make_q_actor,
    "exploration": make_exploration,
    "buffer": make_replay_buffer,
    "loss": make_dqn_loss,
    "target_updater": make_target_updater,
    "optim": make_optimizer,
    "collector": make_collector,
}


@pytest.mark.parametrize("section", sorted(FACTORIES))
def test_every_key_of_a_section_is_a_keyword_of_its_factory(section):
    keys = set(asdict(getattr(Config(), section))) - RUN_KEYS[section]
    parameters = set(inspect.signature(FACTORIES[section]).parameters)
    assert keys <= parameters, sorted(keys - parameters)


def test_a_factory_given_its_section_builds_what_the_pipeline_builds(env):
    cfg = Config()
    network = {k: v for k, v in asdict(cfg.network).items() if k not in RUN_KEYS["network"]}
    network.pop("cnn_kwargs")  # the MLP torso's run passes none
    torch.manual_seed(0)
    built = build_actor(cfg, env)
    torch.manual_seed(0)
    made = make_q_actor(env.observation_spec, env.action_spec, **network)
    a, b = built.state_dict(), made.state_dict()
    assert a.keys() == b.keys() and all(torch.equal(a[k], b[k]) for k in a)

    built, made = (
        build_exploration(cfg, env),
        make_exploration(env.action_spec, **asdict(cfg.exploration)),
    )
    assert type(built) is type(made)
    for name in ("eps_init", "eps_end"):
        assert getattr(built, name).item() == getattr(made, name).item()
    assert built.annealing_num_steps == made.annealing_num_steps == 3000

    buffer = {k: v for k, v in asdict(cfg.buffer).items() if k not in RUN_KEYS["buffer"]}
    buffer.update(prioritized=False, alpha=None, beta=None, eps=None)
    built, made = build_replay_buffer(cfg), make_replay_buffer(**buffer, gamma=cfg.loss.gamma)
    assert built.batch_size == made.batch_size == 512
    assert built._storage.max_size == made._storage.max_size == 50_000
    assert built._transform[0].gamma == made._transform[0].gamma == pytest.approx(0.995)

    learner = build_learner(cfg, built_actor := build_actor(cfg, env), build_replay_buffer(cfg))
    loss = make_dqn_loss(built_actor, **asdict(cfg.loss))
    assert (loss.loss_function, loss.double_dqn) == (learner.loss.loss_function, False)
    updater = make_target_updater(loss, **asdict(cfg.target_updater))
    assert type(updater) is type(learner.target_updater) is HardUpdate
    assert updater.value_network_update_interval == 49  # a copy every 50 updates
    optim = {k: v for k, v in asdict(cfg.optim).items() if k not in RUN_KEYS["optim"]}
    made = make_optimizer(built_actor.parameters(), **optim).defaults
    for name in ("lr", "amsgrad", "weight_decay", "eps"):
        assert made[name] == learner.optimizer.defaults[name], name


def test_an_old_keyword_gets_pythons_own_type_error(env):
    loss = make_dqn_loss(make_q_actor(env.observation_spec, env.action_spec))
    with pytest.raises(TypeError, match="unexpected keyword argument 'hard_update_interval'"):
        make_target_updater(loss, hard_update_interval=50)
    with pytest.raises(TypeError, match="positional argument"):
        make_optimizer(nn.Linear(2, 2).parameters(), 1e-3, True)
    with pytest.raises(TypeError, match="unexpected keyword argument 'tuned'"):
        make_replay_buffer(tuned=True)

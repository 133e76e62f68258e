"""One set of defaults: a factory's defaults are the default config's, except where TorchRL's
behaviour comes first (named here).

The config's schema (``trl_cartpole.config.schema``) holds the defaults of
``python scripts/train.py``; each factory's keyword defaults must equal the schema field it is
built from (the mapping below is the one ``trl_cartpole.run.build`` uses). The one difference:
``make_replay_buffer`` stores one-step transitions unless ``n_steps`` is given (TorchRL's
behaviour), the config 3-step ones.
"""

from __future__ import annotations

import inspect

import pytest
import torch
from torchrl.objectives import HardUpdate

from trl_cartpole.config.schema import Config
from trl_cartpole.parts.collectors import make_collector
from trl_cartpole.parts.env import make_env
from trl_cartpole.parts.exploration import make_exploration
from trl_cartpole.parts.losses import make_dqn_loss, make_target_updater
from trl_cartpole.parts.models import ACTIVATIONS, make_q_actor
from trl_cartpole.parts.optim import make_optimizer, make_update
from trl_cartpole.parts.replay import make_replay_buffer
from trl_cartpole.run.build import build_actor, build_env, build_exploration, build_replay_buffer

# factory -> {argument: config field}
FACTORY_FIELDS = {
    make_env: {"env_name": "env.id", "max_episode_steps": "env.max_episode_steps"},
    make_q_actor: {
        "num_cells": "network.hidden_sizes",
        "head": "network.head",
        "noisy": "network.noisy",
        "noisy_std": "network.noisy_std",
    },
    make_exploration: {
        "schedule": "exploration.schedule",
        "eps_init": "exploration.eps_start",
        "eps_end": "exploration.eps_end",
        "annealing_num_steps": "exploration.decay_frames",
    },
    make_replay_buffer: {
        "max_size": "buffer.size",
        "batch_size": "buffer.batch_size",
        "prioritized": "buffer.prioritized",
    },
    make_dqn_loss: {"delay_value": None},  # the target network (TorchRL's default too)
    make_optimizer: {
        "lr": "optim.lr",
        "amsgrad": "optim.amsgrad",
        "weight_decay": "optim.weight_decay",
        "eps": "optim.eps",
    },
    make_update: {"grad_clip": "optim.grad_clip", "max_grad": "optim.max_grad"},
    make_collector: {
        "frames_per_batch": "collector.frames_per_batch",
        "total_frames": "collector.total_frames",
        "init_random_frames": "collector.init_random_frames",
        "sync": "collector.sync",
        "backend": "collector.backend",
        "ray_address": "collector.ray_address",
    },
}


def _schema_default(dotted: str | None):
    if dotted is None:  # a TorchRL default the config has no field for
        return True
    value = Config()
    for part in dotted.split("."):
        value = getattr(value, part)
    return tuple(value) if isinstance(value, list) else value


@pytest.mark.parametrize("factory", list(FACTORY_FIELDS), ids=lambda f: f.__name__)
def test_factory_defaults_equal_the_default_config(factory):
    parameters = inspect.signature(factory).parameters
    for argument, field in FACTORY_FIELDS[factory].items():
        default = parameters[argument].default
        default = tuple(default) if isinstance(default, list) else default
        assert default == _schema_default(field), f"{factory.__name__}({argument}) vs {field}"


def test_the_defaults_resolved_inside_the_factories_are_the_configs():
    """Defaults that are None in a signature (they depend on other arguments) resolve here."""
    cfg = Config()
    env = build_env(cfg, seed=0, num_envs=1)
    actor = make_q_actor(env.observation_spec, env.action_spec)
    activations = {type(m) for m in actor.modules()} & set(ACTIVATIONS.values())
    assert activations == {ACTIVATIONS[cfg.network.activation]}
    loss = make_dqn_loss(actor)
    assert loss.value_estimator.gamma.item() == pytest.approx(cfg.loss.gamma)
    assert loss.loss_function == cfg.loss.loss_function
    assert loss.double_dqn is cfg.loss.double_dqn
    # the config's target update is hard, a copy every loss.hard_update_interval updates
    updater = make_target_updater(loss)
    assert cfg.loss.target_update == "hard" and isinstance(updater, HardUpdate)
    assert updater.value_network_update_interval == cfg.loss.hard_update_interval - 1
    assert make_target_updater(loss, kind="soft").eps == pytest.approx(1 - cfg.loss.tau)


def test_default_factories_build_the_default_configs_actor_exploration_and_buffer():
    cfg = Config()
    env = build_env(cfg, seed=0, num_envs=1)
    torch.manual_seed(0)
    from_config = build_actor(cfg, env)
    torch.manual_seed(0)
    from_defaults = make_q_actor(env.observation_spec, env.action_spec)
    a, b = from_config.state_dict(), from_defaults.state_dict()
    assert a.keys() == b.keys() and all(torch.equal(a[k], b[k]) for k in a)

    configured, default = build_exploration(cfg, env), make_exploration(env.action_spec)
    assert type(configured) is type(default)
    assert (configured.eps_init, configured.eps_end, configured.annealing_num_steps) == (
        default.eps_init,
        default.eps_end,
        default.annealing_num_steps,
    )
    assert make_replay_buffer()._transform is None or not len(make_replay_buffer()._transform)
    configured = build_replay_buffer(cfg)
    default = make_replay_buffer(n_steps=cfg.buffer.n_steps)  # 1 unless asked (TorchRL's)
    assert type(configured) is type(default)
    assert configured._storage.max_size == default._storage.max_size == cfg.buffer.size
    assert configured.batch_size == default.batch_size == cfg.buffer.batch_size
    assert len(configured._transform) == len(default._transform) == 1  # the 3-step transform


def test_the_replay_buffers_resolved_defaults_are_the_configs():
    """alpha, beta, eps and gamma are None in the signature (refused where they do not apply)
    and resolve to the config's: alpha as TorchRL's exponent on DQNLoss's td_error = delta ** 2,
    half the config's exponent on |delta|."""
    from trl_cartpole.parts import replay
    from trl_cartpole.run.build import torchrl_priority_exponent

    cfg = Config()
    assert cfg.loss.gamma == replay.DEFAULT_GAMMA
    assert cfg.buffer.beta == replay.DEFAULT_BETA
    assert cfg.buffer.priority_eps == replay.DEFAULT_PRIORITY_EPS
    assert torchrl_priority_exponent(cfg.buffer.alpha, False) == replay.DEFAULT_ALPHA
    prioritized = make_replay_buffer(prioritized=True)
    assert prioritized.sampler.alpha == pytest.approx(
        build_replay_buffer(Config(buffer=type(cfg.buffer)(prioritized=True))).sampler.alpha
    )

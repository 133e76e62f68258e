"""Each factory returns the stock TorchRL object with the expected specs, shapes and keys."""

from __future__ import annotations

import math

import pytest
import torch
from tensordict import TensorDict
from torch import nn
from torchrl.collectors import Collector
from torchrl.data import LazyTensorStorage, OneHot, TensorDictReplayBuffer
from torchrl.envs import RewardSum, StepCounter, TransformedEnv
from torchrl.modules import EGreedyModule, QValueActor
from torchrl.objectives import DQNLoss, HardUpdate, SoftUpdate

from trl_cartpole.envs.ids import solve_threshold
from trl_cartpole.parts.collectors import make_collector
from trl_cartpole.parts.env import make_env
from trl_cartpole.parts.exploration import ExponentialEGreedyModule, make_exploration
from trl_cartpole.parts.losses import make_dqn_loss, make_target_updater
from trl_cartpole.parts.models import make_q_actor
from trl_cartpole.parts.replay import make_replay_buffer, sample_minibatches


@pytest.fixture(scope="module")
def env():
    env = make_env("CartPole-v1", seed=0)
    yield env
    env.close()


def test_env_is_transformed_gym_env_with_counters(env):
    assert isinstance(env, TransformedEnv)
    kinds = {type(t) for t in env.transform}
    assert {StepCounter, RewardSum} <= kinds
    assert env.observation_spec["observation"].shape == torch.Size([4])
    assert isinstance(env.action_spec, OneHot) and env.action_spec.space.n == 2
    rollout = env.rollout(5)
    assert rollout["next", "step_count"].squeeze(-1).tolist()[:3] == [1, 2, 3]
    assert rollout["next", "episode_reward"].squeeze(-1).tolist()[:3] == [1.0, 2.0, 3.0]


def test_env_seed_makes_reset_reproducible():
    first = make_env("CartPole-v1", seed=7).reset()["observation"]
    second = make_env("CartPole-v1", seed=7).reset()["observation"]
    other = make_env("CartPole-v1", seed=8).reset()["observation"]
    assert torch.equal(first, second)
    assert not torch.equal(first, other)


def test_batched_env_has_batch_dim():
    env = make_env("CartPole-v1", seed=0, num_envs=3)
    assert env.batch_size == torch.Size([3])
    assert env.reset()["observation"].shape == torch.Size([3, 4])


def test_solve_threshold_comes_from_gymnasium_unless_overridden():
    assert solve_threshold("CartPole-v1") == 475.0
    assert solve_threshold("CartPole-v1", 100) == 100.0


def test_q_actor_shapes_and_hidden_sizes(env):
    actor = make_q_actor(env.observation_spec, env.action_spec, num_cells=[32, 16])
    assert isinstance(actor, QValueActor)
    linears = [m for m in actor.modules() if isinstance(m, nn.Linear)]
    assert [(m.in_features, m.out_features) for m in linears] == [(4, 32), (32, 16), (16, 2)]
    td = actor(TensorDict({"observation": torch.randn(5, 4)}, batch_size=[5]))
    assert td["action_value"].shape == torch.Size([5, 2])
    assert td["chosen_action_value"].shape == torch.Size([5, 1])
    # The greedy action is the one-hot arg-max of the action values.
    expected = torch.nn.functional.one_hot(td["action_value"].argmax(-1), 2)
    assert torch.equal(td["action"], expected)


def test_unknown_head_lists_known_names_in_python_words(env):
    with pytest.raises(ValueError, match=r"^head='nope' .* choose one of \['dueling', 'plain'\]"):
        make_q_actor(env.observation_spec, env.action_spec, head="nope")


def test_exponential_schedule_matches_tutorial_formula(env):
    module = make_exploration(env.action_spec, 0.9, 0.05, 1000, schedule="exponential")
    assert isinstance(module, ExponentialEGreedyModule)
    assert isinstance(module, EGreedyModule)
    assert module.eps.item() == pytest.approx(0.9)
    module.step(1000)  # 0.05 + 0.85 * e^-1
    assert module.eps.item() == pytest.approx(0.36269752, abs=1e-6)
    module.step(1000)  # 0.05 + 0.85 * e^-2
    assert module.eps.item() == pytest.approx(0.16503499, abs=1e-6)
    module.step(100_000)
    assert module.eps.item() == pytest.approx(0.05, abs=1e-6)
    # The frame counter travels with the state_dict (resume keeps the schedule).
    assert module.state_dict()["frames"].item() == 102_000


def test_linear_schedule_is_torchrl_annealing(env):
    module = make_exploration(env.action_spec, 1.0, 0.05, 100)
    assert type(module) is EGreedyModule
    module.step(50)
    assert module.eps.item() == pytest.approx(1.0 - 50 * 0.95 / 100, abs=1e-5)
    module.step(1000)
    assert module.eps.item() == pytest.approx(0.05, abs=1e-6)


def test_exploration_eps_one_is_uniform_and_zero_is_greedy(env):
    torch.manual_seed(0)
    actor = make_q_actor(env.observation_spec, env.action_spec)
    td = TensorDict({"observation": torch.zeros(2000, 4)}, batch_size=[2000])
    greedy = actor(td.clone())["action"][0].argmax().item()
    always_random = make_exploration(env.action_spec, 1.0, 1.0, 1)
    chosen = always_random(actor(td.clone()))["action"].argmax(-1)
    share_greedy = (chosen == greedy).float().mean().item()
    assert 0.45 < share_greedy < 0.55
    never_random = make_exploration(env.action_spec, 0.0, 0.0, 1)
    chosen = never_random(actor(td.clone()))["action"].argmax(-1)
    assert (chosen == greedy).all()


def test_replay_buffer_is_lazy_tensor_storage(env):
    buffer = make_replay_buffer(max_size=10, batch_size=4, n_steps=1)
    assert isinstance(buffer, TensorDictReplayBuffer)
    assert isinstance(buffer._storage, LazyTensorStorage)
    buffer.extend(env.rollout(15, break_when_any_done=False))
    assert len(buffer) == 10  # capacity bounds the storage
    sample = buffer.sample()
    assert sample.batch_size == torch.Size([4])
    assert sample["next", "observation"].shape == torch.Size([4, 4])


def test_loss_and_target_updaters(env):
    actor = make_q_actor(env.observation_spec, env.action_spec)
    loss = make_dqn_loss(actor, gamma=0.9)
    assert isinstance(loss, DQNLoss)
    assert type(make_target_updater(loss, tau=0.1)) is SoftUpdate  # the stock one
    assert isinstance(make_target_updater(loss, value_network_update_interval=2), HardUpdate)


def test_soft_update_moves_target_by_tau(env):
    """theta' <- tau * theta + (1 - tau) * theta'."""
    actor = make_q_actor(env.observation_spec, env.action_spec, num_cells=[8])
    loss = make_dqn_loss(actor)
    updater = make_target_updater(loss, tau=0.25)
    target = loss.target_value_network_params
    online = loss.value_network_params
    target.apply(lambda t: t.data.fill_(0.0))
    online.apply(lambda t: t.data.fill_(2.0))
    updater.step()
    values = torch.cat([t.flatten() for t in target.values(True, True)])
    assert torch.allclose(values, torch.full_like(values, 0.5))  # 0.25 * 2 + 0.75 * 0


def test_hard_update_copies_every_interval(env):
    actor = make_q_actor(env.observation_spec, env.action_spec, num_cells=[8])
    loss = make_dqn_loss(actor)
    updater = make_target_updater(loss, value_network_update_interval=2)
    target = loss.target_value_network_params
    loss.value_network_params.apply(lambda t: t.data.fill_(1.0))
    target.apply(lambda t: t.data.fill_(0.0))
    updater.step()
    updater.step()
    assert all((t == 0).all() for t in target.values(True, True))
    updater.step()
    assert all((t == 1).all() for t in target.values(True, True))
    target.apply(lambda t: t.data.fill_(0.0))
    updater.step()
    updater.step()
    assert all((t == 0).all() for t in target.values(True, True))
    updater.step()  # the 6th update: copied again
    assert all((t == 1).all() for t in target.values(True, True))


def test_collector_yields_batches_of_frames_per_batch(env):
    actor = make_q_actor(env.observation_spec, env.action_spec)
    collector = make_collector(
        env, actor, frames_per_batch=8, total_frames=24, init_random_frames=0
    )
    assert isinstance(collector, Collector)
    sizes = [batch.numel() for batch in collector]
    collector.shutdown()
    assert sizes == [8, 8, 8]
    assert math.isclose(sum(sizes), 24)


def test_minibatches_of_one_draw_are_uniform_and_prioritized_ones_are_drawn_one_by_one():
    uniform = make_replay_buffer(max_size=1000, batch_size=8, n_steps=1)
    uniform.extend(TensorDict(x=torch.arange(100.0)[:, None], batch_size=[100]))
    torch.manual_seed(0)
    batches = list(sample_minibatches(uniform, 5))
    assert [b.shape for b in batches] == [torch.Size([8])] * 5
    drawn = torch.cat([b["x"] for b in batches]).flatten()  # 40 indices with replacement
    assert drawn.min() >= 0 and drawn.max() < 100 and len(drawn.unique()) > 20
    prioritized = make_replay_buffer(
        max_size=1000, batch_size=8, prioritized=True, alpha=0.3, beta=0.4, n_steps=1
    )
    prioritized.extend(TensorDict(x=torch.arange(100.0)[:, None], batch_size=[100]))
    batches = list(sample_minibatches(prioritized, 3))
    assert len(batches) == 3 and all("priority_weight" in b for b in batches)

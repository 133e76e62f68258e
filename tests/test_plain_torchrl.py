"""The factories as an experienced TorchRL user calls them: TorchRL's call forms, TorchRL's
behaviour for TorchRL's arguments, trained policies in plain TorchRL."""

from __future__ import annotations

import subprocess
import sys
import textwrap

import pytest
import torch
from tensordict import TensorDict
from tensordict.nn import TensorDictSequential
from torch import nn
from torchrl.checkpoint import Checkpoint
from torchrl.data import (
    Composite,
    LazyTensorStorage,
    OneHot,
    PrioritizedSampler,
    TensorDictReplayBuffer,
    Unbounded,
)
from torchrl.envs import Transform
from torchrl.modules import MLP, EGreedyModule, QValueActor
from torchrl.objectives import SoftUpdate

from trl_cartpole import choices
from trl_cartpole.parts.collectors import make_collector
from trl_cartpole.parts.env import make_env
from trl_cartpole.parts.exploration import make_exploration
from trl_cartpole.parts.losses import make_dqn_loss, make_target_updater
from trl_cartpole.parts.models import ACTIVATIONS, HEADS, DuelingHead, make_q_actor
from trl_cartpole.parts.optim import make_optimizer, make_update
from trl_cartpole.parts.replay import make_replay_buffer
from trl_cartpole.run.learner import Learner
from trl_cartpole.run.progress import Progress


@pytest.fixture(scope="module")
def env():
    env = make_env("CartPole-v1", seed=0)
    yield env
    env.close()


# --- TorchRL's own call forms --------------------------------------------------------------------


def test_a_callable_env_maker_is_taken_as_torchrls_collector_takes_it(env):
    actor = make_q_actor(env.observation_spec, env.action_spec)
    collector = make_collector(
        lambda: make_env("CartPole-v1", seed=0), actor, frames_per_batch=8, total_frames=16
    )
    try:
        assert [batch.numel() for batch in collector] == [8, 8]
    finally:
        collector.shutdown()


def test_module_is_the_whole_q_network_as_qvalueactor_takes_it(env):
    net = nn.Sequential(nn.Linear(4, 8), nn.Tanh(), nn.Linear(8, 2))
    for actor in (
        make_q_actor(spec=env.action_spec, module=net),
        make_q_actor(net, env.action_spec),
    ):
        assert isinstance(actor, QValueActor)
        td = actor(env.reset())
        assert torch.equal(td["action_value"], net(td["observation"]))
    with pytest.raises(TypeError, match=r"module= is your whole Q-network, so the arguments"):
        make_q_actor(spec=env.action_spec, module=net, head="dueling")


def test_your_own_torso_goes_under_the_factorys_mlp_and_head(env):
    torso = nn.Sequential(nn.Linear(4, 24), nn.ELU())  # [*B, 4] -> [*B, 24]
    actor = make_q_actor(
        env.observation_spec, env.action_spec, torso=torso, num_cells=[16], head="dueling"
    )
    assert any(module is torso for module in actor.modules())
    first_mlp_layer = next(m for m in actor.modules() if isinstance(m, MLP))[0]
    assert first_mlp_layer.in_features == 24  # the torso's width, found on the spec
    assert actor(env.reset().expand(5).clone())["action_value"].shape == (5, 2)


def test_a_composite_spec_holding_the_action_is_taken_as_qvalueactor_takes_it(env):
    actor = make_q_actor(env.observation_spec, spec=Composite(action=OneHot(2)))
    assert actor(env.reset())["action"].shape == (2,)


def test_num_cells_is_read_as_torchrls_mlp_reads_it(env):
    with pytest.raises(ValueError, match=r"num_cells=64 is one width: give depth="):
        make_q_actor(env.observation_spec, env.action_spec, num_cells=64)
    two = make_q_actor(env.observation_spec, env.action_spec, num_cells=64, depth=2)
    widths = [m.out_features for m in two.modules() if isinstance(m, nn.Linear)]
    assert widths == [64, 64, 2]
    torch.manual_seed(0)
    linear = make_q_actor(env.observation_spec, env.action_spec, num_cells=[])
    torch.manual_seed(0)
    reference = MLP(in_features=4, out_features=2, num_cells=[])  # TorchRL: one linear layer
    assert [type(m) for m in linear.modules() if isinstance(m, nn.Linear)] == [nn.Linear]
    assert linear.state_dict()["module.0.module.0.weight"].equal(reference[0].weight)


def test_each_head_and_activation_the_config_accepts_builds_its_torch_module():
    assert {"elu": nn.ELU, "gelu": nn.GELU, "relu": nn.ReLU, "tanh": nn.Tanh} == ACTIVATIONS
    env = make_env("CartPole-v1")
    built = {
        head: make_q_actor(env.observation_spec, env.action_spec, num_cells=[8], head=head)
        for head in choices.HEADS
    }
    assert set(built) == set(HEADS) == {"plain", "dueling"}
    assert any(isinstance(m, DuelingHead) for m in built["dueling"].modules())
    assert not any(isinstance(m, DuelingHead) for m in built["plain"].modules())


# --- nothing changed behind the user's back ------------------------------------------------------


@pytest.mark.parametrize(
    "first",
    [
        # fresh interpreters entered by three doors (seconds each)
        pytest.param("import trl_cartpole.parts", marks=pytest.mark.slow),
        pytest.param("from trl_cartpole import make_env", marks=pytest.mark.slow),
        pytest.param("import trl_cartpole.run.build", marks=pytest.mark.slow),
    ],
)
def test_a_users_own_prioritized_sampler_works_in_a_fresh_process(first):
    """Whichever part of the package is imported first, TorchRL's own PrioritizedSampler works
    (the stand-in trees are given in one place, ``import trl_cartpole.parts``)."""
    script = textwrap.dedent(
        f"""
        {first}
        import torch
        from tensordict import TensorDict
        from torchrl.data import LazyTensorStorage, PrioritizedSampler, TensorDictReplayBuffer
        rb = TensorDictReplayBuffer(
            storage=LazyTensorStorage(10), sampler=PrioritizedSampler(10, 0.6, 0.4), batch_size=4
        )
        rb.extend(TensorDict(x=torch.arange(10.0), batch_size=[10]))
        print(rb.sample()["x"].shape[0])
        """
    )
    done = subprocess.run(
        [sys.executable, "-c", script], capture_output=True, text=True, timeout=120
    )
    assert done.returncode == 0, done.stderr[-2000:]
    assert done.stdout.strip().splitlines()[-1] == "4"


def test_torchrls_arguments_alone_build_a_one_step_buffer(env):
    buffer = make_replay_buffer(storage=LazyTensorStorage(1000), batch_size=8)
    rollout = env.rollout(200, break_when_any_done=False)  # [200]
    buffer.extend(rollout)
    assert len(buffer) == 200
    assert torch.equal(buffer[:]["next", "reward"], rollout["next", "reward"])  # 1.0 each


class _Double(Transform):
    """A user's transform: doubles the reward on the way in."""

    def _inv_call(self, tensordict):
        tensordict.set(("next", "reward"), tensordict["next", "reward"] * 2)
        return tensordict


def test_a_users_transform_is_the_buffers_only_transform_unless_n_steps_is_asked(env):
    buffer = make_replay_buffer(batch_size=8, transform=_Double())
    buffer.extend(env.rollout(10, break_when_any_done=False))
    assert buffer[:]["next", "reward"].unique().tolist() == [2.0]


def test_sampler_arguments_without_a_prioritized_sampler_are_refused_as_torchrl_refuses_them():
    with pytest.raises(ValueError, match=r"alpha, beta: the prioritized sampler's"):
        make_replay_buffer(alpha=0.6, beta=0.4)
    with pytest.raises(ValueError, match=r"gamma=0\.9 discounts n-step returns"):
        make_replay_buffer(gamma=0.9)


def test_a_users_own_prioritized_sampler_is_used_as_given(env):
    sampler = PrioritizedSampler(100, alpha=0.7, beta=0.5)
    buffer = make_replay_buffer(sampler=sampler, batch_size=8)
    assert isinstance(buffer, TensorDictReplayBuffer) and buffer.sampler is sampler
    buffer.extend(env.rollout(20, break_when_any_done=False))
    assert buffer.sample()["priority_weight"].shape == (8,)


# --- one priority rule --------------------------------------------------------------------------


def test_the_pipelines_learner_writes_the_priorities_torchrls_way():
    """Learner.step stores (td_error + eps) ** alpha, td_error = delta ** 2 (by hand, lr 0)."""
    net = nn.Linear(2, 2, bias=False)
    with torch.no_grad():
        net.weight.copy_(torch.tensor([[1.0, 0.0], [0.0, 2.0]]))
    actor = QValueActor(net, in_keys=["observation"], spec=OneHot(2))
    observation = torch.tensor([[1.0, 0.0], [0.0, 1.0], [1.0, 1.0], [2.0, 0.0]])  # [4, 2]
    batch = TensorDict(
        {
            "observation": observation,
            "action": nn.functional.one_hot(torch.tensor([0, 1, 1, 0]), 2),
            "next": {
                "observation": torch.zeros(4, 2),  # max_a Q(s', a) = 0: y = r
                "reward": torch.tensor([[0.0], [1.0], [0.5], [3.0]]),
                "done": torch.zeros(4, 1, dtype=torch.bool),
                "terminated": torch.zeros(4, 1, dtype=torch.bool),
            },
        },
        batch_size=[4],
    )
    # Q(s, a) of the actions taken: 1, 2, 2, 2; delta = y - Q = -1, -1, -1.5, 1
    delta = torch.tensor([-1.0, -1.0, -1.5, 1.0])
    alpha, eps = 0.3, 1e-6
    buffer = make_replay_buffer(batch_size=4, prioritized=True, alpha=alpha, beta=0.4, eps=eps)
    buffer.extend(batch)
    loss = make_dqn_loss(actor, gamma=0.9, loss_function="l2")
    optimizer = torch.optim.SGD(net.parameters(), lr=0.0)
    update = make_update(loss, optimizer, grad_clip="none")
    learner = Learner(buffer, loss, make_target_updater(loss, tau=0.5), optimizer, update)
    for seed in range(10):  # the prioritized draw: 4 of 4 with replacement; lr 0: same deltas
        torch.manual_seed(seed)
        learner.step(1, Progress())
        sampled = learner.last_report.last_sample["index"].unique()  # only these were written
        if len(sampled) >= 2:
            break
    stored = torch.as_tensor(buffer.sampler._sum_tree[torch.arange(4)], dtype=torch.float32)
    assert len(sampled) >= 2
    assert torch.allclose(stored[sampled], ((delta**2 + eps) ** alpha)[sampled], rtol=1e-5)


# --- trained policies in plain TorchRL ----------------------------------------------------------


def test_a_trained_policy_loads_into_an_actor_built_with_torchrl_alone(smoke_checkpoint):
    from trl_cartpole.store.checkpoint import read_checkpoint_config

    cfg = read_checkpoint_config(smoke_checkpoint)
    plain = QValueActor(
        MLP(
            in_features=4,
            out_features=2,
            num_cells=list(cfg.network.num_cells),
            activation_class=nn.ReLU,  # MLP's default is Tanh
        ),
        in_keys=["observation"],
        spec=OneHot(2),
    )
    before = [p.clone() for p in plain.parameters()]
    Checkpoint(policy=plain).load(smoke_checkpoint, components=["policy"])
    assert any(not torch.equal(a, b) for a, b in zip(before, plain.parameters(), strict=True))
    from trl_cartpole.policy.load import load_trained_policy

    trained = load_trained_policy(smoke_checkpoint)
    observation = trained.env.reset()
    trained.env.close()
    assert torch.equal(
        plain(observation.clone())["action_value"], trained.actor(observation)["action_value"]
    )


def test_a_subclass_the_factories_return_is_accepted_where_its_base_is(env):
    """ExponentialEGreedyModule is an EGreedyModule: TorchRL's own composition takes it, and the
    SoftUpdate the factory builds moves the target."""
    actor = make_q_actor(env.observation_spec, env.action_spec)
    exploration = make_exploration(env.action_spec, schedule="exponential")
    policy = TensorDictSequential(actor, exploration)
    assert policy(env.reset())["action"].shape == (2,)
    loss = make_dqn_loss(actor)
    updater = make_target_updater(loss, tau=0.1)
    assert isinstance(updater, SoftUpdate)
    before = [p.clone() for p in loss.target_value_network_params.values(True, True)]
    with torch.no_grad():
        for p in actor.parameters():
            p.add_(1.0)
    updater.step()
    after = list(loss.target_value_network_params.values(True, True))
    assert all(torch.allclose(b + 0.1, a, atol=1e-6) for a, b in zip(after, before, strict=True))
    optimizer = make_optimizer(actor.parameters())
    assert optimizer.defaults["fused"] is True


def test_a_factory_called_from_python_answers_in_its_arguments_names():
    with pytest.raises(ValueError, match=r"^env_name='CartPoel-v1' is not a registered"):
        make_env("CartPoel-v1")
    with pytest.raises(ValueError, match=r"^schedule='exp': choose one of"):
        make_exploration(OneHot(2), schedule="exp")
    with pytest.raises(ValueError, match=r"^torso='resnet': choose 'mlp', 'cnn' or an nn.Module"):
        make_q_actor(Composite(observation=OneHot(4)), OneHot(2), torso="resnet")


def test_module_refuses_the_arguments_that_would_build_a_network(env):
    net = nn.Linear(4, 2)
    for given in ({"num_cells": [64]}, {"head": "dueling"}, {"noisy": True}, {"depth": 2}):
        with pytest.raises(TypeError, match=r"module= is your whole Q-network, so the arguments"):
            make_q_actor(spec=env.action_spec, module=net, **given)


# --- every earlier positional form names the keywords --------------------------------------------


def test_a_cnn_torso_names_the_smallest_image_it_takes():
    image = Composite(pixels=Unbounded(shape=(2, 20, 60), dtype=torch.uint8))
    with pytest.raises(ValueError, match=r"\[2, 20, 60\] is smaller .* at least 29x29"):
        make_q_actor(image, OneHot(2), in_keys=["pixels"], torso="cnn")
    actor = make_q_actor(
        image,
        OneHot(2),
        in_keys=["pixels"],
        torso="cnn",
        cnn_kwargs={"num_cells": [8], "kernel_sizes": [5], "strides": [2]},
    )
    assert actor(TensorDict(pixels=torch.zeros(2, 20, 60, dtype=torch.uint8)))["action"].shape == (
        2,
    )


def test_factory_states_load_into_the_stock_classes_or_differ_as_the_reference_says(env):
    """The reference names the one extra key of the exponential schedule's state."""
    stock = EGreedyModule(env.action_spec)
    stock.load_state_dict(make_exploration(env.action_spec).state_dict())  # strict
    exponential = make_exploration(env.action_spec, schedule="exponential").state_dict()
    missing, unexpected = stock.load_state_dict(exponential, strict=False)
    assert (missing, unexpected) == ([], ["frames"])

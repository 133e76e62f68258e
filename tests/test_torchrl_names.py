"""The factories speak TorchRL: its argument names, its meanings, its other keywords passed on.

Each test is a call an experienced TorchRL user made from the README and failed before: the
name of the TorchRL class's argument, or a keyword of that class the factory did not take.
"""

from __future__ import annotations

import inspect
import subprocess
import sys

import pytest
import torch
from tensordict import TensorDict
from torch import nn
from torchrl.data import (
    Categorical,
    LazyMemmapStorage,
    SamplerWithoutReplacement,
    TensorDictReplayBuffer,
)
from torchrl.envs import GymWrapper
from torchrl.modules import EGreedyModule, QValueActor
from torchrl.objectives import DQNLoss, HardUpdate, SoftUpdate

from trl_cartpole import (
    make_dqn_loss,
    make_env,
    make_exploration,
    make_q_actor,
    make_replay_buffer,
    make_target_updater,
)
from trl_cartpole.parts.env import GYM_WRAPPER_KEYWORDS


@pytest.fixture(scope="module")
def env():
    env = make_env("CartPole-v1", seed=0)
    yield env
    env.close()


def _fill(params, value: float) -> None:
    params.apply(lambda t: t.data.fill_(value))


def _copied_at(updater, loss, steps: int) -> list[int]:
    """The 1-based ``.step()`` calls after which the target equals the online network."""
    copied = []
    _fill(loss.value_network_params, 1.0)
    for step in range(1, steps + 1):
        _fill(loss.target_value_network_params, 0.0)
        updater.step()
        if all((t == 1).all() for t in loss.target_value_network_params.values(True, True)):
            copied.append(step)
    return copied


@pytest.mark.slow  # a fresh interpreter
def test_train_imported_from_the_package_is_the_function_in_a_fresh_interpreter():
    code = "from trl_cartpole import train; import inspect; print(inspect.isfunction(train))"
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True, timeout=120
    )
    assert out.stdout.strip() == "True"


def test_dqn_loss_takes_value_network_and_every_dqnloss_keyword(env):
    actor = make_q_actor(env.observation_spec, env.action_spec)
    loss = make_dqn_loss(value_network=actor, delay_value=False, reduction="sum")
    assert isinstance(loss, DQNLoss)
    assert loss.delay_value is False and loss.reduction == "sum"
    assert loss.loss_function == "l2"  # DQNLoss's own
    assert make_dqn_loss(actor, loss_function="smooth_l1").loss_function == "smooth_l1"


def test_exploration_takes_egreedy_modules_names_in_its_order(env):
    module = make_exploration(spec=env.action_spec, eps_init=0.5, eps_end=0.1)
    assert type(module) is EGreedyModule and module.eps_init.item() == pytest.approx(0.5)
    positional = make_exploration(env.action_spec, 0.8, 0.2, 10)
    assert (positional.eps_init.item(), positional.eps_end.item()) == pytest.approx((0.8, 0.2))
    assert positional.annealing_num_steps == 10
    assert make_exploration(env.action_spec).annealing_num_steps == 1000  # EGreedyModule's


def test_target_updaters_take_torchrls_names_and_count_as_torchrl(env):
    loss = make_dqn_loss(make_q_actor(env.observation_spec, env.action_spec, num_cells=[8]))
    assert make_target_updater(loss, eps=0.9).eps == pytest.approx(0.9)
    soft = make_target_updater(loss, tau=0.1)
    assert isinstance(soft, SoftUpdate) and soft.eps == pytest.approx(0.9)
    # TorchRL's HardUpdate(value_network_update_interval=3) copies at its 4th and 8th step ...
    ours = make_target_updater(loss, value_network_update_interval=3)
    assert isinstance(ours, HardUpdate)
    theirs = HardUpdate(loss, value_network_update_interval=3)
    assert _copied_at(ours, loss, 9) == _copied_at(theirs, loss, 9) == [4, 8]
    # ... and a config's kind reads only its own updater's keys
    hard = make_target_updater(loss, kind="hard", value_network_update_interval=2, tau=0.5)
    assert _copied_at(hard, loss, 9) == [3, 6, 9]
    with pytest.raises(ValueError, match="not both"):
        make_target_updater(loss, tau=0.1, value_network_update_interval=3)


def test_q_actor_takes_mlps_names_and_passes_mlp_and_actor_keywords_on(env):
    actor = make_q_actor(
        env.observation_spec,
        spec=env.action_spec,
        num_cells=[16, 8],
        activation_class=nn.Tanh,
        dropout=0.1,  # an MLP keyword
        action_value_key="q",  # a QValueActor keyword
    )
    assert isinstance(actor, QValueActor)
    linears = [m for m in actor.modules() if isinstance(m, nn.Linear)]
    assert [(m.in_features, m.out_features) for m in linears] == [(4, 16), (16, 8), (8, 2)]
    assert any(isinstance(m, nn.Tanh) for m in actor.modules())
    assert not any(isinstance(m, nn.ReLU) for m in actor.modules())
    assert [m.p for m in actor.modules() if isinstance(m, nn.Dropout)] == [0.1, 0.1]
    td = actor(TensorDict(observation=torch.zeros(3, 4), batch_size=[3]))
    assert td["q"].shape == torch.Size([3, 2])
    # MLP's depth with an int num_cells: three layers of 8
    deep = make_q_actor(env.observation_spec, env.action_spec, num_cells=8, depth=3)
    widths = [m.out_features for m in deep.modules() if isinstance(m, nn.Linear)]
    assert widths == [8, 8, 8, 2]
    with pytest.raises(TypeError, match=r"layer_class: set .* by noisy="):
        make_q_actor(env.observation_spec, env.action_spec, layer_class=nn.Linear)


def test_env_passes_gymwrapper_keywords_on():
    env = make_env("CartPole-v1", seed=0, categorical_action_encoding=True, frame_skip=2)
    assert isinstance(env.action_spec, Categorical)
    rollout = env.rollout(3)
    # two Gymnasium steps per env step: CartPole pays 1 per step, so 2 per frame-skipped step
    assert rollout["next", "reward"].squeeze(-1).tolist() == [2.0, 2.0, 2.0]
    env.close()
    pixels = make_env("CartPole-v1", seed=0, from_pixels=True, pixels_only=True)
    frame = pixels.reset()["pixels"]
    assert frame.dtype == torch.uint8 and frame.shape[-1] == 3 and frame.ndim == 3
    assert "observation" not in pixels.observation_spec.keys()  # noqa: SIM118
    pixels.close()


def test_replay_buffer_takes_storage_sampler_and_transform(tmp_path):
    storage = LazyMemmapStorage(100, scratch_dir=tmp_path)
    buffer = make_replay_buffer(
        storage=storage, sampler=SamplerWithoutReplacement(), batch_size=10, n_steps=1
    )
    assert isinstance(buffer, TensorDictReplayBuffer) and buffer._storage is storage
    buffer.extend(TensorDict(x=torch.arange(10.0), batch_size=[10]))
    assert sorted(buffer.sample()["x"].tolist()) == [float(i) for i in range(10)]  # no repeats
    with pytest.raises(ValueError, match="not both"):
        make_replay_buffer(sampler=SamplerWithoutReplacement(), prioritized=True)


def _n_step_batch(env, buffer):
    buffer.extend(env.rollout(40, break_when_any_done=False))
    return buffer.sample()


def test_loss_takes_the_n_step_buffers_discount_and_refuses_another(env):
    actor = make_q_actor(env.observation_spec, env.action_spec)
    buffer = make_replay_buffer(batch_size=8, n_steps=3, gamma=0.9)
    loss = make_dqn_loss(actor, replay_buffer=buffer)
    assert loss.value_estimator.gamma.item() == pytest.approx(0.9)
    with pytest.raises(ValueError, match=r"gamma=0\.99 .* n-step gamma=0\.9\b"):
        make_dqn_loss(actor, gamma=0.99, replay_buffer=buffer)


def test_the_discount_in_use_is_checked_on_every_n_step_batch(env):
    actor = make_q_actor(env.observation_spec, env.action_spec)
    buffer = make_replay_buffer(batch_size=8, n_steps=3, gamma=0.995)
    batch = _n_step_batch(env, buffer)
    mismatched = make_dqn_loss(actor, gamma=0.99)
    for _ in range(2):  # refused every time, not only at the first batch
        with pytest.raises(ValueError, match=r"gamma=0\.99 differs .* n-step gamma=0\.995"):
            mismatched(batch.clone())
    # TorchRL's way: the loss's estimator made with the buffer's gamma after construction
    torchrls_way = make_dqn_loss(actor)
    torchrls_way.make_value_estimator(gamma=0.995)
    assert torch.isfinite(torchrls_way(batch.clone())["loss"])
    # a loss given the buffer, then another estimator: refused at each call, not trained on
    changed = make_dqn_loss(actor, replay_buffer=buffer)
    assert torch.isfinite(changed(batch.clone())["loss"])
    changed.make_value_estimator(gamma=0.5)
    for _ in range(2):
        with pytest.raises(ValueError, match=r"gamma=0\.5 differs .* n-step gamma=0\.995"):
            changed(batch.clone())
    changed.make_value_estimator(gamma=0.995)  # and back: accepted again
    assert torch.isfinite(changed(batch.clone())["loss"])
    one_step = make_replay_buffer(batch_size=8, n_steps=1)  # no discount in the buffer
    assert torch.isfinite(make_dqn_loss(actor, gamma=0.5)(_n_step_batch(env, one_step))["loss"])


def test_a_c51_loss_checks_its_own_gamma_on_every_n_step_batch(env):
    c51 = make_q_actor(env.observation_spec, env.action_spec, support=torch.linspace(0, 50, 11))
    buffer = make_replay_buffer(batch_size=8, n_steps=3, gamma=0.99)
    batch = _n_step_batch(env, buffer)
    assert torch.isfinite(make_dqn_loss(c51, replay_buffer=buffer)(batch.clone())["loss"])
    for _ in range(2):
        with pytest.raises(ValueError, match=r"gamma=0\.9 differs"):
            make_dqn_loss(c51, gamma=0.9)(batch.clone())


def test_every_gymwrapper_keyword_make_env_routes_is_one_torchrl_reads():
    """``GYM_WRAPPER_KEYWORDS`` go to ``GymWrapper``: each is read somewhere in its classes."""
    classes = [klass for klass in GymWrapper.__mro__ if klass.__module__.startswith("torchrl")]
    parameters = {
        name
        for klass in classes
        for method in ("__init__", "_build_env")  # _build_env reads from_pixels, pixels_only
        if method in vars(klass)
        for name in inspect.signature(vars(klass)[method]).parameters
    }
    source = "".join(inspect.getsource(klass) for klass in classes)
    read = [key for key in GYM_WRAPPER_KEYWORDS if key in parameters or f'"{key}"' in source]
    assert sorted(read) == sorted(GYM_WRAPPER_KEYWORDS)

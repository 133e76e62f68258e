"""Every private TorchRL name ``trl_cartpole.compat`` reads: each test fails where it moved.

These tests build the real TorchRL objects and check that the private attribute is where the
compatibility module reads it, and that reading and writing it does what the callers rely on.
"""

from __future__ import annotations

import inspect
import subprocess

import gymnasium as gym
import pytest
import torch
from tensordict import TensorDict
from torch import nn
from torchrl.collectors import Collector
from torchrl.data import LazyTensorStorage, TensorDictReplayBuffer
from torchrl.modules import DistributionalQValueActor

from trl_cartpole import compat
from trl_cartpole.parts.collectors import make_collector
from trl_cartpole.parts.env import make_env
from trl_cartpole.parts.models import make_q_actor
from trl_cartpole.parts.replay import extend_with_batch, make_replay_buffer


def test_carrier_of_is_the_next_step_of_the_in_process_collector():
    env = make_env("CartPole-v1", seed=0)
    collector = make_collector(env, None, frames_per_batch=8, total_frames=16)
    assert isinstance(collector, Collector)
    batch = next(iter(collector))
    carrier = compat.carrier_of(collector)
    assert "observation" in carrier.keys()  # noqa: SIM118 (a TensorDict)
    # the carrier holds the observation the next batch starts from
    torch.testing.assert_close(carrier["observation"], batch["next", "observation"][-1])
    collector.shutdown()


def test_gym_env_is_the_gymnasium_env_behind_the_wrapper_and_can_be_replaced():
    env = make_env("CartPole-v1", seed=0)
    inner = compat.gym_env(env)
    assert isinstance(inner, gym.Env) and inner.spec.id == "CartPole-v1"
    other = gym.make("CartPole-v1")
    compat.set_gym_env(env, other)
    assert compat.gym_env(env) is other


def test_autoreset_state_of_a_vector_env_reads_and_writes():
    env = make_env("CartPole-v1", seed=0, num_envs=2)
    env.rollout(3)
    memo = compat.autoreset_state(env)
    assert memo is not None
    assert compat.set_autoreset_state(env, memo)
    assert compat.autoreset_state(env) is memo
    single = make_env("CartPole-v1", seed=0)
    assert compat.autoreset_state(single) is None and not compat.set_autoreset_state(single, {})


def _steps(envs: int, steps: int) -> TensorDict:
    """``[envs, steps]`` transitions with no episode end, each env's steps one trajectory."""
    shape = (envs, steps)
    flag = torch.zeros(*shape, 1, dtype=torch.bool)
    states = torch.randn(envs, steps + 1, 4)  # s_0 ... s_T of each env
    return TensorDict(
        {
            "observation": states[:, :-1],
            "action": torch.zeros(*shape, 2, dtype=torch.long),
            "next": {
                "observation": states[:, 1:],
                "reward": torch.ones(*shape, 1),
                "done": flag,
                "terminated": flag.clone(),
                "truncated": flag.clone(),
            },
        },
        batch_size=shape,
    )


def test_n_step_window_is_what_the_multistep_transform_holds_back():
    uniform = make_replay_buffer(max_size=100, batch_size=4, n_steps=1)
    assert compat.n_step_transform(uniform) is None
    buffer = make_replay_buffer(max_size=100, batch_size=4, n_steps=3, gamma=0.9)
    extend_with_batch(buffer, _steps(envs=2, steps=5))
    assert len(buffer) == 2 * (5 - 3)  # windows complete for the first 2 steps of each env
    transform = compat.n_step_transform(buffer)
    window = compat.held_steps(transform)
    assert window is not None and window.batch_size[0] == 2  # one row per env
    held = window.clone()
    compat.set_held_steps(transform, held)
    assert compat.held_steps(compat.n_step_transform(buffer)) is held


def test_n_step_returns_are_torchrls_window_sums():
    reward = torch.tensor([[1.0, 2.0, 4.0, 8.0, 16.0]]).unsqueeze(-1)  # [1, 5, 1]
    ends = torch.tensor([[False, False, True, False, False]])  # a window ends after step 2
    summed, time_to_obs = compat.n_step_returns(0.5, reward, ends, n_steps=2)
    # R_t = r_t + 0.5 r_{t+1} inside the window; a step at the window's end sums itself alone
    assert summed.reshape(-1).tolist() == [2.0, 4.0, 4.0, 16.0, 16.0]
    assert time_to_obs.reshape(-1).tolist() == [1, 1, 0, 1, 0]  # k - 1


def test_weight_sync_schemes_attribute_exists_and_closing_them_is_safe():
    env = make_env("CartPole-v1", seed=0)
    collector = make_collector(env, None, frames_per_batch=8, total_frames=16)
    assert hasattr(collector, "_weight_sync_schemes")
    collector.shutdown()
    compat.close_weight_sync_schemes(collector)


def test_only_a_synchronous_ray_collector_counts_as_one():
    # a live Ray collector is the slow tier's (test_resumed_run_equals_the_uninterrupted_one
    # [ray]); here, without starting Ray: where RayCollector keeps its sync flag, and the answer
    # for each flag and for a collector of another kind
    pytest.importorskip("ray")
    ray_module = pytest.importorskip("torchrl.collectors.distributed.ray")
    assert "self._sync = sync" in inspect.getsource(ray_module.RayCollector.__init__)
    for sync in (True, False):
        ray_collector = object.__new__(ray_module.RayCollector)
        ray_collector._sync = sync
        assert compat.is_synchronous_ray_collector(ray_collector) is sync
    env = make_env("CartPole-v1", seed=0)
    collector = make_collector(env, None, frames_per_batch=8, total_frames=16)
    assert not compat.is_synchronous_ray_collector(collector)
    collector.shutdown()


def test_first_greedy_action_breaks_ties_with_a_single_one_hot():
    env = make_env("CartPole-v1", seed=0)
    actor = make_q_actor(env.observation_spec, env.action_spec, support=torch.linspace(0.0, 1.0, 5))
    assert isinstance(actor, DistributionalQValueActor)
    rules = [m.action_func_mapping for m in actor.modules() if hasattr(m, "action_func_mapping")]
    assert rules and "one_hot" in rules[0]
    tied = torch.zeros(3, 5, 2)  # [B, atoms, actions]: equal log-probabilities, equal values
    one_hot = rules[0]["one_hot"](tied)
    assert one_hot.shape == (3, 2) and torch.equal(one_hot.sum(-1), torch.ones(3, dtype=torch.long))


def test_prioritized_sampler_names_the_segment_trees_it_uses():
    from torchrl.data.replay_buffers.samplers import prioritized

    for name in ("SumSegmentTreeFp32", "MinSegmentTreeFp32", "SumSegmentTreeFp64"):
        assert hasattr(prioritized, name)
    compat.install_segment_trees_if_missing()
    assert prioritized.SumSegmentTreeFp32 is not None


def test_a_prioritized_buffer_keeps_cpu_trees_where_torchrl_has_no_cuda_ones(monkeypatch):
    """TorchRL's ``PrioritizedSampler`` documents CPU trees for a CUDA storage on a build
    without CUDA trees, yet raises (PyPI's 0.14.1 wheel, seen on an H200): the factory asks for
    the CPU trees there, and leaves TorchRL's default (and a caller's choice) alone elsewhere."""
    from torchrl.data.replay_buffers.samplers import prioritized

    names = [f"Cuda{k}SegmentTree{p}" for k in ("Sum", "Min") for p in ("Fp32", "Fp64")]
    assert all(hasattr(prioritized, name) for name in names)  # the names the check reads
    built = compat.cuda_segment_trees_available()
    assert built == all(getattr(prioritized, name) is not None for name in names)

    def sampler_device(**kwargs):
        return make_replay_buffer(
            prioritized=True, max_size=8, alpha=0.3, beta=0.4, **kwargs
        )._sampler._device

    monkeypatch.setattr(prioritized, "CudaSumSegmentTreeFp32", None)
    assert sampler_device() == torch.device("cpu")
    assert sampler_device(sampler_device="meta") == torch.device("meta")  # the caller's
    for name in names:
        monkeypatch.setattr(prioritized, name, object())
    assert sampler_device() is None  # TorchRL's own default: trees follow the storage


@pytest.mark.parametrize("tree", [compat.TensorSumSegmentTree, compat.TensorMinSegmentTree])
def test_segment_tree_stand_ins_answer_queries(tree):
    values = tree(4)
    values[torch.tensor([0, 1, 2, 3])] = torch.tensor([1.0, 4.0, 2.0, 3.0])
    if tree is compat.TensorSumSegmentTree:
        assert values.query(0, 4) == 10.0 and values.query(1, 3) == 6.0
        # prefix sums 1, 5, 7, 10: mass 4.5 falls in index 1, mass 7.5 in index 3
        assert values.scan_lower_bound(torch.tensor([4.5, 7.5])).tolist() == [1, 3]
    else:
        assert values.query(0, 4) == 1.0 and values.query(1, 3) == 2.0


def test_a_partial_step_leaves_the_unmarked_envs_and_the_next_input_is_rollouts():
    from torchrl.envs import SerialEnv

    env = SerialEnv(2, lambda: make_env("CartPole-v1", seed=0))
    env.set_seed(0)
    first = env.reset()
    first["action"] = env.action_spec.zero()  # [2, 2] one-hot
    first["action"][..., 0] = 1
    first.set(compat.PARTIAL_STEP_KEY, torch.tensor([True, False]))
    stepped = env.step(first)
    following = compat.next_step_input(env, stepped)
    moved = (following["observation"] != first["observation"]).any(-1)  # [2]
    assert moved.tolist() == [True, False]  # the second env was not stepped
    # what the policy reads next: the next observation, as env.rollout's step_mdp gives it
    assert torch.equal(following["observation"][0], stepped["next", "observation"][0])
    env.close()


def test_a_storage_is_allocated_from_a_row_and_told_how_full_it_is():
    storage = LazyTensorStorage(4)
    compat.allocate_storage(storage, TensorDict({"x": torch.zeros(2)}, batch_size=[]))
    assert compat.storage_tensors(storage)["x"].shape == (4, 2)  # every row, allocated
    assert len(storage) == 0
    compat.set_storage_length(storage, 3)
    assert len(storage) == 3


def test_the_last_written_row_is_the_one_before_the_writers_cursor():
    buffer = TensorDictReplayBuffer(storage=LazyTensorStorage(4))
    buffer.extend(TensorDict({"x": torch.arange(6.0)}, batch_size=[6]))  # rows 0-3, then 0, 1
    buffer.storage._last_cursor = None  # as a loaded storage checkpoint leaves it
    compat.restore_last_written_row(buffer)
    assert buffer.storage._last_cursor == 1


def test_forward_hooks_are_seen_and_pre_hooks_listed_in_order():
    layer = nn.Linear(2, 2)
    assert not compat.forward_hooks_set(layer) and compat.forward_pre_hooks(layer) == []
    first, second = (lambda module, args: None), (lambda module, args: None)
    layer.register_forward_pre_hook(first)
    layer.register_forward_pre_hook(second)
    layer.register_forward_hook(lambda module, args, out: None)
    assert compat.forward_hooks_set(layer) and compat.forward_pre_hooks(layer) == [first, second]


def test_a_tensors_version_moves_on_an_in_place_write():
    tensor = torch.zeros(1)
    before = compat.tensor_version(tensor)
    tensor.add_(1)
    assert compat.tensor_version(tensor) > before


def test_a_gymnasium_envs_generator_is_none_until_seeded():
    env = gym.make("CartPole-v1").unwrapped
    assert compat.gym_generator(env) is None
    env.reset(seed=0)
    assert compat.gym_generator(env) is env.np_random


def test_the_exit_steps_run_the_atexit_functions(python):
    code = (
        "import atexit, os\n"
        "from trl_cartpole.compat import run_exit_steps\n"
        "atexit.register(print, 'ran')\n"
        "run_exit_steps()\n"
        "os._exit(0)\n"
    )
    proc = subprocess.run([python, "-c", code], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0 and proc.stdout == "ran\n", proc.stderr[-2000:]


def test_a_transforms_parent_is_stepped_and_reset_below_the_transform():
    env = make_env("CartPole-v1", seed=0)
    start = compat.parent_reset(env.base_env, env.base_env.reset())
    stepped = compat.parent_step(env.base_env, start.set("action", env.action_spec.zero()))
    assert stepped["observation"].shape == (4,) and not stepped["done"].any()

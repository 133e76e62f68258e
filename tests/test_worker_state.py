"""A multi-process collector's workers saved and restored: the next batch is the same batch.

Each worker's envs, carrier and torch RNG live in the worker process
(``trl_cartpole.store.worker_state``); a checkpoint reaches them through the collector's own
remote calls. Taken between two batches and put into a new collector's workers, they make the
new collector's next batch equal, frame by frame, to the batch the first collector collected
next.
"""

from __future__ import annotations

import pytest
import torch
from tensordict.nn import TensorDictSequential

from trl_cartpole.config.schema import to_config
from trl_cartpole.parts.collectors import make_collector
from trl_cartpole.run.envs import make_env_from_config, worker_env_constructors
from trl_cartpole.run.from_config import build_actor, build_exploration
from trl_cartpole.store.worker_state import restore_worker_states, worker_states

FRAMES = 64  # per batch: 32 per worker, so episodes are cut mid-way by the batch boundary


def _collector(cfg, policy, init_random_frames: int = 0):
    return make_collector(
        worker_env_constructors(cfg),
        policy,
        frames_per_batch=FRAMES,
        total_frames=10 * FRAMES,
        init_random_frames=init_random_frames,
    )


@pytest.mark.slow  # worker processes, twice
def test_a_batch_after_restoring_the_workers_is_the_batch_they_would_have_collected(compose):
    cfg = to_config(compose("collector.workers=2", "env.num_envs=2", "seed=3"))
    env = make_env_from_config(cfg.env, cfg.seed)
    torch.manual_seed(0)
    policy = TensorDictSequential(build_actor(cfg, env), build_exploration(cfg, env))
    first = _collector(cfg, policy)
    try:
        batches = iter(first)
        for _ in range(2):  # mid-episode: CartPole's first episodes last longer than 16 steps
            next(batches)
        states = worker_states(first)
        expected = next(batches).clone()
    finally:
        first.shutdown()
    assert len(states) == 2
    assert all(state["env"] is not None for state in states)
    assert {"carrier", "torch_rng", "autoreset"} <= set(states[0])

    second = _collector(cfg, policy)
    try:
        assert restore_worker_states(second, states)
        got = next(iter(second)).clone()
        assert restore_worker_states(second, states[:1]) is False  # another number of workers
    finally:
        second.shutdown()
    assert got.batch_size == expected.batch_size  # [workers, envs, T]
    for key in ("observation", "action", ("next", "observation"), ("next", "reward")):
        torch.testing.assert_close(got[key], expected[key], rtol=0, atol=0)
    # fresh workers would start every env at step 0: these continue mid-episode
    assert (expected["step_count"][..., 0] > 0).any()


def test_a_collector_without_worker_processes_has_no_worker_state(compose):
    cfg = compose("seed=3")
    env = make_env_from_config(cfg.env, cfg.seed)
    actor = build_actor(cfg, env)
    collector = make_collector(env, actor, frames_per_batch=8, total_frames=16)
    try:
        assert worker_states(collector) is None
        assert restore_worker_states(collector, [{"env": {}}]) is False
    finally:
        collector.shutdown()


@pytest.mark.slow  # worker processes
def test_worker_states_that_hold_no_env_are_not_restored(compose):
    cfg = compose("collector.workers=2", "env.num_envs=2", "seed=3")
    env = make_env_from_config(cfg.env, cfg.seed)
    collector = _collector(cfg, build_actor(cfg, env))
    try:
        assert restore_worker_states(collector, None) is False  # a checkpoint from before
        assert restore_worker_states(collector, [{"env": None}, {"env": None}]) is False
    finally:
        collector.shutdown()

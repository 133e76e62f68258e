"""Throughput of the collection layouts (``scripts/scaling.py``, docs/scaling.md).

A layout is how many envs each worker steps (``env.num_envs``), how many workers collect
(``collector.workers``) and whether they are synchronous; :func:`collection_fps` times the
collector of a layout alone, with the untrained epsilon-greedy policy and a weight sync after
every batch, as the training loop does.
"""

from __future__ import annotations

import functools
import time

import torch
from tensordict.nn import TensorDictSequential
from torchrl.envs import ParallelEnv

from trl_cartpole.collectors import (
    is_distributed,
    make_collector,
    needs_weight_sync,
    shutdown_collector,
    worker_env_constructors,
)
from trl_cartpole.config import Config
from trl_cartpole.envs import make_env, make_env_from_config
from trl_cartpole.exploration import make_exploration
from trl_cartpole.models import make_q_actor_for_env

__all__ = ["WARMUP_BATCHES", "collection_fps", "make_parallel_env"]

WARMUP_BATCHES = 5  # batches left out of the timing: worker start-up, first allocations


def make_parallel_env(env_id: str, num_envs: int, seed: int) -> ParallelEnv:
    """``num_envs`` single envs of :func:`make_env`, each in its own process (TorchRL)."""
    env = ParallelEnv(num_envs, functools.partial(make_env, env_id))
    env.set_seed(seed)
    return env


def collection_fps(cfg: Config, frames: int, parallel_env: bool = False) -> float:
    """Frames per second of collecting ``frames`` frames in the layout of ``cfg``, alone.

    ``parallel_env`` replaces the Gymnasium ``SyncVectorEnv`` of one worker by TorchRL's
    ``ParallelEnv`` (one process per env). The first ``WARMUP_BATCHES`` batches are not timed.
    """
    torch.set_num_threads(cfg.num_threads)
    env = make_env_from_config(cfg.env, cfg.seed, cfg.device)
    actor = make_q_actor_for_env(env, cfg.network, cfg.device)
    exploration = make_exploration(env.action_spec, "linear", 1.0, 0.05, frames, cfg.device)
    policy = TensorDictSequential(actor, exploration)
    batch_frames = cfg.collector.frames_per_batch
    total = frames + WARMUP_BATCHES * batch_frames
    if is_distributed(cfg.collector.workers, cfg.collector.backend):
        create_env = worker_env_constructors(cfg)
    elif parallel_env:
        create_env = make_parallel_env(cfg.env.id, cfg.env.num_envs, cfg.seed)
    else:
        create_env = env
    collector = make_collector(
        create_env,
        policy,
        batch_frames,
        total,
        device=cfg.device,
        sync=cfg.collector.sync,
        backend=cfg.collector.backend,
        ray_address=cfg.collector.ray_address,
    )
    sync_weights = needs_weight_sync(collector, policy)
    collected, start = 0, None
    for index, batch in enumerate(collector):
        if index == WARMUP_BATCHES:
            start = time.perf_counter()
        if start is not None:
            collected += batch.numel()
        exploration.step(batch.numel())
        if sync_weights:
            collector.update_policy_weights_()
    seconds = time.perf_counter() - start
    shutdown_collector(collector)
    env.close()  # (the collector closed the ParallelEnv when it reached its total)
    return collected / seconds

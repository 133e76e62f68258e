"""Before a run builds its parts: the global seeds, the frame of the first update, and what the
buffer and networks take in memory."""

from __future__ import annotations

import random
import warnings
from functools import partial

import numpy as np
import torch
from torchrl.envs import TransformedEnv

from trl_cartpole.config.schema import Config
from trl_cartpole.run.from_config import build_actor
from trl_cartpole.run.memory_needs import (
    MemoryNeed,
    memory_need,
)

__all__ = ["first_update_frame", "run_memory_need", "seed_everything", "warn_if_no_update"]


def seed_everything(seed: int) -> None:
    """Seed Python's ``random``, NumPy and torch (the env seeds are set by ``make_env``)."""
    random.seed(seed)
    np.random.seed(seed)  # noqa: NPY002 (global state that third-party code reads)
    torch.manual_seed(seed)


def first_update_frame(cfg: Config) -> int:
    """The frames collected before the first gradient update: the random warm-up, the
    ``learning_starts`` floor and one batch of samples."""
    collector = cfg.collector
    return max(cfg.buffer.batch_size, collector.learning_starts, collector.init_random_frames)


def warn_if_no_update(cfg: Config) -> None:
    """Warn in one line when the run ends before its first update: it could not learn."""
    first = first_update_frame(cfg)
    if cfg.collector.total_frames < first:
        warnings.warn(
            f"collector.total_frames={cfg.collector.total_frames} ends before the first update "
            f"at frame {first} (the largest of collector.init_random_frames, "
            "collector.learning_starts and buffer.batch_size): this run collects and evaluates "
            "but does not learn; raise collector.total_frames or lower those",
            stacklevel=2,
        )


def run_memory_need(cfg: Config, env: TransformedEnv) -> MemoryNeed:
    """The lower bound of what ``cfg``'s replay buffer and networks take in memory."""
    return memory_need(
        env,
        cfg.buffer.max_size,
        partial(build_actor, cfg, env),
        amsgrad=cfg.optim.amsgrad,
        frames_stored_once=cfg.buffer.storage == "frames",
    )

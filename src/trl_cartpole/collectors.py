"""Collector factory: TorchRL's single-process ``Collector``."""

from __future__ import annotations

from collections.abc import Callable

from tensordict.nn import TensorDictModuleBase
from torchrl.collectors import Collector
from torchrl.envs import EnvBase

__all__ = ["make_collector"]


def make_collector(
    env: EnvBase | Callable[[], EnvBase],
    policy: TensorDictModuleBase,
    frames_per_batch: int = 1,
    total_frames: int = 100_000,
    init_random_frames: int = 0,
    device: str = "cpu",
) -> Collector:
    """Return a ``Collector`` yielding batches of ``frames_per_batch`` transitions.

    The first ``init_random_frames`` frames come from the env's uniform random policy. The
    collector runs ``policy`` under ``ExplorationType.RANDOM``, so epsilon-greedy is active.
    """
    return Collector(
        env,
        policy,
        frames_per_batch=frames_per_batch,
        total_frames=total_frames,
        init_random_frames=init_random_frames or None,
        device=device,
        auto_register_policy_transforms=False,  # the Q-policy needs no env transform
    )

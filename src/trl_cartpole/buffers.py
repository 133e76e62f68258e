"""Replay buffer factory: uniform sampling over a ``LazyTensorStorage``."""

from __future__ import annotations

from torchrl.data import LazyTensorStorage, TensorDictReplayBuffer
from torchrl.data.replay_buffers import RandomSampler

__all__ = ["make_replay_buffer"]


def make_replay_buffer(
    size: int = 10_000, batch_size: int = 128, device: str = "cpu"
) -> TensorDictReplayBuffer:
    """Return a ``TensorDictReplayBuffer`` of capacity ``size`` sampling ``batch_size`` uniformly.

    The storage allocates lazily on the first ``extend`` from the collected batch's layout, so
    the same factory serves any env. Sampling is with replacement (``RandomSampler``), as
    TorchRL's DQN example does.
    """
    return TensorDictReplayBuffer(
        storage=LazyTensorStorage(size, device=device),
        sampler=RandomSampler(),
        batch_size=batch_size,
    )

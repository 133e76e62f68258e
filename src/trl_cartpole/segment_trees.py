"""Pure-torch stand-ins for TorchRL's C++ sum/min segment trees, used only when those are missing.

TorchRL's ``PrioritizedSampler`` (behind ``TensorDictPrioritizedReplayBuffer``) keeps its
priorities in ``SumSegmentTree`` / ``MinSegmentTree`` classes from the compiled extension
``torchrl._torchrl``. The torchrl 0.14.1 wheel's extension does not load against the CPU
build of torch 2.13.0 this project pins (an undefined C++ symbol), which leaves those classes
``None`` and the sampler unusable. :func:`install_if_missing` fills exactly those missing names
with the classes below, so the stock sampler and buffer run unchanged; where the extension
loads, nothing is replaced.

The stand-ins keep the priorities in one flat tensor: a query is a ``sum``/``min`` over a slice
and ``scan_lower_bound`` a ``cumsum`` plus ``searchsorted``, O(capacity) instead of the trees'
O(log capacity), about 0.1 ms for a 50 000-entry buffer, small next to one gradient step.
"""

from __future__ import annotations

from functools import partial
from typing import Any

import numpy as np
import torch

__all__ = ["TensorMinSegmentTree", "TensorSumSegmentTree", "install_if_missing"]


def _as_index(index: Any) -> torch.Tensor | int:
    if isinstance(index, int | np.integer):
        return int(index)
    return torch.as_tensor(index, dtype=torch.long).reshape(-1)


class _TensorSegmentTree:
    """A flat ``[capacity]`` tensor with the segment trees' item access and ``query``."""

    neutral: float

    def __init__(self, capacity: int, dtype: torch.dtype = torch.float32) -> None:
        self.capacity = capacity
        self.dtype = dtype
        self.values = torch.full((capacity,), self.neutral, dtype=self.dtype)  # [capacity]

    def __len__(self) -> int:
        return self.capacity

    def __getitem__(self, index: Any) -> torch.Tensor | float:
        index = _as_index(index)
        value = self.values[index]
        return float(value) if isinstance(index, int) else value

    def __setitem__(self, index: Any, value: Any) -> None:
        index = _as_index(index)
        self.values[index] = torch.as_tensor(value, dtype=self.dtype).reshape(-1)

    def _slice(self, left: Any, right: Any) -> torch.Tensor:
        return self.values[int(left) : int(right)]


class TensorSumSegmentTree(_TensorSegmentTree):
    """Sum over index ranges and prefix-sum search, the interface of ``SumSegmentTree``."""

    neutral = 0.0

    def query(self, left: Any, right: Any) -> float:
        """Sum of the values at ``[left, right)``."""
        return float(self._slice(left, right).sum())

    def scan_lower_bound(self, mass: Any) -> torch.Tensor:
        """For each ``mass``, the first index whose prefix sum ``values[:i + 1]`` exceeds it."""
        prefix = self.values.cumsum(0)  # [capacity]
        mass = torch.as_tensor(mass, dtype=self.dtype)
        return torch.searchsorted(prefix, mass, right=True)


class TensorMinSegmentTree(_TensorSegmentTree):
    """Minimum over index ranges, the interface of ``MinSegmentTree``."""

    neutral = float("inf")

    def query(self, left: Any, right: Any) -> float:
        """Minimum of the values at ``[left, right)`` (``inf`` when empty)."""
        values = self._slice(left, right)
        return float(values.min()) if values.numel() else self.neutral


def install_if_missing() -> bool:
    """Give TorchRL's ``PrioritizedSampler`` these trees if its C++ ones did not load.

    Returns whether the stand-ins were installed (False when the extension works).
    """
    from torchrl.data.replay_buffers.samplers import prioritized

    if prioritized.SumSegmentTreeFp32 is not None:
        return False
    for precision, dtype in (("Fp32", torch.float32), ("Fp64", torch.float64)):
        setattr(
            prioritized, f"SumSegmentTree{precision}", partial(TensorSumSegmentTree, dtype=dtype)
        )
        setattr(
            prioritized, f"MinSegmentTree{precision}", partial(TensorMinSegmentTree, dtype=dtype)
        )
    return True

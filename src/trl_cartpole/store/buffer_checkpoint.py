"""A replay buffer's checkpoint holds the transitions it has, not its whole capacity.

TorchRL's ``LazyTensorStorage`` allocates its capacity at the first write, and its
checkpointer (``TensorStorageCheckpointer``) writes all of it: a 3 000-frame pixel run's
training state held the preset's 100 000 transitions, 467 MB of them empty. Through the
checkpointer's own hooks, :func:`save_filled_part` writes only the first ``len(storage)``
rows (all of them once the buffer has wrapped around) and puts them back into a storage of
the full capacity on load, so a resumed buffer is the one saved.
"""

from __future__ import annotations

from typing import Any

from tensordict import TensorDictBase
from torchrl.data import LazyTensorStorage

__all__ = ["restore_last_written_row", "save_filled_part"]


class _FilledRows:
    """Save hook: the storage's filled rows ``[len, ...]``."""

    def __init__(self, storage: LazyTensorStorage) -> None:
        self.storage = storage

    def __call__(self, data: TensorDictBase, path: Any = None) -> TensorDictBase:
        return data[: len(self.storage)]


class _IntoCapacity:
    """Load hook: the saved rows written into a storage of ``capacity`` rows (``out``, the
    storage's own, when it has been allocated)."""

    def __init__(self, capacity: int) -> None:
        self.capacity = capacity

    def __call__(self, data: TensorDictBase, out: TensorDictBase | None = None) -> TensorDictBase:
        if out is None:
            out = data[:1].expand(self.capacity, *data.batch_size[1:]).clone()
        out[: data.batch_size[0]] = data
        return out


def save_filled_part(storage: Any) -> bool:
    """Register the hooks on a ``LazyTensorStorage`` (in memory) of one dimension; False (and
    nothing changed) for another storage (a memory-mapped one is already its own files)."""
    if type(storage) is not LazyTensorStorage or storage.ndim != 1:
        return False
    storage.checkpointer.register_save_hook(_FilledRows(storage))
    storage.checkpointer.register_load_hook(_IntoCapacity(storage.max_size))
    return True


def restore_last_written_row(buffer: Any) -> None:
    """Give a loaded buffer's storage the row of its last write (``_last_cursor``).

    TorchRL's storage checkpointers do not restore it, so a state saved again before the next
    write (a resumed run's ending, or a window of n steps still filling) warned "last_cursor is
    None". It is the row before the writer's cursor (the next row to write).
    """
    storage, writer = buffer.storage, getattr(buffer, "_writer", None)
    cursor = getattr(writer, "_cursor", None)
    if getattr(storage, "_last_cursor", 0) is None and len(storage) > 0 and cursor is not None:
        storage._set_last_cursor((int(cursor) - 1) % storage.max_size)

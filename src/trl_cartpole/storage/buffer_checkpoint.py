"""What a loaded replay buffer needs back that TorchRL's storage checkpointers leave out.

A buffer in memory is checkpointed by :mod:`trl_cartpole.storage.chunked` (its filled
rows, in files linked between checkpoints where unchanged), a frames storage by
:class:`~trl_cartpole.storage.frames.FrameStackCheckpointer`, a memory-mapped one by
TorchRL's own.
"""

from __future__ import annotations

from typing import Any

__all__ = ["restore_last_written_row"]


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

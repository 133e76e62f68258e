"""Frames stored once: a replay storage that keeps each distinct frame a single time.

A transition of an Atari game holds its observation and the next one, 4 stacked 84x84 frames
each: 100 000 transitions take 5.6 GB, though consecutive stacks share 3 of their 4 frames
and a transition's next stack is the following one's observation. :class:`FrameStackStorage`
is TorchRL's ``LazyTensorStorage`` whose rows hold, in place of each stack ``[k, H, W]``, the
``k`` slots of its frames in a :class:`FramePool`; the pool keeps each distinct frame once,
counts the rows that use it and frees it when the last one is overwritten. ``get`` gathers the
stacks back, so a sample is what was stored, bit for bit; 100 000 transitions hold about
100 000 frames, 0.8 GB with the pool's first eighth more (:func:`pool_capacity`).

A frame is found again by its bytes (a hash, then an exact comparison), so any layout of the
data stores correctly: the batches of several envs, n-step windows, resets, frames repeated
within a stack. Checkpoints save the rows and the pool's counts (TorchRL's memory-mapped
tensors) and the pool's frames in files of rows linked to the last complete checkpoint's where
unchanged (:mod:`trl_cartpole.storage.chunked`), nothing pickled:
:class:`FrameStackCheckpointer`.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import torch
from tensordict import TensorDict, TensorDictBase
from tensordict.utils import NestedKey
from torchrl.data import LazyTensorStorage
from torchrl.data.replay_buffers.checkpointers import TensorStorageCheckpointer

from trl_cartpole.storage.chunked import INDEX_FILE, ChunkWriter, read_chunks

__all__ = [
    "FramePool",
    "FrameStackCheckpointer",
    "FrameStackStorage",
    "pool_capacity",
    "slots_key",
]

POOL_DIR = "frame_pool"
FRAMES_DIR = "frames"  # the pool's frames, in files of rows (storage/chunked.py)


def slots_key(key: NestedKey) -> NestedKey:
    """Where a row keeps the slots of the stack stored under ``key``: ``pixels`` ->
    ``pixels_slots``, ``("next", "pixels")`` -> ``("next", "pixels_slots")``."""
    if isinstance(key, tuple):
        return (*key[:-1], f"{key[-1]}_slots")
    return f"{key}_slots"


def pool_capacity(max_size: int) -> int:
    """The frames a pool first holds for ``max_size`` transitions: one new frame a transition,
    an eighth more for the stacks that start a game (it grows past this when needed)."""
    return max_size + max_size // 8 + 64


class FramePool:
    """Distinct frames ``[slots, H, W]`` uint8, each with the count of stored rows using it.

    :meth:`intern` returns a frame's slot (an existing one when the same frame is held) and
    counts one more use; :meth:`release` counts one less and frees a slot no row uses. The
    pool grows by half when no slot is free.
    """

    def __init__(self, frame_shape: Sequence[int], capacity: int) -> None:
        self.frames = torch.zeros((capacity, *frame_shape), dtype=torch.uint8)
        self.uses = torch.zeros(capacity, dtype=torch.int64)
        self._hashes: list[int | None] = [None] * capacity
        self._slots_of: dict[int, list[int]] = {}
        self._free = list(range(capacity - 1, -1, -1))
        self.written: list[int] = []  # slots given a new frame since the storage last looked

    @property
    def held(self) -> int:
        """How many distinct frames the pool holds."""
        return len(self._hashes) - len(self._free)

    def intern(self, frames: torch.Tensor) -> torch.Tensor:
        """``[M, H, W]`` uint8 frames -> ``[M]`` int64 slots, each use counted."""
        slots = torch.empty(frames.shape[0], dtype=torch.int64)
        arrays = frames.contiguous().numpy()
        for i, array in enumerate(arrays):
            key = hash(array.tobytes())
            slot = next(
                (s for s in self._slots_of.get(key, ()) if torch.equal(self.frames[s], frames[i])),
                None,
            )
            if slot is None:
                slot = self._take_free()
                self.frames[slot] = frames[i]
                self._remember(slot, key)
                self.written.append(slot)
            slots[i] = slot
        self.uses.index_add_(0, slots, torch.ones_like(slots))
        return slots

    def release(self, slots: torch.Tensor) -> None:
        """Count one use less of each of ``slots`` ``[M]``; free those no row uses."""
        self.uses.index_add_(0, slots, -torch.ones_like(slots))
        for slot in slots.unique().tolist():
            if self.uses[slot] == 0:
                self._forget(slot)

    def _remember(self, slot: int, key: int) -> None:
        """Find ``slot``'s frame again by its bytes' hash ``key``."""
        self._hashes[slot] = key
        self._slots_of.setdefault(key, []).append(slot)

    def _forget(self, slot: int) -> None:
        """Free ``slot``, which no row uses any more."""
        key = self._hashes[slot]
        self._slots_of[key].remove(slot)
        if not self._slots_of[key]:
            del self._slots_of[key]
        self._hashes[slot] = None
        self._free.append(slot)

    def _take_free(self) -> int:
        """A free slot; the pool grows by half when none is left."""
        if not self._free:
            old = self.frames.shape[0]
            extra = max(old // 2, 1)
            more = self.frames.new_zeros((extra, *self.frames.shape[1:]))
            self.frames = torch.cat([self.frames, more])
            self.uses = torch.cat([self.uses, self.uses.new_zeros(extra)])
            self._hashes += [None] * extra
            self._free = list(range(old + extra - 1, old - 1, -1))
        return self._free.pop()

    def state(self) -> TensorDict:
        """The frames and their counts up to the last slot in use (what a checkpoint saves)."""
        end = self.end()
        return TensorDict({"frames": self.frames[:end], "uses": self.uses[:end]}, batch_size=[])

    def end(self) -> int:
        """One past the last slot in use."""
        used = self.uses.nonzero()
        return int(used.max()) + 1 if used.numel() else 0

    def restore(self, frames: torch.Tensor, uses: torch.Tensor) -> None:
        """Put back a saved pool (:meth:`state`) into this pool's capacity or more: the frames,
        the counts, and the lookup rebuilt from them."""
        capacity = max(frames.shape[0], self.frames.shape[0])
        self.frames = frames.new_zeros((capacity, *frames.shape[1:]))
        self.frames[: frames.shape[0]] = frames
        self.restore_counts(uses)

    def restore_counts(self, uses: torch.Tensor) -> None:
        """Put back the counts of the frames already in place (read into ``frames``), and the
        lookup rebuilt from them."""
        capacity = self.frames.shape[0]
        self.uses = uses.new_zeros(capacity)
        self.uses[: uses.shape[0]] = uses
        self._hashes = [None] * capacity
        self._slots_of = {}
        self._free = []
        for slot in range(capacity - 1, -1, -1):
            if self.uses[slot] > 0:
                self._remember(slot, hash(self.frames[slot].numpy().tobytes()))
            else:
                self._free.append(slot)


class FrameStackStorage(LazyTensorStorage):
    """TorchRL's ``LazyTensorStorage`` that stores the frames of each stack once (module
    docstring).

    :param max_size: transitions held, as ``LazyTensorStorage``'s.
    :param frame_keys: the entries holding stacks ``[*, k, H, W]`` uint8; default the pixels
        of a transition and of its next step.
    :param kwargs: passed to ``LazyTensorStorage`` (``device``: the CPU only here).
    """

    def __init__(
        self,
        max_size: int,
        frame_keys: Sequence[NestedKey] = ("pixels", ("next", "pixels")),
        **kwargs: Any,
    ) -> None:
        if str(kwargs.get("device", "cpu")) != "cpu":
            raise ValueError("FrameStackStorage keeps its frames on the CPU: device='cpu'")
        super().__init__(max_size, **kwargs)
        self.frame_keys = [tuple(k) if isinstance(k, list) else k for k in frame_keys]
        self.pool: FramePool | None = None
        # the pool's slots written since the last complete checkpoint (parts/chunked_storage)
        self.pool_chunks = ChunkWriter()

    # the buffer sets the storage's checkpointer to its own or to this class's default
    _default_checkpointer = None  # FrameStackCheckpointer, set below its definition

    def set(self, cursor: Any, data: Any, *, set_cursor: bool = True) -> None:
        """Store ``data`` at ``cursor``: the frames of its stacks into the pool, their slots into
        the rows; the frames of the rows written over are released."""
        if not isinstance(data, TensorDictBase):
            raise TypeError("FrameStackStorage stores TensorDicts of transitions")
        single = isinstance(cursor, int)
        batch = data.unsqueeze(0) if single else data
        positions = self._positions(cursor)  # [B]
        if positions.unique().numel() != positions.numel():
            raise ValueError(
                f"an extend of {positions.numel()} transitions writes some of the "
                f"{self.max_size} rows twice: extend with at most max_size at a time"
            )
        if self.pool is None:
            stack = batch.get(self.frame_keys[0])  # [B, k, H, W]
            self.pool = FramePool(stack.shape[-2:], pool_capacity(self.max_size))
        self._release_rows(positions)
        rows = batch.exclude(*self.frame_keys)
        for key in self.frame_keys:
            stack = batch.get(key)  # [B, k, H, W] uint8
            if stack.dtype != torch.uint8:
                raise TypeError(f"{key}: frames must be uint8, got {stack.dtype}")
            slots = self.pool.intern(stack.reshape(-1, *stack.shape[-2:]))  # [B * k]
            rows.set(slots_key(key), slots.reshape(stack.shape[:-2]))  # [B, k]
        self.pool_chunks.mark(torch.tensor(self.pool.written, dtype=torch.int64))
        self.pool.written.clear()
        super().set(cursor, rows[0] if single else rows, set_cursor=set_cursor)

    def _positions(self, cursor: Any) -> torch.Tensor:
        """``[B]`` the rows ``cursor`` (an int, a slice, a sequence or a tensor) writes."""
        if isinstance(cursor, int):
            return torch.tensor([cursor])
        if isinstance(cursor, slice):
            return torch.arange(*cursor.indices(self.max_size))
        return torch.as_tensor(cursor).reshape(-1).cpu()

    def _release_rows(self, positions: torch.Tensor) -> None:
        """Release the frames of the filled rows among ``positions``, before they are written."""
        filled = positions[positions < len(self)] if self.initialized else positions[:0]
        for key in self.frame_keys if filled.numel() else ():
            self.pool.release(self._storage.get(slots_key(key))[filled].reshape(-1))

    def _empty(self) -> None:
        super()._empty()
        self.pool = None  # ``buffer.empty()``: every frame goes with the rows
        self.pool_chunks.loaded_from(None)

    def chunk_writers(self) -> list[ChunkWriter]:
        """The writer of the pool's frames, told when a checkpoint is complete."""
        return [self.pool_chunks]

    def state_dict(self) -> dict[str, Any]:
        """TorchRL's storage state, with the pool's frames and counts."""
        pool = None if self.pool is None else self.pool.state()
        return {**super().state_dict(), POOL_DIR: pool}

    def load_state_dict(self, state_dict: dict[str, Any]) -> None:
        state = dict(state_dict)
        pool = state.pop(POOL_DIR, None)
        super().load_state_dict(state)
        if pool is not None:
            self.pool = FramePool(pool["frames"].shape[-2:], pool_capacity(self.max_size))
            self.pool.restore(torch.as_tensor(pool["frames"]), torch.as_tensor(pool["uses"]))
        self.pool_chunks.loaded_from(None)  # no checkpoint files to link to

    def get(self, index: Any) -> TensorDictBase:
        """The rows at ``index`` with their stacks gathered back ``[*, k, H, W]`` uint8."""
        rows = super().get(index)
        for key in self.frame_keys:
            slots = rows.get(slots_key(key))  # [*, k]
            frames = self.pool.frames.index_select(0, slots.reshape(-1))  # [* k, H, W]
            rows.set(key, frames.reshape(*slots.shape, *frames.shape[1:]))
        return rows.exclude(*(slots_key(key) for key in self.frame_keys))

    def frame_bytes(self) -> int:
        """The bytes the pool's frames take (its capacity)."""
        return 0 if self.pool is None else self.pool.frames.numel()


class FrameStackCheckpointer(TensorStorageCheckpointer):
    """TorchRL's checkpointer of a tensor storage (the rows, memory-mapped), plus the frame
    pool in ``frame_pool/`` beside them: its counts memory-mapped, its frames in files of rows
    linked to the last complete checkpoint's where unchanged
    (:class:`~trl_cartpole.storage.chunked.ChunkWriter`)."""

    def dumps(self, storage: FrameStackStorage, path: Any) -> None:
        path = Path(path)
        super().dumps(storage, path)
        end = storage.pool.end()
        TensorDict({"uses": storage.pool.uses[:end]}, batch_size=[]).memmap(
            path / POOL_DIR, copy_existing=True
        )
        frames = {("frames",): storage.pool.frames}
        storage.pool_chunks.write(frames, end, path / POOL_DIR / FRAMES_DIR)
        with open(path / POOL_DIR / "frame_keys.json", "w", encoding="utf-8") as file:
            json.dump([list(k) if isinstance(k, tuple) else k for k in storage.frame_keys], file)

    def loads(self, storage: FrameStackStorage, path: Any) -> None:
        path = Path(path)
        saved_keys = json.loads((path / POOL_DIR / "frame_keys.json").read_text(encoding="utf-8"))
        keys = [list(k) if isinstance(k, tuple) else k for k in storage.frame_keys]
        if saved_keys != keys:
            raise ValueError(f"the saved storage holds the frames of {saved_keys}, not {keys}")
        super().loads(storage, path)
        uses = torch.as_tensor(TensorDict.load_memmap(path / POOL_DIR).get("uses"))
        frames_dir = path / POOL_DIR / FRAMES_DIR
        index = json.loads((frames_dir / INDEX_FILE).read_text(encoding="utf-8"))
        frame_shape = index["entries"]["frames"]["row_shape"]
        capacity = max(pool_capacity(storage.max_size), index["filled"])
        pool = FramePool(frame_shape, capacity)
        read_chunks(frames_dir, out={("frames",): pool.frames})  # in place: no second copy
        pool.restore_counts(uses)
        storage.pool = pool
        storage.pool_chunks.loaded_from(frames_dir)


FrameStackStorage._default_checkpointer = FrameStackCheckpointer

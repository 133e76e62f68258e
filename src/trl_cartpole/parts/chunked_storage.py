"""A replay buffer's checkpoint that writes only what changed since the last one.

TorchRL's storage checkpointer writes the whole filled storage at every checkpoint: the pixel
preset's 100 000 transitions (0.67 GB) each time, though one checkpoint interval adds a
fraction of them. Here a storage's tensors are written as files of ``chunk_rows`` rows
(:class:`ChunkWriter`). A file none of whose rows were written since this run's previous
complete checkpoint is a hard link to that checkpoint's file (no byte written, none stored
twice); the others are written anew. A file is never changed once written, so a kill inside a
write leaves every complete checkpoint whole, and deleting an old checkpoint deletes only its
names. Where the file system has no hard links, the file is copied: the same checkpoint, at
the old cost.

:class:`TrackedTensorStorage` is TorchRL's ``LazyTensorStorage`` that notes the rows each
write reaches, checkpointed by :class:`ChunkedStorageCheckpointer`; the frames storage's pool
(:mod:`trl_cartpole.parts.frame_storage`) is written the same way. The files are raw arrays
with a JSON index, nothing pickled; a storage loaded from a checkpoint links its next
checkpoint's unchanged files to that one.
"""

from __future__ import annotations

import json
import os
import shutil
import uuid
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import torch
from tensordict import TensorDict
from torchrl.data import LazyTensorStorage
from torchrl.data.replay_buffers.checkpointers import StorageCheckpointerBase

__all__ = [
    "CHUNK_ROWS",
    "INDEX_FILE",
    "ChunkWriter",
    "ChunkedStorageCheckpointer",
    "TrackedTensorStorage",
    "confirm_chunked_writes",
    "read_chunks",
]

CHUNK_ROWS = 1024  # rows a file holds: 7.4 MB of the pixel preset's stacks
INDEX_FILE = "chunks.json"

Key = tuple[str, ...]


def rows_of(cursor: Any, max_size: int) -> torch.Tensor:
    """``[B]`` the rows a storage write at ``cursor`` (an int, a slice, a sequence or a tensor)
    reaches."""
    if isinstance(cursor, int):
        return torch.tensor([cursor])
    if isinstance(cursor, slice):
        return torch.arange(*cursor.indices(max_size))
    return torch.as_tensor(cursor).reshape(-1).cpu()


def _link_or_copy(source: Path, target: Path) -> bool:
    """Hard-link ``source`` as ``target`` (a copy where the file system has no hard links);
    False if ``source`` is gone (its checkpoint deleted meanwhile)."""
    try:
        os.link(source, target)
    except FileNotFoundError:
        return False
    except OSError:  # EXDEV, EPERM, ENOTSUP: no hard links here
        try:
            shutil.copyfile(source, target)
        except FileNotFoundError:
            return False
    return True


def _as_bytes(tensor: torch.Tensor) -> np.ndarray:
    """A contiguous CPU tensor's bytes as a uint8 array (any dtype, bool too)."""
    return tensor.reshape(-1).view(torch.uint8).numpy()


class ChunkWriter:
    """Writes tensors ``{key: [N, ...]}`` as files of ``chunk_rows`` rows under a directory,
    each file whose rows were not marked since the last confirmed write a hard link to that
    write's (module doc).

    :meth:`mark` the rows each store writes; :meth:`write` at a checkpoint; :meth:`confirm`
    once the checkpoint holding it is complete (only then is it linked to next).
    """

    def __init__(self, chunk_rows: int = CHUNK_ROWS) -> None:
        self.chunk_rows = chunk_rows
        self.changed: set[int] = set()  # chunks written since the confirmed write
        self.previous: Path | None = None  # the directory of the confirmed write
        self._pending: tuple[str, set[int]] | None = None  # (write id, changes it holds)
        self.last_write_bytes = 0  # bytes the last write wrote (links not counted)

    def mark(self, rows: torch.Tensor) -> None:
        """Note that ``rows`` ``[B]`` are written (before or after this call, before the next
        :meth:`write`)."""
        if rows.numel():
            self.changed.update((rows // self.chunk_rows).unique().tolist())

    def write(
        self, tensors: Mapping[Key, torch.Tensor], filled: int, path: Path, **facts: Any
    ) -> None:
        """Write the first ``filled`` rows of every tensor under ``path``, with an index that
        records ``facts`` (JSON values) beside the layout."""
        path.mkdir(parents=True, exist_ok=True)
        rows, previous = self.chunk_rows, self._previous_filled()
        changed = set(self.changed)
        entries, written = {}, 0
        for key, tensor in tensors.items():
            folder = path.joinpath(*key)
            folder.mkdir(parents=True, exist_ok=True)
            array = tensor.detach().cpu()
            entries["/".join(key)] = {
                "key": list(key),
                "dtype": str(array.dtype).removeprefix("torch."),
                "row_shape": list(array.shape[1:]),
            }
            for chunk in range(-(-filled // rows)):
                target = folder / f"{chunk:06d}.bin"
                stop = min((chunk + 1) * rows, filled)
                if (
                    chunk not in changed
                    and previous >= stop  # that write's file holds these rows whole
                    and _link_or_copy(self.previous.joinpath(*key, target.name), target)
                ):
                    continue
                part = array[chunk * rows : stop].contiguous()
                _as_bytes(part).tofile(target)
                written += part.numel() * part.element_size()
        write_id = uuid.uuid4().hex
        index = {
            "write_id": write_id,
            "filled": filled,
            "chunk_rows": rows,
            "entries": entries,
            **facts,
        }
        with open(path / INDEX_FILE, "w", encoding="utf-8") as file:
            json.dump(index, file)
        self._pending = (write_id, changed)
        self.last_write_bytes = written

    def _previous_filled(self) -> int:
        """The rows the confirmed write holds (0: none to link to)."""
        if self.previous is None:
            return 0
        try:
            return json.loads((self.previous / INDEX_FILE).read_text(encoding="utf-8"))["filled"]
        except (OSError, ValueError, KeyError):  # deleted, or not ours: write every file
            return 0

    def confirm(self, checkpoint: Path) -> None:
        """The checkpoint at ``checkpoint`` is complete: if it holds the last :meth:`write`,
        its files are the ones to link to next and its rows no longer count as changed."""
        if self._pending is None:
            return
        write_id, held = self._pending
        for index in checkpoint.rglob(INDEX_FILE):
            if json.loads(index.read_text(encoding="utf-8")).get("write_id") == write_id:
                self.previous, self._pending = index.parent, None
                self.changed -= held
                return

    def loaded_from(self, path: Path | None) -> None:
        """The tensors are now those written at ``path`` (None: emptied): link to it next."""
        self.previous, self._pending = path, None
        self.changed.clear()


def read_chunks(path: Path) -> tuple[dict[Key, torch.Tensor], dict[str, Any]]:
    """The tensors ``{key: [filled, ...]}`` a :class:`ChunkWriter` wrote at ``path``, and its
    index."""
    index = json.loads((path / INDEX_FILE).read_text(encoding="utf-8"))
    tensors = {}
    for folder, entry in index["entries"].items():
        dtype = getattr(torch, entry["dtype"])
        files = sorted((path / folder).glob("*.bin"))
        parts = [torch.from_numpy(np.fromfile(f, dtype=np.uint8)).view(dtype) for f in files]
        flat = torch.cat(parts) if parts else torch.empty(0, dtype=dtype)
        tensors[tuple(entry["key"])] = flat.reshape(index["filled"], *entry["row_shape"])
    return tensors, index


class TrackedTensorStorage(LazyTensorStorage):
    """TorchRL's ``LazyTensorStorage`` (one dimension) whose rows written since its last
    complete checkpoint are noted (``chunks``), checkpointed by
    :class:`ChunkedStorageCheckpointer`."""

    def __init__(self, max_size: int, *, chunk_rows: int = CHUNK_ROWS, **kwargs: Any) -> None:
        super().__init__(max_size, **kwargs)
        self.chunks = ChunkWriter(chunk_rows)

    _default_checkpointer = None  # ChunkedStorageCheckpointer, set below its definition

    def set(self, cursor: Any, data: Any, *, set_cursor: bool = True) -> None:
        self.chunks.mark(rows_of(cursor, self.max_size))
        super().set(cursor, data, set_cursor=set_cursor)

    def _empty(self) -> None:
        super()._empty()
        self.chunks.loaded_from(None)  # nothing left to link to

    def chunk_writers(self) -> list[ChunkWriter]:
        return [self.chunks]


class ChunkedStorageCheckpointer(StorageCheckpointerBase):
    """Checkpoints a :class:`TrackedTensorStorage`'s filled rows in files of its chunks'
    rows, those unchanged since its last complete checkpoint linked to it (module doc)."""

    def dumps(self, storage: TrackedTensorStorage, path: Any) -> None:
        if not storage.initialized:
            raise RuntimeError("Cannot save a non-initialized storage.")
        tensors = {
            key if isinstance(key, tuple) else (key,): tensor
            for key, tensor in storage._storage.items(include_nested=True, leaves_only=True)
        }
        storage.chunks.write(tensors, len(storage), Path(path), capacity=storage.max_size)

    def loads(self, storage: TrackedTensorStorage, path: Any) -> None:
        path = Path(path)
        tensors, index = read_chunks(path)
        rows, capacity = index["chunk_rows"], index["capacity"]
        if rows != storage.chunks.chunk_rows or capacity != storage.max_size:
            raise ValueError(
                f"the saved storage holds {capacity} rows in files of {rows}, not "
                f"{storage.max_size} in files of {storage.chunks.chunk_rows}"
            )
        filled = index["filled"]
        loaded = TensorDict(tensors, batch_size=[filled])
        if not storage.initialized:
            storage._init(loaded[0])
        storage._storage[:filled] = loaded
        storage._len = filled
        storage.chunks.loaded_from(path)


TrackedTensorStorage._default_checkpointer = ChunkedStorageCheckpointer


def confirm_chunked_writes(buffer: Any, checkpoint: Path) -> None:
    """After ``checkpoint`` is complete: the buffer storage's next checkpoint links to it."""
    storage = getattr(buffer, "storage", None)
    for writer in getattr(storage, "chunk_writers", list)():
        writer.confirm(checkpoint)

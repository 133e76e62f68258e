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
(:mod:`trl_cartpole.storage.frames`) is written the same way. The files are raw arrays
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

from trl_cartpole.compat import allocate_storage, set_storage_length, storage_tensors

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
    """``[B]`` the rows a storage write at ``cursor`` reaches: an int (negative ones count from
    the end), a slice, a range, a sequence, an index tensor or a boolean mask."""
    if isinstance(cursor, torch.Tensor):
        cursor = cursor.cpu()
    return torch.arange(max_size)[cursor].reshape(-1)


def _link(source: Path, target: Path) -> bool:
    """Hard-link ``source`` as the new name ``target`` (a copy where the file system has no
    hard links); False if ``source`` is gone (its checkpoint deleted meanwhile)."""
    try:
        os.link(source, target)
    except FileNotFoundError:
        return False
    except FileExistsError:
        raise
    except OSError:  # EXDEV, EPERM, ENOTSUP: no hard links here
        try:
            shutil.copyfile(source, target)
        except FileNotFoundError:
            return False
    return True


def _write_new(target: Path, tensor: torch.Tensor) -> int:
    """Write a contiguous CPU tensor's bytes (any dtype, bool too) as the new file ``target``
    (never through an existing name: it may be another checkpoint's file); the bytes."""
    data = tensor.reshape(-1).view(torch.uint8).numpy()
    with open(target, "xb") as file:
        data.tofile(file)
    return data.nbytes


class ChunkWriter:
    """Writes tensors ``{key: [N, ...]}`` as files of ``chunk_rows`` rows under a directory,
    each file whose rows were not marked since the last confirmed write a hard link to that
    write's (module doc).

    :meth:`mark` the rows each store writes (:meth:`mark_all` when a write's rows are not
    known); :meth:`write` at a checkpoint; :meth:`confirm` once the checkpoint holding it is
    complete (only then is it linked to next).
    """

    def __init__(self, chunk_rows: int = CHUNK_ROWS) -> None:
        self.chunk_rows = chunk_rows
        self.changed: set[int] = set()  # chunks written since the confirmed write
        self.all_changed = False  # a write whose rows are not known: every chunk
        self.previous: Path | None = None  # the directory of the confirmed write
        self._pending: tuple[str, set[int], bool] | None = None  # (write id, its changes)
        self.last_write_bytes = 0  # bytes the last write wrote (links not counted)

    def mark(self, rows: torch.Tensor) -> None:
        """Note that ``rows`` ``[B]`` are written (before or after this call, before the next
        :meth:`write`)."""
        if rows.numel():
            self.changed.update((rows // self.chunk_rows).unique().tolist())

    def mark_all(self) -> None:
        """Note that any row may have changed: the next write links nothing."""
        self.all_changed = True

    def write(
        self, tensors: Mapping[Key, torch.Tensor], filled: int, path: Path, **facts: Any
    ) -> None:
        """Write the first ``filled`` rows of every tensor as new files under ``path``, with an
        index that records ``facts`` (JSON values) beside the layout."""
        path.mkdir(parents=True, exist_ok=True)
        rows, previous = self.chunk_rows, self._previous_filled(path)
        changed, all_changed = set(self.changed), self.all_changed
        entries, written = {}, 0
        for key, tensor in tensors.items():
            folder = path.joinpath(*key)
            folder.mkdir(parents=True, exist_ok=True)
            entries["/".join(key)] = {
                "key": list(key),
                "dtype": str(tensor.dtype).removeprefix("torch."),
                "row_shape": list(tensor.shape[1:]),
            }
            for chunk in range(-(-filled // rows)):
                target = folder / f"{chunk:06d}.bin"
                target.unlink(missing_ok=True)  # a name only: another link keeps its bytes
                start, stop = chunk * rows, min((chunk + 1) * rows, filled)
                if (
                    not all_changed
                    and chunk not in changed
                    and min(previous, start + rows) == stop  # that file holds these rows
                    and _link(self.previous.joinpath(*key, target.name), target)
                ):
                    continue
                written += _write_new(target, tensor[start:stop].detach().contiguous().cpu())
        write_id = uuid.uuid4().hex
        index = {
            "write_id": write_id,
            "filled": filled,
            "chunk_rows": rows,
            "entries": entries,
            **facts,
        }
        (path / INDEX_FILE).unlink(missing_ok=True)
        with open(path / INDEX_FILE, "x", encoding="utf-8") as file:
            json.dump(index, file)
        self._pending = (write_id, changed, all_changed)
        self.last_write_bytes = written

    def _previous_filled(self, path: Path) -> int:
        """The rows the confirmed write holds (0: none to link to, or it is ``path`` itself,
        written over)."""
        if self.previous is None or self.previous.resolve() == path.resolve():
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
        write_id, held, all_held = self._pending
        for index in checkpoint.rglob(INDEX_FILE):
            if json.loads(index.read_text(encoding="utf-8")).get("write_id") == write_id:
                self.previous, self._pending = index.parent, None
                self.changed -= held
                self.all_changed = self.all_changed and not all_held
                return

    def loaded_from(self, path: Path | None) -> None:
        """The tensors are now those written at ``path`` (None: emptied): link to it next."""
        self.previous, self._pending = path, None
        self.changed.clear()
        self.all_changed = False


def read_chunks(
    path: Path, out: Mapping[Key, torch.Tensor] | None = None
) -> tuple[dict[Key, torch.Tensor], dict[str, Any]]:
    """The tensors ``{key: [filled, ...]}`` a :class:`ChunkWriter` wrote at ``path``, and its
    index. With ``out`` (a tensor of at least ``filled`` rows per key), each file is read into
    its rows, with no second copy: the rows of ``out`` are returned."""
    index = json.loads((path / INDEX_FILE).read_text(encoding="utf-8"))
    filled, rows = index["filled"], index["chunk_rows"]
    tensors = {}
    for folder, entry in index["entries"].items():
        key, dtype = tuple(entry["key"]), getattr(torch, entry["dtype"])
        target = torch.empty((filled, *entry["row_shape"]), dtype=dtype)
        if out is not None:
            target = out[key][:filled]
        for chunk in range(-(-filled // rows)):
            data = np.fromfile(path / folder / f"{chunk:06d}.bin", dtype=np.uint8)
            part = torch.from_numpy(data).view(dtype)
            target[chunk * rows : (chunk + 1) * rows] = part.reshape(-1, *entry["row_shape"])
        tensors[key] = target
    return tensors, index


class TrackedTensorStorage(LazyTensorStorage):
    """TorchRL's ``LazyTensorStorage`` (one dimension) whose rows written since its last
    complete checkpoint are noted (``chunks``), checkpointed by
    :class:`ChunkedStorageCheckpointer`."""

    def __init__(self, max_size: int, *, chunk_rows: int = CHUNK_ROWS, **kwargs: Any) -> None:
        super().__init__(max_size, **kwargs)
        self.chunks = ChunkWriter(chunk_rows)
        self._marked = False  # inside ``set``: its rows are marked already

    _default_checkpointer = None  # ChunkedStorageCheckpointer, set below its definition

    def set(self, cursor: Any, data: Any, *, set_cursor: bool = True) -> None:
        self.chunks.mark(rows_of(cursor, self.max_size))
        self._marked = True
        try:
            super().set(cursor, data, set_cursor=set_cursor)
        finally:
            self._marked = False

    def _bump_mutation_revision(self) -> None:
        """TorchRL's note of every change to the contents: one outside ``set`` (the buffer's
        ``update_``, ``set_``, a conditional patch) marks every row changed."""
        chunks = getattr(self, "chunks", None)
        if chunks is not None and not self._marked:
            chunks.mark_all()
        super()._bump_mutation_revision()

    def _empty(self) -> None:
        super()._empty()
        self.chunks.loaded_from(None)  # nothing left to link to

    def loads(self, path: Any) -> None:
        self._marked = True  # the checkpointer records where the rows came from
        try:
            super().loads(path)
        finally:
            self._marked = False

    def load_state_dict(self, state_dict: dict[str, Any]) -> None:
        super().load_state_dict(state_dict)
        self.chunks.loaded_from(None)  # no checkpoint files to link to
        self.chunks.mark_all()

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
            for key, tensor in storage_tensors(storage).items(include_nested=True, leaves_only=True)
        }
        storage.chunks.write(tensors, len(storage), Path(path), capacity=storage.max_size)

    def loads(self, storage: TrackedTensorStorage, path: Any) -> None:
        path = Path(path)
        index = json.loads((path / INDEX_FILE).read_text(encoding="utf-8"))
        rows, capacity = index["chunk_rows"], index["capacity"]
        if rows != storage.chunks.chunk_rows or capacity != storage.max_size:
            raise ValueError(
                f"the saved storage holds {capacity} rows in files of {rows}, not "
                f"{storage.max_size} in files of {storage.chunks.chunk_rows}"
            )
        if not storage.initialized:  # allocated from a row of zeros, then read into
            row = {
                tuple(entry["key"]): torch.zeros(
                    entry["row_shape"], dtype=getattr(torch, entry["dtype"])
                )
                for entry in index["entries"].values()
            }
            allocate_storage(storage, TensorDict(row, batch_size=[]))
        leaves = {
            key if isinstance(key, tuple) else (key,): tensor
            for key, tensor in storage_tensors(storage).items(include_nested=True, leaves_only=True)
        }
        read_chunks(path, out=leaves)  # each file into its rows: no second copy of the buffer
        set_storage_length(storage, index["filled"])
        storage.chunks.loaded_from(path)


TrackedTensorStorage._default_checkpointer = ChunkedStorageCheckpointer


def confirm_chunked_writes(buffer: Any, checkpoint: Path) -> None:
    """After ``checkpoint`` is complete: the buffer storage's next checkpoint links to it."""
    storage = getattr(buffer, "storage", None)
    for writer in getattr(storage, "chunk_writers", list)():
        writer.confirm(checkpoint)

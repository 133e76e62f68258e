"""A replay buffer's checkpoint that writes only what changed since the last one.

TorchRL's storage checkpointer writes the whole filled storage at every checkpoint: the pixel
preset's 100 000 transitions (0.67 GB) each time, though one checkpoint interval adds a
fraction of them. :class:`ChunkedStorageCheckpointer` writes each entry's filled rows as
files of ``chunk_rows`` rows. A file none of whose rows were written since this run's
previous checkpoint is a hard link to that checkpoint's file (no byte written, none stored
twice); the others are written anew. A file is never changed once written, so a kill inside a
write leaves every complete checkpoint whole, and deleting an old checkpoint deletes only its
names. Where the file system has no hard links, the file is copied: the same checkpoint, at
the old cost.

:class:`TrackedTensorStorage` is TorchRL's ``LazyTensorStorage`` that notes which rows each
write reaches, for its checkpointer. The files are raw arrays with a JSON index, nothing
pickled; a storage loaded from a checkpoint links its next checkpoint's unchanged files to it.
"""

from __future__ import annotations

import json
import os
import shutil
import uuid
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
    "ChunkedStorageCheckpointer",
    "TrackedTensorStorage",
    "confirm_chunked_writes",
]

CHUNK_ROWS = 1024  # rows a file holds: 7.4 MB of the pixel preset's stacks
INDEX_FILE = "chunks.json"


def _rows_of(cursor: Any, max_size: int) -> torch.Tensor:
    """``[B]`` the rows a storage write at ``cursor`` (an int, a slice, a sequence or a tensor)
    reaches."""
    if isinstance(cursor, int):
        return torch.tensor([cursor])
    if isinstance(cursor, slice):
        return torch.arange(*cursor.indices(max_size))
    return torch.as_tensor(cursor).reshape(-1).cpu()


class TrackedTensorStorage(LazyTensorStorage):
    """TorchRL's ``LazyTensorStorage`` that remembers the chunks of rows written since its
    last confirmed checkpoint (:class:`ChunkedStorageCheckpointer`), one dimension only."""

    def __init__(self, max_size: int, *, chunk_rows: int = CHUNK_ROWS, **kwargs: Any) -> None:
        super().__init__(max_size, **kwargs)
        self.chunk_rows = chunk_rows
        self.changed_chunks: set[int] = set()

    _default_checkpointer = None  # ChunkedStorageCheckpointer, set below its definition

    def set(self, cursor: Any, data: Any, *, set_cursor: bool = True) -> None:
        rows = _rows_of(cursor, self.max_size)
        self.changed_chunks.update((rows // self.chunk_rows).unique().tolist())
        super().set(cursor, data, set_cursor=set_cursor)

    def _empty(self) -> None:
        super()._empty()
        self.changed_chunks.clear()
        if isinstance(self.checkpointer, ChunkedStorageCheckpointer):
            self.checkpointer.previous = None  # nothing left to link to


def _key_dir(key: tuple[str, ...]) -> str:
    return "/".join(key)


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


class ChunkedStorageCheckpointer(StorageCheckpointerBase):
    """Checkpoints a :class:`TrackedTensorStorage` in files of ``chunk_rows`` rows, linking the
    files whose rows did not change since its previous confirmed checkpoint (module doc).

    ``previous`` is that checkpoint's storage directory, set by :meth:`confirm` once the
    checkpoint holding a write is complete (``confirm_chunked_writes``) and by :meth:`loads`.
    """

    def __init__(self) -> None:
        super().__init__()
        self.previous: Path | None = None
        self._pending: tuple[str, set[int]] | None = None  # (write id, chunks it wrote)
        self.last_write_bytes = 0  # bytes the last dumps wrote (linked files not counted)

    def dumps(self, storage: TrackedTensorStorage, path: Any) -> None:
        path = Path(path)
        path.mkdir(parents=True, exist_ok=True)
        if not storage.initialized:
            raise RuntimeError("Cannot save a non-initialized storage.")
        filled, rows = len(storage), storage.chunk_rows
        chunks = -(-filled // rows)
        changed = set(storage.changed_chunks)
        previous = self._previous_index()
        entries, written = {}, 0
        for key, tensor in storage._storage.items(include_nested=True, leaves_only=True):
            key = key if isinstance(key, tuple) else (key,)
            folder = path / _key_dir(key)
            folder.mkdir(parents=True, exist_ok=True)
            array = tensor.detach().cpu()
            entries[_key_dir(key)] = {
                "key": list(key),
                "dtype": str(array.dtype).removeprefix("torch."),
                "row_shape": list(array.shape[1:]),
            }
            for chunk in range(chunks):
                target = folder / f"{chunk:06d}.bin"
                stop = min((chunk + 1) * rows, filled)
                if (
                    chunk not in changed
                    and previous is not None
                    and previous["filled"] >= stop  # that file holds these rows whole
                    and _link_or_copy(self.previous / _key_dir(key) / target.name, target)
                ):
                    continue
                part = array[chunk * rows : stop].contiguous()
                _as_bytes(part).tofile(target)
                written += part.numel() * part.element_size()
        write_id = uuid.uuid4().hex
        index = {
            "write_id": write_id,
            "filled": filled,
            "capacity": storage.max_size,
            "chunk_rows": rows,
            "entries": entries,
        }
        with open(path / INDEX_FILE, "w", encoding="utf-8") as file:
            json.dump(index, file)
        self._pending = (write_id, changed)
        self.last_write_bytes = written

    def _previous_index(self) -> dict[str, Any] | None:
        if self.previous is None:
            return None
        try:
            return json.loads((self.previous / INDEX_FILE).read_text(encoding="utf-8"))
        except (OSError, ValueError):  # deleted, or not ours: write every file
            return None

    def confirm(self, checkpoint: Path, storage: TrackedTensorStorage) -> None:
        """The checkpoint at ``checkpoint`` (complete) holds the last :meth:`dumps`: its
        files are the ones to link to next, and its rows no longer count as changed."""
        if self._pending is None:
            return
        write_id, written_changes = self._pending
        for index in checkpoint.rglob(INDEX_FILE):
            if json.loads(index.read_text(encoding="utf-8")).get("write_id") == write_id:
                self.previous = index.parent
                storage.changed_chunks -= written_changes
                self._pending = None
                return

    def loads(self, storage: TrackedTensorStorage, path: Any) -> None:
        path = Path(path)
        index = json.loads((path / INDEX_FILE).read_text(encoding="utf-8"))
        filled, rows = index["filled"], index["chunk_rows"]
        if rows != storage.chunk_rows or index["capacity"] != storage.max_size:
            raise ValueError(
                f"the saved storage holds {index['capacity']} rows in files of {rows}, not "
                f"{storage.max_size} in files of {storage.chunk_rows}"
            )
        loaded = TensorDict(batch_size=[filled])
        for folder, entry in index["entries"].items():
            dtype = getattr(torch, entry["dtype"])
            files = sorted((path / folder).glob("*.bin"))
            parts = [_from_bytes(np.fromfile(f, dtype=np.uint8), dtype) for f in files]
            flat = torch.cat(parts) if parts else torch.empty(0, dtype=dtype)
            loaded.set(tuple(entry["key"]), flat.reshape(filled, *entry["row_shape"]))
        if not storage.initialized:
            storage._init(loaded[0])
        storage._storage[:filled] = loaded
        storage._len = filled
        storage.changed_chunks.clear()  # the storage is that checkpoint's: link to it next
        self.previous = path
        self._pending = None


def _as_bytes(tensor: torch.Tensor) -> np.ndarray:
    """A contiguous CPU tensor's bytes as a uint8 array (any dtype, bool and bfloat16 too)."""
    return tensor.reshape(-1).view(torch.uint8).numpy()


def _from_bytes(data: np.ndarray, dtype: torch.dtype) -> torch.Tensor:
    return torch.from_numpy(data.copy()).view(dtype)


def confirm_chunked_writes(buffer: Any, checkpoint: Path) -> None:
    """After ``checkpoint`` is complete: a chunked storage's next checkpoint links to it."""
    storage = getattr(buffer, "storage", None)
    checkpointer = getattr(storage, "checkpointer", None)
    if isinstance(checkpointer, ChunkedStorageCheckpointer):
        checkpointer.confirm(checkpoint, storage)


TrackedTensorStorage._default_checkpointer = ChunkedStorageCheckpointer

"""A buffer's checkpoint writes what changed since the last one and links the rest."""

from __future__ import annotations

import os
from pathlib import Path

import pytest
import torch
from tensordict import TensorDict
from torchrl.checkpoint import Checkpoint, CheckpointRotation
from torchrl.data import TensorDictReplayBuffer

from trl_cartpole.storage.chunked import (
    INDEX_FILE,
    ChunkedStorageCheckpointer,
    TrackedTensorStorage,
    confirm_chunked_writes,
)

ROWS = 64  # rows a file holds here


def _buffer(capacity: int = 1000) -> TensorDictReplayBuffer:
    return TensorDictReplayBuffer(
        storage=TrackedTensorStorage(capacity, chunk_rows=ROWS), batch_size=8
    )


def _transitions(start: int, count: int) -> TensorDict:
    """``count`` transitions numbered from ``start``: every entry tells which one it is."""
    number = torch.arange(start, start + count)
    return TensorDict(
        {
            "pixels": (number[:, None, None] % 251).expand(count, 3, 5).to(torch.uint8),
            "action": number,
            "next": {"reward": number.float() / 7, "done": (number % 9 == 0)[:, None]},
        },
        batch_size=[count],
    )


def _save(buffer: TensorDictReplayBuffer, path: Path) -> Path:
    """A complete checkpoint of the buffer at ``path``, confirmed as the run's checkpointer
    does."""
    saved = Path(Checkpoint(replay_buffer=buffer).save(path))
    confirm_chunked_writes(buffer, saved)
    return saved


def _files(checkpoint: Path) -> dict[str, os.stat_result]:
    """The storage's files (``entry/chunk.bin``, relative to its index) and their stats."""
    storage = next(checkpoint.rglob(INDEX_FILE)).parent
    return {str(f.relative_to(storage)): f.stat() for f in storage.rglob("*.bin")}


def _loaded(checkpoint: Path, capacity: int = 1000) -> TensorDictReplayBuffer:
    buffer = _buffer(capacity)
    Checkpoint(replay_buffer=buffer).load(checkpoint)
    return buffer


def test_a_checkpoint_links_the_files_whose_rows_did_not_change(tmp_path):
    buffer = _buffer()
    buffer.extend(_transitions(0, 640))  # 10 files of 64 rows per entry
    first = _save(buffer, tmp_path / "first")
    writes_first = buffer.storage.chunks.last_write_bytes
    buffer.extend(_transitions(640, 100))  # rows 640..739: files 10 and 11, new
    second = _save(buffer, tmp_path / "second")
    before, after = _files(first), _files(second)
    linked = {
        name for name in after if name in before and after[name].st_ino == before[name].st_ino
    }
    # every entry's files 0..9 are the first checkpoint's own (one inode); 10 and 11 are new
    entries = {name.rsplit("/", 1)[0] for name in after}
    assert linked == {f"{e}/{i:06d}.bin" for e in entries for i in range(10)}
    stored_row = buffer.storage._storage[0]  # the transition and the buffer's own "index"
    row_bytes = sum(t.element_size() * t.numel() for t in stored_row.values(True, True))
    assert buffer.storage.chunks.last_write_bytes == 100 * row_bytes
    assert writes_first == 640 * row_bytes
    # both load to what was stored, bit for bit
    for checkpoint, count in ((first, 640), (second, 740)):
        loaded = _loaded(checkpoint)
        assert len(loaded) == count
        assert (loaded.storage[:count] == buffer.storage[:count]).all()


def test_rows_written_over_after_wrapping_around_are_written_again(tmp_path):
    buffer = _buffer(capacity=256)
    buffer.extend(_transitions(0, 256))  # full: 4 files
    first = _save(buffer, tmp_path / "first")
    buffer.extend(_transitions(256, 70))  # rows 0..69 written over: files 0 and 1
    second = _save(buffer, tmp_path / "second")
    before, after = _files(first), _files(second)
    for name, stat in after.items():
        same = stat.st_ino == before[name].st_ino
        assert same == (name.endswith(("000002.bin", "000003.bin"))), name
    loaded = _loaded(second, capacity=256)
    assert (loaded.storage[:256] == buffer.storage[:256]).all()
    assert loaded.storage[0]["action"].item() == 256  # the row written over


def test_a_write_not_confirmed_is_not_linked_to_and_its_rows_stay_changed(tmp_path):
    # A checkpoint cut off before it was complete is never confirmed: the next one links to the
    # last complete one, and writes the rows changed since that one, including the cut-off's.
    buffer = _buffer()
    buffer.extend(_transitions(0, 128))
    first = _save(buffer, tmp_path / "first")
    buffer.extend(_transitions(128, 64))
    Checkpoint(replay_buffer=buffer).save(tmp_path / "cut-off")  # no confirm: a kill after it
    buffer.extend(_transitions(192, 64))
    third = _save(buffer, tmp_path / "third")
    before, after = _files(first), _files(third)
    linked = {n for n in after if n in before and after[n].st_ino == before[n].st_ino}
    assert {n.rsplit("/", 1)[1] for n in linked} == {"000000.bin", "000001.bin"}
    assert (_loaded(third).storage[:256] == buffer.storage[:256]).all()


def test_deleting_the_older_checkpoint_leaves_the_newer_whole(tmp_path):
    buffer = _buffer()
    rotation = CheckpointRotation(tmp_path / "periodic", keep_last=1)
    buffer.extend(_transitions(0, 300))
    saved = Path(rotation.save(Checkpoint(replay_buffer=buffer), step=300))
    confirm_chunked_writes(buffer, saved)
    buffer.extend(_transitions(300, 10))
    newer = Path(rotation.save(Checkpoint(replay_buffer=buffer), step=310))  # removes the first
    confirm_chunked_writes(buffer, newer)
    assert not saved.exists()
    assert (_loaded(newer).storage[:310] == buffer.storage[:310]).all()
    buffer.extend(_transitions(310, 10))  # and the next links to the newer one
    third = _save(buffer, tmp_path / "third")
    assert _files(third)["action/000000.bin"].st_ino == _files(newer)["action/000000.bin"].st_ino


def test_a_loaded_storage_links_its_next_checkpoint_to_the_one_it_came_from(tmp_path):
    buffer = _buffer()
    buffer.extend(_transitions(0, 200))
    first = _save(buffer, tmp_path / "first")
    resumed = _loaded(first)
    resumed.extend(_transitions(200, 5))
    second = _save(resumed, tmp_path / "second")
    assert _files(second)["action/000000.bin"].st_ino == _files(first)["action/000000.bin"].st_ino
    assert _files(second)["action/000003.bin"].st_ino != _files(first)["action/000003.bin"].st_ino


def test_a_storage_of_another_shape_is_refused(tmp_path):
    buffer = _buffer()
    buffer.extend(_transitions(0, 10))
    first = _save(buffer, tmp_path / "first")
    index = next(first.rglob(INDEX_FILE))
    other = TrackedTensorStorage(1000, chunk_rows=ROWS * 2)
    with pytest.raises(ValueError, match="in files of 128"):
        ChunkedStorageCheckpointer().loads(other, index.parent)


def _stacks(start: int, count: int) -> TensorDict:
    """``count`` transitions of 2-frame 8x8 stacks over the new frames ``start`` to
    ``start + count + 1`` (each frame apart: its number in its bytes); a transition's next
    stack is the following one's."""
    number = torch.arange(start, start + count + 2)
    frames = (number % 256).to(torch.uint8)[:, None, None].expand(-1, 8, 8).clone()
    frames[:, 0, :] = (number // 256).to(torch.uint8)[:, None]  # frames apart past 256
    stacks = torch.stack([frames[i : i + 2] for i in range(count + 1)])  # [count + 1, 2, 8, 8]
    return TensorDict(
        {"pixels": stacks[:-1], "action": number[:count], "next": {"pixels": stacks[1:]}},
        batch_size=[count],
    )


def test_a_frames_checkpoint_links_the_pools_unchanged_frames(tmp_path):
    from trl_cartpole.storage.frames import FrameStackStorage

    buffer = TensorDictReplayBuffer(storage=FrameStackStorage(5000), batch_size=8)
    buffer.extend(_stacks(0, 2100))  # 2 102 frames: pool files 0, 1 and 2
    first = _save(buffer, tmp_path / "first")
    buffer.extend(_stacks(2102, 10))  # 12 more frames, in pool file 2
    second = _save(buffer, tmp_path / "second")
    before, after = _files(first), _files(second)
    assert after["frames/000000.bin"].st_ino == before["frames/000000.bin"].st_ino
    assert after["frames/000001.bin"].st_ino == before["frames/000001.bin"].st_ino
    assert after["frames/000002.bin"].st_ino != before["frames/000002.bin"].st_ino
    loaded = TensorDictReplayBuffer(storage=FrameStackStorage(5000), batch_size=8)
    Checkpoint(replay_buffer=loaded).load(second)
    rows = torch.arange(len(buffer))
    assert (loaded.storage.get(rows) == buffer.storage.get(rows)).all()


def test_a_linked_file_keeps_its_digest_and_both_checkpoints_verify(tmp_path):
    import json

    from trl_cartpole.store.checkpoint import INTEGRITY, verify_checkpoint, write_integrity

    buffer = _buffer()
    buffer.extend(_transitions(0, 300))
    first = write_integrity(_save(buffer, tmp_path / "first"))
    buffer.extend(_transitions(300, 30))
    second = write_integrity(_save(buffer, tmp_path / "second"))
    verify_checkpoint(first)  # every digest read again from the bytes
    verify_checkpoint(second)
    digests = [json.loads((c / INTEGRITY).read_text()) for c in (first, second)]
    shared = [name for name in digests[1] if name.endswith("action/000000.bin")]
    assert shared and digests[0][shared[0]] == digests[1][shared[0]]


def test_a_file_holding_more_rows_than_now_filled_is_written_anew(tmp_path):
    # The frame pool's filled end can move down (its top slots freed): a file of the previous
    # write with more rows than the new end is not linked, so each file holds its rows exactly.
    from trl_cartpole.storage.chunked import ChunkWriter, read_chunks

    writer = ChunkWriter(chunk_rows=64)
    frames = torch.arange(200 * 3, dtype=torch.int16).reshape(200, 3)
    writer.write({("frames",): frames}, 100, tmp_path / "first")  # files of 64 and 36 rows
    writer.confirm(tmp_path / "first")
    writer.write({("frames",): frames}, 90, tmp_path / "second")  # nothing marked
    first, second = (tmp_path / name / "frames" for name in ("first", "second"))
    assert (second / "000000.bin").stat().st_ino == (first / "000000.bin").stat().st_ino
    assert (second / "000001.bin").stat().st_ino != (first / "000001.bin").stat().st_ino
    tensors, _ = read_chunks(tmp_path / "second")
    assert torch.equal(tensors[("frames",)], frames[:90])


def test_every_way_of_writing_rows_is_noted(tmp_path):
    buffer = _buffer(capacity=256)
    buffer.extend(_transitions(0, 256))
    first = _save(buffer, tmp_path / "first")
    buffer.storage.set(-1, _transitions(900, 1)[0])  # the last row: the last file
    buffer.storage.set(torch.arange(256) == 3, _transitions(901, 1))  # a mask: the first file
    second = _save(buffer, tmp_path / "second")
    before, after = _files(first), _files(second)
    new = {n.rsplit("/", 1)[1] for n in after if after[n].st_ino != before[n].st_ino}
    assert new == {"000000.bin", "000003.bin"}
    # a change TorchRL makes outside ``set`` (a state loaded in place): every file anew
    buffer.storage.load_state_dict(buffer.storage.state_dict())
    third = _save(buffer, tmp_path / "third")
    assert all(_files(third)[n].st_ino != after[n].st_ino for n in after)
    loaded = _loaded(third, capacity=256)
    assert (loaded.storage[:256] == buffer.storage[:256]).all()


def test_a_linked_file_is_not_read_again_for_its_digest(tmp_path, monkeypatch):
    from trl_cartpole.store import checkpoint as checkpoint_module

    buffer = _buffer()
    buffer.extend(_transitions(0, 640))
    checkpoint_module.write_integrity(_save(buffer, tmp_path / "first"))
    buffer.extend(_transitions(640, 10))  # files 10 (new), 0..9 linked
    hashed = []
    real = checkpoint_module.hashlib.sha256

    def counting(data=b""):
        hashed.append(len(data))
        return real(data)

    monkeypatch.setattr(checkpoint_module.hashlib, "sha256", counting)
    checkpoint_module.write_integrity(_save(buffer, tmp_path / "second"))
    chunk_files = [f for f in _files(tmp_path / "second").values()]
    linked = [f for f in chunk_files if f.st_nlink > 1]
    assert len(linked) == 10 * len({n.rsplit("/", 1)[0] for n in _files(tmp_path / "second")})
    assert (
        len(hashed)
        == sum(1 for f in (tmp_path / "second").rglob("*") if f.is_file()) - len(linked) - 1
    )  # every file but the linked ones and the integrity record itself

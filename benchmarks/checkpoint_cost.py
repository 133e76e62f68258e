"""What a training state's replay buffer costs to checkpoint: seconds and bytes, linked or whole.

    python -m benchmarks checkpoint-cost [--filled 100000] [--added 10000] [env=cartpole_pixels]

Fills a buffer of the preset's ``buffer.max_size`` in memory with ``--filled`` transitions shaped
like the env's (random values) and checkpoints it as a run does (TorchRL's ``Checkpoint``,
then the integrity record), then adds ``--added`` more and checkpoints again: the storage a
run uses (:class:`~trl_cartpole.storage.chunked.TrackedTensorStorage`, files linked
where unchanged), then TorchRL's ``LazyTensorStorage`` with its own checkpointer (the whole
storage each time; the earlier version of this project wrote its filled rows each time, the
same once the buffer is full). For each: the seconds, the bytes written
(new files; linked ones are not written) and the disk the two checkpoints take together
(each file once, however many names it has).
"""

from __future__ import annotations

import argparse
import json
import shutil
import tempfile
import time
from pathlib import Path
from typing import Any

import torch
from tensordict import TensorDict
from torchrl.checkpoint import Checkpoint
from torchrl.data import LazyTensorStorage, TensorDictReplayBuffer

from trl_cartpole.config.compose import compose_config
from trl_cartpole.config.schema import to_config
from trl_cartpole.run.from_config import build_env
from trl_cartpole.storage.chunked import TrackedTensorStorage, confirm_chunked_writes
from trl_cartpole.store.checkpoint import write_integrity

SEEDS = [0]  # the config's seed: the harness's common arguments
OUT = Path("runs/bench/checkpoint_cost")
LINKED = "this project's (files linked where unchanged)"
TABLE_HEAD = [
    "| storage | first checkpoint, s | second, s | second writes, MiB | both on disk, MiB |",
    "| --- | --- | --- | --- | --- |",
]


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--filled", type=int, default=100_000, help="transitions at first")
    parser.add_argument("--added", type=int, default=10_000, help="transitions added after")
    parser.add_argument("--record", type=Path, help="write the figures to this results file")


def _transitions(template: TensorDict, count: int) -> TensorDict:
    """``count`` transitions shaped like ``template``'s, of random values."""

    def random_like(tensor: torch.Tensor) -> torch.Tensor:
        shape = (count, *tensor.shape)
        if tensor.dtype == torch.uint8:
            return torch.randint(0, 256, shape, dtype=torch.uint8)
        if tensor.dtype == torch.bool:
            return torch.rand(shape) < 0.01
        return torch.rand(shape).to(tensor.dtype)

    return template.apply(random_like, batch_size=[count])


def _disk_bytes(*paths: Path) -> int:
    """The bytes the files under ``paths`` take, each inode counted once."""
    seen: dict[tuple[int, int], int] = {}
    for path in paths:
        for file in path.rglob("*"):
            if file.is_file():
                stat = file.stat()
                seen[(stat.st_dev, stat.st_ino)] = stat.st_size
    return sum(seen.values())


def _written_bytes(before: set[tuple[int, int]], path: Path) -> int:
    """The bytes of the files under ``path`` that are not among the inodes ``before``."""
    total = 0
    for file in path.rglob("*"):
        if file.is_file():
            stat = file.stat()
            total += 0 if (stat.st_dev, stat.st_ino) in before else stat.st_size
    return total


def _inodes(path: Path) -> set[tuple[int, int]]:
    return {(f.stat().st_dev, f.stat().st_ino) for f in path.rglob("*") if f.is_file()}


def _checkpoint(buffer, path: Path) -> float:
    start = time.perf_counter()
    saved = write_integrity(Path(Checkpoint(replay_buffer=buffer).save(path)))
    confirm_chunked_writes(buffer, saved)
    return time.perf_counter() - start


def _measure(buffer, batches: list[TensorDict], root: Path, label: str) -> dict[str, Any]:
    buffer.extend(batches[0])
    first_seconds = _checkpoint(buffer, root / "first")
    inodes = _inodes(root / "first")
    for batch in batches[1:]:
        buffer.extend(batch)
    second_seconds = _checkpoint(buffer, root / "second")
    row = {
        "storage": label,
        "first_seconds": first_seconds,
        "second_seconds": second_seconds,
        "second_written_bytes": _written_bytes(inodes, root / "second"),
        "disk_bytes": _disk_bytes(root / "first", root / "second"),
    }
    print(table_row(row), flush=True)
    return row


def table_row(row: dict[str, Any]) -> str:
    """One storage's figures as a row of :data:`TABLE_HEAD`."""
    return (
        f"| {row['storage']} | {row['first_seconds']:.2f} | {row['second_seconds']:.2f} | "
        f"{row['second_written_bytes'] / 2**20:.1f} | {row['disk_bytes'] / 2**20:.1f} |"
    )


def main(args: argparse.Namespace) -> None:
    cfg = to_config(compose_config("configs", ["env=cartpole_pixels", *args.overrides]))
    env = build_env(cfg, cfg.seed, num_envs=1)
    step = env.rand_step(env.reset())
    template = step[0] if step.batch_dims else step  # one transition
    env.close()
    size = cfg.buffer.max_size
    added = [args.added] if args.added <= size else []
    batches = [_transitions(template, args.filled), *(_transitions(template, n) for n in added)]
    print(
        f"{cfg.env.id}, a buffer of {size}: {args.filled} transitions, "
        f"then {args.added} more; each checkpoint with its integrity record"
    )
    print("\n".join(TABLE_HEAD))
    args.out.mkdir(parents=True, exist_ok=True)
    root = Path(tempfile.mkdtemp(dir=args.out))
    try:
        linked = TensorDictReplayBuffer(storage=TrackedTensorStorage(size), batch_size=32)
        rows = [_measure(linked, batches, root / "linked", LINKED)]
        whole = TensorDictReplayBuffer(storage=LazyTensorStorage(size), batch_size=32)
        rows.append(_measure(whole, batches, root / "whole", "TorchRL's (the whole storage)"))
    finally:
        shutil.rmtree(root, ignore_errors=True)
    if args.record:
        _record(args, rows, cfg.env.id, size, _bytes_per_row(batches[0]))


def _bytes_per_row(batch: TensorDict) -> int:
    return sum(t.numel() * t.element_size() for t in batch.values(True, True)) // batch.numel()


def _record(args: argparse.Namespace, rows: list[dict], env_id: str, size: int, row_bytes: int):
    """The figures and the buffer they were measured on, with where and when (a results file:
    docs/reliability.md is generated from it)."""
    from benchmarks.harness import provenance

    command = "python -m benchmarks checkpoint-cost " + " ".join(
        [f"--filled {args.filled}", f"--added {args.added}", *args.overrides]
    )
    buffer = {"env_id": env_id, "size": size, "filled": args.filled, "added": args.added}
    record = {**provenance(), "command": command, "buffer": {**buffer, "row_bytes": row_bytes}}
    args.record.write_text(json.dumps({**record, "rows": rows}, indent=2) + "\n")

"""Resident memory over a whole run: does it grow beyond what the replay buffer fills?

    python -m benchmarks memory [--seeds 100] [--out runs/memory] [env=lunarlander ...]

Per seed, one ``scripts/train.py`` run to its whole budget (``env=lunarlander`` unless the
overrides name another env). Every evaluation records the process's resident memory
(``eval_curve.rss_mb`` in ``summary.json``). The replay buffer's storage is allocated whole with
its first batch, but its pages become resident only as transitions are written, so memory may
grow by what the buffer fills and by nothing else. The table gives, per seed, the resident
memory at the first and the last evaluation, the peak, the buffer's bytes (its component in
``checkpoints/last``), what the buffer filled between those two evaluations
(``bytes * (min(frames, size) at the last - the same at the first) / size``) and the growth
beyond it: ``last - first - filled``, which a leak would make positive and large.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import yaml

from benchmarks.harness import run_training
from trl_cartpole.store.files import tree_bytes

SEEDS, OUT = [100], "runs/memory"
MIB = 2**20
COLUMNS = (
    "seed",
    "evaluations",
    "first MiB (frame)",
    "last MiB (frame)",
    "peak MiB",
    "buffer MiB",
    "filled between MiB",
    "growth beyond the buffer MiB",
)


def memory_row(run_dir: Path, summary: dict) -> list[str]:
    """One row of ``COLUMNS`` for a finished run."""
    curve = summary["eval_curve"]
    points = [(f, mb) for f, mb in zip(curve["frames"], curve["rss_mb"], strict=True) if mb]
    (first_frame, first_mb), (last_frame, last_mb) = points[0], points[-1]
    size = yaml.safe_load((run_dir / "config.yaml").read_text())["buffer"]["size"]
    components = run_dir / "checkpoints" / "last" / "components"
    buffer_mb = sum(tree_bytes(path) for path in components.glob("*replay_buffer")) / MIB
    filled_mb = buffer_mb * (min(last_frame, size) - min(first_frame, size)) / size
    growth = last_mb - first_mb - filled_mb
    return [
        str(summary["seed"]),
        str(len(points)),
        f"{first_mb:.0f} ({first_frame})",
        f"{last_mb:.0f} ({last_frame})",
        f"{summary['peak_rss_mb']:.0f}",
        f"{buffer_mb:.1f}",
        f"{filled_mb:.1f}",
        f"{growth:+.1f}",
    ]


def add_arguments(parser: argparse.ArgumentParser) -> None:
    del parser  # --seeds, --out and the overrides are all it takes


def main(args: argparse.Namespace) -> None:
    overrides = list(args.overrides)
    if not any(item.startswith(("env=", "env.id=")) for item in overrides):
        overrides.insert(0, "env=lunarlander")
    lines = [f"| {' | '.join(COLUMNS)} |", "|" + " --- |" * len(COLUMNS)]
    for seed in args.seeds:
        summary = run_training("dqn", seed, args.out, overrides)
        lines.append(f"| {' | '.join(memory_row(Path(summary['run_dir']), summary))} |")
    text = "\n".join(lines)
    print(text)
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "results.md").write_text(text + "\n")
    (args.out / "results.json").write_text(json.dumps({"overrides": overrides}, indent=2) + "\n")

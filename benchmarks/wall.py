"""Where a default run's wall time goes, against its training time and importing torch + TorchRL.

    python -m benchmarks wall [--seeds 0 1 2] [--out runs/wall] [key=value ...]

Per seed, one after the other in this order: a process that only imports torch and TorchRL
(``python -c "import torch, torchrl"``, start to exit), then ``scripts/train.py`` (start to exit,
a fresh run every time). The table splits the run's wall time into training (``train_seconds``),
the rest of the run (evaluations, the final evaluation, plots, checkpoints: ``wall_seconds -
train_seconds`` of its summary) and start-up and exit (imports, config, interpreter exit), and
gives the ratio ``wall / (training + import process)`` with its median over seeds; the target
is at most 1.25.
"""

from __future__ import annotations

import argparse
import json
import shutil
import statistics
import subprocess
import sys
import time

from benchmarks.harness import REPOSITORY, TRAIN_SCRIPT, subprocess_env

SEEDS, OUT = [0, 1, 2], "runs/wall"
RATIO_TARGET = 1.25
COLUMNS = ("import s", "wall s", "training s", "rest of the run s", "start-up and exit s", "ratio")


def _timed(command: list[str]) -> float:
    """Seconds from the start of ``command`` to its exit (run in the repository root)."""
    start = time.perf_counter()
    subprocess.run(
        command, check=True, stdout=subprocess.DEVNULL, cwd=REPOSITORY, env=subprocess_env()
    )
    return time.perf_counter() - start


def measure(seed: int, out, overrides: list[str]) -> tuple[float, ...]:
    """One row of the table for ``seed``: the figures of ``COLUMNS``."""
    import_s = _timed([sys.executable, "-c", "import torch, torchrl"])
    run_dir = (out / f"seed{seed}").resolve()
    shutil.rmtree(run_dir, ignore_errors=True)  # always a fresh run
    train = [sys.executable, str(TRAIN_SCRIPT), f"seed={seed}", f"run_dir={run_dir}"]
    wall_s = _timed([*train, "logger.progress_bar=false", *overrides])
    summary = json.loads((run_dir / "summary.json").read_text())
    train_s, run_s = summary["train_seconds"], summary["wall_seconds"]
    return import_s, wall_s, train_s, run_s - train_s, wall_s - run_s, wall_s / (train_s + import_s)


def wall_table(rows: dict[int, tuple[float, ...]]) -> str:
    """The markdown table: one row per seed, then the medians."""
    lines = [f"| seed | {' | '.join(COLUMNS)} |", "|" + " --- |" * (len(COLUMNS) + 1)]
    medians = tuple(statistics.median(column) for column in zip(*rows.values(), strict=True))
    for name, row in [*rows.items(), ("median", medians)]:
        cells = [f"{value:.2f}" for value in row]
        lines.append(f"| {name} | {' | '.join(cells)} |")
    met = "met" if medians[-1] <= RATIO_TARGET else "not met"
    lines.append(f"\nmedian ratio {medians[-1]:.2f} (target <= {RATIO_TARGET}: {met})")
    return "\n".join(lines)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    del parser  # --seeds, --out and the overrides are all it takes


def main(args: argparse.Namespace) -> None:
    if args.jobs != 1:
        raise SystemExit("error: wall times whole processes one at a time; use --jobs 1")
    args.out.mkdir(parents=True, exist_ok=True)
    rows = {seed: measure(seed, args.out, args.overrides) for seed in args.seeds}
    text = wall_table(rows)
    print(text)
    (args.out / "results.md").write_text(text + "\n")

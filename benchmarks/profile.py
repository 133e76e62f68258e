"""Where training time goes: the seconds of each loop phase, as every run's summary reports them.

    python -m benchmarks profile [--algo dqn] [--seeds 0] [--out runs/profile] [key=value ...]

Trains ``--algo`` with the overrides once per seed (``scripts/train.py`` in its own process;
finished runs are reused) and prints a markdown table from the summaries' ``phase_seconds``
(``trl_cartpole.run.progress.Progress.phase``): per phase, the median seconds over seeds and its
share of the median training seconds; then the training seconds no phase timed and the seconds
outside training (evaluation, checkpoints, start-up: ``wall_seconds - train_seconds``).
"""

from __future__ import annotations

import argparse
import statistics
from collections.abc import Sequence
from typing import Any

from benchmarks.harness import run_presets

SEEDS, OUT = [0], "runs/profile"


def phase_table(summaries: Sequence[dict[str, Any]]) -> str:
    """The markdown table of the medians over ``summaries`` (one per seed) of each phase."""
    train = statistics.median(s["train_seconds"] for s in summaries)
    phases = dict.fromkeys(name for s in summaries for name in s["phase_seconds"])
    rows = [(name, [s["phase_seconds"].get(name, 0.0) for s in summaries]) for name in phases]
    untimed = [s["train_seconds"] - sum(s["phase_seconds"].values()) for s in summaries]
    lines = ["| phase | seconds (median) | share of training seconds |", "| --- | --- | --- |"]
    for name, seconds in [*rows, ("not in a phase", untimed)]:
        median = statistics.median(seconds)
        lines.append(f"| {name} | {median:.2f} | {100 * median / train:.1f} % |")
    lines.append(f"| **training** | {train:.2f} | 100 % |")
    outside = statistics.median(s["wall_seconds"] - s["train_seconds"] for s in summaries)
    lines.append(f"| evaluation, checkpoints, start-up (not training) | {outside:.2f} | - |")
    return "\n".join(lines)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--algo", default="dqn", help="the algo preset to train")


def main(args: argparse.Namespace) -> None:
    runs = run_presets([args.algo], args.seeds, args.out, args.overrides, jobs=args.jobs)
    text = phase_table(runs[args.algo])
    print(text)
    (args.out / "results.md").write_text(text + "\n")

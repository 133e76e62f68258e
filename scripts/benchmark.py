"""Median frames and seconds to solve over seeds, per preset.

    python scripts/benchmark.py --algos dqn tutorial --seeds 0 1 2 3 4 \
        [--out runs/bench] [key=value ...]

Each (preset, seed) is one ``scripts/train.py`` run in its own process (the machine's noise is
the same for all); the table of medians is printed and written to ``OUT/results.md`` and
``OUT/results.json``. Timings are training wall time without evaluation, as in summary.json.
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
from pathlib import Path

TRAIN = Path(__file__).resolve().parent / "train.py"


def run_one(algo: str, seed: int, out: Path, overrides: list[str]) -> dict:
    run_dir = out / f"{algo}-seed{seed}"
    summary_path = run_dir / "summary.json"
    if not summary_path.exists():
        command = [
            sys.executable,
            str(TRAIN),
            f"algo={algo}",
            f"seed={seed}",
            f"run_dir={run_dir}",
            "logger.progress_bar=false",
            *overrides,
        ]
        subprocess.run(command, check=True, stdout=subprocess.DEVNULL)
    return json.loads(summary_path.read_text())


def median_or_none(values: list[float | None]) -> float | None:
    present = [v for v in values if v is not None]
    return statistics.median(present) if len(present) == len(values) and present else None


def table(results: dict[str, list[dict]]) -> str:
    lines = [
        "| preset | seeds | solved | median frames_to_solve | median seconds_to_solve | "
        "median final 100-ep greedy return | frames_to_solve per seed |",
        "| --- | --- | --- | --- | --- | --- | --- |",
    ]
    for algo, runs in results.items():
        frames = [r["frames_to_solve"] for r in runs]
        seconds = [r["seconds_to_solve"] for r in runs]
        final = statistics.median(r["final_eval_return_mean"] for r in runs)
        med_frames, med_seconds = median_or_none(frames), median_or_none(seconds)
        lines.append(
            f"| {algo} | {len(runs)} | {sum(r['solved'] for r in runs)}/{len(runs)} | "
            f"{'n/a' if med_frames is None else f'{med_frames:.0f}'} | "
            f"{'n/a' if med_seconds is None else f'{med_seconds:.1f}'} | {final:.1f} | "
            f"{', '.join('-' if f is None else str(f) for f in frames)} |"
        )
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--algos", nargs="+", default=["dqn"])
    parser.add_argument("--seeds", nargs="+", type=int, default=[0, 1, 2, 3, 4])
    parser.add_argument("--out", type=Path, default=Path("runs/benchmark"))
    parser.add_argument("overrides", nargs="*", help="Hydra overrides passed to every run")
    args = parser.parse_args()
    results = {
        algo: [run_one(algo, seed, args.out, args.overrides) for seed in args.seeds]
        for algo in args.algos
    }
    text = table(results)
    print(text)
    (args.out / "results.md").write_text(text + "\n")
    (args.out / "results.json").write_text(json.dumps(results, indent=2) + "\n")


if __name__ == "__main__":
    main()

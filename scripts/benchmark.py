"""Median frames and seconds to solve over seeds, per preset.

    python scripts/benchmark.py --algos dqn tutorial --seeds 0 1 2 3 4 \
        [--out runs/bench] [key=value ...]

Each (preset, seed) is one ``scripts/train.py`` run in its own process, one after another (the
machine's noise is the same for all); the table of medians is printed and written to
``OUT/results.md`` and ``OUT/results.json``. Timings are training wall time without
evaluation, as in summary.json.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from trl_cartpole.benchmarking import markdown_table, run_presets


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--algos", nargs="+", default=["dqn"])
    parser.add_argument("--seeds", nargs="+", type=int, default=[0, 1, 2, 3, 4])
    parser.add_argument("--out", type=Path, default=Path("runs/benchmark"))
    parser.add_argument("overrides", nargs="*", help="Hydra overrides passed to every run")
    args = parser.parse_args()
    results = run_presets(args.algos, args.seeds, args.out, args.overrides)
    text = markdown_table(results)
    print(text)
    (args.out / "results.md").write_text(text + "\n")
    (args.out / "results.json").write_text(json.dumps(results, indent=2) + "\n")


if __name__ == "__main__":
    main()

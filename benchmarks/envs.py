"""Train the env presets over seeds and check them against their targets (docs/environments.md).

    python -m benchmarks envs [--envs acrobot mountaincar lunarlander] [--seeds 0 1 2]
        [--jobs 2] [--out runs/envs] [key=value ...]

Each (env preset, seed) is one ``scripts/train.py env=<preset> seed=<seed>`` run in its own
process (``--jobs`` at a time), into ``OUT/<preset>/dqn-seed<seed>``; a finished run is not
run again. The figure a target is checked on is the median over seeds of the best policy's
final greedy return over ``eval.final_episodes`` (100) episodes. Prints the table, writes it to
``OUT/results.md`` and draws ``OUT/<preset>.png`` (eval return against frames and training
seconds: median over seeds with the interquartile band).
"""

from __future__ import annotations

import argparse
import statistics
from pathlib import Path

from benchmarks.harness import ENV_TARGETS, run_presets
from trl_cartpole.plotting import plot_comparison

SEEDS, OUT = [0, 1, 2], "runs/envs"


def table(results: dict[str, list[dict]]) -> str:
    """One markdown row per env preset: target, median final return, frames and seconds."""
    rows = [
        "| preset | env | target | median final return | per seed | met | frames | "
        "train s (median) | wall s (median) |",
        "| --- | --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    for preset, runs in results.items():
        finals = [run["final_eval_return_mean"] for run in runs]
        median = statistics.median(finals)
        target = ENV_TARGETS[preset]
        rows.append(
            f"| {preset} | {runs[0]['env_id']} | >= {target:g} | {median:.1f} | "
            f"{', '.join(f'{value:.1f}' for value in finals)} | "
            f"{'yes' if median >= target else 'no'} | "
            f"{statistics.median(run['frames'] for run in runs):,.0f} | "
            f"{statistics.median(run['train_seconds'] for run in runs):.0f} | "
            f"{statistics.median(run['wall_seconds'] for run in runs):.0f} |"
        )
    return "\n".join(rows)


def plot(preset: str, runs: list[dict], out: Path) -> Path:
    """Eval return against frames and training seconds, median over the seeds."""
    curves = [run["eval_curve"] for run in runs]
    panels = {
        "Frames": {preset: [(c["frames"], c["returns"]) for c in curves]},
        "Training seconds": {preset: [(c["seconds"], c["returns"]) for c in curves]},
    }
    return plot_comparison(panels, out / f"{preset}.png", threshold=ENV_TARGETS[preset])


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--envs", nargs="+", default=list(ENV_TARGETS), choices=list(ENV_TARGETS))


def main(args: argparse.Namespace) -> None:
    results = {}
    for preset in args.envs:
        out = args.out / preset
        results[preset] = run_presets(
            ["dqn"], args.seeds, out, [f"env={preset}", *args.overrides], jobs=args.jobs
        )["dqn"]
        print(f"{preset}: {plot(preset, results[preset], args.out)}", flush=True)
    text = table(results)
    print(text)
    (args.out / "results.md").write_text(text + "\n")

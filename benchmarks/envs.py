"""Train the env presets over seeds and check them against their targets (docs/environments.md).

    python -m benchmarks envs [--envs acrobot mountaincar lunarlander cartpole_pixels]
        [--seeds 0 1 2]
        [--jobs 2] [--out runs/envs] [--record docs/results/PRESET.json] [key=value ...]

Each (env preset, seed) is one ``scripts/train.py env=<preset> seed=<seed>`` run in its own
process (``--jobs`` at a time), into ``OUT/<preset>/dqn-seed<seed>``; a finished run is not
run again. A target is checked on the best policy's final greedy return over
``eval.final_episodes`` (100) episodes: every seed must reach it (and LunarLander's median over
seeds its own). The table gives the interquartile mean with its 95 % stratified bootstrap
interval (``trl_cartpole.report.interval_estimates``), the median and the worst seed, and the
training seconds until the first periodic evaluation at or above the target (its 20 or 50
episodes, a first sign; the target itself is the final 100). Prints it,
writes it to ``OUT/results.md`` and draws ``OUT/<preset>.png`` (eval return against frames
and training seconds: median over seeds with the interquartile band).
"""

from __future__ import annotations

import argparse
import json
import math
import statistics
import sys
from pathlib import Path

from benchmarks.harness import ENV_MEDIAN_TARGETS, ENV_TARGETS, provenance, run_presets
from trl_cartpole.report.interval_estimates import interval_estimate
from trl_cartpole.report.plotting import plot_comparison

SEEDS, OUT = [0, 1, 2], "runs/envs"


def target_text(preset: str) -> str:
    """``every seed >= -80``, with the median target where the preset has one."""
    text = f"every seed >= {ENV_TARGETS[preset]:g}"
    if preset in ENV_MEDIAN_TARGETS:
        text += f", median >= {ENV_MEDIAN_TARGETS[preset]:g}"
    return text


def target_met(preset: str, finals: list[float]) -> bool:
    """Every seed at or above the preset's target, and the median at or above its own."""
    median_target = ENV_MEDIAN_TARGETS.get(preset, -float("inf"))
    return min(finals) >= ENV_TARGETS[preset] and statistics.median(finals) >= median_target


def seconds_to_target(run: dict, target: float) -> float | None:
    """Training seconds at the first periodic evaluation at or above ``target`` (None: never)."""
    curve = run["eval_curve"]
    reached = (s for s, r in zip(curve["seconds"], curve["returns"], strict=True) if r >= target)
    return next(reached, None)


def _median_seconds_to_target(runs: list[dict], target: float) -> str:
    """The median over seeds (a seed that never reached it counts as slowest), or ``never``."""
    seconds = [seconds_to_target(run, target) for run in runs]
    median = statistics.median(math.inf if s is None else s for s in seconds)
    return "never" if math.isinf(median) else f"{median:.0f}"


def table(results: dict[str, list[dict]]) -> str:
    """One markdown row per env preset: the final returns over seeds, frames and seconds."""
    rows = [
        "| preset | env | target | final return IQM [95% CI] | median | worst seed | per seed | "
        "met | frames | train s to the first eval >= target (median) | train s (median) | "
        "wall s (median) |",
        "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    for preset, runs in results.items():
        finals = [run["final_eval_return_mean"] for run in runs]
        seeds_met = sum(final >= ENV_TARGETS[preset] for final in finals)
        rows.append(
            f"| {preset} | {runs[0]['env_id']} | {target_text(preset)} | "
            f"{interval_estimate(finals)} ({len(finals)} seed{'s' if len(finals) > 1 else ''}) | "
            f"{statistics.median(finals):.1f} | {min(finals):.1f} | "
            f"{', '.join(f'{value:.1f}' for value in finals)} | "
            f"{'yes' if target_met(preset, finals) else 'no'} "
            f"({seeds_met}/{len(finals)} seeds) | "
            f"{statistics.median(run['frames'] for run in runs):,.0f} | "
            f"{_median_seconds_to_target(runs, ENV_TARGETS[preset])} | "
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
    parser.add_argument(  # cartpole_pixels (30 minutes a seed) only when asked for
        "--envs",
        nargs="+",
        default=[preset for preset in ENV_TARGETS if preset != "cartpole_pixels"],
        choices=list(ENV_TARGETS),
    )
    parser.add_argument(
        "--record",
        type=Path,
        help="also write every summary to this results file (docs/results), for one preset",
    )


def write_record(path: Path, command: str, runs: list[dict]) -> None:
    """``path`` (docs/results/*.json): the command, when and where it ran, and every seed's
    summary; ``python -m maintain docs`` renders the per-seed table from it."""
    record = {**provenance(), "command": command, "runs": runs}
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(record, indent=2) + "\n")


def main(args: argparse.Namespace) -> None:
    if args.record is not None and len(args.envs) != 1:
        raise SystemExit("error: --record writes one preset's runs; name one with --envs")
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
    if args.record is not None:
        command = "python -m benchmarks envs " + " ".join(sys.argv[2:])
        write_record(args.record, command, results[args.envs[0]])

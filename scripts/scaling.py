"""Measure how collection scales on this machine (docs/scaling.md).

    python scripts/scaling.py [--seeds 0 1 2] [--frames 16384] [--train-frames 8192]
        [--out runs/scaling] [--parts collect train solve]

- ``collect``: frames per second of the collector alone, for 1, 2 and 4 envs per worker and
  1 worker, 2 synchronous and 2 asynchronous workers, then the default's 32 envs on 1 worker or
  split 16 + 16 over 2, plus TorchRL's ``ParallelEnv`` in place of Gymnasium's
  ``SyncVectorEnv`` (one worker); median over ``--seeds`` repetitions (``--envs`` picks layouts).
- ``train``: frames per second of whole training runs (``--train-frames`` frames, evaluation
  excluded, ``buffer.n_steps=1`` everywhere so asynchronous workers run the same algorithm) in
  the same layouts, each run its own process, one at a time.
- ``solve``: the default config with its 32 envs on 1 worker, on 2 synchronous and 2
  asynchronous worker processes, and on 2 Ray actors (a local Ray instance): solve rate,
  median frames and seconds to solve over ``--seeds``.

Prints the tables and writes them to ``OUT/results.md``. Run it on an idle machine.
"""

from __future__ import annotations

import argparse
import statistics
from pathlib import Path

from trl_cartpole.benchmarking import CONFIG_DIR, markdown_table, run_training
from trl_cartpole.cli import compose_config
from trl_cartpole.config import to_config
from trl_cartpole.scaling import collection_fps

WORKER_LAYOUTS = {  # label -> overrides
    "1 worker": ["collector.workers=1"],
    "2 workers, sync": ["collector.workers=2", "collector.sync=true"],
    "2 workers, async": ["collector.workers=2", "collector.sync=false"],
}
# (envs per worker, worker layout): 1, 2 and 4 envs in every layout, then the default's 32 envs
# in one process or split over two.
LAYOUTS = [(envs, layout) for envs in (1, 2, 4) for layout in WORKER_LAYOUTS] + [
    (32, "1 worker"),
    (16, "2 workers, sync"),
    (16, "2 workers, async"),
]
PARALLEL_ENV_SIZES = (2, 4)  # also timed with TorchRL's ParallelEnv in place of SyncVectorEnv
TRAIN_OVERRIDES = [
    "buffer.n_steps=1",
    "eval.stop_when_solved=false",
    "eval.interval_frames=1000000000",  # no periodic evaluation: the final one only
    "eval.final_episodes=10",
    "checkpoint.interval_frames=0",
    "logger.plots=false",
    "logger.live_plot=false",
]
SOLVE_LAYOUTS = {  # label -> overrides of the default config (32 envs in all)
    "1 worker, 32 envs": [],
    "2 workers, sync, 16 envs each": ["collector.workers=2", "env.num_envs=16"],
    "2 workers, async, 16 envs each": [
        "collector.workers=2",
        "env.num_envs=16",
        "collector.sync=false",
        "buffer.n_steps=1",
    ],
    "2 Ray actors, sync, 16 envs each": [
        "collector.backend=ray",
        "collector.workers=2",
        "env.num_envs=16",
    ],
}


def _median_row(label: str, values: list[float]) -> str:
    per_seed = ", ".join(f"{value:,.0f}" for value in values)
    return f"| {label} | {statistics.median(values):,.0f} | {per_seed} |"


def _label(envs: int, layout: str) -> str:
    return f"{envs} env{'s' if envs > 1 else ''} per worker, {layout}"


def collect_table(seeds: list[int], frames: int, env_counts: list[int]) -> str:
    rows = ["| layout | collection frames/s (median) | per repetition |", "| --- | --- | --- |"]
    for envs, layout in LAYOUTS:
        if envs not in env_counts:
            continue
        fps = []
        for seed in seeds:
            overrides = [f"env.num_envs={envs}", f"seed={seed}", *WORKER_LAYOUTS[layout]]
            fps.append(collection_fps(to_config(compose_config(CONFIG_DIR, overrides)), frames))
        rows.append(_median_row(_label(envs, layout), fps))
        print(rows[-1], flush=True)
        if envs in PARALLEL_ENV_SIZES and layout == "1 worker":
            fps = []
            for seed in seeds:
                cfg = to_config(
                    compose_config(CONFIG_DIR, [f"env.num_envs={envs}", f"seed={seed}"])
                )
                fps.append(collection_fps(cfg, frames, parallel_env=True))
            rows.append(_median_row(f"{envs} envs, 1 worker, TorchRL ParallelEnv", fps))
            print(rows[-1], flush=True)
    return "\n".join(rows)


def train_table(seeds: list[int], frames: int, out: Path, env_counts: list[int]) -> str:
    rows = ["| layout | training frames/s (median) | per seed |", "| --- | --- | --- |"]
    for envs, layout in LAYOUTS:
        if envs not in env_counts:
            continue
        name = f"envs{envs}-{layout.replace(', ', '-').replace(' ', '')}"
        overrides = [
            f"env.num_envs={envs}",
            f"collector.total_frames={frames}",
            *TRAIN_OVERRIDES,
            *WORKER_LAYOUTS[layout],
        ]
        summaries = [run_training("dqn", seed, out / "train" / name, overrides) for seed in seeds]
        fps = [summary["frames"] / summary["train_seconds"] for summary in summaries]
        rows.append(_median_row(_label(envs, layout), fps))
        print(rows[-1], flush=True)
    return "\n".join(rows)


def solve_table(seeds: list[int], out: Path) -> str:
    results = {}
    for label, overrides in SOLVE_LAYOUTS.items():
        name = label.replace(", ", "-").replace(" ", "")
        results[label] = [
            run_training("dqn", seed, out / "solve" / name, overrides) for seed in seeds
        ]
        print(
            f"{label}: {sum(s['solved'] for s in results[label])}/{len(seeds)} solved", flush=True
        )
    return markdown_table(results, label="layout")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", nargs="+", type=int, default=[0, 1, 2])
    parser.add_argument("--frames", type=int, default=16_384, help="frames timed per layout")
    parser.add_argument("--train-frames", type=int, default=8_192)
    parser.add_argument("--out", type=Path, default=Path("runs/scaling"))
    parser.add_argument(
        "--envs",
        nargs="+",
        type=int,
        default=sorted({envs for envs, _ in LAYOUTS}),
        help="only the layouts with this many envs per worker",
    )
    parser.add_argument(
        "--parts",
        nargs="+",
        default=["collect", "train", "solve"],
        choices=["collect", "train", "solve"],
    )
    args = parser.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    sections = []
    if "collect" in args.parts:
        sections.append(
            "## Collection alone\n\n" + collect_table(args.seeds, args.frames, args.envs)
        )
    if "train" in args.parts:
        sections.append(
            "## Training\n\n" + train_table(args.seeds, args.train_frames, args.out, args.envs)
        )
    if "solve" in args.parts:
        sections.append("## Solving CartPole with workers\n\n" + solve_table(args.seeds, args.out))
    text = "\n\n".join(sections)
    print(text)
    (args.out / "results.md").write_text(text + "\n")


if __name__ == "__main__":
    main()

"""How collection and training scale with envs and workers here (docs/scaling-measured.md).

    python -m benchmarks scaling [--seeds 0 1 2] [--frames 16384] [--train-frames 8192]
        [--out runs/scaling] [--parts collect train solve] [--solve-layouts one sync async ray]
        [key=value ...]

A layout is how many envs each worker steps (``env.num_envs``), how many workers collect
(``collector.workers``) and whether they are synchronous; the overrides apply to every layout.

- ``collect``: frames per second of the collector alone (:func:`collection_fps`), for 1, 2 and
  4 envs per worker and 1 worker, 2 synchronous and 2 asynchronous workers, then the default's
  32 envs on 1 worker or split 16 + 16 over 2, plus TorchRL's ``ParallelEnv`` in place of
  Gymnasium's ``SyncVectorEnv`` (one worker); median over ``--seeds`` repetitions (``--envs``
  picks layouts).
- ``train``: frames per second of whole training runs (``--train-frames`` frames, evaluation
  excluded, ``buffer.n_steps=1`` everywhere so asynchronous workers run the same algorithm) in
  the same layouts, each run its own process, ``--jobs`` at a time.
- ``solve``: the default config with its 32 envs on 1 worker, on 2 synchronous and 2
  asynchronous worker processes, and on 2 Ray actors (a local Ray instance): solve rate,
  median frames and seconds to solve over ``--seeds``.

Prints the tables and writes them to ``OUT/results.md``. Run it on an idle machine.
"""

from __future__ import annotations

import argparse
import functools
import statistics
import time
from pathlib import Path

import torch
from tensordict.nn import TensorDictSequential
from torchrl.envs import EnvBase, ParallelEnv

from benchmarks.harness import CONFIG_DIR, run_presets
from trl_cartpole.config.compose import compose_config
from trl_cartpole.config.schema import Config, to_config
from trl_cartpole.parts.collectors import (
    is_distributed,
    make_collector,
    needs_weight_sync,
    shutdown_collector,
)
from trl_cartpole.run.build import choose_num_threads
from trl_cartpole.run.envs import worker_env_constructors
from trl_cartpole.run.from_config import build_actor, build_env, build_exploration
from trl_cartpole.tools.comparison import markdown_table

SEEDS, OUT = [0, 1, 2], "runs/scaling"
WARMUP_BATCHES = 5  # batches left out of the timing: worker start-up, first allocations

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
SOLVE_LAYOUTS = {  # name -> (label, overrides of the default config: 32 envs in all)
    "one": ("1 worker, 32 envs", []),
    "sync": ("2 workers, sync, 16 envs each", ["collector.workers=2", "env.num_envs=16"]),
    "async": (
        "2 workers, async, 16 envs each",
        ["collector.workers=2", "env.num_envs=16", "collector.sync=false", "buffer.n_steps=1"],
    ),
    "ray": (
        "2 Ray actors, sync, 16 envs each",
        ["collector.backend=ray", "collector.workers=2", "env.num_envs=16"],
    ),
}


def make_parallel_env(cfg: Config) -> ParallelEnv:
    """``cfg.env.num_envs`` single envs of ``cfg``, each in its own process (TorchRL)."""
    env = ParallelEnv(cfg.env.num_envs, functools.partial(build_env, cfg, cfg.seed, 1))
    env.set_seed(cfg.seed)
    return env


def collection_fps(cfg: Config, frames: int, parallel_env: bool = False) -> float:
    """Frames per second of collecting ``frames`` frames in the layout of ``cfg``, alone.

    The collector steps the untrained actor and its exploration as built for training, with a
    weight sync after every batch where training has one. ``parallel_env`` replaces the
    Gymnasium ``SyncVectorEnv`` of one worker by TorchRL's ``ParallelEnv`` (one process per
    env). The first ``WARMUP_BATCHES`` batches are not timed.
    """
    torch.set_num_threads(choose_num_threads(cfg.num_threads))
    env = build_env(cfg, cfg.seed)
    actor = build_actor(cfg, env)
    exploration = build_exploration(cfg, env)
    policy = actor if exploration is None else TensorDictSequential(actor, exploration)
    batch_frames = cfg.collector.frames_per_batch
    create_env_fn: EnvBase | list = env
    if is_distributed(cfg.collector.workers, cfg.collector.backend):
        create_env_fn = worker_env_constructors(cfg)
    elif parallel_env:
        create_env_fn = make_parallel_env(cfg)
    collector = make_collector(
        create_env_fn,
        policy,
        frames_per_batch=batch_frames,
        total_frames=frames + WARMUP_BATCHES * batch_frames,
        init_random_frames=0,  # the policy from the first frame: random ones time the env alone
        device=cfg.device,
        sync=cfg.collector.sync,
        backend=cfg.collector.backend,
        ray_address=cfg.collector.ray_address,
    )
    sync_weights = needs_weight_sync(collector, policy)
    collected, start = 0, None
    for index, batch in enumerate(collector):
        if index == WARMUP_BATCHES:
            start = time.perf_counter()
        if start is not None:
            collected += batch.numel()
        if exploration is not None:
            exploration.step(batch.numel())
        if sync_weights:
            collector.update_policy_weights_()
    seconds = time.perf_counter() - start
    shutdown_collector(collector)
    env.close()  # (the collector closed a ParallelEnv when it reached its total)
    return collected / seconds


def _median_row(label: str, values: list[float]) -> str:
    per_seed = ", ".join(f"{value:,.0f}" for value in values)
    return f"| {label} | {statistics.median(values):,.0f} | {per_seed} |"


def _label(envs: int, layout: str) -> str:
    return f"{envs} env{'s' if envs > 1 else ''} per worker, {layout}"


def _layout_fps(
    seeds: list[int], frames: int, overrides: list[str], parallel_env: bool = False
) -> list[float]:
    """:func:`collection_fps` of the config of ``overrides``, once per seed."""
    return [
        collection_fps(
            to_config(compose_config(CONFIG_DIR, [*overrides, f"seed={seed}"])),
            frames,
            parallel_env,
        )
        for seed in seeds
    ]


def collect_table(
    seeds: list[int], frames: int, env_counts: list[int], overrides: list[str]
) -> str:
    rows = ["| layout | collection frames/s (median) | per repetition |", "| --- | --- | --- |"]
    for envs, layout in LAYOUTS:
        if envs not in env_counts:
            continue
        layout_overrides = [*overrides, f"env.num_envs={envs}", *WORKER_LAYOUTS[layout]]
        rows.append(_median_row(_label(envs, layout), _layout_fps(seeds, frames, layout_overrides)))
        print(rows[-1], flush=True)
        if envs in PARALLEL_ENV_SIZES and layout == "1 worker":
            fps = _layout_fps(seeds, frames, layout_overrides, parallel_env=True)
            rows.append(_median_row(f"{envs} envs, 1 worker, TorchRL ParallelEnv", fps))
            print(rows[-1], flush=True)
    return "\n".join(rows)


def train_table(
    seeds: list[int], frames: int, out: Path, env_counts: list[int], overrides: list[str], jobs: int
) -> str:
    rows = ["| layout | training frames/s (median) | per seed |", "| --- | --- | --- |"]
    for envs, layout in LAYOUTS:
        if envs not in env_counts:
            continue
        name = f"envs{envs}-{layout.replace(', ', '-').replace(' ', '')}"
        layout_overrides = [
            *overrides,
            f"env.num_envs={envs}",
            f"collector.total_frames={frames}",
            *TRAIN_OVERRIDES,
            *WORKER_LAYOUTS[layout],
        ]
        summaries = run_presets(["dqn"], seeds, out / "train" / name, layout_overrides, jobs=jobs)
        summaries = summaries["dqn"]
        fps = [summary["frames"] / summary["train_seconds"] for summary in summaries]
        rows.append(_median_row(_label(envs, layout), fps))
        print(rows[-1], flush=True)
    return "\n".join(rows)


def solve_table(
    seeds: list[int], out: Path, overrides: list[str], jobs: int, layouts: list[str]
) -> str:
    results = {}
    for label, layout_overrides in (SOLVE_LAYOUTS[name] for name in layouts):
        name = label.replace(", ", "-").replace(" ", "")
        results[label] = run_presets(
            ["dqn"], seeds, out / "solve" / name, [*overrides, *layout_overrides], jobs=jobs
        )["dqn"]
        print(
            f"{label}: {sum(s['solved'] for s in results[label])}/{len(seeds)} solved", flush=True
        )
    return markdown_table(results, label="layout")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--frames", type=int, default=16_384, help="frames timed per layout")
    parser.add_argument("--train-frames", type=int, default=8_192)
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
    parser.add_argument(
        "--solve-layouts",
        nargs="+",
        default=list(SOLVE_LAYOUTS),
        choices=list(SOLVE_LAYOUTS),
        help="the layouts of the solve part: "
        + "; ".join(f"{name}: {label}" for name, (label, _) in SOLVE_LAYOUTS.items()),
    )


def main(args: argparse.Namespace) -> None:
    args.out.mkdir(parents=True, exist_ok=True)
    sections = []
    if "collect" in args.parts:
        table = collect_table(args.seeds, args.frames, args.envs, args.overrides)
        sections.append("## Collection alone\n\n" + table)
    if "train" in args.parts:
        table = train_table(
            args.seeds, args.train_frames, args.out, args.envs, args.overrides, args.jobs
        )
        sections.append("## Training\n\n" + table)
    if "solve" in args.parts:
        table = solve_table(args.seeds, args.out, args.overrides, args.jobs, args.solve_layouts)
        sections.append("## Solving CartPole with workers\n\n" + table)
    text = "\n\n".join(sections)
    print(text)
    (args.out / "results.md").write_text(text + "\n")

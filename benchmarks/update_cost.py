"""Milliseconds per replay sample, gradient update and priority write-back, per preset.

    python -m benchmarks update-cost [--algos dqn rainbow ...] [--updates 300] [--seeds 0]
        [key=value ...]

Builds each preset's env, Q-actor, replay buffer and learner with ``trl_cartpole.build``, as
training does (its optimizer, sampling, thread count and ``compile`` flag), fills the buffer
with 3 000 random frames, warms up for 20 updates or more, then times ``--updates`` updates
in batches of ``collector.updates_per_batch`` (one ``Learner.step``, phase by phase) and
prints the medians per update of the three phases over batches and seeds ("update" includes
the target network's step). Runs in this process, one preset at a time, so ``--jobs`` must
be 1.
"""

from __future__ import annotations

import argparse
import math
import statistics
import time
from itertools import chain

import torch

from benchmarks.harness import CONFIG_DIR, VARIANT_PRESETS
from trl_cartpole.buffers import extend_with_batch, sample_minibatches
from trl_cartpole.build import (
    TRANSITION_KEYS,
    build_actor,
    build_env,
    build_learner,
    build_replay_buffer,
    seed_everything,
)
from trl_cartpole.cli import compose_config
from trl_cartpole.config import to_config
from trl_cartpole.losses import priority_from_loss
from trl_cartpole.validation import validate

SEEDS, OUT = [0], "runs/update_cost"
RANDOM_FRAMES, WARMUP_UPDATES = 3000, 20

Timing = tuple[float, float, float]  # seconds per update: sample, update, priority


def time_learner(algo: str, seed: int, updates: int, overrides: list[str]) -> list[Timing]:
    """Per-update (sample, update, priority) seconds of each timed ``Learner.step``."""
    cfg = validate(
        to_config(compose_config(CONFIG_DIR, [f"algo={algo}", f"seed={seed}", *overrides]))
    )
    torch.set_num_threads(cfg.num_threads)
    seed_everything(seed)
    env = build_env(cfg, seed)
    learner = build_learner(cfg, build_actor(cfg, env), build_replay_buffer(cfg))
    steps = math.ceil(RANDOM_FRAMES / env.batch_size.numel())
    rollout = env.rollout(steps, break_when_any_done=False)  # [envs, T] or [T]: random actions
    extend_with_batch(learner.buffer, rollout.select(*TRANSITION_KEYS))
    env.close()
    count = cfg.collector.updates_per_batch
    timings: list[Timing] = []
    warmup_steps = math.ceil(WARMUP_UPDATES / count)
    for step in range(warmup_steps + math.ceil(updates / count)):
        sample_s = update_s = priority_s = 0.0
        minibatches = sample_minibatches(learner.buffer, count)
        for _ in range(count):
            start = time.perf_counter()
            sample = next(minibatches)
            sampled = time.perf_counter()
            learner.update(sample)
            learner.target_updater.step()
            updated = time.perf_counter()
            if learner.prioritized:
                priority = priority_from_loss(learner.loss, sample)
                learner.buffer.update_priority(sample["index"], priority)
            done = time.perf_counter()
            sample_s += sampled - start
            update_s += updated - sampled
            priority_s += done - updated
        if step >= warmup_steps:
            timings.append((sample_s / count, update_s / count, priority_s / count))
    return timings


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--algos", nargs="+", default=list(VARIANT_PRESETS))
    parser.add_argument("--updates", type=int, default=300, help="updates timed per seed")


def main(args: argparse.Namespace) -> None:
    if args.jobs != 1:
        raise SystemExit("error: update-cost times its updates in this process; use --jobs 1")
    lines = [
        "| preset | sample ms | update ms | priority ms | total ms |",
        "| --- | --- | --- | --- | --- |",
    ]
    print("\n".join(lines), flush=True)
    for algo in args.algos:
        timings = chain.from_iterable(
            time_learner(algo, seed, args.updates, args.overrides) for seed in args.seeds
        )
        sample, update, priority = (
            1e3 * statistics.median(phase) for phase in zip(*timings, strict=True)
        )
        total = sample + update + priority
        lines.append(f"| {algo} | {sample:.2f} | {update:.2f} | {priority:.2f} | {total:.2f} |")
        print(lines[-1], flush=True)
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "results.md").write_text("\n".join(lines) + "\n")

"""Milliseconds per replay sample, gradient update and priority write-back, per preset.

    python -m benchmarks update-cost [--algos dqn rainbow ...] [--updates 300] [--seeds 0]
        [key=value ...]

Builds each preset's env, Q-actor, replay buffer and learner with ``trl_cartpole.run.build``, as
training does (its optimizer, sampling, thread count and ``compile`` flag), fills the buffer
with 3 000 random frames, warms up for 20 updates or more, then times ``--updates`` updates
in batches of ``collector.updates_per_batch`` (one ``Learner.step``, phase by phase) and
prints the medians per update of the three phases over batches and seeds ("update" includes
the target network's step). Runs in this process, one preset at a time, so ``--jobs`` must
be 1.

With ``dqn`` among the presets a last row times the same math in raw PyTorch, interleaved with
the ``dqn`` updates batch by batch (``raw_update``: the same MLP, batch, n-step TD target,
Huber loss, gradient-norm clipping, fused AdamW and hard target copy, on plain tensors
sampled with one ``randint``), and the framework tax: the ``dqn`` row's total over the raw
one (the target is at most 1.2).
"""

from __future__ import annotations

import argparse
import copy
import math
import statistics
import time
from itertools import chain, pairwise

import torch

from benchmarks.harness import CONFIG_DIR, VARIANT_PRESETS
from trl_cartpole.config.compose import compose_config
from trl_cartpole.config.schema import to_config
from trl_cartpole.config.validation import validate
from trl_cartpole.parts.optim import make_optimizer
from trl_cartpole.parts.replay import extend_with_batch, sample_minibatches
from trl_cartpole.run.from_config import (
    build_actor,
    build_env,
    build_learner,
    build_replay_buffer,
    transition_keys,
)
from trl_cartpole.run.resources import seed_everything

SEEDS, OUT = [0], "runs/update_cost"
RANDOM_FRAMES, WARMUP_UPDATES = 3000, 20
TAX_TARGET = 1.2

Timing = tuple[float, float, float]  # seconds per update: sample, update, priority


def raw_update(cfg, obs_dim: int, num_actions: int, size: int = RANDOM_FRAMES):
    """One DQN update of the default's math in raw PyTorch: ``step() -> (sample s, update s)``.

    The replay memory is plain tensors of random transitions (the arithmetic does not depend
    on their values); the TD target is r + gamma^k (1 - terminated) max_a Q_target(s', a).
    """
    if cfg.network.head != "plain" or cfg.network.noisy or cfg.network.distributional:
        raise ValueError("raw_update times plain DQN only")
    widths = [obs_dim, *cfg.network.hidden_sizes]
    layers: list[torch.nn.Module] = []
    for width_in, width_out in pairwise(widths):
        layers += [torch.nn.Linear(width_in, width_out), torch.nn.ReLU()]
    online = torch.nn.Sequential(*layers, torch.nn.Linear(widths[-1], num_actions))
    target = copy.deepcopy(online).requires_grad_(False)
    optimizer = make_optimizer(
        online.parameters(),
        lr=cfg.optim.lr,
        amsgrad=cfg.optim.amsgrad,
        weight_decay=cfg.optim.weight_decay,
    )
    memory = {
        "obs": torch.randn(size, obs_dim),  # [N, obs_dim]
        "action": torch.randint(num_actions, (size,)),  # [N]
        "reward": torch.randn(size),  # [N]
        "next_obs": torch.randn(size, obs_dim),  # [N, obs_dim]
        "terminated": torch.rand(size) < 0.05,  # [N]
        "steps": torch.randint(1, cfg.buffer.n_steps + 1, (size,)),  # [N] n-step length k
    }
    batch_size, gamma = cfg.buffer.batch_size, cfg.loss.gamma
    params, counter = list(online.parameters()), [0]

    def step() -> tuple[float, float]:
        start = time.perf_counter()
        index = torch.randint(size, (batch_size,))  # [B]
        batch = {key: value[index] for key, value in memory.items()}
        sampled = time.perf_counter()
        q = online(batch["obs"]).gather(1, batch["action"].unsqueeze(1)).squeeze(1)  # [B]
        with torch.no_grad():
            next_max = target(batch["next_obs"]).max(1).values  # [B]
            discount = gamma ** batch["steps"] * (~batch["terminated"])  # [B]
            td_target = batch["reward"] + discount * next_max  # [B]
        loss = torch.nn.functional.smooth_l1_loss(q, td_target)
        optimizer.zero_grad(set_to_none=True)
        loss.backward()
        torch.nn.utils.clip_grad_norm_(params, cfg.optim.max_grad, foreach=True)
        optimizer.step()
        counter[0] += 1
        if counter[0] % cfg.loss.hard_update_interval == 0:
            torch._foreach_copy_(list(target.parameters()), params)
        return sampled - start, time.perf_counter() - sampled

    return step


def time_learner(
    algo: str, seed: int, updates: int, overrides: list[str], raw: list[Timing] | None = None
) -> list[Timing]:
    """Per-update (sample, update, priority) seconds of each timed ``Learner.step``.

    With ``raw`` (a list) and a state-vector env, a :func:`raw_update` follows each of the
    learner's updates and its per-update seconds of each batch are appended to ``raw``
    (priority 0).
    """
    cfg = validate(
        to_config(compose_config(CONFIG_DIR, [f"algo={algo}", f"seed={seed}", *overrides]))
    )
    torch.set_num_threads(cfg.num_threads)
    seed_everything(seed)
    env = build_env(cfg, seed)
    actor = build_actor(cfg, env)
    learner = build_learner(cfg, actor, build_replay_buffer(cfg))
    steps = math.ceil(RANDOM_FRAMES / env.batch_size.numel())
    rollout = env.rollout(steps, break_when_any_done=False)  # [envs, T] or [T]: random actions
    extend_with_batch(learner.buffer, rollout.select(*transition_keys(actor.in_keys[0])))
    vector = "observation" in env.observation_spec  # the raw MLP reads a state vector
    raw_step = None if raw is None or not vector else raw_update(cfg, *_sizes(env))
    env.close()
    count = cfg.collector.updates_per_batch
    timings: list[Timing] = []
    warmup_steps = math.ceil(WARMUP_UPDATES / count)
    for step in range(warmup_steps + math.ceil(updates / count)):
        sample_s = update_s = priority_s = raw_sample_s = raw_update_s = 0.0
        minibatches = sample_minibatches(learner.buffer, count)
        for _ in range(count):
            start = time.perf_counter()
            sample = next(minibatches)
            sampled = time.perf_counter()
            learner.update(sample)
            learner.target_updater.step()
            updated = time.perf_counter()
            if learner.prioritized:
                learner.buffer.update_tensordict_priority(sample)  # as Learner.step
            done = time.perf_counter()
            sample_s += sampled - start
            update_s += updated - sampled
            priority_s += done - updated
            if raw_step is not None:
                raw_sample, raw_update_seconds = raw_step()
                raw_sample_s += raw_sample
                raw_update_s += raw_update_seconds
        if step >= warmup_steps:
            timings.append((sample_s / count, update_s / count, priority_s / count))
            if raw_step is not None:
                raw.append((raw_sample_s / count, raw_update_s / count, 0.0))
    return timings


def _sizes(env) -> tuple[int, int]:
    """(observation size, number of actions) of ``env``."""
    return env.observation_spec["observation"].shape[-1], env.action_spec.shape[-1]


def _row(name: str, timings) -> tuple[str, float]:
    """A table row of the medians per phase of ``timings``, and its total in ms."""
    sample, update, priority = (
        1e3 * statistics.median(phase) for phase in zip(*timings, strict=True)
    )
    total = sample + update + priority
    return f"| {name} | {sample:.2f} | {update:.2f} | {priority:.2f} | {total:.2f} |", total


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
    raw: list[Timing] = []
    totals = {}
    for algo in args.algos:
        timings = chain.from_iterable(
            time_learner(algo, seed, args.updates, args.overrides, raw if algo == "dqn" else None)
            for seed in args.seeds
        )
        row, totals[algo] = _row(algo, timings)
        lines.append(row)
        print(lines[-1], flush=True)
    if raw:
        row, raw_total = _row("raw PyTorch, the dqn math", raw)
        tax = totals["dqn"] / raw_total
        met = "met" if tax <= TAX_TARGET else "not met"
        lines += [row, "", f"framework tax (dqn / raw): {tax:.2f} (target <= {TAX_TARGET}: {met})"]
        print("\n".join(lines[-3:]), flush=True)
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "results.md").write_text("\n".join(lines) + "\n")

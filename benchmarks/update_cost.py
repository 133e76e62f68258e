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

With ``dqn`` among the presets three more rows come from the same batches, interleaved with
the ``dqn`` updates batch by batch so that the machine's drift slows all alike:

- ``dqn, compile=true``: the same preset with its update compiled whole (``torch.compile``
  of the gradient step, the learning rate held, as ``compile=true`` trains), its compilation
  timed apart;
- raw PyTorch (``raw_update``: the same MLP, batch, n-step TD target, Huber loss,
  gradient-norm clipping, fused AdamW and hard target copy, on plain tensors sampled with one
  ``randint``), eager;
- the FLOP floor: the update's matrix-product arithmetic (:func:`update_flops`) at the rate
  this core multiplies a large matrix in the same process (:func:`matmul_rate`);
- for a CNN (``network.torso=cnn``), ``dqn, channels-last``: the same update with the
  convolution kernels of both networks in channels-last memory format (NHWC), in which
  oneDNN then runs the convolutions (:func:`to_channels_last`); the state-vector rows above
  (raw, floor) are an MLP's only;

then the framework tax (the ``dqn`` row's total over the raw one; the target is at most 1.2).
"""

from __future__ import annotations

import argparse
import copy
import json
import math
import statistics
import time
from itertools import chain, pairwise
from pathlib import Path

import torch

from benchmarks.harness import CONFIG_DIR, VARIANT_PRESETS
from trl_cartpole.config.compose import compose_config
from trl_cartpole.config.schema import to_config
from trl_cartpole.config.validation import validate
from trl_cartpole.parts.optim import make_optimizer
from trl_cartpole.parts.replay import extend_with_batch, sample_minibatches
from trl_cartpole.run.build import choose_num_threads
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
    widths = [obs_dim, *cfg.network.num_cells]
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
        if counter[0] % (cfg.target_updater.value_network_update_interval + 1) == 0:  # HardUpdate's
            torch._foreach_copy_(list(target.parameters()), params)
        return sampled - start, time.perf_counter() - sampled

    return step


def update_flops(cfg, obs_dim: int, num_actions: int) -> float:
    """Floating-point operations of the matrix products of one update of ``cfg``'s MLP.

    One pass of a batch ``B`` through widths ``w_0 .. w_L`` is ``F = 2 B sum w_i w_{i+1}``;
    an update makes the online pass on ``s`` and its backward pass (``2 F``: the gradients of
    the weights and of each layer's input, less the first layer's input), the target pass on
    ``s'`` and, for double DQN, an online pass on ``s'``: ``(4 + double) F`` less ``2 B w_0 w_1``.
    The elementwise work (activations, loss, AdamW: about ten operations a parameter) is left
    out: a floor, not an estimate.
    """
    widths = [obs_dim, *cfg.network.num_cells, num_actions]
    batch = cfg.buffer.batch_size
    one_pass = 2 * batch * sum(a * b for a, b in pairwise(widths))
    return (4 + int(cfg.loss.double_dqn)) * one_pass - 2 * batch * widths[0] * widths[1]


def matmul_rate(size: int = 512, repeats: int = 50) -> float:
    """FLOP/s of this core on a ``size`` x ``size`` float32 matrix product (the best of
    ``repeats``, after a warm-up): the rate the FLOP floor divides by."""
    a, b = torch.randn(size, size), torch.randn(size, size)
    best = math.inf
    for _ in range(repeats + 5):
        start = time.perf_counter()
        torch.mm(a, b)
        best = min(best, time.perf_counter() - start)
    return 2 * size**3 / best


def _built(algo: str, seed: int, overrides: list[str]):
    """(cfg, learner, env) of ``algo``, its buffer filled with random frames, as training has
    them; the env is closed."""
    cfg = validate(
        to_config(compose_config(CONFIG_DIR, [f"algo={algo}", f"seed={seed}", *overrides]))
    )
    torch.set_num_threads(choose_num_threads(cfg.num_threads))
    seed_everything(seed)
    env = build_env(cfg, seed)
    actor = build_actor(cfg, env)
    learner = build_learner(cfg, actor, build_replay_buffer(cfg))
    steps = math.ceil(RANDOM_FRAMES / env.batch_size.numel())
    rollout = env.rollout(steps, break_when_any_done=False)  # [envs, T] or [T]: random actions
    extend_with_batch(learner.buffer, rollout.select(*transition_keys(actor.in_keys[0])))
    env.close()
    return cfg, learner, env


def to_channels_last(learner) -> int:
    """Put the 4-d parameters and buffers (convolution kernels) of ``learner``'s loss, the
    online network's and the target's, in channels-last memory format, in place (before its
    first step, so that the optimizer's state follows); returns how many were changed."""
    kernels = [t for t in chain(learner.loss.parameters(), learner.loss.buffers()) if t.dim() == 4]
    for kernel in kernels:
        kernel.data = kernel.data.contiguous(memory_format=torch.channels_last)
    return len(kernels)


def _learner_batch(learner, count: int) -> Timing:
    """Per-update (sample, update, priority) seconds of one batch of ``count`` updates, phase
    by phase as ``Learner.step`` runs them ("update" includes the target network's step)."""
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
            learner.buffer.update_tensordict_priority(sample)  # as Learner.step
        done = time.perf_counter()
        sample_s += sampled - start
        update_s += updated - sampled
        priority_s += done - updated
    return sample_s / count, update_s / count, priority_s / count


def time_learner(
    algo: str, seed: int, updates: int, overrides: list[str], others: dict | None = None
) -> list[Timing]:
    """Per-update (sample, update, priority) seconds of each timed ``Learner.step``.

    With ``others`` (a dict), the compiled learner (``"compiled"``) and, on a state-vector env,
    a :func:`raw_update` (``"raw"``) take a batch of updates after each of the learner's, and
    their per-update seconds are appended to ``others[name]``; ``others["compile_s"]`` gets
    the compiled learner's first call, ``others["flop_floor"]`` (state vectors) the floor's
    seconds per update.
    """
    cfg, learner, env = _built(algo, seed, overrides)
    contenders = {}
    if others is not None:
        _, compiled, _ = _built(algo, seed, [*overrides, "compile=true", "optim.lr_end=null"])
        start = time.perf_counter()
        _learner_batch(compiled, 1)  # the first call compiles
        others.setdefault("compile_s", []).append(time.perf_counter() - start)
        contenders["compiled"] = lambda count: _learner_batch(compiled, count)
    if others is not None and cfg.network.torso == "cnn":
        _, channels_last, _ = _built(algo, seed, overrides)
        if to_channels_last(channels_last) == 0:
            raise RuntimeError("the CNN learner has no convolution kernel to make channels-last")
        contenders["channels_last"] = lambda count: _learner_batch(channels_last, count)
    plain = cfg.network.head == "plain" and not cfg.network.noisy and not cfg.network.distributional
    if others is not None and plain and "observation" in env.observation_spec:  # a plain MLP
        raw_step = raw_update(cfg, *_sizes(env))
        contenders["raw"] = lambda count: _raw_batch(raw_step, count)
        others.setdefault("flop_floor", []).append(update_flops(cfg, *_sizes(env)) / matmul_rate())
    count = cfg.collector.updates_per_batch
    timings: list[Timing] = []
    warmup_steps = math.ceil(WARMUP_UPDATES / count)
    for step in range(warmup_steps + math.ceil(updates / count)):
        timing = _learner_batch(learner, count)
        other_timings = {name: batch(count) for name, batch in contenders.items()}
        if step >= warmup_steps:
            timings.append(timing)
            for name, other in other_timings.items():
                others.setdefault(name, []).append(other)
    return timings


def _raw_batch(raw_step, count: int) -> Timing:
    """Per-update (sample, update, 0) seconds of ``count`` raw updates."""
    seconds = [raw_step() for _ in range(count)]
    return sum(s for s, _ in seconds) / count, sum(u for _, u in seconds) / count, 0.0


def _sizes(env) -> tuple[int, int]:
    """(observation size, number of actions) of ``env``."""
    return env.observation_spec["observation"].shape[-1], env.action_spec.shape[-1]


def _row(name: str, timings) -> dict:
    """The medians per phase of ``timings`` in ms, and their total."""
    sample, update, priority = (
        1e3 * statistics.median(phase) for phase in zip(*timings, strict=True)
    )
    return {
        "name": name,
        "sample_ms": sample,
        "update_ms": update,
        "priority_ms": priority,
        "total_ms": sample + update + priority,
    }


TABLE_HEAD = [
    "| update | sample ms | update ms | priority ms | total ms |",
    "| --- | --- | --- | --- | --- |",
]


def table_row(row: dict) -> str:
    """A results file's row as a line of the table (``-`` where a phase has no figure)."""
    cells = [row.get(f"{phase}_ms") for phase in ("sample", "update", "priority", "total")]
    return (
        f"| {row['name']} | "
        + " | ".join("-" if cell is None else f"{cell:.2f}" for cell in cells)
        + " |"
    )


def summary_line(record: dict) -> str:
    """The ratios of a results file's measurement, in one line."""
    totals = {row["name"]: row["total_ms"] for row in record["rows"]}
    parts = []
    if RAW in totals:
        parts.append(
            f"framework tax (dqn / raw): {totals['dqn'] / totals[RAW]:.2f} (target <= {TAX_TARGET})"
        )
    parts.append(f"compiled / eager dqn: {totals[COMPILED] / totals['dqn']:.2f}")
    if FLOOR in totals:
        updates = {row["name"]: row["update_ms"] for row in record["rows"]}
        parts.append(f"compiled update / FLOP floor: {updates[COMPILED] / updates[FLOOR]:.2f}")
    parts.append(f"compilation (first call): {record['compile_seconds']:.1f} s")
    return "; ".join(parts)


COMPILED = "dqn, compile=true (the whole update compiled)"
RAW = "raw PyTorch, the dqn math, eager"
FLOOR = "FLOP floor: the matrix products at this core's rate"
CHANNELS_LAST = "dqn, channels-last (the convolution kernels in NHWC)"
OTHER_ROWS = (COMPILED, CHANNELS_LAST, RAW, FLOOR)  # recorded beside the dqn row, this order


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--algos", nargs="+", default=list(VARIANT_PRESETS))
    parser.add_argument("--updates", type=int, default=300, help="updates timed per seed")
    parser.add_argument(
        "--record",
        type=Path,
        help="add the dqn rows to this results file (a measurement with the same overrides "
        "is replaced)",
    )
    parser.add_argument(
        "--note", default="", help="what else the machine did meanwhile, kept with the record"
    )


def main(args: argparse.Namespace) -> None:
    if args.jobs != 1:
        raise SystemExit("error: update-cost times its updates in this process; use --jobs 1")
    lines = list(TABLE_HEAD)
    print("\n".join(lines), flush=True)
    others: dict[str, list] = {}
    rows = []
    for algo in args.algos:
        timings = chain.from_iterable(
            time_learner(
                algo, seed, args.updates, args.overrides, others if algo == "dqn" else None
            )
            for seed in args.seeds
        )
        rows.append(_row(algo, timings))
        lines.append(table_row(rows[-1]))
        print(lines[-1], flush=True)
    if "compiled" in others:
        rows.append(_row(COMPILED, others["compiled"]))
        if "channels_last" in others:
            rows.append(_row(CHANNELS_LAST, others["channels_last"]))
        if "raw" in others:
            floor = 1e3 * statistics.median(others["flop_floor"])
            rows += [
                _row(RAW, others["raw"]),
                {"name": FLOOR, "update_ms": floor, "total_ms": floor},
            ]
        record = {
            "num_threads": torch.get_num_threads(),  # as the last run set it (num_threads)
            "rows": [row for row in rows if row["name"] in ("dqn", *OTHER_ROWS)],
            "compile_seconds": others["compile_s"][0],  # the first seed's: a run's compile
        }
        added = len(record["rows"]) - 1
        lines += [*(table_row(row) for row in rows[-added:]), "", summary_line(record)]
        print("\n".join(lines[-added - 2 :]), flush=True)
        if args.record:
            _record(args, record)
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "results.md").write_text("\n".join(lines) + "\n")


def _record(args: argparse.Namespace, record: dict) -> None:
    """Add the measurement to ``args.record`` with its command, machine and date; one with the
    same overrides on the same kind of processor (its vector units and the limits held on its
    kernels) is replaced (docs/results/speed.md is generated from the file)."""
    from benchmarks.harness import provenance

    command = " ".join(
        [
            "python -m benchmarks update-cost --algos dqn",
            f"--seeds {' '.join(map(str, args.seeds))}",
            f"--updates {args.updates}",
            *args.overrides,
        ]
    )
    measurement = {**provenance(), "command": command, "overrides": args.overrides, **record}
    if args.note:
        measurement["note"] = args.note
    existing = json.loads(args.record.read_text()) if args.record.exists() else {"runs": []}

    def kind(run: dict) -> tuple:
        machine = run["machine"]
        limits = machine.get("kernels", {}).get("limits", {})
        return run["overrides"], machine["vector_units"], sorted(limits.items())

    runs = [run for run in existing["runs"] if kind(run) != kind(measurement)]
    args.record.write_text(json.dumps({"runs": [*runs, measurement]}, indent=2) + "\n")

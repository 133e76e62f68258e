"""Milliseconds per replay sample, gradient update and priority write-back, per preset.

    python scripts/update_cost.py [--algos dqn rainbow ...] [--updates 300] [key=value ...]

Builds each preset's components exactly as ``train()`` does, fills the replay buffer with
3 000 random CartPole frames, warms up for 20 updates, then times ``--updates`` updates and
prints the medians of the three phases (one thread, as in training; "update" includes the
target network's update).
"""

from __future__ import annotations

import argparse
import statistics
import time

import torch

from trl_cartpole.benchmarking import CONFIG_DIR, VARIANT_PRESETS
from trl_cartpole.buffers import make_replay_buffer
from trl_cartpole.cli import compose_config
from trl_cartpole.config import to_config
from trl_cartpole.envs import make_env
from trl_cartpole.losses import make_dqn_loss, make_target_updater, priority_from_loss
from trl_cartpole.models import make_q_actor_for_env
from trl_cartpole.train import TRANSITION_KEYS
from trl_cartpole.update import make_optimizer, make_update


def time_preset(algo: str, updates: int, overrides: list[str]) -> tuple[float, float, float]:
    """Median (sample, update, priority) milliseconds for ``algo``."""
    cfg = to_config(compose_config(CONFIG_DIR, [f"algo={algo}", *overrides]))
    torch.manual_seed(0)
    env = make_env(cfg.env.id, 0, "cpu", cfg.env.max_episode_steps)
    actor = make_q_actor_for_env(env, cfg.network)
    loss = make_dqn_loss(actor, cfg.loss.gamma, cfg.loss.loss_function, cfg.loss.double_dqn)
    buffer = make_replay_buffer(
        cfg.buffer.size,
        cfg.buffer.batch_size,
        prioritized=cfg.buffer.prioritized,
        n_steps=cfg.buffer.n_steps,
        gamma=cfg.loss.gamma,
    )
    buffer.extend(env.rollout(3000, break_when_any_done=False).select(*TRANSITION_KEYS))
    target = make_target_updater(
        loss, cfg.loss.target_update, cfg.loss.tau, cfg.loss.hard_update_interval
    )
    optimizer = make_optimizer(actor.parameters(), cfg.optim.lr, cfg.optim.amsgrad)
    noisy = actor if cfg.network.noisy else None
    update = make_update(loss, optimizer, cfg.optim.grad_clip, cfg.optim.max_grad, noisy)
    timings: list[tuple[float, float, float]] = []
    for step in range(20 + updates):
        start = time.perf_counter()
        sample = buffer.sample()
        sampled = time.perf_counter()
        update(sample)
        target.step()
        updated = time.perf_counter()
        if cfg.buffer.prioritized:
            buffer.update_priority(sample["index"], priority_from_loss(loss, sample))
        done = time.perf_counter()
        if step >= 20:
            timings.append((sampled - start, updated - sampled, done - updated))
    env.close()
    return tuple(1e3 * statistics.median(phase) for phase in zip(*timings, strict=True))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--algos", nargs="+", default=list(VARIANT_PRESETS))
    parser.add_argument("--updates", type=int, default=300)
    parser.add_argument("overrides", nargs="*", help="Hydra overrides applied to every preset")
    args = parser.parse_args()
    torch.set_num_threads(1)
    print("| preset | sample ms | update ms | priority ms | total ms |")
    print("| --- | --- | --- | --- | --- |")
    for algo in args.algos:
        sample, update, priority = time_preset(algo, args.updates, args.overrides)
        total = sample + update + priority
        print(f"| {algo} | {sample:.2f} | {update:.2f} | {priority:.2f} | {total:.2f} |")


if __name__ == "__main__":
    main()

"""``train(cfg)``: compose the TorchRL components and run the DQN loop (Mnih et al. 2015).

One collected batch at a time: extend the replay buffer, take ``updates_per_batch`` gradient
steps on sampled batches (writing back their priorities and resampling the network noise when
those are on), move the target network, step epsilon (or anneal the importance-sampling beta),
sync the collector's policy, and every ``eval.interval_frames`` play greedy episodes on a
separate env. At the end the best
policy (by periodic evaluation) is evaluated over ``eval.final_episodes`` episodes and
``summary.json`` is written.
"""

from __future__ import annotations

import copy
import math
import random
import signal
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import tensordict
import torch
import torchrl
from omegaconf import DictConfig, OmegaConf
from tensordict import TensorDictBase
from tensordict.nn import TensorDictSequential
from torchrl.checkpoint import Checkpoint
from tqdm.auto import tqdm

from trl_cartpole.buffers import (
    annealed_beta,
    extend_with_batch,
    make_replay_buffer,
    sample_minibatches,
)
from trl_cartpole.checkpoint import (
    load_training_state,
    read_observation_norm,
    save_policy,
    save_training_state,
)
from trl_cartpole.collectors import (
    check_ray_address,
    is_distributed,
    make_collector,
    needs_weight_sync,
    shutdown_collector,
    worker_env_constructors,
)
from trl_cartpole.config import Config, ConfigError, to_config, validate
from trl_cartpole.envs import estimate_observation_norm, make_env_from_config, solve_threshold
from trl_cartpole.evaluation import EvalResult, evaluate
from trl_cartpole.exploration import make_exploration
from trl_cartpole.files import write_json_atomic, write_text_atomic
from trl_cartpole.losses import make_dqn_loss, make_target_updater, priority_from_loss
from trl_cartpole.metrics import (
    History,
    Stopwatch,
    make_logger,
    peak_rss_mb,
    truncate_csv_metrics,
)
from trl_cartpole.models import expected_action_values, make_q_actor_for_env, reset_network_noise
from trl_cartpole.plotting import LiveDurationPlot, plot_dashboard, plot_durations
from trl_cartpole.run_control import StopRequest, TrainingFailed, TrainingInterrupted
from trl_cartpole.run_state import RunState
from trl_cartpole.update import make_optimizer, make_update

__all__ = [
    "TRANSITION_KEYS",
    "prepare_run_dir",
    "seed_everything",
    "train",
]

# What the replay buffer stores of a collected frame; the rest (Q-values, counters) is dropped.
TRANSITION_KEYS = (
    "observation",
    "action",
    ("next", "observation"),
    ("next", "reward"),
    ("next", "done"),
    ("next", "terminated"),
    ("next", "truncated"),
)


UPDATE_LOG_INTERVAL = 100  # log TD loss, grad norm and epsilon once per this many updates


def seed_everything(seed: int) -> None:
    """Seed Python's ``random``, NumPy and torch (the env seeds are set by ``make_env``)."""
    random.seed(seed)
    np.random.seed(seed)  # noqa: NPY002 (global state that third-party code reads)
    torch.manual_seed(seed)


def prepare_run_dir(run_dir: str | Path) -> Path:
    """Create ``run_dir`` or raise a one-line ConfigError if it cannot be written."""
    path = Path(run_dir)
    try:
        path.mkdir(parents=True, exist_ok=True)
        probe = path / ".write-probe"
        probe.write_text("")
        probe.unlink()
    except OSError as error:
        raise ConfigError(
            f"run_dir={str(path)!r} is not writable ({error.strerror}); choose another run_dir"
        ) from None
    return path


@dataclass
class _Progress:
    frames: int = 0
    updates: int = 0
    best_eval: float = -float("inf")
    best_state: dict[str, torch.Tensor] | None = None
    frames_to_solve: int | None = None
    seconds_to_solve: float | None = None
    last_eval_frame: int = -1
    collect_seconds: float = 0.0  # waiting on the collector (env steps + policy)
    update_seconds: float = 0.0  # replay sampling + gradient steps + target updates
    history: History = field(default_factory=History)


def _env_rows(batch: TensorDictBase) -> TensorDictBase:
    """``[workers, envs, T]`` -> ``[workers * envs, T]``: one row per env, steps in time order."""
    return batch.reshape(-1, batch.shape[-1]) if batch.ndim > 2 else batch


def _timed_batches(collector, progress: _Progress):
    """Yield the collector's batches, adding the time spent producing each to ``progress``."""
    iterator = iter(collector)
    while True:
        start = time.perf_counter()
        try:
            batch = next(iterator)
        except StopIteration:
            return
        progress.collect_seconds += time.perf_counter() - start
        yield batch


def _log(logger, scalars: dict[str, float], step: int) -> None:
    if logger is not None:
        for name, value in scalars.items():
            logger.log_scalar(name, float(value), step=step)


def _record_episodes(batch: TensorDictBase, progress: _Progress, logger) -> None:
    """Append finished episodes of ``batch`` ``[frames_per_batch]`` to the history and log."""
    done = batch["next", "done"].reshape(-1)  # [F]
    if not done.any():
        return
    returns = batch["next", "episode_reward"].reshape(-1)[done].tolist()
    lengths = batch["next", "step_count"].reshape(-1)[done].tolist()
    for episode_return, length in zip(returns, lengths, strict=True):
        progress.history.episode_returns.append(episode_return)
        progress.history.episode_lengths.append(length)
        _log(
            logger,
            {"train/episode_return": episode_return, "train/episode_length": length},
            progress.frames,
        )


def train(
    cfg: Config | DictConfig | dict[str, Any], resume: str | Path | None = None
) -> dict[str, Any]:
    """Train DQN as configured, write the run directory and return the summary dict.

    With ``resume`` (a training-state checkpoint, see ``checkpoint.find_resume_checkpoint``)
    every component is restored from it and the run continues where it stopped; ``cfg`` must
    be its stored config (``checkpoint.resume_config``). SIGINT/SIGTERM write a checkpoint and
    raise :class:`TrainingInterrupted`; a non-finite loss raises :class:`TrainingFailed`.
    """
    cfg = validate(to_config(cfg))
    wall_start = time.perf_counter()
    torch.set_num_threads(cfg.num_threads)
    seed_everything(cfg.seed)
    threshold = solve_threshold(cfg.env.id, cfg.eval.solve_threshold)

    # --- components: each a stock TorchRL object -------------------------------------------
    # The envs first: one that does not fit (continuous actions, images) stops the run here,
    # before anything is written. Observation statistics are estimated once per run (a resumed
    # run reads them back) and shared by the training and evaluation envs.
    observation_norm = None
    if cfg.env.normalize_observations:
        observation_norm = (
            estimate_observation_norm(cfg.env, cfg.seed)
            if resume is None
            else read_observation_norm(resume)
        )
    env = make_env_from_config(cfg.env, cfg.seed, cfg.device, observation_norm=observation_norm)
    eval_env = make_env_from_config(
        cfg.env,
        cfg.seed + cfg.eval.seed_offset,
        cfg.device,
        num_envs=cfg.eval.episodes,
        observation_norm=observation_norm,
    )
    if cfg.collector.backend == "ray" and cfg.collector.ray_address is not None:
        check_ray_address(cfg.collector.ray_address)  # before anything is written
    run_dir = prepare_run_dir(cfg.run_dir)
    frames_done = 0
    if resume is not None:  # rows logged after the checkpoint will be logged again
        frames_done = Checkpoint.manifest(resume)["metadata"]["counters"]["frames"]
        truncate_csv_metrics(run_dir, frames_done)
    write_text_atomic(run_dir / "config.yaml", OmegaConf.to_yaml(OmegaConf.structured(cfg)))
    actor = make_q_actor_for_env(env, cfg.network, cfg.device)
    exploration = make_exploration(
        env.action_spec,
        cfg.exploration.schedule,
        cfg.exploration.eps_start,
        cfg.exploration.eps_end,
        cfg.exploration.decay_frames,
        cfg.device,
    )
    policy = actor if exploration is None else TensorDictSequential(actor, exploration)
    buffer = make_replay_buffer(
        cfg.buffer.size,
        cfg.buffer.batch_size,
        cfg.device,
        prioritized=cfg.buffer.prioritized,
        alpha=cfg.buffer.alpha,
        beta=cfg.buffer.beta,
        priority_eps=cfg.buffer.priority_eps,
        n_steps=cfg.buffer.n_steps,
        gamma=cfg.loss.gamma,
    )
    beta_anneal_frames = cfg.buffer.beta_anneal_frames or cfg.collector.total_frames
    loss = make_dqn_loss(actor, cfg.loss.gamma, cfg.loss.loss_function, cfg.loss.double_dqn)
    target_updater = make_target_updater(
        loss, cfg.loss.target_update, cfg.loss.tau, cfg.loss.hard_update_interval
    )
    optimizer = make_optimizer(
        actor.parameters(), cfg.optim.lr, cfg.optim.amsgrad, cfg.optim.weight_decay
    )
    update = make_update(
        loss,
        optimizer,
        cfg.optim.grad_clip,
        cfg.optim.max_grad,
        noisy_network=actor if cfg.network.noisy else None,
    )
    if cfg.compile:
        update = torch.compile(update)
    # Workers (processes or Ray actors) build their own envs; their counters are not saved, so
    # a resumed run gives them only the frames still to collect.
    distributed = is_distributed(cfg.collector.workers, cfg.collector.backend)
    # (a single-process collector's own frame counter is restored from the checkpoint instead)
    frames_not_counted = frames_done if distributed else 0
    collector = make_collector(
        worker_env_constructors(cfg, observation_norm) if distributed else env,
        policy,
        cfg.collector.frames_per_batch,
        cfg.collector.total_frames - frames_not_counted,
        max(cfg.collector.init_random_frames - frames_not_counted, 0),
        cfg.device,
        sync=cfg.collector.sync,
        backend=cfg.collector.backend,
        ray_address=cfg.collector.ray_address,
    )
    # A single-process collector steps the very policy being trained; only a copy needs syncing.
    sync_policy_weights = needs_weight_sync(collector, policy)
    logger = make_logger(cfg.logger.backend, run_dir, cfg.logger.project, cfg.logger.wandb_offline)
    title = f"{cfg.env.id} {cfg.algo.name} seed {cfg.seed}"
    live_plot = LiveDurationPlot(run_dir / "durations.png", title) if cfg.logger.live_plot else None
    learning_starts = max(
        cfg.buffer.batch_size, cfg.collector.learning_starts, cfg.collector.init_random_frames
    )

    def release() -> None:
        """Close what holds resources before leaving the run early."""
        bar.close()
        shutdown_collector(collector)
        for closable in (env, eval_env):
            closable.close()
        if logger is not None:
            logger.close()

    progress = _Progress()
    history = progress.history
    train_clock = Stopwatch()
    run_state = RunState(
        progress,
        train_clock,
        None if distributed else env,
        eval_env,
        collector,
        buffer,
        target_updater,
    )
    state_components: dict[str, Any] = {
        "policy": actor,
        "loss": loss,
        "optimizer": optimizer,
        **({} if exploration is None else {"exploration": exploration}),
        **({"replay_buffer": buffer} if cfg.checkpoint.include_buffer else {}),
        **({} if distributed else {"collector": collector}),
        "run": run_state,  # loads after "collector": its carrier replaces the fresh one
    }
    if resume is not None:
        components = dict(state_components)
        if "replay_buffer" not in Checkpoint.manifest(resume)["components"]:
            components.pop("replay_buffer", None)  # saved while an n-step buffer was empty
        load_training_state(resume, **components)

    def save_state(path: Path, keep_last: int | None = None) -> Path:
        counters = {"frames": progress.frames, "updates": progress.updates}
        # An n-step buffer may still be empty (its windows are not complete yet): nothing to save.
        components = {
            name: component
            for name, component in state_components.items()
            if name != "replay_buffer" or len(buffer) > 0
        }
        return save_training_state(
            path, cfg, counters, keep_last, observation_norm=observation_norm, **components
        )

    bar = tqdm(
        initial=progress.frames,
        total=cfg.collector.total_frames,
        disable=not cfg.logger.progress_bar,
        unit="frame",
        dynamic_ncols=True,
        desc=f"{cfg.env.id} {cfg.algo.name} seed={cfg.seed}",
    )
    postfix: dict[str, str] = {}  # ep_return, eps, eval, best: shown together on the bar

    def run_evaluation() -> bool:
        """Greedy evaluation; keeps the best weights; returns whether the env is solved."""
        result = evaluate(actor, eval_env, cfg.eval.max_steps)
        progress.last_eval_frame = progress.frames
        history.eval_frames.append(progress.frames)
        history.eval_returns.append(result.mean)
        history.eval_seconds.append(round(train_clock.seconds, 3))
        history.eval_initial_values.append(result.initial_value)
        _log(
            logger,
            {
                "eval/return_mean": result.mean,
                "eval/return_std": result.std,
                "eval/initial_value": result.initial_value,
            },
            progress.frames,
        )
        if result.mean > progress.best_eval:
            progress.best_eval = result.mean
            progress.best_state = copy.deepcopy(actor.state_dict())
            if cfg.checkpoint.save_best:
                save_policy(
                    run_dir / "checkpoints" / "best",
                    actor,
                    cfg,
                    frames=progress.frames,
                    eval_return_mean=result.mean,
                    observation_norm=observation_norm,
                )
        solved = threshold is not None and result.mean >= threshold
        if solved and progress.frames_to_solve is None:
            progress.frames_to_solve = progress.frames
            progress.seconds_to_solve = train_clock.seconds
        postfix.update(eval=f"{result.mean:.1f}", best=f"{progress.best_eval:.1f}")
        bar.set_postfix(postfix, refresh=False)
        return solved

    # --- the loop ----------------------------------------------------------------------------
    periodic_dir = run_dir / "checkpoints" / "periodic"
    last_periodic = progress.frames
    stop = StopRequest()
    train_clock.start()
    with stop:
        # batch: [T] (one env) or [envs, T] (envs of all synchronous workers), T * envs frames
        for batch in _timed_batches(collector, progress):
            batch = _env_rows(batch)
            progress.frames += batch.numel()
            extend_with_batch(buffer, batch.select(*TRANSITION_KEYS))
            _record_episodes(batch, progress, logger)

            updates_before = progress.updates
            update_start = time.perf_counter()
            if len(buffer) >= learning_starts:
                for sample in sample_minibatches(buffer, cfg.collector.updates_per_batch):
                    metrics = update(sample)  # sample: [batch_size]
                    if cfg.buffer.prioritized:
                        buffer.update_priority(sample["index"], priority_from_loss(loss, sample))
                    target_updater.step()
                    progress.updates += 1
                    loss_value = metrics["loss"].item()
                    if not math.isfinite(loss_value):
                        release()
                        _fail(cfg, run_dir, progress, f"TD loss is {loss_value}", wall_start)
                    history.update_frames.append(progress.frames)
                    history.td_losses.append(loss_value)
                    history.grad_norms.append(metrics["grad_norm"].item())
            progress.update_seconds += time.perf_counter() - update_start
            if exploration is not None:
                exploration.step(batch.numel())
            if cfg.network.noisy:
                reset_network_noise(actor)  # fresh noise for the next collected batch too
            if cfg.buffer.prioritized:
                buffer.sampler.beta = annealed_beta(
                    cfg.buffer.beta, progress.frames, beta_anneal_frames
                )
            if sync_policy_weights:
                collector.update_policy_weights_()

            bar.update(batch.numel())
            if history.episode_returns:
                postfix.update(ep_return=f"{history.episode_returns[-1]:.0f}")
            if exploration is not None:
                postfix.update(eps=f"{exploration.eps.item():.3f}")
            bar.set_postfix(postfix, refresh=False)
            if progress.updates // UPDATE_LOG_INTERVAL > updates_before // UPDATE_LOG_INTERVAL:
                scalars = {
                    "train/td_loss": history.td_losses[-1],
                    "train/grad_norm": history.grad_norms[-1],
                    "train/frames_per_second": progress.frames / max(train_clock.seconds, 1e-9),
                }
                if batch.get("action_value", None) is not None:  # None in random warm-up batches
                    q = expected_action_values(actor, batch["action_value"])  # [F, num_actions]
                    scalars["train/q_max_mean"] = q.max(-1).values.mean().item()
                if exploration is not None:
                    scalars["train/epsilon"] = exploration.eps.item()
                if cfg.buffer.prioritized:
                    scalars["train/mean_importance_weight"] = (
                        sample["priority_weight"].mean().item()
                    )
                _log(logger, scalars, progress.frames)

            if progress.frames - max(progress.last_eval_frame, 0) >= cfg.eval.interval_frames:
                train_clock.pause()
                solved = run_evaluation()
                if live_plot is not None:
                    live_plot.update(history.episode_lengths)
                train_clock.start()
                if solved and cfg.eval.stop_when_solved:
                    break
            due = progress.frames - last_periodic >= (cfg.checkpoint.interval_frames or math.inf)
            if due or stop.requested:  # a safe point: between batches
                train_clock.pause()
                save_state(periodic_dir, cfg.checkpoint.keep_last)
                last_periodic = progress.frames
                if stop.requested:
                    release()
                    raise TrainingInterrupted(
                        f"stopped by {signal.Signals(stop.signum).name} at frame "
                        f"{progress.frames}; checkpoint written; resume with: python "
                        f"scripts/train.py resume={run_dir}",
                        stop.signum,
                    )
                train_clock.start()
    train_clock.pause()
    bar.close()
    if cfg.checkpoint.save_last:
        save_state(run_dir / "checkpoints" / "last")
    shutdown_collector(collector)

    if progress.last_eval_frame != progress.frames:
        run_evaluation()

    # --- final evaluation of the best policy, artefacts ------------------------------------
    actor.load_state_dict(progress.best_state)
    final_env = make_env_from_config(
        cfg.env,
        cfg.seed + 2 * cfg.eval.seed_offset,
        cfg.device,
        num_envs=cfg.eval.final_episodes,
        observation_norm=observation_norm,
    )
    final = evaluate(actor, final_env, cfg.eval.max_steps)
    _log(logger, {"eval/final_return_mean": final.mean}, progress.frames)
    if logger is not None:
        logger.close()  # flushes TensorBoard events, finishes a wandb run

    if cfg.logger.plots:
        plot_durations(history.episode_lengths, run_dir / "durations.png", title)
        plot_dashboard(
            history.eval_frames,
            history.eval_returns,
            history.eval_initial_values,
            history.update_frames,
            history.td_losses,
            history.grad_norms,
            run_dir / "dashboard.png",
        )
    for closable in (env, eval_env, final_env):
        closable.close()

    summary = _summary(cfg, progress, final, threshold, train_clock.seconds, wall_start, run_dir)
    write_json_atomic(run_dir / "summary.json", summary)
    return summary


def _fail(cfg: Config, run_dir: Path, progress: _Progress, what: str, wall_start: float) -> None:
    """Record a numerical fault in ``summary.json`` and raise :class:`TrainingFailed`.

    The last periodic checkpoint (written before the fault) stays the one to resume from.
    """
    message = f"{what} at update {progress.updates} (frame {progress.frames}); training stopped"
    periodic = run_dir / "checkpoints" / "periodic"
    summary = {
        "env_id": cfg.env.id,
        "seed": cfg.seed,
        "algo": cfg.algo.name,
        "frames": progress.frames,
        "updates": progress.updates,
        "wall_seconds": round(time.perf_counter() - wall_start, 3),
        "solved": progress.frames_to_solve is not None,
        "frames_to_solve": progress.frames_to_solve,
        "failed": True,
        "failure": message,
        "best_eval_return_mean": progress.best_eval if progress.best_state else None,
        "last_good_checkpoint": str(periodic) if periodic.is_dir() else None,
        "run_dir": str(run_dir),
    }
    write_json_atomic(run_dir / "summary.json", summary)
    raise TrainingFailed(f"{message}; the failure is recorded in {run_dir / 'summary.json'}")


def _summary(
    cfg: Config,
    progress: _Progress,
    final: EvalResult,
    threshold: float | None,
    train_seconds: float,
    wall_start: float,
    run_dir: Path,
) -> dict[str, Any]:
    best = run_dir / "checkpoints" / "best"
    return {
        "env_id": cfg.env.id,
        "seed": cfg.seed,
        "algo": cfg.algo.name,
        "frames": progress.frames,
        "updates": progress.updates,
        "train_seconds": round(train_seconds, 3),
        "wall_seconds": round(time.perf_counter() - wall_start, 3),
        "solved": progress.frames_to_solve is not None,
        "solve_threshold": threshold,
        "frames_to_solve": progress.frames_to_solve,
        "seconds_to_solve": None
        if progress.seconds_to_solve is None
        else round(progress.seconds_to_solve, 3),
        "final_eval_return_mean": final.mean,
        "final_eval_return_std": final.std,
        "final_eval_episodes": len(final.returns),
        "final_eval_returns": final.returns,
        "best_eval_return_mean": progress.best_eval,
        "episodes": len(progress.history.episode_returns),
        # Throughput of the two halves of the loop, and the process's peak resident memory.
        "collect_frames_per_second": round(progress.frames / max(progress.collect_seconds, 1e-9)),
        "updates_per_second": round(progress.updates / max(progress.update_seconds, 1e-9), 1),
        "peak_rss_mb": round(peak_rss_mb(), 1),
        "eval_curve": {
            "frames": progress.history.eval_frames,
            "seconds": progress.history.eval_seconds,  # training seconds, evaluation excluded
            "returns": progress.history.eval_returns,
        },
        "checkpoint": str(best) if cfg.checkpoint.save_best else None,
        "run_dir": str(run_dir),
        "versions": {
            "torch": torch.__version__,
            "torchrl": torchrl.__version__,
            "tensordict": tensordict.__version__,
            "gymnasium": gym.__version__,
        },
    }

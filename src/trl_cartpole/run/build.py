"""A run assembled: its parts built from the config and joined into :class:`Components`.

:func:`build_components` turns a validated :class:`~trl_cartpole.config.schema.Config` into the
:class:`Components` of a run, every one a stock TorchRL object or a small object with one
concern: the envs (``TransformedEnv``), the Q-actor (``QValueActor``) and its exploration
(``EGreedyModule``), the replay buffer (``TensorDictReplayBuffer``), the learner (``DQNLoss``,
``SoftUpdate``/``HardUpdate``, AdamW), the ``Collector``, the evaluator, the checkpointer,
the metrics log, the progress bar and the history. ``Components`` is a context manager:
leaving it, normally or by an exception, closes the collector (its worker processes or Ray
actors), the envs and the logger.

Each TorchRL part comes from a ``build_*`` function of :mod:`trl_cartpole.run.from_config`,
the one module that turns a factory's config section into its arguments; this module reads
only the run's own sections (checkpoint, logger, eval) and joins the parts.
"""

from __future__ import annotations

import os
import time
import warnings
from contextlib import ExitStack
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path
from typing import Any

import torch
from omegaconf import OmegaConf
from tensordict.nn import TensorDictModuleBase, TensorDictSequential
from torchrl.checkpoint import Checkpoint
from torchrl.collectors import BaseCollector
from torchrl.data import TensorDictReplayBuffer
from torchrl.envs import TransformedEnv
from torchrl.modules import DistributionalQValueActor, EGreedyModule, QValueActor

from trl_cartpole.config.compose import variant_label
from trl_cartpole.config.schema import Config
from trl_cartpole.envs.ids import solve_threshold, time_limit
from trl_cartpole.parts.collectors import (
    check_ray_address,
    is_distributed,
    needs_weight_sync,
    ray_placement,
    shutdown_collector,
    whole_batches,
)
from trl_cartpole.parts.optim import choose_autocast
from trl_cartpole.report.loggers import MetricsLog, make_logger, truncate_csv_metrics
from trl_cartpole.report.plotting import LiveDurationPlot
from trl_cartpole.report.progress_bar import ProgressBar
from trl_cartpole.run.checkpointer import Checkpointer
from trl_cartpole.run.env_kind import EnvKind
from trl_cartpole.run.envs import (
    close_env,
    estimate_observation_norm,
)
from trl_cartpole.run.eval_protocol import EvalProtocol, PeriodicEvaluation
from trl_cartpole.run.evaluation import Evaluator
from trl_cartpole.run.from_config import (
    REPLAY_FILES,
    build_actor,
    build_collector,
    build_env,
    build_exploration,
    build_learner,
    build_replay_buffer,
    build_schedules,
    run_title,
    transition_keys,
)
from trl_cartpole.run.history import History
from trl_cartpole.run.learner import Learner
from trl_cartpole.run.memory_needs import (
    available_memory_bytes,
    check_buffer_fits_on_disk,
    check_fits_in_memory,
)
from trl_cartpole.run.progress import Progress
from trl_cartpole.run.resources import (
    first_update_frame,
    run_memory_need,
    seed_everything,
    warn_if_no_update,
)
from trl_cartpole.run.run_dir import prepare_run_dir, worker_log_dir
from trl_cartpole.run.schedules import Schedules
from trl_cartpole.store.checkpoint import read_observation_norm
from trl_cartpole.store.collection_state import EnvState
from trl_cartpole.store.files import free_bytes, write_text_atomic
from trl_cartpole.store.run_lock import RunLock

__all__ = ["Components", "RunSettings", "build_components"]


@dataclass(frozen=True)
class RunSettings:
    """What the end of a run needs of its config, read once by the builder (plain values)."""

    env_id: str
    seed: int
    algo: str
    variant: str  # the algo preset and the switches the run changed (:func:`variant_label`)
    title: str  # the plots' title (:func:`run_title`)
    return_label: str  # the duration plot's y axis: CartPole's return is its episode's length
    plots: bool  # logger.plots: draw durations.png and dashboard.png
    replay_files: Path | None  # buffer.storage=memmap's files, deleted once the state is saved
    gamma: float  # the discount the dashboard's value reference uses
    time_limit: int | None  # the env's step limit, for the same reference
    max_grad_norm: float | None  # the dashboard's clip line (None: no norm clipping)
    best_checkpoint: Path | None  # checkpoints/best, when the run saves it
    autocast: str  # the update's number type as chosen for this machine: bfloat16 | none
    num_threads: int  # torch's intra-op threads as set for this process (choose_num_threads)

    @classmethod
    def of(cls, cfg: Config, run_dir: Path, learner: Learner) -> RunSettings:
        return cls(
            env_id=cfg.env.id,
            seed=cfg.seed,
            algo=cfg.algo.name,
            variant=variant_label(cfg),
            title=run_title(cfg),
            return_label="Episode return (its length: +1 a step)"
            if cfg.env.id.startswith("CartPole")
            else "Episode return",
            plots=cfg.logger.plots,
            replay_files=run_dir / REPLAY_FILES if cfg.buffer.storage == "memmap" else None,
            gamma=cfg.loss.gamma,
            time_limit=time_limit(cfg.env.id, cfg.env.max_episode_steps),
            max_grad_norm=cfg.optim.max_grad if cfg.optim.grad_clip == "norm" else None,
            best_checkpoint=run_dir / "checkpoints" / "best" if cfg.checkpoint.save_best else None,
            autocast=learner.autocast,
            num_threads=torch.get_num_threads(),
        )


@dataclass
class Components:
    """Everything a run is made of, built in one step; a context manager that releases it.

    The training loop (:func:`~trl_cartpole.run.training.train`) drives these parts; each one has a
    single concern: the metrics log takes ready-made scalars, the progress bar shows the run,
    the history keeps the curves, the checkpointer writes states and the best policy.
    """

    run_dir: Path
    env: TransformedEnv
    eval_env: TransformedEnv
    observation_norm: dict[str, list[float]] | None
    actor: QValueActor | DistributionalQValueActor
    exploration: EGreedyModule | None
    policy: TensorDictModuleBase  # the actor, then epsilon-greedy: what the collector steps
    buffer: TensorDictReplayBuffer
    learner: Learner
    collector: BaseCollector
    evaluator: Evaluator
    progress: Progress
    history: History
    metrics: MetricsLog
    progress_bar: ProgressBar
    live_plot: LiveDurationPlot | None
    checkpointer: Checkpointer
    lock: RunLock  # the run directory's, released on close
    threshold: float | None
    learning_starts: int  # no update before the buffer holds this many transitions
    updates_per_batch: int  # gradient steps after each collected batch
    env_id: str  # the env's id, for messages about it
    schedules: Schedules  # epsilon, network noise, beta: stepped after each batch
    sync_policy_weights: bool  # the collector steps a copy of the policy
    ray_nodes: dict[str, Any] | None  # Ray runs: the learner's and each actor's node id
    transition_keys: tuple[Any, ...]  # what the buffer stores of each frame (transition_keys)
    wall_start: float  # perf_counter() when the build began
    protocol: EvalProtocol  # the end of the run's evaluations: seeds, envs, episodes
    worker_log_dir: Path | None  # where local worker processes write (None on Ray: Ray keeps it)
    settings: RunSettings  # what the end of the run needs of the config
    _collector_released: bool = field(default=False, init=False, repr=False)

    def release_collector(self) -> None:
        """Shut the collector down (its worker processes, Ray actors) once."""
        if not self._collector_released:
            self._collector_released = True
            shutdown_collector(self.collector)

    def close(self) -> None:
        """Release the collector (workers, Ray actors), the envs, the logger and the lock."""
        self.progress_bar.close()
        self.progress_bar.clear()  # a status line of the end, before an error's line
        self.release_collector()
        for env in (self.env, self.eval_env):
            close_env(env)
        self.metrics.close()
        self.lock.release()

    def __enter__(self) -> Components:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()


def build_components(cfg: Config, resume: str | Path | None = None) -> Components:
    """Build every component of a run of ``cfg`` (validated), restored from ``resume`` if given.

    The order is fixed: the envs first (an env that does not fit stops the run before anything
    is written), then the run directory, the networks (the torch RNG's first draws), the
    buffer, the learner and the collector. With ``resume`` (a training-state checkpoint) every
    component is loaded from it and ``cfg`` must be its stored config.
    """
    wall_start = time.perf_counter()
    warn_if_no_update(cfg)
    say_autocast(cfg.optim.autocast, cfg.device)
    threads = choose_num_threads(cfg.num_threads)
    torch.set_num_threads(threads)
    if cfg.num_threads == 0:
        print(f"num_threads=0: torch uses the {threads} cores this process may use", flush=True)
    seed_everything(cfg.seed)
    # Observation statistics are estimated once per run (a resumed run reads them back) and
    # shared by the training and evaluation envs.
    observation_norm = None
    if cfg.env.normalize_observations:
        observation_norm = (
            estimate_observation_norm(cfg.env, cfg.seed)
            if resume is None
            else read_observation_norm(resume)
        )
    env = build_env(
        cfg, cfg.seed, observation_norm=observation_norm, step_timeout=cfg.env.step_timeout
    )
    protocol = EvalProtocol.from_config(cfg, observation_norm)
    periodic = protocol.periodic()  # a pixel policy is chosen on the frames it is evaluated on
    with ExitStack() as on_error:  # an error while building the rest closes what it holds
        on_error.callback(periodic.close)
        on_error.callback(close_env, env)
        if cfg.device == "cpu":  # a buffer or network that cannot fit stops here, not midway
            need, in_files = run_memory_need(cfg, env), cfg.buffer.storage == "memmap"
            check_fits_in_memory(need, available_memory_bytes(), buffer_in_memory=not in_files)
            if in_files:
                files = Path(cfg.run_dir) / REPLAY_FILES
                check_buffer_fits_on_disk(need, files, free_bytes(files))
        if cfg.collector.backend == "ray" and cfg.collector.ray_address is not None:
            check_ray_address(cfg.collector.ray_address)  # before anything is written
        run_dir = prepare_run_dir(cfg.run_dir)
        lock = RunLock(run_dir)  # a second writer of run_dir stops here
        on_error.callback(lock.release)
        components = _assemble(
            cfg,
            resume,
            run_dir,
            env,
            protocol,
            periodic,
            observation_norm,
            lock,
            wall_start,
            on_error,
        )
        if resume is not None:
            components.checkpointer.load(resume, components.progress)
            if components.sync_policy_weights:  # the workers got the weights before the load
                components.collector.update_policy_weights_()
        on_error.pop_all()
    components.progress_bar.open(components.progress.frames)
    return components


def choose_num_threads(requested: int) -> int:
    """``requested`` torch threads, or for 0 every core this process may use: its CPU affinity
    (``taskset`` and container limits narrow it), else the machine's cores."""
    if requested > 0:
        return requested
    if hasattr(os, "sched_getaffinity"):
        return len(os.sched_getaffinity(0))
    return os.cpu_count() or 1


def say_autocast(requested: str, device: str) -> None:
    """The update's number type in one line where the machine chose it (``auto``), a warning
    where the bfloat16 asked for is emulated (:func:`~trl_cartpole.parts.optim.choose_autocast`)."""
    _, line = choose_autocast(requested, device)
    if line is not None and requested == "bfloat16":
        warnings.warn(line, stacklevel=2)
    elif line is not None:
        print(line, flush=True)


def _assemble(
    cfg: Config,
    resume: str | Path | None,
    run_dir: Path,
    env: TransformedEnv,
    protocol: EvalProtocol,
    periodic: PeriodicEvaluation,
    observation_norm: dict[str, list[float]] | None,
    lock: RunLock,
    wall_start: float,
    on_error: ExitStack,
) -> Components:
    """Everything after the envs and the run directory: networks, buffer, learner, collector..."""
    frames_done, logger_step = _resumed_counters(resume, run_dir)
    write_text_atomic(run_dir / "config.yaml", OmegaConf.to_yaml(OmegaConf.structured(cfg)))
    actor = build_actor(cfg, env)
    exploration = build_exploration(cfg, env)
    policy = actor if exploration is None else TensorDictSequential(actor, exploration)
    buffer = build_replay_buffer(cfg, run_dir)
    learner = build_learner(cfg, actor, buffer)
    collector, collector_state_saved = build_collector(
        cfg, env, policy, observation_norm, run_dir, frames_done
    )
    on_error.callback(shutdown_collector, collector)  # worker processes, Ray actors
    metrics = _metrics_log(cfg, run_dir, resume, frames_done, logger_step)
    on_error.callback(metrics.close)
    threshold = solve_threshold(cfg.env.id, cfg.eval.solve_threshold)
    evaluator = Evaluator(
        partial(periodic.play, actor), actor, cfg.eval.interval_frames, threshold,
        cfg.eval.stop_when_solved, candidates=cfg.eval.candidates,
    )  # fmt: skip
    progress, history = Progress(), History()
    saved = {
        "policy": actor,
        "loss": learner.loss,
        "optimizer": learner.optimizer,
        **({} if exploration is None else {"exploration": exploration}),
        **({"replay_buffer": buffer} if cfg.checkpoint.include_buffer else {}),
        **({"collector": collector} if collector_state_saved else {}),
        "progress": progress,
        "learner": learner,
        "evaluator": evaluator,
        "history": history,
        # last: its carrier replaces the one the collector's own state restored
        "envs": _env_state(cfg, env, periodic.env, collector, buffer),
    }
    return Components(
        run_dir=run_dir,
        env=env,
        eval_env=periodic.env,
        observation_norm=observation_norm,
        actor=actor,
        exploration=exploration,
        policy=policy,
        buffer=buffer,
        learner=learner,
        collector=collector,
        evaluator=evaluator,
        progress=progress,
        history=history,
        metrics=metrics,
        progress_bar=_progress_bar(cfg),
        live_plot=_live_plot(cfg, run_dir),
        checkpointer=_checkpointer(cfg, run_dir, saved, observation_norm, metrics),
        lock=lock,
        threshold=threshold,
        learning_starts=first_update_frame(cfg),
        updates_per_batch=cfg.collector.updates_per_batch,
        env_id=cfg.env.id,
        schedules=build_schedules(cfg, exploration, actor, buffer, learner),
        sync_policy_weights=needs_weight_sync(collector, policy),
        ray_nodes=ray_placement(collector),
        transition_keys=transition_keys(actor.in_keys[0], atari=EnvKind(cfg.env).atari),
        wall_start=wall_start,
        protocol=protocol,
        worker_log_dir=worker_log_dir(cfg, run_dir),
        settings=RunSettings.of(cfg, run_dir, learner),
    )


def _checkpointer(
    cfg: Config,
    run_dir: Path,
    saved: dict[str, Any],
    observation_norm: dict[str, list[float]] | None,
    metrics: MetricsLog,
) -> Checkpointer:
    """The run's checkpointer: ``saved`` in every training state, ``cfg`` stored with each
    checkpoint, its settings read here once."""
    settings = cfg.checkpoint
    return Checkpointer(
        run_dir,
        cfg,
        saved,
        observation_norm,
        metrics,
        interval_frames=settings.interval_frames,
        keep_last=settings.keep_last,
        save_best=settings.save_best,
        save_last=settings.save_last,
    )


def _env_state(
    cfg: Config,
    env: TransformedEnv,
    eval_env: TransformedEnv,
    collector: BaseCollector,
    buffer: TensorDictReplayBuffer,
) -> EnvState:
    """What a checkpoint keeps of the envs (the training env's only where this process
    steps it: workers and Ray actors hold their own)."""
    return EnvState(
        None if is_distributed(cfg.collector.workers, cfg.collector.backend) else env,
        eval_env,
        collector,
        buffer,
        trust_pickle=cfg.checkpoint.trust_pickled_envs,
    )


def _metrics_log(
    cfg: Config,
    run_dir: Path,
    resume: str | Path | None,
    frames_done: int,
    logger_step: int | None,
) -> MetricsLog:
    """The run's metrics log on the configured TorchRL logger (a resumed run's continued)."""
    logger = make_logger(
        cfg.logger.backend,
        run_dir,
        cfg.logger.project,
        cfg.logger.wandb_offline,
        resumed_at=None if resume is None else frames_done,
        logger_step=logger_step,
    )
    return MetricsLog(logger)


def _progress_bar(cfg: Config) -> ProgressBar:
    batches = whole_batches(cfg.collector.total_frames, cfg.collector.frames_per_batch)
    return ProgressBar(cfg.logger.progress_bar, cfg.env.id, batches)


def _live_plot(cfg: Config, run_dir: Path) -> LiveDurationPlot | None:
    if not cfg.logger.live_plot:
        return None
    return LiveDurationPlot(
        run_dir / "durations.png", run_title(cfg), min_seconds=cfg.logger.live_plot_seconds
    )


def _resumed_counters(resume: str | Path | None, run_dir: Path) -> tuple[int, int | None]:
    """The frames and logger step a resumed run starts from ((0, None) for a new run); rows
    logged after the checkpoint are cut from the CSV metrics, to be logged again."""
    if resume is None:
        return 0, None
    counters = Checkpoint.manifest(resume)["metadata"]["counters"]
    frames_done = counters["frames"]
    truncate_csv_metrics(run_dir, frames_done)
    return frames_done, counters.get("logger_step")

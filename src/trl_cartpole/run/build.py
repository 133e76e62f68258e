"""The one place where config sections become factory arguments.

:func:`build_components` turns a validated :class:`~trl_cartpole.config.schema.Config` into the
:class:`Components` of a run, every one a stock TorchRL object or a small object with one
concern: the envs (``TransformedEnv``), the Q-actor (``QValueActor``) and its exploration
(``EGreedyModule``), the replay buffer (``TensorDictReplayBuffer``), the learner (``DQNLoss``,
``SoftUpdate``/``HardUpdate``, AdamW), the ``Collector``, the evaluator, the checkpointer,
the metrics log, the progress bar and the history. ``Components`` is a context manager:
leaving it, normally or by an exception, closes the collector (its worker processes or Ray
actors), the envs and the logger.

The ``build_*`` functions build one part each from the config; evaluation, rendering, the
notebook and the benchmark tools use them too, so every tool builds what training builds.
"""

from __future__ import annotations

import os
import random
import shutil
import time
import warnings
from contextlib import ExitStack
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np
import torch
from omegaconf import OmegaConf
from tensordict.nn import TensorDictModuleBase, TensorDictSequential
from torchrl.checkpoint import Checkpoint
from torchrl.collectors import BaseCollector
from torchrl.data import LazyMemmapStorage, TensorDictReplayBuffer
from torchrl.envs import EnvBase, TransformedEnv
from torchrl.modules import DistributionalQValueActor, EGreedyModule, QValueActor

from trl_cartpole.config.schema import Config
from trl_cartpole.env_ids import solve_threshold
from trl_cartpole.errors import ConfigError
from trl_cartpole.parts.collectors import (
    RAY_ACTOR_OPTIONS,
    check_ray_address,
    is_distributed,
    make_collector,
    needs_weight_sync,
    ray_placement,
    shutdown_collector,
    whole_batches,
)
from trl_cartpole.parts.exploration import make_exploration
from trl_cartpole.parts.fused_loss import fuse_dqn_loss
from trl_cartpole.parts.losses import make_dqn_loss, make_target_updater
from trl_cartpole.parts.models import ACTIVATIONS, make_q_actor
from trl_cartpole.parts.optim import make_optimizer, make_update
from trl_cartpole.parts.pixels import PIXELS_KEY, RandomShift
from trl_cartpole.parts.replay import make_replay_buffer
from trl_cartpole.report.loggers import MetricsLog, make_logger, truncate_csv_metrics
from trl_cartpole.report.plotting import LiveDurationPlot
from trl_cartpole.report.progress_bar import ProgressBar
from trl_cartpole.run.checkpointer import Checkpointer
from trl_cartpole.run.envs import (
    close_env,
    estimate_observation_norm,
    make_env_from_config,
    worker_env_constructors,
)
from trl_cartpole.run.evaluation import Evaluator, evaluate
from trl_cartpole.run.history import History
from trl_cartpole.run.judging import Judge
from trl_cartpole.run.learner import Learner
from trl_cartpole.run.memory_needs import (
    MemoryNeed,
    available_memory_bytes,
    check_buffer_fits_on_disk,
    check_fits_in_memory,
    memory_need,
)
from trl_cartpole.run.progress import Progress
from trl_cartpole.run.schedules import Schedules
from trl_cartpole.store.buffer_checkpoint import save_filled_part
from trl_cartpole.store.checkpoint import read_observation_norm
from trl_cartpole.store.collection_state import EnvState
from trl_cartpole.store.files import free_bytes, write_text_atomic
from trl_cartpole.store.run_lock import RunLock

__all__ = [
    "Components",
    "build_actor",
    "build_components",
    "build_env",
    "build_exploration",
    "build_learner",
    "build_replay_buffer",
    "prepare_run_dir",
    "run_title",
    "seed_everything",
    "transition_keys",
]


def transition_keys(observation_key: str = "observation") -> tuple[Any, ...]:
    """What the replay buffer stores of a collected frame: the observation the network reads
    (``"observation"``, or ``"pixels"``), the action, and the next step's observation, reward
    and flags. The rest (Q-values, counters) is dropped."""
    return (
        observation_key,
        "action",
        ("next", observation_key),
        ("next", "reward"),
        ("next", "done"),
        ("next", "terminated"),
        ("next", "truncated"),
    )


def seed_everything(seed: int) -> None:
    """Seed Python's ``random``, NumPy and torch (the env seeds are set by ``make_env``)."""
    random.seed(seed)
    np.random.seed(seed)  # noqa: NPY002 (global state that third-party code reads)
    torch.manual_seed(seed)


def run_title(cfg: Config) -> str:
    """``CartPole-v1 dqn seed 0`` (``CartPole-v1 from pixels dqn seed 0``): a run's plot title."""
    pixels = " from pixels" if cfg.env.from_pixels else ""
    return f"{cfg.env.id}{pixels} {cfg.algo.name} seed {cfg.seed}"


def point_latest(run_dir: Path) -> None:
    """Point ``runs/latest`` at ``run_dir`` when it lies in a ``runs`` directory (best effort).

    So a command can name the newest run without knowing its timestamp
    (``scripts/evaluate.py checkpoint=runs/latest``); the link is replaced atomically.
    """
    real = run_dir.resolve()
    if real.parent.name != "runs" or real.name == "latest":
        return
    temporary = real.parent / f".latest-{os.getpid()}"
    try:
        temporary.unlink(missing_ok=True)
        temporary.symlink_to(real.name)
        os.replace(temporary, real.parent / "latest")
    except OSError:  # a file system without symbolic links, or a real directory named latest
        temporary.unlink(missing_ok=True)


def prepare_run_dir(run_dir: str | Path) -> Path:
    """Create ``run_dir`` (and point ``runs/latest`` at it), or raise a one-line ConfigError."""
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
    point_latest(path)
    return path


def worker_log_dir(cfg: Config, run_dir: Path) -> Path | None:
    """Where local collector worker processes write their output (None on Ray: Ray keeps it)."""
    return run_dir / "workers" if cfg.collector.backend == "local" else None


def fresh_worker_log_dir(cfg: Config, run_dir: Path) -> Path | None:
    """:func:`worker_log_dir`, emptied of an earlier session's logs (a resume, a rerun)."""
    log_dir = worker_log_dir(cfg, run_dir)
    if log_dir is not None:
        shutil.rmtree(log_dir, ignore_errors=True)
    return log_dir


# --- one part each ----------------------------------------------------------------------------


def build_env(
    cfg: Config,
    seed: int,
    num_envs: int | None = None,
    observation_norm: dict[str, list[float]] | None = None,
    render_mode: str | None = None,
    step_timeout: float | None = None,
) -> TransformedEnv:
    """The env of ``cfg.env`` (``num_envs`` overrides its count), seeded ``seed``; a training
    env's steps are bounded by ``step_timeout`` (``cfg.env.step_timeout``)."""
    return make_env_from_config(
        cfg.env,
        seed,
        cfg.device,
        num_envs,
        observation_norm=observation_norm,
        render_mode=render_mode,
        step_timeout=step_timeout,
    )


def first_update_frame(cfg: Config) -> int:
    """The frames collected before the first gradient update: the random warm-up, the
    ``learning_starts`` floor and one batch of samples."""
    collector = cfg.collector
    return max(cfg.buffer.batch_size, collector.learning_starts, collector.init_random_frames)


def warn_if_no_update(cfg: Config) -> None:
    """Warn in one line when the run ends before its first update: it could not learn."""
    first = first_update_frame(cfg)
    if cfg.collector.total_frames < first:
        warnings.warn(
            f"collector.total_frames={cfg.collector.total_frames} ends before the first update "
            f"at frame {first} (the largest of collector.init_random_frames, "
            "collector.learning_starts and buffer.batch_size): this run collects and evaluates "
            "but does not learn; raise collector.total_frames or lower those",
            stacklevel=2,
        )


def run_memory_need(cfg: Config, env: TransformedEnv) -> MemoryNeed:
    """The lower bound of what ``cfg``'s replay buffer and networks take in memory."""
    return memory_need(
        env,
        cfg.buffer.size,
        partial(build_actor, cfg, env),
        amsgrad=cfg.optim.amsgrad,
    )


def build_actor(
    cfg: Config, env: EnvBase, device: str | None = None
) -> QValueActor | DistributionalQValueActor:
    """The Q-value actor of ``cfg.network``, sized from ``env``'s specs (on ``cfg.device``
    unless ``device`` is given)."""
    network = cfg.network
    support = (
        torch.linspace(network.v_min, network.v_max, network.atoms)
        if network.distributional
        else None
    )
    cnn = network.torso == "cnn"
    return make_q_actor(
        env.observation_spec,
        env.action_spec,
        in_keys=[PIXELS_KEY] if cnn else ["observation"],
        torso=network.torso,
        cnn_kwargs={
            "channels": network.cnn_channels,
            "kernel_sizes": network.cnn_kernels,
            "strides": network.cnn_strides,
        }
        if cnn
        else None,
        num_cells=network.hidden_sizes,
        activation_class=ACTIVATIONS[network.activation],
        head=network.head,
        device=cfg.device if device is None else device,
        noisy=network.noisy,
        noisy_std=network.noisy_std,
        support=support,
    )


def build_exploration(cfg: Config, env: TransformedEnv) -> EGreedyModule | None:
    """The epsilon-greedy module of ``cfg.exploration`` (None for noisy networks)."""
    explore = cfg.exploration
    return make_exploration(
        env.action_spec,
        eps_init=explore.eps_start,
        eps_end=explore.eps_end,
        annealing_num_steps=explore.decay_frames,
        schedule=explore.schedule,
        device=cfg.device,
    )


# Where buffer.storage=memmap keeps its files, in the run directory.
REPLAY_FILES = "replay_buffer"


def build_replay_buffer(cfg: Config, run_dir: Path | None = None) -> TensorDictReplayBuffer:
    """The replay buffer of ``cfg.buffer`` (n-step returns discounted by ``cfg.loss.gamma``).

    ``buffer.storage=memmap`` stores it in TorchRL's ``LazyMemmapStorage``, in files under
    ``run_dir/replay_buffer`` (TorchRL's temporary directory without ``run_dir``).
    """
    buffer = cfg.buffer
    storage = None  # make_replay_buffer's LazyTensorStorage
    if buffer.storage == "memmap":
        scratch_dir = None if run_dir is None else str(run_dir / REPLAY_FILES)
        # existsok: a resumed run writes over the files its stopped run left
        storage = LazyMemmapStorage(
            buffer.size, scratch_dir=scratch_dir, device=cfg.device, existsok=True
        )
    replay_buffer = make_replay_buffer(
        storage=storage,
        max_size=buffer.size if storage is None else None,
        batch_size=buffer.batch_size,
        device=cfg.device,
        prioritized=buffer.prioritized,
        **(
            {
                "alpha": torchrl_priority_exponent(buffer.alpha, cfg.network.distributional),
                "beta": buffer.beta,
                "eps": buffer.priority_eps,
            }
            if buffer.prioritized
            else {}
        ),
        n_steps=buffer.n_steps,
        **({"gamma": cfg.loss.gamma} if buffer.n_steps > 1 else {}),
        transform=RandomShift(buffer.pixels_shift) if buffer.pixels_shift else None,
    )
    save_filled_part(replay_buffer.storage)  # a checkpoint holds the transitions, not capacity
    return replay_buffer


def torchrl_priority_exponent(alpha: float, distributional: bool) -> float:
    """TorchRL's ``alpha`` for Schaul et al.'s exponent ``alpha`` on |delta| (``buffer.alpha``).

    TorchRL stores ``(td_error + eps) ** alpha``, and ``DQNLoss`` writes ``td_error`` =
    delta ** 2, so |delta| ** alpha is (delta ** 2) ** (alpha / 2). ``DistributionalDQNLoss``
    writes the cross-entropy, Rainbow's priority itself (Hessel et al. 2018), so C51 keeps it.
    """
    return alpha if distributional else alpha / 2


def build_learner(cfg: Config, actor: torch.nn.Module, buffer: TensorDictReplayBuffer) -> Learner:
    """``DQNLoss`` (or C51's), its target updater, AdamW and the gradient step of ``cfg``."""
    loss_cfg = cfg.loss
    if cfg.network.distributional:  # C51's loss has neither switch (validate refuses them)
        loss = make_dqn_loss(actor, gamma=loss_cfg.gamma, replay_buffer=buffer)
    else:
        loss = make_dqn_loss(
            actor,
            gamma=loss_cfg.gamma,
            loss_function=loss_cfg.loss_function,
            double_dqn=loss_cfg.double_dqn,
            replay_buffer=buffer,
        )
    if loss_cfg.target_update == "soft":
        target_updater = make_target_updater(loss, tau=loss_cfg.tau)
    else:
        target_updater = make_target_updater(
            loss, hard_update_interval=loss_cfg.hard_update_interval
        )
    optimizer = make_optimizer(
        actor.parameters(),
        lr=cfg.optim.lr,
        amsgrad=cfg.optim.amsgrad,
        weight_decay=cfg.optim.weight_decay,
        eps=cfg.optim.eps,
    )
    fused = fuse_dqn_loss(loss) if loss_cfg.fused else None  # None: C51, noisy layers
    update = make_update(
        loss if fused is None else fused,
        optimizer,
        cfg.optim.grad_clip,
        cfg.optim.max_grad,
        noisy_network=actor if cfg.network.noisy else None,
    )
    if cfg.compile:
        update = torch.compile(update)
    return Learner(buffer, loss, target_updater, optimizer, update)


# --- a whole run ------------------------------------------------------------------------------


@dataclass
class Components:
    """Everything a run is made of, built in one step; a context manager that releases it.

    The training loop (:func:`~trl_cartpole.run.training.train`) drives these parts; each one has a
    single concern: the metrics log takes ready-made scalars, the progress bar shows the run,
    the history keeps the curves, the checkpointer writes states and the best policy.
    """

    cfg: Config
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
    judge: Judge  # the end of the run's evaluations: seeds, envs, episodes
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
    torch.set_num_threads(cfg.num_threads)
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
    judge = Judge.from_config(cfg, observation_norm)
    # a pixel policy is chosen on the frames it is judged on
    eval_env = judge.make_envs(judge.seed_for("periodic"), judge.periodic_episodes)
    with ExitStack() as on_error:  # an error while building the rest closes what it holds
        on_error.callback(close_env, eval_env)
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
            cfg, resume, run_dir, env, judge, eval_env, observation_norm, lock, wall_start, on_error
        )
        if resume is not None:
            components.checkpointer.load(resume, components.progress)
        on_error.pop_all()
    components.progress_bar.open(components.progress.frames)
    return components


def _assemble(
    cfg: Config,
    resume: str | Path | None,
    run_dir: Path,
    env: TransformedEnv,
    judge: Judge,
    eval_env: TransformedEnv,
    observation_norm: dict[str, list[float]] | None,
    lock: RunLock,
    wall_start: float,
    on_error: ExitStack,
) -> Components:
    """Everything after the envs and the run directory: networks, buffer, learner, collector..."""
    frames_done, logger_step = 0, None
    if resume is not None:  # rows logged after the checkpoint will be logged again
        counters = Checkpoint.manifest(resume)["metadata"]["counters"]
        frames_done, logger_step = counters["frames"], counters.get("logger_step")
        truncate_csv_metrics(run_dir, frames_done)
    write_text_atomic(run_dir / "config.yaml", OmegaConf.to_yaml(OmegaConf.structured(cfg)))

    actor = build_actor(cfg, env)
    exploration = build_exploration(cfg, env)
    policy = actor if exploration is None else TensorDictSequential(actor, exploration)
    buffer = build_replay_buffer(cfg, run_dir)
    learner = build_learner(cfg, actor, buffer)
    # Workers (processes or Ray actors) build their own envs; their counters are not saved, so
    # a resumed run gives them only the frames still to collect (a single-process collector's
    # own frame counter is restored from the checkpoint instead).
    distributed = is_distributed(cfg.collector.workers, cfg.collector.backend)
    # The collector's own state (its frame counter, its env's) is saved for a single-process
    # collector over a state-vector env; a pixel env's (TorchRL's SerialEnv, restarted with
    # fresh transforms once the collector has closed it) is not, and counts as workers' do.
    collector_state_saved = not distributed and not cfg.env.from_pixels
    frames_not_counted = 0 if collector_state_saved else frames_done
    collector = make_collector(
        worker_env_constructors(cfg, observation_norm, fresh_worker_log_dir(cfg, run_dir))
        if distributed
        else env,
        policy,
        frames_per_batch=cfg.collector.frames_per_batch,
        total_frames=cfg.collector.total_frames - frames_not_counted,
        init_random_frames=max(cfg.collector.init_random_frames - frames_not_counted, 0),
        device=cfg.device,
        sync=cfg.collector.sync,
        backend=cfg.collector.backend,
        ray_address=cfg.collector.ray_address,
        remote_configs={**RAY_ACTOR_OPTIONS, "resources": dict(cfg.collector.ray_resources)},
        ray_init_config={"runtime_env": dict(cfg.collector.ray_runtime_env)}
        if cfg.collector.ray_runtime_env
        else None,
    )
    on_error.callback(shutdown_collector, collector)  # worker processes, Ray actors
    metrics = MetricsLog(
        make_logger(
            cfg.logger.backend,
            run_dir,
            cfg.logger.project,
            cfg.logger.wandb_offline,
            resumed_at=None if resume is None else frames_done,
            logger_step=logger_step,
        )
    )
    on_error.callback(metrics.close)
    threshold = solve_threshold(cfg.env.id, cfg.eval.solve_threshold)
    evaluator = Evaluator(
        partial(evaluate, actor, eval_env, cfg.eval.max_steps),
        actor,
        cfg.eval.interval_frames,
        threshold,
        cfg.eval.stop_when_solved,
        candidates=cfg.eval.candidates,
    )
    progress, history = Progress(), History()
    checkpointer = Checkpointer(
        run_dir,
        cfg,
        {
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
            "envs": EnvState(
                None if distributed else env,
                eval_env,
                collector,
                buffer,
                trust_pickle=cfg.checkpoint.trust_pickled_envs,
            ),
        },
        observation_norm,
        metrics,
    )
    return Components(
        cfg,
        run_dir,
        env,
        eval_env,
        observation_norm,
        actor,
        exploration,
        policy,
        buffer,
        learner,
        collector,
        evaluator,
        progress,
        history,
        metrics,
        ProgressBar(
            cfg.logger.progress_bar,
            cfg.env.id,
            whole_batches(cfg.collector.total_frames, cfg.collector.frames_per_batch),
        ),
        LiveDurationPlot(
            run_dir / "durations.png", run_title(cfg), min_seconds=cfg.logger.live_plot_seconds
        )
        if cfg.logger.live_plot
        else None,
        checkpointer,
        lock,
        threshold,
        learning_starts=first_update_frame(cfg),
        updates_per_batch=cfg.collector.updates_per_batch,
        env_id=cfg.env.id,
        schedules=Schedules(
            exploration,
            actor if cfg.network.noisy else None,
            buffer if cfg.buffer.prioritized else None,
            cfg.buffer.beta,
            cfg.buffer.beta_anneal_frames or cfg.collector.total_frames,
            learner.optimizer if cfg.optim.lr_end is not None else None,
            cfg.optim.lr,
            cfg.optim.lr_end or cfg.optim.lr,
            cfg.optim.lr_decay_frames or cfg.collector.total_frames,
        ),
        sync_policy_weights=needs_weight_sync(collector, policy),
        ray_nodes=ray_placement(collector),
        transition_keys=transition_keys(actor.in_keys[0]),
        wall_start=wall_start,
        judge=judge,
    )

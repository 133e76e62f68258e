"""The config's factory sections as factory arguments, the one place where they are read.

Each ``build_x(cfg, ...)`` calls the factory of :mod:`trl_cartpole.parts` with the values of
its section, as TorchRL's own examples' ``make_x(cfg)`` do; evaluation, rendering, the notebook
and the benchmarks use them too, so every tool builds what training builds."""

from __future__ import annotations

from dataclasses import asdict
from pathlib import Path
from typing import Any

import torch
from tensordict.nn import TensorDictModuleBase
from torchrl.collectors import BaseCollector
from torchrl.data import Categorical, LazyMemmapStorage, TensorDictReplayBuffer, TensorSpec
from torchrl.envs import Compose, EnvBase, Transform, TransformedEnv
from torchrl.modules import DistributionalQValueActor, EGreedyModule, QValueActor

from trl_cartpole.config.schema import Config
from trl_cartpole.envs.atari import EOL_KEY, LearnerView
from trl_cartpole.envs.pixels import PIXELS_KEY, RandomShift
from trl_cartpole.fast.loss import fuse_dqn_loss
from trl_cartpole.fast.n_step import use_windowed_n_steps
from trl_cartpole.parts.collectors import (
    RAY_ACTOR_OPTIONS,
    is_distributed,
    make_collector,
)
from trl_cartpole.parts.exploration import make_exploration
from trl_cartpole.parts.losses import make_dqn_loss, make_target_updater
from trl_cartpole.parts.models import make_q_actor
from trl_cartpole.parts.optim import choose_autocast, make_optimizer, make_update
from trl_cartpole.parts.replay import make_replay_buffer
from trl_cartpole.run.env_kind import EnvKind
from trl_cartpole.run.envs import (
    make_env_from_config,
    worker_env_constructors,
)
from trl_cartpole.run.learner import Learner
from trl_cartpole.run.run_dir import fresh_worker_log_dir
from trl_cartpole.run.schedules import Schedules
from trl_cartpole.storage.chunked import TrackedTensorStorage
from trl_cartpole.storage.frames import FrameStackStorage

__all__ = [
    "REPLAY_FILES",
    "build_actor",
    "build_collector",
    "build_env",
    "build_exploration",
    "build_learner",
    "build_replay_buffer",
    "build_schedules",
    "run_title",
    "transition_keys",
]


def transition_keys(observation_key: str = "observation", atari: bool = False) -> tuple[Any, ...]:
    """What the replay buffer stores of a collected frame: the observation the network reads
    (``"observation"``, or ``"pixels"``), the action, and the next step's observation, reward
    and flags (an Atari game's ``("next", "end-of-life")`` too, which the buffer's
    :class:`LearnerView` folds into them). The rest (Q-values, counters) is dropped."""
    keys = (
        observation_key,
        "action",
        ("next", observation_key),
        ("next", "reward"),
        ("next", "done"),
        ("next", "terminated"),
        ("next", "truncated"),
    )
    return (*keys, ("next", EOL_KEY)) if atari else keys


def run_title(cfg: Config) -> str:
    """``CartPole-v1 dqn seed 0`` (``CartPole-v1 from pixels dqn seed 0``): a run's plot title."""
    return f"{EnvKind(cfg.env).title} {cfg.algo.name} seed {cfg.seed}"


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


def _per_env_action_spec(env: EnvBase) -> TensorSpec:
    """``env``'s action spec as the actor reads it: a batch of envs whose actions are indices
    (``Categorical``, e.g. a ``SerialEnv`` of Atari games: ``[num_envs]``) gives one env's
    (``[]``), which TorchRL's ``QValueModule`` checks each action against; a one-hot spec is
    kept as the env gives it (its last dimension is the actions')."""
    spec = env.action_spec
    if env.batch_size and isinstance(spec, Categorical) and spec.shape == env.batch_size:
        return env.action_spec_unbatched
    return spec


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
        _per_env_action_spec(env),
        in_keys=[PIXELS_KEY] if cnn else ["observation"],
        torso=network.torso,
        cnn_kwargs=asdict(network.cnn_kwargs) if cnn else None,
        num_cells=network.num_cells,
        activation_class=network.activation_class,
        head=network.head,
        device=cfg.device if device is None else device,
        noisy=network.noisy,
        noisy_std=network.noisy_std,
        support=support,
    )


def build_exploration(cfg: Config, env: TransformedEnv) -> EGreedyModule | None:
    """The epsilon-greedy module of ``cfg.exploration`` (None for noisy networks)."""
    return make_exploration(env.action_spec, **asdict(cfg.exploration), device=cfg.device)


# Where buffer.storage=memmap keeps its files, in the run directory.
REPLAY_FILES = "replay_buffer"


def build_replay_buffer(cfg: Config, run_dir: Path | None = None) -> TensorDictReplayBuffer:
    """The replay buffer of ``cfg.buffer`` (n-step returns discounted by ``cfg.loss.gamma``).

    ``buffer.storage=memmap`` stores it in TorchRL's ``LazyMemmapStorage``, in files under
    ``run_dir/replay_buffer`` (TorchRL's temporary directory without ``run_dir``);
    ``buffer.storage=frames`` keeps each distinct frame of the pixel stacks once
    (:class:`~trl_cartpole.storage.frames.FrameStackStorage`).
    """
    buffer = cfg.buffer
    # in memory: TorchRL's LazyTensorStorage, its checkpoints writing what changed since the
    # last (storage/chunked.py)
    storage = TrackedTensorStorage(buffer.max_size, device=cfg.device)
    if buffer.storage == "frames":
        storage = FrameStackStorage(buffer.max_size, device=cfg.device)
    if buffer.storage == "memmap":
        scratch_dir = None if run_dir is None else str(run_dir / REPLAY_FILES)
        # existsok: a resumed run writes over the files its stopped run left
        storage = LazyMemmapStorage(
            buffer.max_size, scratch_dir=scratch_dir, device=cfg.device, existsok=True
        )
    replay_buffer = make_replay_buffer(
        storage=storage,
        max_size=None,
        batch_size=buffer.batch_size,
        device=cfg.device,
        prioritized=buffer.prioritized,
        **(
            {"alpha": buffer.alpha, "beta": buffer.beta, "eps": buffer.eps}
            if buffer.prioritized
            else {}
        ),
        n_steps=buffer.n_steps,
        **({"gamma": cfg.loss.gamma} if buffer.n_steps > 1 else {}),
        transform=_buffer_transform(cfg),
    )
    if cfg.fast:
        use_windowed_n_steps(replay_buffer)
    return replay_buffer


def _buffer_transform(cfg: Config) -> Transform | None:
    """What the buffer does to what it stores and samples, besides n-step returns: an Atari
    game's learner view (a lost life ends the learner's episode, rewards clipped:
    :class:`LearnerView`) when a batch is stored; DrQ's random shift of sampled frames."""
    transforms: list[Transform] = []
    if EnvKind(cfg.env).atari:
        atari = cfg.env.atari
        transforms.append(LearnerView(atari.life_loss_ends, atari.clip_rewards))
    if cfg.buffer.pixels_shift:
        transforms.append(RandomShift(cfg.buffer.pixels_shift))
    if len(transforms) > 1:
        return Compose(*transforms)
    return transforms[0] if transforms else None


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
    target_updater = make_target_updater(loss, **asdict(cfg.target_updater))
    optimizer = make_optimizer(
        actor.parameters(),
        lr=cfg.optim.lr,
        amsgrad=cfg.optim.amsgrad,
        weight_decay=cfg.optim.weight_decay,
        eps=cfg.optim.eps,
    )
    fused = fuse_dqn_loss(loss) if cfg.fast else None  # None: C51, noisy layers
    chosen, _ = choose_autocast(cfg.optim.autocast, cfg.device)  # said by the run
    autocast_dtype = None if chosen == "none" else getattr(torch, chosen)
    update = make_update(
        loss if fused is None else fused,
        optimizer,
        cfg.optim.grad_clip,
        cfg.optim.max_grad,
        noisy_network=actor if cfg.network.noisy else None,
        autocast_dtype=autocast_dtype,
    )
    if cfg.compile:  # validate refuses optim.lr_end here: the compiled step holds lr fixed
        update = torch.compile(update)
    return Learner(buffer, loss, target_updater, optimizer, update, autocast=chosen)


def build_collector(
    cfg: Config,
    env: TransformedEnv,
    policy: TensorDictModuleBase,
    observation_norm: dict[str, list[float]] | None,
    run_dir: Path,
    frames_done: int = 0,
) -> tuple[BaseCollector, bool]:
    """The collector of ``cfg.collector`` stepping ``policy``, and whether its own state is
    saved with the run's (a resumed run's ``frames_done`` frames are not collected again)."""
    # Workers (processes or Ray actors) build their own envs; their counters are not saved, so
    # a resumed run gives them only the frames still to collect (a single-process collector's
    # own frame counter is restored from the checkpoint instead).
    distributed = is_distributed(cfg.collector.workers, cfg.collector.backend)
    # The collector's own state is saved for a single-process collector over an env whose
    # kind allows it; otherwise its frames count as workers' do.
    collector_state_saved = not distributed and EnvKind(cfg.env).collector_state_saved
    frames_not_counted = 0 if collector_state_saved else frames_done
    collector = make_collector(
        worker_env_constructors(cfg, observation_norm, fresh_worker_log_dir(cfg, run_dir))
        if distributed
        else env,
        policy,
        frames_per_batch=cfg.collector.frames_per_batch,
        # a run whose training is done goes to its ending without collecting (``train``): its
        # collector, never iterated, is built for one batch, as TorchRL needs at least that
        total_frames=max(
            cfg.collector.total_frames - frames_not_counted, cfg.collector.frames_per_batch
        ),
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
    return collector, collector_state_saved


def build_schedules(
    cfg: Config,
    exploration: EGreedyModule | None,
    actor: torch.nn.Module,
    buffer: TensorDictReplayBuffer,
    learner: Learner,
) -> Schedules:
    """What moves after each batch: epsilon, network noise, the prioritized buffer's beta,
    the learning rate's taper."""
    total = cfg.collector.total_frames
    return Schedules(
        exploration,
        actor if cfg.network.noisy else None,
        buffer if cfg.buffer.prioritized else None,
        cfg.buffer.beta,
        cfg.buffer.beta_anneal_frames or total,
        learner.optimizer if cfg.optim.lr_end is not None else None,
        cfg.optim.lr,
        cfg.optim.lr_end or cfg.optim.lr,
        cfg.optim.lr_decay_frames or total,
    )

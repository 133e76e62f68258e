"""Typed configuration schema and the rules between its fields.

The schema's defaults are the tuned default preset (``configs/algo/dqn.yaml`` restates them), so
``train({...})`` without Hydra trains what ``python scripts/train.py`` trains.

The dataclasses below are the schema Hydra composes ``configs/`` onto (registered in
Hydra's ConfigStore as ``base_config``): a misspelt key or a wrong type fails at
composition time. :func:`validate` then checks what a type cannot express (ranges and
rules between fields) and raises :class:`ConfigError` with one line naming the field
and how to fix it.
"""

from __future__ import annotations

import importlib.util
from dataclasses import dataclass, field
from datetime import datetime
from typing import Any

from omegaconf import DictConfig, OmegaConf

__all__ = [
    "AlgoConfig",
    "BufferConfig",
    "CheckpointConfig",
    "CollectorConfig",
    "Config",
    "ConfigError",
    "EnvConfig",
    "EvalConfig",
    "ExplorationConfig",
    "LoggerConfig",
    "LossConfig",
    "NetworkConfig",
    "OptimConfig",
    "flat_fields",
    "register_configs",
    "to_config",
    "validate",
]


class ConfigError(ValueError):
    """A configuration that cannot run; the message is one line saying what to change."""


@dataclass
class EnvConfig:
    # Any Gymnasium id with a vector observation and discrete actions: a registered id, or
    # module:Id / module:EnvClass (imported, and registered if a class), see trl_cartpole.envs.
    id: str = "CartPole-v1"
    imports: list[str] = field(default_factory=list)  # modules whose import registers env ids
    max_episode_steps: int | None = None  # None: Gymnasium's registered TimeLimit
    num_envs: int = 32  # training envs stepped together (a Gymnasium SyncVectorEnv when > 1)
    normalize_observations: bool = False  # TorchRL ObservationNorm, stats from random rollouts
    normalization_frames: int = 10_000  # random-policy frames the stats are estimated from


@dataclass
class AlgoConfig:
    name: str = "dqn"  # preset name, recorded in summary.json


@dataclass
class NetworkConfig:
    head: str = "plain"  # see trl_cartpole.models.HEADS
    hidden_sizes: list[int] = field(default_factory=lambda: [128, 128])
    activation: str = "relu"  # relu | tanh | elu | gelu
    noisy: bool = False  # NoisyLinear layers (Fortunato et al. 2018); needs exploration=none
    noisy_std: float = 0.5  # sigma_0 of the factorised noise (the paper's 0.5)
    distributional: bool = False  # C51 (Bellemare et al. 2017): a return distribution per action
    atoms: int = 51  # support points of the distribution
    v_min: float = 0.0  # support [v_min, v_max]; CartPole's returns lie in [0, 1 / (1 - gamma)]
    v_max: float = 200.0  # 1 / (1 - 0.995), the default gamma


@dataclass
class ExplorationConfig:
    schedule: str = "linear"  # linear (TorchRL) | exponential (PyTorch tutorial) | none (noisy)
    eps_start: float = 1.0
    eps_end: float = 0.05
    decay_frames: int = 3000  # linear: frames to reach eps_end; exponential: time constant


@dataclass
class BufferConfig:
    size: int = 50_000
    batch_size: int = 512
    prioritized: bool = False  # proportional prioritized replay (Schaul et al. 2016)
    alpha: float = 0.6  # P(i) ~ (|delta_i| + priority_eps) ** alpha
    beta: float = 0.4  # importance-sampling exponent at the start, annealed linearly to 1
    beta_anneal_frames: int | None = None  # frames to reach beta = 1; None: collector.total_frames
    priority_eps: float = 1e-6
    n_steps: int = 3  # n-step returns (Sutton 1988) through MultiStepTransform when > 1


@dataclass
class LossConfig:
    gamma: float = 0.995
    loss_function: str = "smooth_l1"  # smooth_l1 (Huber, as the tutorial) | l2
    double_dqn: bool = False
    target_update: str = "hard"  # hard (copy every N updates) | soft (Polyak, tau)
    tau: float = 0.02
    hard_update_interval: int = 50  # gradient updates between hard copies


@dataclass
class OptimConfig:
    lr: float = 4e-3
    amsgrad: bool = True
    weight_decay: float = 0.0  # the tutorial keeps AdamW's default 0.01
    grad_clip: str = "norm"  # norm | value | none
    max_grad: float = 10.0  # the max norm, or the clip value per element


@dataclass
class CollectorConfig:
    total_frames: int = 50_000
    frames_per_batch: int = 32  # frames per collected batch, over all envs
    init_random_frames: int = 1000  # frames drawn with a uniform random policy first
    updates_per_batch: int = 6  # gradient steps after each collected batch
    learning_starts: int = 0  # no update before the buffer holds max(this, batch_size)
    # Scaling out (docs/scaling.md): collection in worker processes or Ray actors, each with
    # env.num_envs envs. workers=1 on the local backend collects in the training process.
    workers: int = 1
    sync: bool = True  # workers > 1: batches from all workers (true) or the first ready (false)
    backend: str = "local"  # local (this machine) | ray (TorchRL's RayCollector)
    ray_address: str | None = None  # ray: a running cluster's host:port; null: start one here


@dataclass
class EvalConfig:
    interval_frames: int = 1000  # greedy evaluation every this many frames
    episodes: int = 20  # episodes per periodic evaluation
    final_episodes: int = 100  # episodes for the final evaluation of the best policy
    solve_threshold: float | None = None  # None: Gymnasium's reward_threshold for the env
    stop_when_solved: bool = True
    max_steps: int = 10_000  # step cap for an episode of an env with no TimeLimit
    seed_offset: int = 1_000_000  # eval env seed = seed + seed_offset


@dataclass
class LoggerConfig:
    backend: str = "csv"  # csv | tensorboard | wandb | none
    project: str = "trl_cartpole"  # wandb project
    wandb_offline: bool = True  # wandb runs offline (sync later with `wandb sync`)
    progress_bar: bool = True
    plots: bool = True  # durations.png and dashboard.png at the end of the run
    live_plot: bool = True  # redraw the duration plot at each evaluation (notebook/window/PNG)


@dataclass
class CheckpointConfig:
    save_best: bool = True  # the best policy by periodic evaluation
    save_last: bool = True  # the full training state at the end of the run
    include_buffer: bool = True  # store the replay buffer in training states (exact resume)
    interval_frames: int = 10_000  # a training state every this many frames (0: never)
    keep_last: int = 2  # periodic training states kept (checkpoints/periodic)


@dataclass
class Config:
    seed: int = 0
    run_dir: str = "runs/${env.id}-${algo.name}-seed${seed}-${now:%Y%m%d-%H%M%S}"
    device: str = "cpu"
    num_threads: int = 1  # torch intra-op threads; 1 is fastest for small MLPs
    compile: bool = False  # torch.compile the gradient step (about 10 s once, then ~2x faster)
    env: EnvConfig = field(default_factory=EnvConfig)
    algo: AlgoConfig = field(default_factory=AlgoConfig)
    network: NetworkConfig = field(default_factory=NetworkConfig)
    exploration: ExplorationConfig = field(default_factory=ExplorationConfig)
    buffer: BufferConfig = field(default_factory=BufferConfig)
    loss: LossConfig = field(default_factory=LossConfig)
    optim: OptimConfig = field(default_factory=OptimConfig)
    collector: CollectorConfig = field(default_factory=CollectorConfig)
    eval: EvalConfig = field(default_factory=EvalConfig)
    logger: LoggerConfig = field(default_factory=LoggerConfig)
    checkpoint: CheckpointConfig = field(default_factory=CheckpointConfig)


if not OmegaConf.has_resolver("now"):
    OmegaConf.register_new_resolver(
        "now", lambda pattern: datetime.now().strftime(pattern), use_cache=True
    )


def register_configs() -> None:
    """Register the schema with Hydra's ConfigStore as ``base_config``."""
    from hydra.core.config_store import ConfigStore

    ConfigStore.instance().store(name="base_config", node=Config)


def to_config(cfg: Config | DictConfig | dict[str, Any]) -> Config:
    """Return a resolved :class:`Config` from a dataclass, a DictConfig or a plain dict."""
    if isinstance(cfg, Config):
        merged = OmegaConf.merge(OmegaConf.structured(Config), OmegaConf.structured(cfg))
    else:
        merged = OmegaConf.merge(OmegaConf.structured(Config), cfg)
    return OmegaConf.to_object(merged)


_CHOICES = {
    "exploration.schedule": ("exponential", "linear", "none"),
    "loss.loss_function": ("smooth_l1", "l2"),
    "loss.target_update": ("soft", "hard"),
    "optim.grad_clip": ("value", "norm", "none"),
    "logger.backend": ("csv", "tensorboard", "wandb", "none"),
    "collector.backend": ("local", "ray"),
}


def flat_fields(cfg: Config | dict[str, Any], prefix: str = "") -> dict[str, Any]:
    """``{"section.key": value}`` for every leaf of a config (lists become tuples, hashable)."""
    tree = cfg if isinstance(cfg, dict) else OmegaConf.to_container(OmegaConf.structured(cfg))
    flat: dict[str, Any] = {}
    for key, value in tree.items():
        if isinstance(value, dict):
            flat.update(flat_fields(value, f"{prefix}{key}."))
        else:
            flat[f"{prefix}{key}"] = tuple(value) if isinstance(value, list) else value
    return flat


def _get(cfg: Config, dotted: str) -> Any:
    value: Any = cfg
    for part in dotted.split("."):
        value = getattr(value, part)
    return value


def validate(cfg: Config) -> Config:
    """Check ranges and cross-field rules; raise :class:`ConfigError` on the first failure."""
    for key, options in _CHOICES.items():
        if _get(cfg, key) not in options:
            raise ConfigError(
                f"{key}={_get(cfg, key)!r} is not a known option; choose one of {list(options)}"
            )
    checks: list[tuple[bool, str]] = [
        (0.0 < cfg.loss.gamma <= 1.0, f"loss.gamma={cfg.loss.gamma} must lie in (0, 1]"),
        (0.0 < cfg.loss.tau <= 1.0, f"loss.tau={cfg.loss.tau} must lie in (0, 1]"),
        (cfg.loss.hard_update_interval >= 1, "loss.hard_update_interval must be >= 1"),
        (cfg.buffer.size >= 1, f"buffer.size={cfg.buffer.size} must be >= 1"),
        (cfg.buffer.batch_size >= 1, f"buffer.batch_size={cfg.buffer.batch_size} must be >= 1"),
        (
            cfg.buffer.batch_size <= cfg.buffer.size,
            f"buffer.batch_size={cfg.buffer.batch_size} is larger than buffer.size="
            f"{cfg.buffer.size}; lower the batch size or grow the buffer",
        ),
        (
            0.0 <= cfg.exploration.eps_end <= cfg.exploration.eps_start <= 1.0,
            f"exploration needs 0 <= eps_end <= eps_start <= 1, got eps_start="
            f"{cfg.exploration.eps_start}, eps_end={cfg.exploration.eps_end}",
        ),
        (cfg.exploration.decay_frames >= 1, "exploration.decay_frames must be >= 1"),
        (cfg.optim.lr > 0, f"optim.lr={cfg.optim.lr} must be > 0"),
        (cfg.optim.weight_decay >= 0, "optim.weight_decay must be >= 0"),
        (cfg.optim.max_grad > 0, f"optim.max_grad={cfg.optim.max_grad} must be > 0"),
        (
            all(size >= 1 for size in cfg.network.hidden_sizes),
            f"network.hidden_sizes={list(cfg.network.hidden_sizes)} must all be >= 1",
        ),
        (cfg.collector.frames_per_batch >= 1, "collector.frames_per_batch must be >= 1"),
        (cfg.env.num_envs >= 1, f"env.num_envs={cfg.env.num_envs} must be >= 1"),
        (
            cfg.env.normalization_frames >= 1,
            f"env.normalization_frames={cfg.env.normalization_frames} must be >= 1",
        ),
        (cfg.collector.workers >= 1, f"collector.workers={cfg.collector.workers} must be >= 1"),
        (
            cfg.collector.frames_per_batch % _envs_per_batch(cfg) == 0,
            f"collector.frames_per_batch={cfg.collector.frames_per_batch} must be a multiple "
            f"of {_envs_per_batch_text(cfg)} (each batch steps every env equally often)"
            f"{_split_hint(cfg)}",
        ),
        (
            cfg.collector.total_frames >= cfg.collector.frames_per_batch,
            f"collector.total_frames={cfg.collector.total_frames} must be >= "
            f"collector.frames_per_batch={cfg.collector.frames_per_batch}",
        ),
        (cfg.collector.init_random_frames >= 0, "collector.init_random_frames must be >= 0"),
        (cfg.collector.updates_per_batch >= 0, "collector.updates_per_batch must be >= 0"),
        (cfg.collector.learning_starts >= 0, "collector.learning_starts must be >= 0"),
        (cfg.eval.interval_frames >= 1, "eval.interval_frames must be >= 1"),
        (cfg.eval.episodes >= 1, "eval.episodes must be >= 1"),
        (cfg.eval.final_episodes >= 1, "eval.final_episodes must be >= 1"),
        (cfg.eval.max_steps >= 1, "eval.max_steps must be >= 1"),
        (cfg.network.noisy_std > 0, f"network.noisy_std={cfg.network.noisy_std} must be > 0"),
        (cfg.network.atoms >= 2, f"network.atoms={cfg.network.atoms} must be >= 2"),
        (
            cfg.network.v_min < cfg.network.v_max,
            f"network.v_min={cfg.network.v_min} must be < network.v_max={cfg.network.v_max}",
        ),
        (cfg.buffer.alpha >= 0, f"buffer.alpha={cfg.buffer.alpha} must be >= 0"),
        (0 <= cfg.buffer.beta <= 1, f"buffer.beta={cfg.buffer.beta} must lie in [0, 1]"),
        (cfg.buffer.priority_eps > 0, "buffer.priority_eps must be > 0"),
        (
            cfg.buffer.beta_anneal_frames is None or cfg.buffer.beta_anneal_frames >= 1,
            "buffer.beta_anneal_frames must be >= 1 (or null for collector.total_frames)",
        ),
        (cfg.buffer.n_steps >= 1, f"buffer.n_steps={cfg.buffer.n_steps} must be >= 1"),
        (cfg.checkpoint.interval_frames >= 0, "checkpoint.interval_frames must be >= 0"),
        (cfg.checkpoint.keep_last >= 1, "checkpoint.keep_last must be >= 1"),
        (cfg.num_threads >= 1, f"num_threads={cfg.num_threads} must be >= 1"),
        (cfg.seed >= 0, f"seed={cfg.seed} must be >= 0"),
        (bool(str(cfg.run_dir).strip()), "run_dir must not be empty"),
    ]
    for ok, message in checks:
        if not ok:
            raise ConfigError(message)
    if cfg.device != "cpu" and not cfg.device.startswith(("cuda", "mps")):
        raise ConfigError(f"device={cfg.device!r} is not a torch device; use cpu or cuda[:N]")
    _check_combination(cfg)
    # Local imports: envs and models import this module.
    from trl_cartpole.envs import resolve_env_id
    from trl_cartpole.models import check_network_choices

    check_network_choices(cfg.network.head, cfg.network.activation)
    resolve_env_id(cfg.env.id, cfg.env.imports)
    return cfg


def _envs_per_batch(cfg: Config) -> int:
    """How many envs step in one collected batch: every worker's when they are synchronous."""
    collector = cfg.collector  # (>= 1 each: the range checks run after this is computed)
    return max(cfg.env.num_envs, 1) * (max(collector.workers, 1) if collector.sync else 1)


def _envs_per_batch_text(cfg: Config) -> str:
    if cfg.collector.sync and cfg.collector.workers > 1:
        return f"env.num_envs * collector.workers = {_envs_per_batch(cfg)}"
    return f"env.num_envs={cfg.env.num_envs}"


def _split_hint(cfg: Config) -> str:
    """Suggest spreading the envs over the workers when that makes the batch fit."""
    workers, frames = cfg.collector.workers, cfg.collector.frames_per_batch
    if cfg.collector.sync and workers > 1 and frames % workers == 0:
        per_worker = frames // workers
        return f"; e.g. env.num_envs={per_worker} ({per_worker} envs on each of {workers} workers)"
    return ""


def _check_combination(cfg: Config) -> None:
    """Refuse switches that the chosen components would ignore, rather than drop them silently."""
    collector = cfg.collector
    if collector.ray_address is not None and collector.backend != "ray":
        raise ConfigError(
            f"collector.ray_address={collector.ray_address!r} is only read by the Ray backend; "
            "set collector.backend=ray or drop the address"
        )
    if not collector.sync and collector.workers == 1 and collector.backend == "local":
        raise ConfigError(
            "collector.sync=false needs collector.workers > 1 (one local worker collects in the "
            "training process); raise collector.workers"
        )
    if collector.backend == "ray" and importlib.util.find_spec("ray") is None:
        raise ConfigError(
            "collector.backend=ray needs Ray, which is not installed: "
            'pip install -e ".[distributed]"'
        )
    if not collector.sync and collector.workers > 1 and cfg.buffer.n_steps > 1:
        raise ConfigError(
            f"buffer.n_steps={cfg.buffer.n_steps} needs each env's steps in order, but with "
            "collector.sync=false consecutive batches come from different workers; set "
            "buffer.n_steps=1 or collector.sync=true"
        )
    noisy, schedule = cfg.network.noisy, cfg.exploration.schedule
    if noisy and schedule != "none":
        raise ConfigError(
            f"network.noisy=true explores through its parameter noise, so exploration.schedule="
            f"{schedule!r} would add epsilon-greedy on top; set exploration.schedule=none"
        )
    if not noisy and schedule == "none":
        raise ConfigError(
            "exploration.schedule=none leaves a plain network with no exploration at all; "
            "set network.noisy=true or choose exploration.schedule=linear|exponential"
        )
    if cfg.network.distributional:
        if not cfg.loss.double_dqn:
            raise ConfigError(
                "network.distributional=true always picks the next action with the online "
                "network (double DQN) and cannot switch it off; set loss.double_dqn=true"
            )
        if cfg.loss.loss_function != "smooth_l1":
            raise ConfigError(
                f"network.distributional=true trains with the cross-entropy to the projected "
                f"target, not loss.loss_function={cfg.loss.loss_function!r}; leave it smooth_l1"
            )

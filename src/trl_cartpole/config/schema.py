"""Typed configuration schema and the rules between its fields.

The schema's defaults are the tuned default preset (``configs/algo/dqn.yaml`` restates them), so
``train({...})`` without Hydra trains what ``python scripts/train.py`` trains.

The dataclasses below are the schema Hydra composes ``configs/`` onto (registered in
Hydra's ConfigStore as ``base_config``): a misspelt key or a wrong type fails at
composition time. ``trl_cartpole.config.validation.validate`` then checks what a type cannot
express (ranges and rules between fields) and raises ``ConfigError`` with one line naming the
field and how to fix it. Of the package it imports only ``trl_cartpole.defaults``, where the
defaults it shares with the factories are stated.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from datetime import datetime
from typing import Any

from omegaconf import DictConfig, OmegaConf

from trl_cartpole import defaults

__all__ = [
    "AlgoConfig",
    "AtariConfig",
    "BufferConfig",
    "CheckpointConfig",
    "CollectorConfig",
    "Config",
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
]


@dataclass
class AtariConfig:
    """The standard Atari preprocessing (Mnih et al. 2015; Machado et al. 2018), for an
    ``env.id`` of ALE's (``ALE/Breakout-v5``): trl_cartpole.parts.atari, docs/atari.md."""

    noop_max: int = 30  # NOOP frames after a reset: 1 to noop_max, drawn per game (0: none)
    frame_skip: int = 4  # frames each action is held; the max of the last two is seen
    screen_size: int = 84  # the screen resized to screen_size x screen_size gray (INTER_AREA)
    frames: int = 4  # the last N screens stacked (CatFrames)
    # FIRE steps after a reset and after a lost life, where the game has FIRE
    fire_on_reset: bool = True
    # 2: sticky actions swallow one 4-frame FIRE step once in 256 and the game would wait
    fire_steps: int = 2
    life_loss_ends: bool = True  # a lost life ends the learner's episode (never the game)
    clip_rewards: bool = True  # the learner's rewards clipped to their sign (the score is not)


@dataclass
class EnvConfig:
    # Any Gymnasium id with a vector observation and discrete actions: a registered id, or
    # module:Id / module:EnvClass (imported, and registered if a class), see trl_cartpole.parts.env.
    id: str = defaults.ENV_ID  # a Gymnasium id (vector observation, discrete actions), or module:Id
    imports: list[str] = field(default_factory=list)  # modules whose import registers env ids
    # null: Gymnasium's registered TimeLimit (an Atari game: agent steps, ALE's cap of 108 000
    # frames otherwise)
    max_episode_steps: int | None = None
    num_envs: int = 32  # training envs stepped together (a Gymnasium SyncVectorEnv when > 1)
    # seconds a training env's step or reset may take before the run stops naming it (null: no
    # limit); a SIGALRM alarm, so the main thread of the training or worker process only
    step_timeout: float | None = 60.0
    normalize_observations: bool = False  # TorchRL ObservationNorm, stats from random rollouts
    normalization_frames: int = 10_000  # random-policy frames the stats are estimated from
    # Learning from pixels (docs/environments.md): the rendered frame instead of the state
    from_pixels: bool = False  # the network sees only the env's rendered frames
    # [top, bottom, left, right] rows and columns of the frame kept (null: up to the edge)
    pixels_crop: list[int | None] = field(default_factory=lambda: [None, None, None, None])
    pixels_pool: int = 1  # average the kept patch over pool x pool blocks (a smaller image)
    pixels_frames: int = 1  # the last N patches stacked (CatFrames): the motion
    # who draws the training frames: "gymnasium" (its render(), one env at a time) or "drawn"
    # (CartPole only: the same pooled frame drawn from a batch of states,
    # parts/cartpole_drawing.py); the evaluations always play on Gymnasium's own picture
    pixels_renderer: str = "gymnasium"
    # drawn only: this share of each drawn batch's envs (its first share * num_envs, rounded
    # up) shows Gymnasium's own picture instead (its pygame calls, about 0.4 ms a frame), so
    # the network also learns the frames it is judged on; 1.0: every frame Gymnasium's
    pixels_rendered_share: float = 0.0
    # An Atari game (env.id=ALE/...) is learnt from its screen, preprocessed as configured here
    atari: AtariConfig = field(default_factory=AtariConfig)
    # keywords given to gymnasium.make as they are, for any env: its own options (ALE's
    # repeat_action_probability, full_action_space, mode, difficulty...)
    make_kwargs: dict[str, Any] = field(default_factory=dict)


@dataclass
class AlgoConfig:
    name: str = "dqn"  # preset name, recorded in summary.json


@dataclass
class NetworkConfig:
    head: str = "plain"  # plain | dueling (Wang et al. 2016), see trl_cartpole.defaults.HEADS
    torso: str = "mlp"  # mlp (TorchRL MLP) | cnn (TorchRL ConvNet, then the MLP; for pixels)
    cnn_channels: list[int] = field(
        default_factory=lambda: list(defaults.CNN_CHANNELS)
    )  # cnn: channels
    cnn_kernels: list[int] = field(
        default_factory=lambda: list(defaults.CNN_KERNELS)
    )  # cnn: kernel sizes
    cnn_strides: list[int] = field(
        default_factory=lambda: list(defaults.CNN_STRIDES)
    )  # cnn: strides
    hidden_sizes: list[int] = field(
        default_factory=lambda: list(defaults.HIDDEN_SIZES)
    )  # MLP torso widths
    activation: str = defaults.ACTIVATION  # relu | tanh | elu | gelu
    noisy: bool = False  # NoisyLinear layers (Fortunato et al. 2018); needs exploration=none
    noisy_std: float = defaults.NOISY_STD  # sigma_0 of the factorised noise (the paper's 0.5)
    distributional: bool = False  # C51 (Bellemare et al. 2017): a return distribution per action
    atoms: int = 51  # support points of the distribution
    v_min: float = 0.0  # support [v_min, v_max]; CartPole's returns lie in [0, 1 / (1 - gamma)]
    v_max: float = 200.0  # 1 / (1 - 0.995), the default gamma


@dataclass
class ExplorationConfig:
    schedule: str = "linear"  # linear (TorchRL) | exponential (PyTorch tutorial) | none (noisy)
    eps_start: float = defaults.EPS_START  # probability of a random action at the start
    eps_end: float = defaults.EPS_END  # ... after decay_frames (linear) and the floor (exponential)
    # linear: frames to reach eps_end; exponential: time constant
    decay_frames: int = defaults.DECAY_FRAMES


@dataclass
class BufferConfig:
    size: int = defaults.BUFFER_SIZE  # transitions kept (the oldest are overwritten)
    # memory: TorchRL's LazyTensorStorage, in RAM | memmap: its LazyMemmapStorage, files in
    # RUN_DIR/replay_buffer (removed at the end), for a buffer larger than the RAM to spare |
    # frames: in RAM, each distinct frame of the pixel stacks once (parts/frame_storage.py)
    storage: str = "memory"
    batch_size: int = defaults.BATCH_SIZE  # transitions per gradient step
    prioritized: bool = False  # proportional prioritized replay (Schaul et al. 2016)
    # P(i) ~ |delta_i| ** alpha (Schaul et al.); stored TorchRL's way as
    # (delta_i ** 2 + priority_eps) ** (alpha / 2)
    alpha: float = defaults.ALPHA
    beta: float = defaults.BETA  # importance-sampling exponent at the start, annealed linearly to 1
    beta_anneal_frames: int | None = None  # frames to reach beta = 1; null: collector.total_frames
    # added to delta ** 2 (TorchRL's td_error) so that no transition has priority 0
    priority_eps: float = defaults.PRIORITY_EPS
    # n-step returns (Sutton 1988) through MultiStepTransform when > 1
    n_steps: int = defaults.N_STEPS
    # pixels only: DrQ's random shift of each sampled frame by up to this many pixels (0: none)
    pixels_shift: int = 0


@dataclass
class LossConfig:
    gamma: float = defaults.GAMMA  # discount factor
    loss_function: str = defaults.LOSS_FUNCTION  # smooth_l1 (Huber, as the tutorial) | l2
    double_dqn: bool = False  # double DQN target (van Hasselt et al. 2016)
    target_update: str = "hard"  # hard (copy every N updates) | soft (Polyak, tau)
    tau: float = defaults.TAU  # soft: target <- (1 - tau) target + tau online, after each update
    # gradient updates between hard copies
    hard_update_interval: int = defaults.HARD_UPDATE_INTERVAL
    # DQNLoss's arithmetic on plain tensors (trl_cartpole.parts.fused_loss): bitwise the same
    # loss, about a fifth less time per update; false calls DQNLoss itself. C51 and noisy
    # layers always call the loss module
    fused: bool = True


@dataclass
class OptimConfig:
    lr: float = defaults.LR  # AdamW learning rate
    amsgrad: bool = defaults.AMSGRAD  # AdamW's AMSGrad variant, as the tutorial
    weight_decay: float = defaults.WEIGHT_DECAY  # the tutorial keeps AdamW's default 0.01
    # the floor under AdamW's denominator (its own default; data-efficient Rainbow: 1.5e-4)
    eps: float = defaults.ADAM_EPS
    grad_clip: str = defaults.GRAD_CLIP  # norm | value | none
    max_grad: float = defaults.MAX_GRAD  # the max norm, or the clip value per element
    # the learning rate tapered linearly from lr to this, set from the frames after each batch
    # (null: lr the whole run)
    lr_end: float | None = None
    lr_decay_frames: int | None = None  # frames to reach lr_end; null: collector.total_frames
    # none | bfloat16: the update's network passes under torch.autocast in that type (Breakout's
    # whole update about two thirds of the time on a CPU with AVX-512 BF16; docs/performance.md)
    autocast: str = "none"


@dataclass
class CollectorConfig:
    total_frames: int = defaults.TOTAL_FRAMES  # env steps at most (rounded up to whole batches)
    # seconds of training at most (evaluations not counted), then the run ends as at its last
    # frame; the frames it reaches follow the machine's speed (null: no limit)
    max_train_seconds: float | None = None
    frames_per_batch: int = defaults.FRAMES_PER_BATCH  # frames per collected batch, over all envs
    # frames with a uniform random policy first (whole batches)
    init_random_frames: int = defaults.INIT_RANDOM_FRAMES
    updates_per_batch: int = 6  # gradient steps after each collected batch
    learning_starts: int = 0  # no update before the buffer holds max(this, batch_size)
    # Scaling out (docs/scaling.md): collection in worker processes or Ray actors, each with
    # env.num_envs envs. workers=1 on the local backend collects in the training process.
    workers: int = 1  # collector processes or Ray actors (docs/scaling.md); 1: in this process
    sync: bool = True  # workers > 1: batches from all workers (true) or the first ready (false)
    backend: str = "local"  # local (this machine) | ray (TorchRL's RayCollector)
    ray_address: str | None = None  # ray: a running cluster's host:port; null: start one here
    # ray: custom resources each actor needs (Ray's `resources`); {collector_node: 1} places the
    # actors on nodes started with `ray start --resources='{"collector_node": N}'`
    ray_resources: dict[str, float] = field(default_factory=dict)
    # ray (a cluster): Ray's runtime environment for the run's actors, e.g. {py_modules:
    # [src/trl_cartpole]} ships this package to nodes that lack it (docs/scaling.md)
    ray_runtime_env: dict[str, Any] = field(default_factory=dict)


@dataclass
class EvalConfig:
    interval_frames: int = 1000  # greedy evaluation every this many frames
    episodes: int = 20  # episodes per periodic evaluation
    final_episodes: int = 100  # episodes for the final evaluation of the best policy
    # the best this many policies (by periodic evaluation) each play candidate_episodes new
    # episodes before the final evaluation, and the best over those is kept; 1: the best
    # periodic evaluation's policy, as is (docs/choices.md)
    candidates: int = 1
    candidate_episodes: int = 50  # the same episodes for every candidate
    solve_threshold: float | None = None  # null: Gymnasium's reward_threshold for the env
    stop_when_solved: bool = True  # end the run at the first evaluation >= the threshold
    max_steps: int = 10_000  # step cap for an episode of an env with no TimeLimit
    seed_offset: int = 1_000_000  # eval env seed = seed + seed_offset


@dataclass
class LoggerConfig:
    backend: str = "csv"  # csv | tensorboard | wandb | none
    project: str = "trl_cartpole"  # wandb project
    wandb_offline: bool = True  # wandb runs offline (sync later with `wandb sync`)
    progress_bar: bool = True  # a progress bar on a terminal (a line per evaluation otherwise)
    verbose: bool = False  # also show the libraries' INFO lines and warnings
    plots: bool = True  # durations.png and dashboard.png at the end of the run
    live_plot: bool = True  # redraw the duration plot at evaluations (notebook/window/PNG)
    live_plot_seconds: float = 5.0  # at most one live redraw per this many seconds of wall time


@dataclass
class CheckpointConfig:
    save_best: bool = True  # the best policy by periodic evaluation
    save_last: bool = True  # the full training state at the end of the run
    include_buffer: bool = True  # store the replay buffer in training states (exact resume)
    interval_frames: int = 10_000  # a training state every this many frames (0: never)
    keep_last: int = 2  # periodic training states kept (checkpoints/periodic)
    # store and load envs that are not classic control pickled; loading runs any code the
    # checkpoint holds, so a resume reads this from its command line only (docs/reliability.md)
    trust_pickled_envs: bool = False


@dataclass
class Config:
    seed: int = 0  # seeds torch, the envs and the exploration (same seed, same run)
    # where the run writes; the default name also lists the overrides that differ from presets
    # (run_env: the env id, and "-pixels" for a pixel run: runs/CartPole-v1-pixels-dqn-seed0-...)
    run_dir: str = "runs/${run_env:}-${algo.name}-seed${seed}-${now:%Y%m%d-%H%M%S}"
    device: str = "cpu"  # cpu | cuda | cuda:N (networks, losses and the replay buffer)
    num_threads: int = 1  # torch intra-op threads; 1 is fastest for small MLPs
    compile: bool = False  # the whole gradient step compiled (3-25 s once; docs/performance.md)
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


def _run_env(_root_: Any) -> str:
    """``${run_env:}``: the env id a run directory is named after, ``-pixels`` added for a
    pixel run, a namespace's ``/`` written ``-`` (``ALE-Breakout-v5``: one directory)."""
    return f"{_root_.env.id}{'-pixels' if _root_.env.from_pixels else ''}".replace("/", "-")


if not OmegaConf.has_resolver("run_env"):
    OmegaConf.register_new_resolver("run_env", _run_env)


def register_configs() -> None:
    """Register the schema with Hydra's ConfigStore as ``base_config``.

    Hydra composes in struct mode (an unknown key is an error); a dict field whose keys are the
    user's to name (``collector.ray_resources``, ``ray_runtime_env``) is left open, so that
    ``collector.ray_resources={collector_node: 1}`` sets it without Hydra's ``+``.
    """
    from hydra.core.config_store import ConfigStore

    schema = OmegaConf.structured(Config)
    for open_dict in (
        schema.collector.ray_resources,
        schema.collector.ray_runtime_env,
        schema.env.make_kwargs,
    ):
        OmegaConf.set_struct(open_dict, False)
    ConfigStore.instance().store(name="base_config", node=schema)


def to_config(cfg: Config | DictConfig | dict[str, Any]) -> Config:
    """Return a resolved :class:`Config` from a dataclass, a DictConfig or a plain dict."""
    if isinstance(cfg, Config):
        merged = OmegaConf.merge(OmegaConf.structured(Config), OmegaConf.structured(cfg))
    else:
        merged = OmegaConf.merge(OmegaConf.structured(Config), cfg)
    return OmegaConf.to_object(merged)


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

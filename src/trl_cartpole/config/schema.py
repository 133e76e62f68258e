"""Typed configuration schema and the rules between its fields.

The schema's defaults are the default run (DQN on CartPole-v1, tuned for a CPU; the presets in
``configs/`` change some of them), so ``train({...})`` without Hydra trains what
``python scripts/train.py`` trains. A section's keys are the keyword arguments of the factory it
feeds, in TorchRL's names (``network`` -> ``make_q_actor``, ``exploration`` ->
``make_exploration``, ``buffer`` -> ``make_replay_buffer``, ``loss`` -> ``make_dqn_loss``,
``target_updater`` -> ``make_target_updater``, ``optim`` -> ``make_optimizer``, ``collector``
-> ``make_collector``); the few keys a factory does not take are marked "(the run's)".

The dataclasses below are the schema Hydra composes ``configs/`` onto (registered in
Hydra's ConfigStore as ``base_config``): a misspelt key or a wrong type fails at
composition time. ``trl_cartpole.config.validation.validate`` then checks what a type cannot
express (ranges and rules between fields) and raises ``ConfigError`` with one line naming the
field and how to fix it. It imports nothing of the package.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from datetime import datetime
from typing import Any

from omegaconf import DictConfig, OmegaConf

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
    "TargetUpdaterConfig",
    "flat_fields",
    "register_configs",
    "to_config",
]


@dataclass
class AtariConfig:
    """The standard Atari preprocessing (Mnih et al. 2015; Machado et al. 2018), for an
    ``env.id`` of ALE's (``ALE/Breakout-v5``): trl_cartpole.envs.atari, docs/atari.md."""

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
    id: str = "CartPole-v1"  # a Gymnasium id (vector observation, discrete actions), or module:Id
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
    # envs/cartpole_drawing.py); the evaluations always play on Gymnasium's own picture
    pixels_renderer: str = "gymnasium"
    # drawn only: this share of each drawn batch's envs (its first share * num_envs, rounded
    # up) shows Gymnasium's own picture instead (its pygame calls, about 0.4 ms a frame), so
    # the network also learns the frames it is evaluated on; 1.0: every frame Gymnasium's
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
class CnnKwargs:
    """TorchRL ``ConvNet``'s arguments (``make_cnn_features``): the PyTorch DQN tutorial's
    first, pixel version by default (three 5x5, stride-2 convolutions)."""

    num_cells: list[int] = field(default_factory=lambda: [16, 32, 32])  # each layer's channels
    kernel_sizes: list[int] = field(default_factory=lambda: [5, 5, 5])  # each layer's kernel
    strides: list[int] = field(default_factory=lambda: [2, 2, 2])  # each layer's stride


@dataclass
class NetworkConfig:
    """``make_q_actor(observation_spec, action_spec, **network)``."""

    num_cells: list[int] = field(default_factory=lambda: [128, 128])  # the MLP's hidden widths
    activation_class: str = "relu"  # relu | tanh | elu | gelu
    head: str = "plain"  # plain | dueling (Wang et al. 2016)
    torso: str = "mlp"  # mlp (TorchRL MLP) | cnn (TorchRL ConvNet, then the MLP; for pixels)
    cnn_kwargs: CnnKwargs = field(default_factory=CnnKwargs)  # torso=cnn only
    noisy: bool = False  # NoisyLinear layers (Fortunato et al. 2018); needs exploration=none
    noisy_std: float = 0.5  # sigma_0 of the factorised noise (the paper's 0.5)
    # (the run's) C51 (Bellemare et al. 2017): a return distribution per action, over a
    # support of `atoms` points in [v_min, v_max] (make_q_actor's `support`)
    distributional: bool = False
    atoms: int = 51  # support points of the distribution
    v_min: float = 0.0  # CartPole's returns lie in [0, 1 / (1 - gamma)]
    v_max: float = 200.0  # 1 / (1 - 0.995), the default gamma


@dataclass
class ExplorationConfig:
    """``make_exploration(action_spec, **exploration)`` (TorchRL's ``EGreedyModule``)."""

    eps_init: float = 1.0  # probability of a random action at the start
    eps_end: float = 0.05  # ... after annealing_num_steps (linear); the floor (exponential)
    # linear: frames to reach eps_end; exponential: the time constant
    annealing_num_steps: int = 3000
    schedule: str = "linear"  # linear (TorchRL) | exponential (PyTorch tutorial) | none (noisy)


@dataclass
class BufferConfig:
    """``make_replay_buffer(**buffer)``; n-step returns discounted by ``loss.gamma``."""

    max_size: int = 50_000  # transitions kept (the oldest are overwritten)
    # (the run's) memory: TorchRL's LazyTensorStorage, in RAM | memmap: its LazyMemmapStorage,
    # files in RUN_DIR/replay_buffer (removed at the end), for a buffer larger than the RAM to
    # spare | frames: in RAM, each distinct frame of the pixel stacks once (storage/frames.py)
    storage: str = "memory"
    batch_size: int = 512  # transitions per gradient step
    prioritized: bool = False  # proportional prioritized replay (Schaul et al. 2016)
    # TorchRL's PrioritizedSampler: P(i) ~ (td_error_i + eps) ** alpha, where DQNLoss's
    # td_error is delta ** 2 (so Schaul et al.'s 0.6 on |delta| is 0.3) and C51's the
    # cross-entropy (algo=rainbow: 0.6)
    alpha: float = 0.3
    beta: float = 0.4  # importance-sampling exponent at the start, annealed linearly to 1
    eps: float = 1e-6  # added to td_error so that no transition has priority 0
    # n-step returns (Sutton 1988) through MultiStepTransform when > 1
    n_steps: int = 3
    # (the run's) frames to reach beta = 1; null: collector.total_frames
    beta_anneal_frames: int | None = None
    # (the run's) pixels only: DrQ's random shift of each sampled frame by up to this many
    # pixels (0: none)
    pixels_shift: int = 0


@dataclass
class LossConfig:
    """``make_dqn_loss(actor, **loss)`` (TorchRL's ``DQNLoss``)."""

    gamma: float = 0.995  # discount factor
    loss_function: str = "smooth_l1"  # smooth_l1 (Huber, as the tutorial) | l2
    double_dqn: bool = False  # double DQN target (van Hasselt et al. 2016)


@dataclass
class TargetUpdaterConfig:
    """``make_target_updater(loss, **target_updater)``: TorchRL's ``HardUpdate`` or
    ``SoftUpdate``, after each gradient update; ``kind`` reads only its own updater's keys."""

    kind: str = "hard"  # hard (a copy) | soft (Polyak averaging, tau)
    # hard: a copy on every (value_network_update_interval + 1)-th update (TorchRL's count)
    value_network_update_interval: int = 49
    tau: float = 0.02  # soft: target <- (1 - tau) target + tau online


@dataclass
class OptimConfig:
    """``make_optimizer(params, lr, amsgrad=, weight_decay=, eps=)`` (PyTorch's AdamW); the
    other keys are the run's gradient step's."""

    lr: float = 4e-3  # AdamW learning rate
    amsgrad: bool = True  # AdamW's AMSGrad variant, as the tutorial
    weight_decay: float = 0.0  # the tutorial keeps AdamW's default 0.01
    # the floor under AdamW's denominator (its own default; data-efficient Rainbow: 1.5e-4)
    eps: float = 1e-8
    grad_clip: str = "norm"  # (the run's) norm | value | none
    max_grad: float = 10.0  # (the run's) the max norm, or the clip value per element
    # (the run's) the learning rate tapered linearly from lr to this, set from the frames after
    # each batch (null: lr the whole run)
    lr_end: float | None = None
    lr_decay_frames: int | None = None  # frames to reach lr_end; null: collector.total_frames
    # none | bfloat16 | auto: the update's network passes under torch.autocast in bfloat16
    # (Breakout's whole update about two thirds of float32's time on a CPU with AVX-512 BF16,
    # several times float32's where bfloat16 is emulated); auto: bfloat16 where the device
    # computes it natively, float32 elsewhere, said when the run starts (docs/atari.md)
    autocast: str = "none"


@dataclass
class CollectorConfig:
    """``make_collector(env, policy, **collector)`` (TorchRL's ``Collector``)."""

    total_frames: int = 50_000  # env steps at most (rounded up to whole batches)
    # seconds of training at most (evaluations not counted), then the run ends as at its last
    # frame; the frames it reaches follow the machine's speed (null: no limit)
    max_train_seconds: float | None = None
    frames_per_batch: int = 32  # frames per collected batch, over all envs
    # frames with a uniform random policy first (whole batches)
    init_random_frames: int = 1000
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
    # torch intra-op threads; 1 is fastest for small MLPs; 0: every core this process may use
    # (a CNN's update; `taskset -c 0` gives a run one core, so two runs share a 2-core machine)
    num_threads: int = 1
    # TorchRL's DQNLoss, SoftUpdate and MultiStepTransform rewritten on plain tensors, the same
    # arithmetic in less time (trl_cartpole.fast; docs/performance.md); false: TorchRL's own
    fast: bool = False
    compile: bool = False  # the whole gradient step compiled (3-25 s once; docs/performance.md)
    env: EnvConfig = field(default_factory=EnvConfig)
    algo: AlgoConfig = field(default_factory=AlgoConfig)
    network: NetworkConfig = field(default_factory=NetworkConfig)
    exploration: ExplorationConfig = field(default_factory=ExplorationConfig)
    buffer: BufferConfig = field(default_factory=BufferConfig)
    loss: LossConfig = field(default_factory=LossConfig)
    target_updater: TargetUpdaterConfig = field(default_factory=TargetUpdaterConfig)
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
    pixel run, a namespace's ``/`` and a module's ``:`` written ``-`` (``ALE-Breakout-v5``,
    ``my_module-MyEnv``: one directory, a name every shell and file system takes)."""
    name = f"{_root_.env.id}{'-pixels' if _root_.env.from_pixels else ''}"
    return name.replace("/", "-").replace(":", "-")


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

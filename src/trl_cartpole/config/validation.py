"""The rules a config must follow beyond its types: ranges, rules between fields, known names.

:func:`validate` raises :class:`~trl_cartpole.errors.ConfigError` with one line naming the field
and how to fix it, before anything is built or written.
"""

from __future__ import annotations

import importlib.util
import math
import os
import shutil
import sys
from collections.abc import Sequence
from typing import Any

from trl_cartpole import choices
from trl_cartpole.config.schema import Config, flat_fields
from trl_cartpole.envs.ids import (
    CARTPOLE_FRAME,
    cartpole_crop_bounds,
    check_builtin_env_fits,
    is_atari_id,
    resolve_env_id,
)
from trl_cartpole.errors import ConfigError, install_hint

__all__ = [
    "BOOLEAN_WORDS",
    "MAX_ENVS_AT_ONCE",
    "MAX_INTEGER",
    "check_boolean_overrides",
    "check_envs_at_once",
    "check_integer_size",
    "check_logger_installed",
    "check_seed",
    "validate",
]


_CHOICES = {
    "exploration.schedule": choices.SCHEDULES,
    "loss.loss_function": ("smooth_l1", "l2"),
    "target_updater.kind": choices.TARGET_UPDATERS,
    "optim.grad_clip": choices.GRAD_CLIPS,
    "optim.autocast": ("none", "bfloat16", "auto"),
    "logger.backend": ("csv", "tensorboard", "wandb", "none"),
    "collector.backend": choices.COLLECTOR_BACKENDS,
    "buffer.storage": ("memory", "memmap", "frames"),
    "network.torso": ("mlp", "cnn"),
    "network.head": choices.HEADS,
    "network.activation_class": choices.ACTIVATIONS,
    "env.pixels_renderer": ("gymnasium", "drawn"),
}


# What a switch may be set to on the command line. OmegaConf would also take any integer (a
# nonzero one as true), so a number typed in the wrong key would turn a switch on unseen.
# The largest integer setting: torch and numpy take 64-bit integers, and seeds and frame counts
# are added together (seed + 2 * eval.seed_offset + env index), so there is room for sums.
MAX_INTEGER = 2**62
# The longest env.step_timeout: a week (the real-time timer takes no more on every platform).
MAX_STEP_TIMEOUT = 604_800

# The most envs built at once in one vector env (env.num_envs per worker, one per evaluation
# episode); far above any use here, and below the memory and time a bad value would take.
MAX_ENVS_AT_ONCE = 4096
BOOLEAN_WORDS = ("true", "false", "yes", "no", "on", "off", "1", "0")


def check_boolean_overrides(overrides: Sequence[str]) -> None:
    """Refuse ``switch=value`` for a boolean field of the schema unless ``value`` says yes or no."""
    switches = {key for key, value in flat_fields(Config()).items() if isinstance(value, bool)}
    for override in overrides:
        key, _, value = override.lstrip("+").partition("=")
        words = value.lower().split(",")  # a sweep's list: loss.double_dqn=true,false
        if key in switches and not all(word.strip() in BOOLEAN_WORDS for word in words):
            raise ConfigError(f"{key}={value} is not a switch value; use {key}=true or false")


def _get(cfg: Config, dotted: str) -> Any:
    value: Any = cfg
    for part in dotted.split("."):
        value = getattr(value, part)
    return value


def validate(cfg: Config) -> Config:
    """Check ranges and cross-field rules; raise :class:`ConfigError` on the first failure.

    Imports neither torch nor TorchRL for a CPU config (Gymnasium only, for the env id), so a
    command line is checked in well under a second.
    """
    for key, value in flat_fields(cfg).items():  # NaN slips through every comparison below
        if isinstance(value, float) and not math.isfinite(value):
            raise ConfigError(f"{key}={value} must be a finite number")
        for number in value if isinstance(value, (list, tuple)) else [value]:
            check_integer_size(key, number)
    for key in ("env.num_envs", "eval.episodes", "eval.final_episodes", "eval.candidate_episodes"):
        check_envs_at_once(key, _get(cfg, key))
    for key, options in _CHOICES.items():
        if _get(cfg, key) not in options:
            raise ConfigError(
                f"{key}={_get(cfg, key)!r} is not a known option; choose one of {list(options)}"
            )
    checks = [  # by concern, each section's rules in one function below
        *_learning_rules(cfg),
        *_buffer_rules(cfg),
        *_collector_rules(cfg),
        *_env_rules(cfg),
        *_atari_rules(cfg),
        *_pixels_rules(cfg),
        *_evaluation_rules(cfg),
        *_network_rules(cfg),
        *_run_rules(cfg),
    ]
    for ok, message in checks:
        if not ok:
            raise ConfigError(message)
    check_device(cfg.device)
    if cfg.compile:
        check_compiler(cfg.device)
    _check_combination(cfg)
    check_logger_installed(cfg.logger.backend)
    check_builtin_env_fits(resolve_env_id(cfg.env.id, cfg.env.imports), cfg.env.from_pixels)
    return cfg


def _learning_rules(cfg: Config) -> list[tuple[bool, str]]:
    """(holds, the message when it does not) for the loss, the optimizer and exploration."""
    return [
        (0.0 < cfg.loss.gamma <= 1.0, f"loss.gamma={cfg.loss.gamma} must lie in (0, 1]"),
        (
            0.0 < cfg.target_updater.tau <= 1.0,
            f"target_updater.tau={cfg.target_updater.tau} must lie in (0, 1]",
        ),
        (
            cfg.target_updater.value_network_update_interval >= 0,
            "target_updater.value_network_update_interval must be >= 0 (0: a copy every update)",
        ),
        (
            0.0 <= cfg.exploration.eps_end <= cfg.exploration.eps_init <= 1.0,
            f"exploration needs 0 <= eps_end <= eps_init <= 1, got eps_init="
            f"{cfg.exploration.eps_init}, eps_end={cfg.exploration.eps_end}",
        ),
        (
            cfg.exploration.annealing_num_steps >= 1,
            "exploration.annealing_num_steps must be >= 1",
        ),
        (cfg.optim.lr > 0, f"optim.lr={cfg.optim.lr} must be > 0"),
        (cfg.optim.weight_decay >= 0, "optim.weight_decay must be >= 0"),
        (cfg.optim.eps > 0, f"optim.eps={cfg.optim.eps} must be > 0 (AdamW's: 1e-08)"),
        (cfg.optim.max_grad > 0, f"optim.max_grad={cfg.optim.max_grad} must be > 0"),
        (
            cfg.optim.lr_end is None or cfg.optim.lr_end > 0,
            f"optim.lr_end={cfg.optim.lr_end} must be > 0 (null: no taper)",
        ),
        (
            cfg.optim.autocast == "none" or uses_fused_loss(cfg),
            f"optim.autocast={cfg.optim.autocast} runs the fast path's DQN loss under "
            "torch.autocast (noisy networks and C51 do not use it): pass fast=true, or "
            "optim.autocast=none",
        ),
        (
            cfg.optim.lr_decay_frames is None or cfg.optim.lr_decay_frames >= 1,
            f"optim.lr_decay_frames={cfg.optim.lr_decay_frames} must be >= 1 (null: "
            "collector.total_frames)",
        ),
        (
            cfg.optim.lr_end is None or not cfg.compile,
            "optim.lr_end tapers the learning rate, which the compiled update holds fixed: "
            "pass compile=false, or optim.lr_end=null",
        ),
    ]


def _buffer_rules(cfg: Config) -> list[tuple[bool, str]]:
    """(holds, the message when it does not) for the replay buffer."""
    return [
        (cfg.buffer.max_size >= 1, f"buffer.max_size={cfg.buffer.max_size} must be >= 1"),
        (cfg.buffer.batch_size >= 1, f"buffer.batch_size={cfg.buffer.batch_size} must be >= 1"),
        (
            cfg.buffer.batch_size <= cfg.buffer.max_size,
            f"buffer.batch_size={cfg.buffer.batch_size} is larger than buffer.max_size="
            f"{cfg.buffer.max_size}; lower the batch size or grow the buffer",
        ),
        (cfg.buffer.alpha >= 0, f"buffer.alpha={cfg.buffer.alpha} must be >= 0"),
        (0 <= cfg.buffer.beta <= 1, f"buffer.beta={cfg.buffer.beta} must lie in [0, 1]"),
        (cfg.buffer.eps > 0, "buffer.eps must be > 0"),
        (
            cfg.buffer.beta_anneal_frames is None or cfg.buffer.beta_anneal_frames >= 1,
            "buffer.beta_anneal_frames must be >= 1 (or null for collector.total_frames)",
        ),
        (cfg.buffer.n_steps >= 1, f"buffer.n_steps={cfg.buffer.n_steps} must be >= 1"),
    ]


def _collector_rules(cfg: Config) -> list[tuple[bool, str]]:
    """(holds, the message when it does not) for collection: workers, batches, budgets."""
    return [
        (cfg.collector.frames_per_batch >= 1, "collector.frames_per_batch must be >= 1"),
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
        (
            cfg.collector.max_train_seconds is None or cfg.collector.max_train_seconds > 0,
            f"collector.max_train_seconds={cfg.collector.max_train_seconds} must be > 0, or null "
            "for no limit",
        ),
    ]


# keywords of gymnasium.make the run sets itself, so env.make_kwargs may not
RESERVED_MAKE_KWARGS = {
    "max_episode_steps",
    "render_mode",
    "seed",
    "preprocessing",
    "num_envs",
    "device",
    "observation_norm",
    "from_pixels",
    "pixels_only",
}


def _env_rules(cfg: Config) -> list[tuple[bool, str]]:
    """(holds, the message when it does not) for the env and its envs at once."""
    return [
        (
            not RESERVED_MAKE_KWARGS & set(cfg.env.make_kwargs),
            f"env.make_kwargs: {sorted(RESERVED_MAKE_KWARGS & set(cfg.env.make_kwargs))} are set "
            "by the run (env.max_episode_steps, the seed, the render mode, env.atari); set those "
            "fields instead",
        ),
        (cfg.env.num_envs >= 1, f"env.num_envs={cfg.env.num_envs} must be >= 1"),
        (
            cfg.env.step_timeout is None or 0 < cfg.env.step_timeout <= MAX_STEP_TIMEOUT,
            f"env.step_timeout={cfg.env.step_timeout} must be > 0 and at most "
            f"{MAX_STEP_TIMEOUT} seconds, a week (or null: no limit)",
        ),
        (
            cfg.env.normalization_frames >= 1,
            f"env.normalization_frames={cfg.env.normalization_frames} must be >= 1",
        ),
        (
            cfg.env.max_episode_steps is None or cfg.env.max_episode_steps >= 1,
            f"env.max_episode_steps={cfg.env.max_episode_steps} must be >= 1 (or null for the "
            "env's registered limit)",
        ),
    ]


def _atari_rules(cfg: Config) -> list[tuple[bool, str]]:
    """(holds, the message when it does not) for an Atari game and its preprocessing."""
    atari = cfg.env.atari
    return [
        (atari.noop_max >= 0, f"env.atari.noop_max={atari.noop_max} must be >= 0 (0: none)"),
        (atari.frame_skip >= 1, f"env.atari.frame_skip={atari.frame_skip} must be >= 1"),
        (atari.screen_size >= 8, f"env.atari.screen_size={atari.screen_size} must be >= 8"),
        (atari.frames >= 1, f"env.atari.frames={atari.frames} must be >= 1"),
        (
            atari.fire_steps >= 1,
            f"env.atari.fire_steps={atari.fire_steps} must be >= 1 (no FIRE: "
            "env.atari.fire_on_reset=false)",
        ),
        (
            not {"frameskip", "obs_type"} & set(cfg.env.make_kwargs),
            "env.make_kwargs: frameskip and obs_type are the Atari preprocessing's (ALE's "
            "frameskip=1, grayscale); set env.atari.frame_skip instead",
        ),
        (
            not is_atari_id(cfg.env.id) or cfg.network.torso == "cnn",
            f"env.id={cfg.env.id} is an Atari game, learnt from its screen by a CNN: use an "
            "Atari preset (env=breakout; env=breakout env.id=ALE/<Game>-v5 for another game), "
            "or set network.torso=cnn",
        ),
        (
            not (
                is_atari_id(cfg.env.id) and (cfg.env.from_pixels or cfg.env.normalize_observations)
            ),
            f"env.id={cfg.env.id} is an Atari game, always learnt from its preprocessed screen "
            "(env.atari): set env.from_pixels=false and env.normalize_observations=false",
        ),
    ]


def _pixels_rules(cfg: Config) -> list[tuple[bool, str]]:
    """(holds, the message when it does not) for learning from pixels: frames, CNN, renderer."""
    cnn = cfg.network.cnn_kwargs
    return [
        (cfg.env.pixels_pool >= 1, f"env.pixels_pool={cfg.env.pixels_pool} must be >= 1"),
        (cfg.env.pixels_frames >= 1, f"env.pixels_frames={cfg.env.pixels_frames} must be >= 1"),
        (
            len(cfg.env.pixels_crop) == 4,
            f"env.pixels_crop={list(cfg.env.pixels_crop)} must be [top, bottom, left, right]",
        ),
        (
            len(cnn.num_cells) == len(cnn.kernel_sizes) == len(cnn.strides) >= 1,
            "network.cnn_kwargs: num_cells, kernel_sizes and strides need one entry per layer",
        ),
        (
            min([*cnn.num_cells, *cnn.kernel_sizes, *cnn.strides]) >= 1,
            "network.cnn_kwargs: num_cells, kernel_sizes and strides must all be >= 1",
        ),
        (
            is_atari_id(cfg.env.id) or cfg.env.from_pixels == (cfg.network.torso == "cnn"),
            f"env.from_pixels={cfg.env.from_pixels} with network.torso={cfg.network.torso}: "
            "pixels need the cnn torso and the cnn torso needs pixels (env=cartpole_pixels sets "
            "both)",
        ),
        (
            cfg.env.pixels_renderer != "drawn"
            or (cfg.env.from_pixels and str(cfg.env.id).startswith("CartPole-")),
            f"env.pixels_renderer=drawn draws CartPole from pixels only (env={cfg.env.id}, "
            f"from_pixels={cfg.env.from_pixels}): use env=cartpole_pixels, or "
            "env.pixels_renderer=gymnasium env.pixels_rendered_share=0",
        ),
        (
            cfg.env.pixels_renderer != "drawn" or _drawn_crop_fits(cfg.env),
            f"env.pixels_crop={list(cfg.env.pixels_crop)} keeps less than one "
            f"{cfg.env.pixels_pool}x{cfg.env.pixels_pool} block (env.pixels_pool) of CartPole's "
            f"{CARTPOLE_FRAME[0]}x{CARTPOLE_FRAME[1]} frame: keep more rows and columns, or a "
            "smaller pool",
        ),
        (
            0.0 <= cfg.env.pixels_rendered_share <= 1.0,
            f"env.pixels_rendered_share={cfg.env.pixels_rendered_share} must be between 0 and 1 "
            "(the share of the drawn envs Gymnasium's picture is painted for): set, e.g., 0.25",
        ),
        (
            cfg.env.pixels_rendered_share == 0 or cfg.env.pixels_renderer == "drawn",
            f"env.pixels_rendered_share={cfg.env.pixels_rendered_share} mixes Gymnasium's "
            f"frames into drawn ones, and this run has env.pixels_renderer="
            f"{cfg.env.pixels_renderer}: set env.pixels_rendered_share=0, or use "
            "env=cartpole_pixels",
        ),
        (
            cfg.buffer.pixels_shift >= 0,
            f"buffer.pixels_shift={cfg.buffer.pixels_shift} must be >= 0 (0: no shift)",
        ),
        (
            cfg.buffer.pixels_shift == 0 or cfg.env.from_pixels or is_atari_id(cfg.env.id),
            f"buffer.pixels_shift={cfg.buffer.pixels_shift} shifts frames, and this run has "
            "none (env.from_pixels=false): set it to 0, or use env=cartpole_pixels",
        ),
        (
            cfg.buffer.storage != "frames" or cfg.device == "cpu",
            f"buffer.storage=frames keeps its frames on the CPU, and device={cfg.device}: set "
            "buffer.storage=memory, or device=cpu",
        ),
        (
            cfg.buffer.storage != "frames" or cfg.env.from_pixels or is_atari_id(cfg.env.id),
            "buffer.storage=frames stores the frames of pixel stacks once, and this run has "
            "none: set buffer.storage=memory",
        ),
        (
            not (cfg.env.from_pixels and cfg.env.normalize_observations),
            "env.normalize_observations=true normalises a state vector; pixels have none",
        ),
    ]


def _evaluation_rules(cfg: Config) -> list[tuple[bool, str]]:
    """(holds, the message when it does not) for evaluation."""
    return [
        (cfg.eval.interval_frames >= 1, "eval.interval_frames must be >= 1"),
        (cfg.eval.episodes >= 1, "eval.episodes must be >= 1"),
        (cfg.eval.final_episodes >= 1, "eval.final_episodes must be >= 1"),
        (cfg.eval.candidates >= 1, f"eval.candidates={cfg.eval.candidates} must be >= 1"),
        (
            cfg.eval.candidate_episodes >= 1,
            f"eval.candidate_episodes={cfg.eval.candidate_episodes} must be >= 1",
        ),
        (cfg.eval.max_steps >= 1, "eval.max_steps must be >= 1"),
        (
            cfg.eval.seed_offset >= 0,
            f"eval.seed_offset={cfg.eval.seed_offset} must be >= 0 (Gymnasium takes no "
            "negative seed)",
        ),
    ]


def _network_rules(cfg: Config) -> list[tuple[bool, str]]:
    """(holds, the message when it does not) for the network."""
    return [
        (
            all(size >= 1 for size in cfg.network.num_cells),
            f"network.num_cells={list(cfg.network.num_cells)} must all be >= 1",
        ),
        (cfg.network.noisy_std > 0, f"network.noisy_std={cfg.network.noisy_std} must be > 0"),
        (cfg.network.atoms >= 2, f"network.atoms={cfg.network.atoms} must be >= 2"),
        (
            cfg.network.v_min < cfg.network.v_max,
            f"network.v_min={cfg.network.v_min} must be < network.v_max={cfg.network.v_max}",
        ),
    ]


def _run_rules(cfg: Config) -> list[tuple[bool, str]]:
    """(holds, the message when it does not) for the run: threads, seeds, its directory."""
    return [
        (cfg.checkpoint.interval_frames >= 0, "checkpoint.interval_frames must be >= 0"),
        (cfg.checkpoint.keep_last >= 1, "checkpoint.keep_last must be >= 1"),
        (
            cfg.num_threads >= 0,
            f"num_threads={cfg.num_threads} must be >= 1, or 0 for every core this process may use",
        ),
        (
            cfg.num_threads <= (os.cpu_count() or 1),
            f"num_threads={cfg.num_threads} is more than this machine's {os.cpu_count()} cores",
        ),
        (cfg.seed >= 0, f"seed={cfg.seed} must be >= 0"),
        (bool(str(cfg.run_dir).strip()), "run_dir must not be empty"),
    ]


# logger.backend -> (the package it needs, the extra that installs it)
LOGGER_PACKAGES = {"tensorboard": ("tensorboard", "tensorboard"), "wandb": ("wandb", "wandb")}


def check_logger_installed(backend: str) -> None:
    """Refuse a logger whose package is missing, in one line naming the extra (``validate``
    calls it before the run directory is made, ``make_logger`` for a caller of its own)."""
    if backend in LOGGER_PACKAGES:
        package, extra = LOGGER_PACKAGES[backend]
        # a module already imported counts as it stands (None: its import was blocked)
        loaded = sys.modules.get(package, ...)
        if loaded is None or (loaded is ... and importlib.util.find_spec(package) is None):
            raise ConfigError(
                f"logger.backend={backend} needs {package}, which is not installed: "
                f"{install_hint(extra)}"
            )


def _drawn_crop_fits(env: Any) -> bool:
    """Whether ``env.pixels_crop`` keeps at least one pool block of CartPole's frame."""
    if len(env.pixels_crop) != 4 or env.pixels_pool < 1:
        return True  # refused by their own checks
    top, bottom, left, right = cartpole_crop_bounds(env.pixels_crop)
    return min(bottom - top, right - left) >= env.pixels_pool


def check_integer_size(key: str, value: Any) -> None:
    """Refuse an integer setting beyond :data:`MAX_INTEGER` either way (a 64-bit overflow)."""
    if isinstance(value, int) and not isinstance(value, bool) and abs(value) > MAX_INTEGER:
        raise ConfigError(
            f"{key}={value} is too large: integer settings stop at 2**62 = {MAX_INTEGER} "
            "(torch and numpy count in 64-bit integers)"
        )


def check_seed(key: str, seed: int | None) -> None:
    """Refuse a seed that Gymnasium and torch cannot take (None: the default seeds)."""
    if seed is not None:
        check_integer_size(key, seed)
        if seed < 0:
            raise ConfigError(f"{key}={seed} must be >= 0 (Gymnasium takes no negative seed)")


def check_envs_at_once(key: str, value: int) -> None:
    """Refuse more than :data:`MAX_ENVS_AT_ONCE` envs built together for ``key``."""
    if value > MAX_ENVS_AT_ONCE:
        raise ConfigError(
            f"{key}={value} would build that many envs at once; at most {MAX_ENVS_AT_ONCE}"
        )


def check_device(device: str) -> None:
    """Raise a one-line :class:`ConfigError` unless ``device`` exists on this machine.

    ``cpu`` is answered without importing torch (so a typo elsewhere is answered at once).
    """
    if device == "cpu":
        return
    import torch

    try:
        parsed = torch.device(device)
    except (RuntimeError, ValueError):
        raise ConfigError(f"device={device!r} is not a torch device; use cpu or cuda[:N]") from None
    if parsed.type == "cuda":
        if not torch.cuda.is_available():
            build = "a CPU-only build" if torch.version.cuda is None else "no CUDA GPU visible"
            raise ConfigError(
                f"device={device!r} but this machine has no usable CUDA GPU (torch "
                f"{torch.__version__}: {build}); use device=cpu"
            )
        if parsed.index is not None and parsed.index >= torch.cuda.device_count():
            raise ConfigError(
                f"device={device!r} but this machine has {torch.cuda.device_count()} CUDA "
                f"GPU(s), numbered from 0"
            )
    elif parsed.type == "mps" and not torch.backends.mps.is_available():
        raise ConfigError(f"device={device!r} but MPS is not available here; use device=cpu")
    elif parsed.type not in ("cpu", "cuda", "mps"):
        raise ConfigError(f"device={device!r} is not supported; use cpu or cuda[:N]")


def uses_fused_loss(cfg: Config) -> bool:
    """Whether the update computes TorchRL's DQN loss on plain tensors
    (``fast=true``, :mod:`trl_cartpole.fast.loss`): what ``optim.autocast`` runs under
    ``torch.autocast``."""
    return cfg.fast and not cfg.network.noisy and not cfg.network.distributional


def check_compiler(device: str) -> None:
    """``compile=true`` on the CPU needs the C++ compiler torch's Inductor calls (``$CXX``).

    Without one, the first update would fail after the random frames were already collected.
    """
    if device.split(":", 1)[0] != "cpu":
        return
    compiler = os.environ.get("CXX", "clang++" if sys.platform == "darwin" else "g++")
    if shutil.which(compiler) is None:
        raise ConfigError(
            f"compile=true needs a C++ compiler for torch.compile on the CPU, and {compiler!r} "
            "(the CXX variable, or its default) is not found; install one or pass compile=false"
        )


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
    if collector.ray_resources and collector.backend != "ray":
        raise ConfigError(
            f"collector.ray_resources={dict(collector.ray_resources)} is only read by the Ray "
            "backend; set collector.backend=ray or drop the resources"
        )
    if collector.ray_resources and collector.ray_address is None:
        raise ConfigError(
            "collector.ray_resources places actors on the nodes of a cluster; the Ray instance a "
            "run starts on this machine has no custom resources: set collector.ray_address"
        )
    if collector.ray_runtime_env and collector.ray_address is None:
        raise ConfigError(
            "collector.ray_runtime_env ships code to the nodes of a cluster; the Ray instance a "
            "run starts on this machine runs this Python: set collector.ray_address or drop it"
        )
    for name, amount in collector.ray_resources.items():
        if not (math.isfinite(amount) and amount > 0):
            raise ConfigError(
                f"collector.ray_resources.{name}={amount} must be a positive number of that "
                "resource per actor (as Ray's resources option)"
            )
    if not collector.sync and collector.workers == 1 and collector.backend == "local":
        raise ConfigError(
            "collector.sync=false needs collector.workers > 1 (one local worker collects in the "
            "training process); raise collector.workers"
        )
    if collector.backend == "ray" and importlib.util.find_spec("ray") is None:
        raise ConfigError(
            "collector.backend=ray needs Ray, which is not installed: "
            f"{install_hint('distributed')}"
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

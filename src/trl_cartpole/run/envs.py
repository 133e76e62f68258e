"""Envs from the config's ``env`` section: the run's envs, the pixel envs, each collector
worker's env constructor and the observation statistics.

The factories in :mod:`trl_cartpole.parts` take TorchRL's arguments and know nothing of the
config; this module reads the ``env`` section (and the run's seed) and calls them.
"""

from __future__ import annotations

import math
import os
import sys
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torchrl.envs import Compose, EnvBase, ObservationNorm, SerialEnv, TransformedEnv

from trl_cartpole.compat import gym_env
from trl_cartpole.config.schema import Config, EnvConfig
from trl_cartpole.envs.atari import ATARI_DEFAULTS, make_atari_env
from trl_cartpole.envs.faults import StepDeadline
from trl_cartpole.envs.ids import resolve_env_id
from trl_cartpole.envs.pixels import drawn_pixel_transforms, pixel_transforms
from trl_cartpole.errors import ConfigError
from trl_cartpole.parts.env import MIN_OBSERVATION_SCALE, OBSERVATION_KEY, make_env
from trl_cartpole.run.env_kind import EnvKind
from trl_cartpole.store.worker_state import WorkerSnapshot

__all__ = [
    "WorkerEnvFactory",
    "estimate_observation_norm",
    "make_env_from_config",
    "make_game_env",
    "make_pixel_env",
    "rendered_envs",
    "worker_env_constructors",
]


def make_env_from_config(
    env_cfg: EnvConfig,
    seed: int | None = None,
    device: str | torch.device = "cpu",
    num_envs: int | None = None,
    observation_norm: Mapping[str, Sequence[float]] | None = None,
    render_mode: str | None = None,
    step_timeout: float | None = None,
) -> TransformedEnv:
    """:func:`make_env` for the ``env`` section of a config (``num_envs`` overrides its own).

    ``observation_norm`` must be given when ``env_cfg.normalize_observations`` is on: the
    statistics belong to a run (:func:`estimate_observation_norm`, stored in its checkpoints).
    ``step_timeout`` bounds each step and reset (:class:`StepDeadline`, appended last): a
    training env's gets the config's ``env.step_timeout``.
    """
    env = _env_from_config(env_cfg, seed, device, num_envs, observation_norm, render_mode)
    if step_timeout is None:
        return env
    if isinstance(env, TransformedEnv):
        return env.append_transform(StepDeadline(step_timeout))
    return TransformedEnv(env, Compose(StepDeadline(step_timeout)))  # a pixel env's SerialEnv


def _env_from_config(
    env_cfg: EnvConfig,
    seed: int | None,
    device: str | torch.device,
    num_envs: int | None,
    observation_norm: Mapping[str, Sequence[float]] | None,
    render_mode: str | None,
) -> EnvBase:
    if env_cfg.normalize_observations and observation_norm is None:
        raise ValueError("env.normalize_observations=true needs the run's observation_norm stats")
    if EnvKind(env_cfg).atari:
        return make_game_env(env_cfg, seed, device, num_envs, render_mode)
    if EnvKind(env_cfg).pixels:
        if render_mode not in (None, "rgb_array"):
            raise ConfigError(
                f"render_mode={render_mode!r}: a policy from pixels plays on rendered frames "
                "(rgb_array); write a file instead (output=x.gif)"
            )
        return make_pixel_env(env_cfg, seed, device, num_envs)
    return _configured_env(
        env_cfg,
        device,
        seed=seed,
        num_envs=env_cfg.num_envs if num_envs is None else num_envs,
        render_mode=render_mode,
        observation_norm=observation_norm if env_cfg.normalize_observations else None,
    )


def _configured_env(
    env_cfg: EnvConfig, device: str | torch.device = "cpu", **make_env_kwargs: Any
) -> TransformedEnv:
    """:func:`make_env` of ``env_cfg``'s env (its id resolved), step limit and
    ``env.make_kwargs``."""
    return make_env(
        resolve_env_id(env_cfg.id, env_cfg.imports),
        device,
        max_episode_steps=env_cfg.max_episode_steps,
        **make_env_kwargs,
        **env_cfg.make_kwargs,
    )


def make_pixel_env(
    env_cfg: EnvConfig,
    seed: int | None = None,
    device: str | torch.device = "cpu",
    num_envs: int | None = None,
) -> EnvBase:
    """The env of ``env_cfg`` seen through its rendered frames only (``trl_cartpole.envs.pixels``).

    With ``env.pixels_renderer=drawn`` (CartPole), the frames are drawn from a vector env's
    states in one call (:func:`_drawn_pixel_env`). Otherwise Gymnasium renders them: one env is
    ``make_env(..., from_pixels=True, pixels_only=True)`` plus the pixel transforms: its only
    observation is ``"pixels"`` ``[frames, h, w]`` uint8. Gymnasium renders one env
    at a time, so ``num_envs > 1`` is TorchRL's ``SerialEnv`` of such envs, seeded ``seed``,
    ``seed + 1``, ... (batch ``[num_envs]``).
    """
    count = env_cfg.num_envs if num_envs is None else num_envs
    if EnvKind(env_cfg).name == "drawn pixels":
        return _drawn_pixel_env(env_cfg, seed, device, count)
    os.environ.setdefault("SDL_VIDEODRIVER", "dummy")  # frames only: no window, no display
    build = partial(_one_pixel_env, env_cfg, device)
    env = build() if count == 1 else SerialEnv(count, build, device=device)
    if seed is not None:
        env.set_seed(seed)
    return env


def make_game_env(
    env_cfg: EnvConfig,
    seed: int | None = None,
    device: str | torch.device = "cpu",
    num_envs: int | None = None,
    render_mode: str | None = None,
) -> EnvBase:
    """The Atari game of ``env_cfg`` (:func:`~trl_cartpole.envs.atari.make_atari_env`, its
    preprocessing ``env.atari``, ``env.make_kwargs`` given to ``gymnasium.make``); ``num_envs
    > 1``: TorchRL's ``SerialEnv`` of such games, seeded ``seed``, ``seed + 1``, ...
    ``render_mode="rgb_array"`` lets a video read the game's colour screen (one env)."""
    count = env_cfg.num_envs if num_envs is None else num_envs
    make_kwargs = dict(env_cfg.make_kwargs)
    if render_mode is not None:
        make_kwargs["render_mode"] = render_mode
    if env_cfg.max_episode_steps is not None:  # agent steps, each frame_skip of ALE's frames
        make_kwargs["max_episode_steps"] = env_cfg.max_episode_steps * env_cfg.atari.frame_skip
    build = partial(
        make_atari_env,
        resolve_env_id(env_cfg.id, env_cfg.imports),
        device,
        preprocessing={  # the env's part of env.atari (the learner's is LearnerView's)
            key: value for key, value in asdict(env_cfg.atari).items() if key in ATARI_DEFAULTS
        },
        **make_kwargs,
    )
    env = build() if count == 1 else SerialEnv(count, build, device=device)
    if seed is not None:
        env.set_seed(seed)
    return env


def rendered_envs(share: float, count: int) -> int:
    """How many of ``count`` drawn envs ``env.pixels_rendered_share=share`` paints with
    Gymnasium's calls: ``share * count`` rounded up (at least one for a share above 0)."""
    return math.ceil(share * count - 1e-9)  # 0.3 * 10 is 3.0000000000000004 in floats


def _drawn_pixel_env(
    env_cfg: EnvConfig, seed: int | None, device: str | torch.device, count: int
) -> TransformedEnv:
    """CartPole's state env (a Gymnasium ``SyncVectorEnv`` for ``count > 1``) drawn into the
    pixel preset's frames for the whole batch at once (:func:`drawn_pixel_transforms`), its
    first :func:`rendered_envs` envs painted by Gymnasium's own calls."""
    env = _configured_env(env_cfg, device, seed=seed, num_envs=count)
    cartpole = gym_env(env)
    cartpole = (cartpole.envs[0] if hasattr(cartpole, "envs") else cartpole).unwrapped
    for transform in drawn_pixel_transforms(
        env_cfg.pixels_crop,
        env_cfg.pixels_pool,
        env_cfg.pixels_frames,
        length=cartpole.length,
        x_threshold=cartpole.x_threshold,
        rendered=rendered_envs(env_cfg.pixels_rendered_share, count),
    ):
        env = env.append_transform(transform)
    return env


def _one_pixel_env(env_cfg: EnvConfig, device: str | torch.device) -> TransformedEnv:
    env = _configured_env(env_cfg, device, from_pixels=True, pixels_only=True)
    for transform in pixel_transforms(
        env_cfg.pixels_crop, env_cfg.pixels_pool, env_cfg.pixels_frames
    ):
        env = env.append_transform(transform)
    return env


def estimate_observation_norm(env_cfg: EnvConfig, seed: int) -> dict[str, list[float]]:
    """Mean and std per observation feature over ``env_cfg.normalization_frames`` random frames.

    TorchRL's ``ObservationNorm.init_stats`` plays uniform random actions in one env; the torch
    RNG is forked, so estimating does not shift the run's random numbers. The scale is floored
    at ``MIN_OBSERVATION_SCALE``. Returns ``{"loc": [...], "scale": [...]}`` (JSON-ready).
    """
    env = _configured_env(env_cfg, seed=seed)
    norm = ObservationNorm(in_keys=[OBSERVATION_KEY], standard_normal=True)
    env.append_transform(norm)
    with torch.random.fork_rng():
        torch.manual_seed(seed)
        norm.init_stats(num_iter=env_cfg.normalization_frames, reduce_dim=0, cat_dim=0)
    env.close()
    return {
        "loc": norm.loc.tolist(),  # [obs_dim]
        "scale": norm.scale.clamp_min(MIN_OBSERVATION_SCALE).tolist(),  # [obs_dim]
    }


@dataclass(frozen=True)
class WorkerEnvFactory:
    """Builds one worker's envs and seeds that worker's torch RNG (its epsilon-greedy draws).

    The env ends with :class:`WorkerSnapshot`, through which a checkpoint saves and restores
    the worker's envs, carrier and RNG (:mod:`trl_cartpole.store.worker_state`).

    A fresh worker process (spawned, or a Ray actor) otherwise starts from a random torch seed,
    so its exploration could not be repeated. The training process itself keeps its RNG:
    TorchRL builds the first worker's envs there once to read their specs.
    """

    env_cfg: EnvConfig
    env_seed: int  # the worker's envs are seeded env_seed, env_seed + 1, ...
    rng_seed: int
    device: str
    observation_norm: Mapping[str, Sequence[float]] | None
    parent_pid: int
    log_dir: str | None = None  # a worker's output goes to log_dir/worker-<pid>.log

    def __call__(self) -> EnvBase:
        if os.getpid() != self.parent_pid:  # in the worker
            torch.manual_seed(self.rng_seed)
            if self.log_dir is not None:
                _send_output_to_log(Path(self.log_dir))
        env = make_env_from_config(
            self.env_cfg,
            self.env_seed,
            self.device,
            observation_norm=self.observation_norm,
            step_timeout=self.env_cfg.step_timeout,
        )
        if not isinstance(env, TransformedEnv):  # a pixel env's SerialEnv
            env = TransformedEnv(env)
        return env.append_transform(WorkerSnapshot())  # last: a checkpoint reaches it there


def _send_output_to_log(log_dir: Path) -> None:
    """Point this worker process's stdout and stderr (file descriptors 1 and 2) at its log.

    A worker that dies prints its traceback there instead of on the user's console; the
    training process names the fault in one line from it (:func:`worker_env_fault`).
    """
    log_dir.mkdir(parents=True, exist_ok=True)
    with open(log_dir / f"worker-{os.getpid()}.log", "a", encoding="utf-8") as log:
        for stream in (sys.stdout, sys.stderr):
            stream.flush()
        os.dup2(log.fileno(), 1)
        os.dup2(log.fileno(), 2)


def worker_env_constructors(
    cfg: Config, observation_norm=None, log_dir: Path | None = None
) -> list[WorkerEnvFactory]:
    """One picklable env constructor per collector worker.

    Worker ``i`` seeds its ``env.num_envs`` envs from ``seed + i * env.num_envs`` (no two envs
    of a run share a seed) and its torch RNG from child ``i`` of ``SeedSequence(seed)``; with
    ``log_dir``, a worker process's output goes to a log there.
    """
    workers = cfg.collector.workers
    rng_seeds = np.random.SeedSequence(cfg.seed).spawn(workers)
    return [
        WorkerEnvFactory(
            cfg.env,
            cfg.seed + worker * cfg.env.num_envs,
            int(rng_seeds[worker].generate_state(1)[0]),
            cfg.device,
            observation_norm,
            os.getpid(),
            None if log_dir is None else str(log_dir),
        )
        for worker in range(workers)
    ]


def close_env(env: EnvBase) -> None:
    """Close ``env`` unless it already is (TorchRL's ``SerialEnv`` refuses a second close; the
    collector closes the env it steps)."""
    if not getattr(env, "is_closed", False):
        env.close()

"""Checkpoints through ``torchrl.checkpoint.Checkpoint``: the best policy and the training state.

``Checkpoint.save`` stages every file under a temporary name and renames the directory into
place, so an interrupted save leaves the previous checkpoint intact.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from omegaconf import OmegaConf
from torch import nn
from torchrl.checkpoint import Checkpoint, CheckpointError, GlobalRNGState

from trl_cartpole.config import Config, ConfigError, to_config

__all__ = ["load_policy", "read_checkpoint_config", "save_policy", "save_training_state"]


def _config_metadata(cfg: Config, **extra: Any) -> dict[str, Any]:
    return {"config": OmegaConf.to_container(OmegaConf.structured(cfg), resolve=True), **extra}


def save_policy(path: str | Path, actor: nn.Module, cfg: Config, **metadata: Any) -> Path:
    """Save the Q-actor's weights with the config that rebuilds it."""
    return Checkpoint(policy=actor).save(path, metadata=_config_metadata(cfg, **metadata))


def save_training_state(
    path: str | Path, cfg: Config, counters: dict[str, Any], **components: Any
) -> Path:
    """Save every component (modules, optimizer, buffer, collector...) plus RNGs and counters."""
    checkpoint = Checkpoint(rng=GlobalRNGState(), **components)
    return checkpoint.save(path, metadata=_config_metadata(cfg, counters=counters))


def read_checkpoint_config(path: str | Path) -> Config:
    """Return the config stored in a checkpoint's manifest, or raise a one-line ConfigError."""
    path = Path(path)
    if not path.exists():
        raise ConfigError(f"checkpoint={str(path)!r} does not exist; pass a checkpoint directory")
    try:
        manifest = Checkpoint.manifest(path)
        return to_config(manifest["metadata"]["config"])
    except (CheckpointError, KeyError, TypeError, ValueError) as error:
        raise ConfigError(
            f"checkpoint={str(path)!r} is not a trl_cartpole checkpoint ({error})"
        ) from None


def load_policy(path: str | Path, actor: nn.Module) -> nn.Module:
    """Load policy weights saved by :func:`save_policy` into ``actor`` (in place)."""
    try:
        Checkpoint(policy=actor).load(path, components=["policy"])
    except (CheckpointError, RuntimeError, KeyError) as error:
        first_line = str(error).splitlines()[0]
        raise ConfigError(
            f"checkpoint={str(path)!r} does not fit this policy ({first_line})"
        ) from None
    return actor

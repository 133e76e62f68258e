"""trl_cartpole: a modular Deep Q-Learning pipeline built from stock TorchRL parts.

The factories (``trl_cartpole.parts``) return TorchRL objects and take the arguments of the
TorchRL class each builds, with TorchRL's meanings and behaviour, so they can be reused on
their own (examples/torchrl_dqn_example.py is TorchRL's DQN example on them)::

    from trl_cartpole import make_env, make_q_actor, make_exploration, make_replay_buffer

``train(cfg)`` runs the whole pipeline; ``build_components(cfg)`` builds it without running
it; docs/architecture.md says which module does what. Names are imported on first use, so
``import trl_cartpole.config.schema`` stays light.
"""

from __future__ import annotations

import importlib
from typing import Any

_EXPORTS = {
    "Config": "trl_cartpole.config.schema",
    "ConfigError": "trl_cartpole.errors",
    "TrainingFailed": "trl_cartpole.errors",
    "TrainingInterrupted": "trl_cartpole.errors",
    "validate": "trl_cartpole.config.validation",
    "make_env": "trl_cartpole.parts.env",
    "make_q_actor": "trl_cartpole.parts.models",
    "make_q_network": "trl_cartpole.parts.models",
    "make_exploration": "trl_cartpole.parts.exploration",
    "make_replay_buffer": "trl_cartpole.parts.replay",
    "make_dqn_loss": "trl_cartpole.parts.losses",
    "make_target_updater": "trl_cartpole.parts.losses",
    "make_optimizer": "trl_cartpole.parts.optim",
    "make_update": "trl_cartpole.parts.optim",
    "make_collector": "trl_cartpole.parts.collectors",
    "evaluate": "trl_cartpole.run.evaluation",
    "build_components": "trl_cartpole.run.build",
    "load_trained_policy": "trl_cartpole.policy.load",
    "train": "trl_cartpole.run.training",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str) -> Any:
    if name not in _EXPORTS:
        raise AttributeError(f"module 'trl_cartpole' has no attribute {name!r}")
    return getattr(importlib.import_module(_EXPORTS[name]), name)


def __dir__() -> list[str]:
    return sorted([*globals(), *_EXPORTS])

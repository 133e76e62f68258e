"""The factories' defaults beside TorchRL's, read off the code for the API reference.

``docs/reference/factories.md`` holds :func:`defaults_table`, written into the file by
``python -m maintain docs`` from the signatures of each factory and of the TorchRL class it
builds (``tests/test_docs_in_sync.py`` fails when it drifts), so it reads on the repository
page and on the site alike; it lives outside the package, since only the docs need it. A
default that is ``None`` in a factory's signature because it depends on another argument is
shown as it resolves.
"""

from __future__ import annotations

import inspect
from typing import Any

__all__ = ["FACTORIES", "defaults_table"]

FACTORIES = (
    "make_env",
    "make_q_actor",
    "make_exploration",
    "make_replay_buffer",
    "make_dqn_loss",
    "make_target_updater",
    "make_optimizer",
    "make_update",
    "make_collector",
)


def _builds() -> dict[str, tuple[str, list[Any], list[str]]]:
    """factory: (what it returns, the TorchRL classes its arguments go to, arguments shown)."""
    import torch
    from torchrl.collectors import Collector
    from torchrl.data import LazyTensorStorage, PrioritizedSampler, TensorDictReplayBuffer
    from torchrl.envs import EnvBase, GymEnv, GymWrapper, MultiStepTransform
    from torchrl.modules import MLP, EGreedyModule, QValueActor
    from torchrl.objectives import DQNLoss, HardUpdate, SoftUpdate

    return {
        "make_env": (
            "TorchRL's `TransformedEnv(GymWrapper)`",
            [GymEnv, GymWrapper, EnvBase],
            ["env_name", "device"],
        ),
        "make_q_actor": (
            "TorchRL's `QValueActor` (`DistributionalQValueActor` with `support`) over TorchRL's"
            " `MLP`; `head='dueling'` puts this project's `DuelingHead` module in it",
            [MLP, QValueActor],
            ["module", "num_cells", "activation_class", "head", "in_keys", "device"],
        ),
        "make_exploration": (
            "TorchRL's `EGreedyModule`; `schedule='exponential'`: `ExponentialEGreedyModule`,"
            " this project's subclass",
            [EGreedyModule],
            ["eps_init", "eps_end", "annealing_num_steps", "schedule", "device"],
        ),
        "make_replay_buffer": (
            "TorchRL's `TensorDictReplayBuffer` (`TensorDictPrioritizedReplayBuffer` with"
            " `prioritized`); `n_steps > 1` adds `NStepTransform`, this project's"
            " `MultiStepTransform` subclass",
            [TensorDictReplayBuffer, LazyTensorStorage, PrioritizedSampler, MultiStepTransform],
            [
                "storage",
                "sampler",
                "batch_size",
                "transform",
                "max_size",
                "prioritized",
                "alpha",
                "beta",
                "eps",
                "n_steps",
                "gamma",
            ],
        ),
        "make_dqn_loss": (
            "TorchRL's `DQNLoss` (`DistributionalDQNLoss` for C51)",
            [DQNLoss],
            ["gamma", "loss_function", "delay_value", "double_dqn"],
        ),
        "make_target_updater": (
            "TorchRL's `HardUpdate` or `SoftUpdate`",
            [SoftUpdate, HardUpdate],
            ["eps", "tau", "value_network_update_interval"],
        ),
        "make_optimizer": (
            "PyTorch's `torch.optim.AdamW`",
            [torch.optim.AdamW],
            ["lr", "amsgrad", "weight_decay", "eps"],
        ),
        "make_update": (
            "this project's function `update(batch) -> TensorDict(loss, grad_norm)`",
            [],
            [],
        ),
        "make_collector": (
            "TorchRL's `Collector`",
            [Collector],
            ["frames_per_batch", "total_frames", "init_random_frames", "device"],
        ),
    }


def _left_out() -> dict[tuple[str, str], str]:
    """What an argument left out becomes, where the signature's default does not say it."""
    return {
        ("make_dqn_loss", "gamma"): "the buffer's with `replay_buffer`, else 0.99 (TorchRL's)",
        ("make_dqn_loss", "loss_function"): "`'l2'` (`DQNLoss`'s)",
        ("make_dqn_loss", "double_dqn"): "`False`",
        ("make_target_updater", "value_network_update_interval"): "`1000` (`HardUpdate`'s)",
        ("make_target_updater", "tau"): "required with `kind='soft'`",
        ("make_replay_buffer", "max_size"): "`1000` (TorchRL's default storage's)",
        ("make_replay_buffer", "storage"): "`LazyTensorStorage(max_size)`",
        ("make_replay_buffer", "sampler"): "`RandomSampler()`",
        (
            "make_replay_buffer",
            "transform",
        ): "none (yours, after `NStepTransform` with `n_steps > 1`)",
        ("make_replay_buffer", "alpha"): "required with `prioritized` (refused without)",
        ("make_replay_buffer", "beta"): "required with `prioritized` (refused without)",
        ("make_replay_buffer", "eps"): "1e-08 with `prioritized` (refused without)",
        ("make_replay_buffer", "gamma"): "0.99 with `n_steps > 1` (refused without)",
        ("make_q_actor", "module"): "None: built from `observation_spec`",
        ("make_q_actor", "num_cells"): "None (`MLP`'s: no hidden layer)",
        ("make_q_actor", "device"): "the spec's",
        ("make_exploration", "device"): "the spec's",
        ("make_collector", "frames_per_batch"): "required (as TorchRL)",
    }


# the config section each factory's keywords come from (``make_x(**cfg.section)``)
_SECTIONS = {
    "make_q_actor": "network",
    "make_exploration": "exploration",
    "make_replay_buffer": "buffer",
    "make_dqn_loss": "loss",
    "make_target_updater": "target_updater",
    "make_optimizer": "optim",
    "make_collector": "collector",
}


# What a TorchRL signature does not say by itself.
_TORCHRL_NOTES = {
    ("DQNLoss", "gamma"): "0.99 (its value estimator's)",
    ("SoftUpdate", "eps"): "required (eps or tau)",
    ("SoftUpdate", "tau"): "required (eps or tau)",
    ("TensorDictReplayBuffer", "storage"): "`ListStorage(1_000)`",
    ("TensorDictReplayBuffer", "sampler"): "`RandomSampler()`",
    ("TensorDictReplayBuffer", "batch_size"): "None (given to `sample`)",
    ("TensorDictReplayBuffer", "transform"): "none",
    ("MLP", "num_cells"): "None (no hidden layer; 32 per layer with `depth`)",
    ("QValueActor", "module"): "required",
    ("PrioritizedSampler", "eps"): "1e-8",
    ("LazyTensorStorage", "max_size"): "required (TorchRL's default `ListStorage`: 1 000)",
    ("MultiStepTransform", "n_steps"): "required (no n-step without it)",
    ("MultiStepTransform", "gamma"): "required",
}


def _shown(value: Any) -> str:
    if value is inspect.Parameter.empty:
        return "required"
    if isinstance(value, type):
        return f"`{value.__module__.split('.')[0]}.{value.__qualname__}`".replace("`torch.", "`nn.")
    if isinstance(value, str) and (" " in value or "`" in value):
        return value  # prose: how the default resolves
    return f"`{value}`" if isinstance(value, str) else f"`{value!r}`"


def _torchrl_default(classes: list[Any], argument: str) -> str:
    for cls in classes:
        name = cls.__name__
        if (name, argument) in _TORCHRL_NOTES:
            return f"{_TORCHRL_NOTES[name, argument]} (`{name}`)"
        parameters = inspect.signature(cls.__init__).parameters
        if argument in parameters:
            return f"{_shown(parameters[argument].default)} (`{name}`)"
    return "none"


def defaults_table() -> str:
    """Markdown: per factory, what it returns, then a table of each argument's default: left
    out, TorchRL's (read off the TorchRL class), and the default run's (its config key)."""
    from dataclasses import asdict

    import trl_cartpole
    from trl_cartpole.config.schema import Config

    left_out_of, run = _left_out(), asdict(Config())
    sections = []
    for factory, (returns, classes, arguments) in _builds().items():
        parameters = inspect.signature(getattr(trl_cartpole, factory)).parameters
        section = run.get(_SECTIONS.get(factory, ""), {})
        lines = [f"**`{factory}`** returns {returns}."]
        if arguments:
            lines += [
                "",
                "| argument | left out | TorchRL's | the default run's |",
                "| --- | --- | --- | --- |",
            ]
        for argument in arguments:
            left_out = left_out_of.get((factory, argument), parameters[argument].default)
            theirs = _torchrl_default(classes, argument)
            ours = (
                f"{_shown(section[argument])} (`{_SECTIONS[factory]}.{argument}`)"
                if argument in section
                else "the same"
            )
            lines.append(f"| `{argument}` | {_shown(left_out)} | {theirs} | {ours} |")
        sections.append("\n".join(lines))
    return "\n\n".join(sections)

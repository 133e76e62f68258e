"""Two sets of defaults for the factories: TorchRL's, and this project's tuned ones on request.

A factory called with TorchRL's arguments alone behaves as the TorchRL class it builds, with
that class's defaults (:data:`TORCHRL`). ``tuned=True`` is the one explicit step to this
project's values (:data:`TUNED`): every argument the call leaves out takes the value the
default config trains CartPole-v1 with (``trl_cartpole.defaults``, which
``scripts/train.py`` reads too), so ``make_replay_buffer(tuned=True)`` is the buffer of
``python scripts/train.py`` but for its 3-step returns, which stay one ``n_steps=3`` away.
An argument given in the call is always used as given.

``docs/reference/factories.md``'s table is written from these two mappings, and
``tests/test_defaults.py`` holds :data:`TORCHRL` to the TorchRL signatures and :data:`TUNED` to
the default config.
"""

from __future__ import annotations

from typing import Any, TypeVar

from torch import nn

from trl_cartpole import defaults

__all__ = ["TORCHRL", "TUNED", "resolve"]

T = TypeVar("T")

# factory -> {argument: the value an argument left out takes without tuned=True}: the default
# of the TorchRL (or PyTorch) class the argument goes to.
TORCHRL: dict[str, dict[str, Any]] = {
    "make_q_actor": {"num_cells": None, "activation_class": nn.Tanh},  # MLP's
    "make_exploration": {"eps_init": 1.0, "eps_end": 0.1, "annealing_num_steps": 1000},
    "make_replay_buffer": {
        "max_size": 1_000,  # the capacity of TorchRL's default ListStorage
        "batch_size": None,  # given to sample()
        "eps": 1e-8,  # PrioritizedSampler's; alpha and beta it requires
        "gamma": 0.99,  # MultiStepTransform requires one: the loss's default discount
    },
    "make_dqn_loss": {"gamma": 0.99, "loss_function": "l2"},  # DQNLoss's (its TD(0)'s gamma)
    "make_target_updater": {"value_network_update_interval": 1000},  # HardUpdate's
    "make_optimizer": {"lr": 1e-3, "amsgrad": False, "weight_decay": 1e-2, "eps": 1e-8},  # AdamW
    "make_collector": {"total_frames": -1, "init_random_frames": None, "device": None},
}

# factory -> {argument: this project's value, taken with tuned=True}: the default config's.
TUNED: dict[str, dict[str, Any]] = {
    "make_q_actor": {"num_cells": list(defaults.HIDDEN_SIZES), "activation_class": nn.ReLU},
    "make_exploration": {
        "eps_init": defaults.EPS_START,
        "eps_end": defaults.EPS_END,
        "annealing_num_steps": defaults.DECAY_FRAMES,
    },
    "make_replay_buffer": {
        "max_size": defaults.BUFFER_SIZE,
        "batch_size": defaults.BATCH_SIZE,
        # TorchRL's exponent acts on DQNLoss's td_error = delta ** 2: half Schaul et al.'s on
        # |delta| (the config's buffer.alpha)
        "alpha": defaults.ALPHA / 2,
        "beta": defaults.BETA,
        "eps": defaults.PRIORITY_EPS,
        "gamma": defaults.GAMMA,
    },
    "make_dqn_loss": {"gamma": defaults.GAMMA, "loss_function": defaults.LOSS_FUNCTION},
    "make_target_updater": {
        "value_network_update_interval": defaults.HARD_UPDATE_INTERVAL - 1,
        "tau": defaults.TAU,
    },
    "make_optimizer": {
        "lr": defaults.LR,
        "amsgrad": defaults.AMSGRAD,
        "weight_decay": defaults.WEIGHT_DECAY,
        "eps": defaults.ADAM_EPS,
    },
    "make_collector": {
        "frames_per_batch": defaults.FRAMES_PER_BATCH,
        "total_frames": defaults.TOTAL_FRAMES,
        "init_random_frames": defaults.INIT_RANDOM_FRAMES,
        "device": "cpu",
    },
}


def resolve(factory: str, argument: str, given: T | None, tuned: bool) -> T | Any:
    """``given`` when the call gave it (not None), else the tuned or TorchRL's default."""
    if given is not None:
        return given
    table = TUNED if tuned else TORCHRL
    return table[factory].get(argument)

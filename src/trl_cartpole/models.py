"""Q-network factories: an MLP torso and head inside a TorchRL ``QValueActor``.

``HEADS`` maps a config name (``network.head``) to a function building the ``nn.Module``
that maps an observation ``[*B, obs_dim]`` to action values ``[*B, num_actions]``.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

from torch import nn
from torchrl.data import TensorSpec
from torchrl.envs import EnvBase
from torchrl.modules import MLP, QValueActor
from torchrl.modules.models.models import DuelingMlpDQNet

from trl_cartpole.config import ConfigError, NetworkConfig

__all__ = [
    "ACTIVATIONS",
    "HEADS",
    "check_network_choices",
    "make_q_actor",
    "make_q_actor_for_env",
    "make_q_network",
]

ACTIVATIONS: dict[str, type[nn.Module]] = {
    "relu": nn.ReLU,
    "tanh": nn.Tanh,
    "elu": nn.ELU,
    "gelu": nn.GELU,
}


def _plain_head(
    obs_dim: int, num_actions: int, hidden_sizes: Sequence[int], activation: type[nn.Module]
) -> nn.Module:
    """Q(s, .) = MLP(s): the tutorial's Linear-ReLU-Linear-ReLU-Linear network."""
    return MLP(
        in_features=obs_dim,
        out_features=num_actions,
        num_cells=list(hidden_sizes),
        activation_class=activation,
    )


def _dueling_head(
    obs_dim: int, num_actions: int, hidden_sizes: Sequence[int], activation: type[nn.Module]
) -> nn.Module:
    """Q(s, a) = V(s) + A(s, a) - mean_a' A(s, a') (Wang et al. 2016), TorchRL's DuelingMlpDQNet.

    The torso is the plain head's hidden layers; V and A are one linear layer each on top of
    it, so the dueling network has one ``Linear(hidden_sizes[-1], 1)`` more than the plain one.
    """
    return DuelingMlpDQNet(
        num_actions,
        mlp_kwargs_feature={
            "in_features": obs_dim,
            "num_cells": list(hidden_sizes[:-1]),
            "out_features": hidden_sizes[-1],
            "activation_class": activation,
            "activate_last_layer": True,
        },
        mlp_kwargs_output={"depth": 0, "in_features": hidden_sizes[-1]},
    )


HEADS: dict[str, Callable[..., nn.Module]] = {"plain": _plain_head, "dueling": _dueling_head}


def check_network_choices(head: str, activation: str) -> None:
    """Raise :class:`ConfigError` unless ``head`` and ``activation`` are known names."""
    if head not in HEADS:
        known = sorted(HEADS)
        raise ConfigError(f"network.head={head!r} is not a known head; choose one of {known}")
    if activation not in ACTIVATIONS:
        raise ConfigError(
            f"network.activation={activation!r} is unknown; choose one of {sorted(ACTIVATIONS)}"
        )


def make_q_network(
    obs_dim: int,
    num_actions: int,
    hidden_sizes: Sequence[int] = (128, 128),
    activation: str = "relu",
    head: str = "plain",
) -> nn.Module:
    """Return the Q-network module ``[*B, obs_dim] -> [*B, num_actions]`` for ``head``."""
    check_network_choices(head, activation)
    return HEADS[head](obs_dim, num_actions, hidden_sizes, ACTIVATIONS[activation])


def make_q_actor(
    observation_spec: TensorSpec,
    action_spec: TensorSpec,
    hidden_sizes: Sequence[int] = (128, 128),
    activation: str = "relu",
    head: str = "plain",
    device: str = "cpu",
) -> QValueActor:
    """Return a ``QValueActor`` reading ``"observation"`` and writing ``"action"`` (greedy).

    ``observation_spec`` is the env's full observation spec (a ``Composite``) and
    ``action_spec`` its action spec; the actor writes ``action_value`` ``[*B, num_actions]``,
    ``chosen_action_value`` ``[*B, 1]`` and the arg-max ``action``.
    """
    obs_dim = observation_spec["observation"].shape[-1]
    num_actions = action_spec.space.n
    module = make_q_network(obs_dim, num_actions, hidden_sizes, activation, head).to(device)
    return QValueActor(module, in_keys=["observation"], spec=action_spec.to(device))


def make_q_actor_for_env(env: EnvBase, network: NetworkConfig, device: str = "cpu") -> QValueActor:
    """``make_q_actor`` sized from ``env``'s specs, with the ``network`` section of the config."""
    return make_q_actor(
        env.observation_spec,
        env.action_spec,
        network.hidden_sizes,
        network.activation,
        network.head,
        device,
    )

"""Q-network factories: an MLP torso and a head inside a TorchRL Q-value actor.

``HEADS`` maps a config name (``network.head``) to a function building the output layers on
top of the torso. Two switches apply to every head:

- ``noisy``: every linear layer is TorchRL's ``NoisyLinear`` (Fortunato et al. 2018), whose
  factorised Gaussian noise is on under ``ExplorationType.RANDOM`` and off otherwise;
- ``atoms``: the network outputs logits over a fixed support of returns, ``[*B, atoms,
  num_actions]``, for a ``DistributionalQValueActor`` (C51, Bellemare et al. 2017); without it,
  action values ``[*B, num_actions]`` for a ``QValueActor``.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from functools import partial

import torch
from torch import nn
from torchrl.data import TensorSpec
from torchrl.envs import EnvBase
from torchrl.modules import (
    MLP,
    DistributionalQValueActor,
    NoisyLinear,
    QValueActor,
    reset_noise,
)

from trl_cartpole.config import ConfigError, NetworkConfig

__all__ = [
    "ACTIVATIONS",
    "HEADS",
    "DuelingHead",
    "check_network_choices",
    "expected_action_values",
    "make_q_actor",
    "make_q_actor_for_env",
    "make_q_network",
    "reset_network_noise",
]

ACTIVATIONS: dict[str, type[nn.Module]] = {
    "relu": nn.ReLU,
    "tanh": nn.Tanh,
    "elu": nn.ELU,
    "gelu": nn.GELU,
}


class DuelingHead(nn.Module):
    """Q(s, a) = V(s) + A(s, a) - mean_a' A(s, a') (Wang et al. 2016, eq. 9).

    ``value`` maps features ``[*B, H]`` to ``[*B, atoms]`` and ``advantage`` to
    ``[*B, atoms * num_actions]``; with ``atoms=1`` the output is squeezed to
    ``[*B, num_actions]``, otherwise it is ``[*B, atoms, num_actions]`` logits, the
    distributional dueling form of Rainbow (Hessel et al. 2018, eq. 5, before the softmax).
    """

    def __init__(self, value: nn.Module, advantage: nn.Module, num_actions: int, atoms: int):
        super().__init__()
        self.value = value
        self.advantage = advantage
        self.num_actions = num_actions
        self.atoms = atoms

    def streams(self, features: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Return V ``[*B, atoms, 1]`` and the centred advantage ``[*B, atoms, num_actions]``."""
        value = self.value(features).unsqueeze(-1)  # [*B, atoms, 1]
        advantage = self.advantage(features).unflatten(-1, (self.atoms, self.num_actions))
        return value, advantage - advantage.mean(-1, keepdim=True)

    def forward(self, features: torch.Tensor) -> torch.Tensor:
        value, centred_advantage = self.streams(features)
        q = value + centred_advantage  # [*B, atoms, num_actions]
        return q.squeeze(-2) if self.atoms == 1 else q


def _plain_head(
    in_features: int, num_actions: int, atoms: int, linear: Callable[..., nn.Module]
) -> nn.Module:
    """One linear layer: Q(s, .) (or the atoms' logits) straight from the features."""
    out = linear(in_features, atoms * num_actions)
    return out if atoms == 1 else nn.Sequential(out, nn.Unflatten(-1, (atoms, num_actions)))


def _dueling_head(
    in_features: int, num_actions: int, atoms: int, linear: Callable[..., nn.Module]
) -> nn.Module:
    """Value and advantage streams of one linear layer each (see :class:`DuelingHead`)."""
    return DuelingHead(
        value=linear(in_features, atoms),
        advantage=linear(in_features, atoms * num_actions),
        num_actions=num_actions,
        atoms=atoms,
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
    noisy: bool = False,
    noisy_std: float = 0.5,
    atoms: int | None = None,
) -> nn.Module:
    """Return ``[*B, obs_dim] -> [*B, num_actions]`` (or ``[*B, atoms, num_actions]`` logits).

    The torso is an MLP over ``hidden_sizes`` (activation after every hidden layer); the head
    from ``HEADS`` maps its last hidden layer to the output.
    """
    check_network_choices(head, activation)
    linear = partial(NoisyLinear, std_init=noisy_std) if noisy else nn.Linear
    torso = MLP(
        in_features=obs_dim,
        out_features=hidden_sizes[-1],
        num_cells=list(hidden_sizes[:-1]),
        activation_class=ACTIVATIONS[activation],
        activate_last_layer=True,
        layer_class=linear,
    )
    return nn.Sequential(torso, HEADS[head](hidden_sizes[-1], num_actions, atoms or 1, linear))


def make_q_actor(
    observation_spec: TensorSpec,
    action_spec: TensorSpec,
    hidden_sizes: Sequence[int] = (128, 128),
    activation: str = "relu",
    head: str = "plain",
    device: str = "cpu",
    noisy: bool = False,
    noisy_std: float = 0.5,
    support: torch.Tensor | None = None,
) -> QValueActor | DistributionalQValueActor:
    """Return a Q-value actor reading ``"observation"`` and writing the greedy ``"action"``.

    ``observation_spec`` is the env's full observation spec (a ``Composite``) and
    ``action_spec`` its action spec. Without ``support`` it is a ``QValueActor`` writing
    ``action_value`` ``[*B, num_actions]`` and ``chosen_action_value`` ``[*B, 1]``; with a
    ``support`` ``[atoms]`` of returns it is a ``DistributionalQValueActor`` writing
    log-probabilities ``action_value`` ``[*B, atoms, num_actions]`` and acting greedily on
    their expectation.
    """
    obs_dim = observation_spec["observation"].shape[-1]
    num_actions = action_spec.space.n
    atoms = None if support is None else support.numel()
    module = make_q_network(
        obs_dim, num_actions, hidden_sizes, activation, head, noisy, noisy_std, atoms
    ).to(device)
    spec = action_spec.to(device)
    if support is None:
        return QValueActor(module, in_keys=["observation"], spec=spec)
    actor = DistributionalQValueActor(
        module, support=support.to(device), in_keys=["observation"], spec=spec
    )
    return _with_single_greedy_action(actor)


def _with_single_greedy_action(actor: DistributionalQValueActor) -> DistributionalQValueActor:
    """Make the one-hot greedy action pick the first maximum when expected values tie.

    TorchRL's Q-value modules build the one-hot action as ``value == value.max()``, which marks
    every tied action. C51 distributions that saturate on the support tie exactly, and a
    two-hot action then breaks ``DistributionalDQNLoss`` (a run crashed on it). The module's
    own categorical rule (the arg-max of the expected values) is used instead. The plain
    ``QValueActor`` keeps TorchRL's rule: every measured figure was taken with it, and
    changing it changed the default run's trajectory (see the README's choices).
    """
    for module in actor.modules():
        rules = getattr(module, "action_func_mapping", None)
        if rules is not None and "one_hot" in rules:
            categorical = rules["categorical"]

            def one_hot(value: torch.Tensor, _categorical=categorical) -> torch.Tensor:
                greedy = _categorical(value)  # [*B]
                return nn.functional.one_hot(greedy, value.shape[-1]).to(torch.long)

            rules["one_hot"] = one_hot
    return actor


def make_q_actor_for_env(
    env: EnvBase, network: NetworkConfig, device: str = "cpu"
) -> QValueActor | DistributionalQValueActor:
    """``make_q_actor`` sized from ``env``'s specs, with the ``network`` section of the config."""
    support = (
        torch.linspace(network.v_min, network.v_max, network.atoms)
        if network.distributional
        else None
    )
    return make_q_actor(
        env.observation_spec,
        env.action_spec,
        network.hidden_sizes,
        network.activation,
        network.head,
        device,
        noisy=network.noisy,
        noisy_std=network.noisy_std,
        support=support,
    )


def expected_action_values(actor: nn.Module, action_value: torch.Tensor) -> torch.Tensor:
    """Q-values ``[*B, num_actions]`` from an actor's ``action_value`` output.

    For a ``DistributionalQValueActor`` that is sum_i z_i p_i(s, a) over its support; for a
    ``QValueActor`` the output already is Q.
    """
    if isinstance(actor, DistributionalQValueActor):
        support = actor.support  # [atoms]
        return (action_value.exp() * support.unsqueeze(-1)).sum(-2)
    return action_value


def reset_network_noise(module: nn.Module) -> None:
    """Resample the noise of every ``NoisyLinear`` in ``module`` (a no-op without any)."""
    module.apply(reset_noise)

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

import inspect
from collections.abc import Callable, Sequence
from functools import partial
from typing import Any

import torch
from torch import nn
from torchrl.data import Categorical, Composite, OneHot, TensorSpec
from torchrl.envs import EnvBase
from torchrl.modules import (
    MLP,
    ConvNet,
    DistributionalQValueActor,
    NoisyLinear,
    QValueActor,
    reset_noise,
)

from trl_cartpole.aliases import resolve_alias
from trl_cartpole.compat import use_first_greedy_action
from trl_cartpole.config import NetworkConfig
from trl_cartpole.errors import ConfigError
from trl_cartpole.pixels import PIXELS_KEY, ScaleImage
from trl_cartpole.validation import ACTIVATION_NAMES, HEAD_NAMES, check_network_choices

__all__ = [
    "ACTIVATIONS",
    "HEADS",
    "DuelingHead",
    "check_network_choices",
    "expected_action_values",
    "make_cnn_features",
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
# the names the config accepts are checked before torch is imported (trl_cartpole.validation)
assert set(HEADS) == set(HEAD_NAMES) and set(ACTIVATIONS) == set(ACTIVATION_NAMES)


def make_q_network(
    obs_dim: int,
    num_actions: int,
    num_cells: Sequence[int] | int = (128, 128),
    activation_class: type[nn.Module] = nn.ReLU,
    head: str = "plain",
    noisy: bool = False,
    noisy_std: float = 0.5,
    atoms: int | None = None,
    *,
    hidden_sizes: Sequence[int] | None = None,
    **mlp_kwargs: Any,
) -> nn.Module:
    """Return ``[*B, obs_dim] -> [*B, num_actions]`` (or ``[*B, atoms, num_actions]`` logits).

    The torso is TorchRL's ``MLP`` over the widths ``num_cells`` (an activation after every
    hidden layer; an int with ``depth=`` in ``mlp_kwargs`` is ``depth`` layers of that width, as
    ``MLP`` reads it); ``mlp_kwargs`` go to ``MLP`` (``norm_class``, ``dropout``...). The head
    from ``HEADS`` maps its last hidden layer to the output. ``hidden_sizes`` is an alias of
    ``num_cells``.
    """
    check_network_choices(head, None)
    fixed = sorted(set(mlp_kwargs) & _MLP_SET_HERE)
    if fixed:
        raise TypeError(
            f"{', '.join(fixed)}: set from the specs and the head here (layer_class by noisy=), "
            "not passed to MLP"
        )
    widths = _widths(num_cells if hidden_sizes is None else hidden_sizes, mlp_kwargs)
    linear = partial(NoisyLinear, std_init=noisy_std) if noisy else nn.Linear
    torso = MLP(
        in_features=obs_dim,
        out_features=widths[-1],
        num_cells=widths[:-1],
        activation_class=activation_class,
        activate_last_layer=True,
        layer_class=linear,
        **mlp_kwargs,
    )
    return nn.Sequential(torso, HEADS[head](widths[-1], num_actions, atoms or 1, linear))


def make_cnn_features(
    image_shape: Sequence[int],
    channels: Sequence[int] = (16, 32, 32),
    kernel_sizes: Sequence[int] = (5, 5, 5),
    strides: Sequence[int] = (2, 2, 2),
    activation_class: type[nn.Module] = nn.ReLU,
) -> tuple[nn.Module, int]:
    """``[*B, C, H, W]`` uint8 pixels -> ``[*B, F]`` features, and ``F``.

    The pixels are scaled to [0, 1] (:class:`~trl_cartpole.pixels.ScaleImage`), then go through
    TorchRL's ``ConvNet`` (a convolution and ``activation_class`` per entry of ``channels``,
    flattened at the end). The defaults are the three 5x5, stride-2 convolutions of 16, 32 and
    32 channels of the PyTorch DQN tutorial's first, pixel version (without its batch norm).
    """
    conv = ConvNet(
        in_features=image_shape[0],
        num_cells=list(channels),
        kernel_sizes=list(kernel_sizes),
        strides=list(strides),
        activation_class=activation_class,
    )
    features = nn.Sequential(ScaleImage(), conv)
    with torch.device("meta"):  # the flattened size, found on shapes only
        width = conv(torch.zeros(1, *image_shape)).shape[-1]
    return features, width


def _widths(num_cells: Sequence[int] | int, mlp_kwargs: dict[str, Any]) -> list[int]:
    """The hidden layers' widths: ``num_cells``, or ``depth`` times an int ``num_cells``."""
    depth = mlp_kwargs.pop("depth", None)
    if isinstance(num_cells, int):
        return [num_cells] * (1 if depth is None else depth)
    if depth is not None and depth != len(num_cells):
        raise ValueError(f"depth={depth} but num_cells has {len(num_cells)} widths")
    if not num_cells:
        raise ValueError("num_cells is empty: the Q-network needs at least one hidden layer")
    return list(num_cells)


# The keywords of TorchRL's MLP that make_q_actor hands to the torso (the rest go to the actor),
# and those the factory sets itself: the input and output sizes, the layer type, the last
# activation (the head follows the torso).
_MLP_KEYWORDS = frozenset(inspect.signature(MLP.__init__).parameters) - {"self"}
_MLP_SET_HERE = frozenset({"in_features", "out_features", "layer_class", "activate_last_layer"})


def make_q_actor(
    observation_spec: TensorSpec,
    spec: TensorSpec | None = None,
    *,
    num_cells: Sequence[int] | int = (128, 128),
    activation_class: type[nn.Module] = nn.ReLU,
    head: str = "plain",
    device: str | torch.device | None = None,
    noisy: bool = False,
    noisy_std: float = 0.5,
    support: torch.Tensor | None = None,
    in_keys: Sequence[str] = ("observation",),
    action_spec: TensorSpec | None = None,
    hidden_sizes: Sequence[int] | None = None,
    activation: str | None = None,
    torso: str = "mlp",
    cnn_kwargs: dict[str, Any] | None = None,
    **kwargs: Any,
) -> QValueActor | DistributionalQValueActor:
    """Return TorchRL's ``QValueActor`` reading ``in_keys`` and writing the greedy ``"action"``.

    ``observation_spec`` is the env's full observation spec (a ``Composite`` holding the one
    vector entry ``in_keys`` names) and ``spec`` its action spec (one discrete action:
    ``OneHot`` or ``Categorical``), the actor's ``spec``; anything else is refused with a
    one-line :class:`ConfigError`. The network is :func:`make_q_network`: TorchRL's ``MLP``
    torso and a ``head`` from ``HEADS``.

    The arguments are TorchRL's where a TorchRL class has them. ``num_cells`` and
    ``activation_class`` are ``MLP``'s; any other keyword of ``MLP`` (``depth``,
    ``norm_class``, ``dropout``, ``activation_kwargs``...) goes to the torso, and any other
    keyword to the actor (``action_space``, ``action_value_key``, ``safe``...). Defaults,
    ours (the default config's ``network`` section) beside TorchRL's: ``num_cells`` (128, 128)
    (``MLP``: 32 per layer), ``activation_class`` ``nn.ReLU`` (``MLP``: ``nn.Tanh``),
    ``in_keys`` ``["observation"]`` (as ``QValueActor``), ``device`` the spec's.
    ``head``, ``noisy``, ``noisy_std`` and ``support`` are this project's: the dueling head is
    :class:`DuelingHead` (TorchRL 0.14 has dueling networks only for images,
    ``DuelingCnnDQNet``), noisy layers are TorchRL's ``NoisyLinear``. ``action_spec``,
    ``hidden_sizes`` and ``activation`` (a name: relu, tanh, elu, gelu) are this project's
    earlier names, kept as aliases.

    ``torso="cnn"`` reads an image entry (``in_keys`` ``["pixels"]``, ``[C, H, W]`` uint8)
    through :func:`make_cnn_features` (``cnn_kwargs``: its ``channels``, ``kernel_sizes``,
    ``strides``) before the MLP and the head, so every head and switch composes with it.

    Without ``support`` it is a ``QValueActor`` writing ``action_value`` ``[*B, num_actions]``
    and ``chosen_action_value`` ``[*B, 1]``; with a ``support`` ``[atoms]`` of returns it is a
    ``DistributionalQValueActor`` writing log-probabilities ``action_value``
    ``[*B, atoms, num_actions]`` and acting greedily on their expectation.

    Example::

        >>> from trl_cartpole import make_env, make_q_actor
        >>> env = make_env("CartPole-v1")
        >>> actor = make_q_actor(env.observation_spec, env.action_spec, num_cells=[64, 64],
        ...                      head="dueling")
        >>> actor(env.reset())["action_value"].shape
        torch.Size([2])
    """
    spec = resolve_alias("spec", spec, "action_spec", action_spec)
    if spec is None:
        raise TypeError("make_q_actor() needs spec (the env's action_spec)")
    if activation is not None:
        check_network_choices(head, activation)
        activation_class = ACTIVATIONS[activation]
    mlp_kwargs = {key: kwargs.pop(key) for key in list(kwargs) if key in _MLP_KEYWORDS}
    features = None
    if torso == "cnn":
        features, obs_dim = make_cnn_features(
            _image_shape(observation_spec, in_keys),
            activation_class=activation_class,
            **(cnn_kwargs or {}),
        )
    elif torso == "mlp":
        obs_dim = _input_size(observation_spec, in_keys)
    else:
        raise ConfigError(f"torso={torso!r} is not one of ['mlp', 'cnn']")
    num_actions = _action_count(spec)
    atoms = None if support is None else support.numel()
    module = make_q_network(
        obs_dim,
        num_actions,
        num_cells if hidden_sizes is None else hidden_sizes,
        activation_class,
        head,
        noisy,
        noisy_std,
        atoms,
        **mlp_kwargs,
    )
    if features is not None:
        module = nn.Sequential(features, module)
    if device is not None:
        module, spec = module.to(device), spec.to(device)
    in_keys = list(in_keys)
    if support is None:
        return QValueActor(module, in_keys=in_keys, spec=spec, **kwargs)
    support = support if device is None else support.to(device)
    actor = DistributionalQValueActor(module, support=support, in_keys=in_keys, spec=spec, **kwargs)
    return use_first_greedy_action(actor)


def _input_size(observation_spec: TensorSpec, in_keys: Sequence[str]) -> int:
    """The width of the one vector observation ``in_keys`` names in ``observation_spec``."""
    if len(in_keys) != 1:
        raise ConfigError(f"in_keys={list(in_keys)}: the Q-network reads one observation entry")
    key = in_keys[0]
    keys = (
        list(observation_spec.keys(True, True)) if isinstance(observation_spec, Composite) else []
    )
    if key not in keys:
        raise ConfigError(
            f"observation_spec has no entry {key!r} (it has {keys}); pass the env's "
            "observation_spec (a Composite) and the key of its vector observation as in_keys"
        )
    shape = tuple(observation_spec[key].shape)
    if not shape:
        raise ConfigError(f"observation entry {key!r} is a scalar; the Q-network needs a vector")
    return shape[-1]


def _image_shape(observation_spec: TensorSpec, in_keys: Sequence[str]) -> tuple[int, int, int]:
    """The ``[C, H, W]`` shape of the one image entry ``in_keys`` names."""
    key = in_keys[0] if len(in_keys) == 1 else None
    keys = (
        list(observation_spec.keys(True, True)) if isinstance(observation_spec, Composite) else []
    )
    if key not in keys or len(observation_spec[key].shape) < 3:
        raise ConfigError(
            f"the cnn torso reads one [C, H, W] image entry; in_keys={list(in_keys)} and the "
            f"observation spec has {keys} (an env with from_pixels=True has 'pixels')"
        )
    return tuple(observation_spec[key].shape[-3:])  # a batched env's spec leads with [E]


def _action_count(action_spec: TensorSpec) -> int:
    """The number of discrete actions of ``action_spec`` (``OneHot`` or ``Categorical``)."""
    if not isinstance(action_spec, (OneHot, Categorical)):
        raise ConfigError(
            f"action_spec is {type(action_spec).__name__}; a Q-value actor needs one discrete "
            "action (TorchRL OneHot or Categorical, a Gymnasium Discrete space)"
        )
    return action_spec.space.n


def make_q_actor_for_env(
    env: EnvBase, network: NetworkConfig, device: str = "cpu"
) -> QValueActor | DistributionalQValueActor:
    """``make_q_actor`` sized from ``env``'s specs, with the ``network`` section of the config."""
    support = (
        torch.linspace(network.v_min, network.v_max, network.atoms)
        if network.distributional
        else None
    )
    cnn = network.torso == "cnn"
    return make_q_actor(
        env.observation_spec,
        env.action_spec,
        in_keys=[PIXELS_KEY] if cnn else ["observation"],
        torso=network.torso,
        cnn_kwargs={
            "channels": network.cnn_channels,
            "kernel_sizes": network.cnn_kernels,
            "strides": network.cnn_strides,
        }
        if cnn
        else None,
        num_cells=network.hidden_sizes,
        activation_class=ACTIVATIONS[network.activation],
        head=network.head,
        device=device,
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

"""Q-network factories: an MLP torso and a head inside a TorchRL Q-value actor.

``HEADS`` maps a config name (``network.head``) to a function building the output layers on
top of the torso. ``make_q_network`` builds the plain head as TorchRL's own layout instead: one
``MLP`` whose last linear layer is what ``HEADS["plain"]`` builds.
Two switches apply to every head:

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
from torchrl.modules import (
    MLP,
    ConvNet,
    DistributionalQValueActor,
    NoisyLinear,
    QValueActor,
    reset_noise,
)

from trl_cartpole import choices
from trl_cartpole.compat import use_first_greedy_action
from trl_cartpole.envs.pixels import ScaleImage
from trl_cartpole.errors import ConfigError

__all__ = [
    "ACTIVATIONS",
    "HEADS",
    "DuelingHead",
    "check_head",
    "expected_action_values",
    "make_cnn_features",
    "make_q_actor",
    "make_q_network",
    "reset_network_noise",
]

# each of choices.ACTIVATIONS: the torch.nn class of that name, case left aside (relu: ReLU)
ACTIVATIONS: dict[str, type[nn.Module]] = {
    name: next(cls for cls_name, cls in vars(nn).items() if cls_name.lower() == name)
    for name in choices.ACTIVATIONS
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


# each of choices.HEADS: the function _<name>_head above
HEADS: dict[str, Callable[..., nn.Module]] = {
    name: globals()[f"_{name}_head"] for name in choices.HEADS
}


def check_head(head: str) -> None:
    """Raise ``ValueError`` naming the choices unless ``head`` is a key of ``HEADS``."""
    if head not in HEADS:
        raise ValueError(f"head={head!r} is not a head here; choose one of {sorted(HEADS)}")


def make_q_network(
    obs_dim: int,
    num_actions: int,
    num_cells: Sequence[int] | int | None = None,
    activation_class: type[nn.Module] = nn.Tanh,
    head: str = "plain",
    noisy: bool = False,
    noisy_std: float = 0.5,
    atoms: int | None = None,
    **mlp_kwargs: Any,
) -> nn.Module:
    """Return ``[*B, obs_dim] -> [*B, num_actions]`` (or ``[*B, atoms, num_actions]`` logits).

    The torso is TorchRL's ``MLP`` (an activation after every hidden layer); the head from
    ``HEADS`` maps its last hidden layer to the output. The plain head is TorchRL's own layout:
    one ``MLP`` whose last linear layer is the head.

    :param obs_dim: the width of the observation vector, the MLP's ``in_features``.
    :param num_actions: the number of discrete actions.
    :param num_cells: the hidden widths, read as ``MLP`` reads them: a list of widths
        (``[]``: no hidden layer, the head reads the input), an int with ``depth=`` in
        ``mlp_kwargs`` (``depth`` layers of that width). Default None, ``MLP``'s: no hidden
        layer.
    :param activation_class: the activation after every hidden layer. Default ``nn.Tanh``,
        ``MLP``'s.
    :param head: a key of ``HEADS``: ``"plain"`` (default) or ``"dueling"``
        (:class:`DuelingHead`).
    :param noisy: every linear layer, the head's included, is TorchRL's ``NoisyLinear``
        (Fortunato et al. 2018). Default False.
    :param noisy_std: the ``NoisyLinear`` layers' ``std_init``, sigma_0 of their factorised
        noise. Default 0.5.
    :param atoms: with it, the output is logits ``[*B, atoms, num_actions]`` over a support of
        returns (C51); None: action values ``[*B, num_actions]``.
    :param mlp_kwargs: go to ``MLP`` (``norm_class``, ``dropout``...).
    :returns: TorchRL's ``MLP`` for the plain head, else ``nn.Sequential(torso MLP, head)``.
    """
    check_head(head)
    fixed = sorted(set(mlp_kwargs) & _MLP_SET_HERE)
    if fixed:
        raise TypeError(
            f"{', '.join(fixed)}: set from the specs and the head here (layer_class by noisy=), "
            "not passed to MLP"
        )
    widths = _widths(num_cells, mlp_kwargs)
    if noisy:  # every linear layer, the head's included
        layer_kwargs = {"std_init": noisy_std, **(mlp_kwargs.pop("layer_kwargs", None) or {})}
        mlp_kwargs["layer_kwargs"] = layer_kwargs
    layer_class = NoisyLinear if noisy else nn.Linear
    if head == "plain":  # TorchRL's own layout: one MLP, the head its last linear layer
        return MLP(
            in_features=obs_dim,
            out_features=num_actions if atoms is None else (atoms, num_actions),
            num_cells=widths,
            activation_class=activation_class,
            layer_class=layer_class,
            **mlp_kwargs,
        )
    if widths:
        torso = MLP(
            in_features=obs_dim,
            out_features=widths[-1],
            num_cells=widths[:-1],
            activation_class=activation_class,
            activate_last_layer=True,
            layer_class=layer_class,
            **mlp_kwargs,
        )
    else:  # num_cells=[]: the head reads the input itself
        torso = nn.Identity()
    linear = partial(layer_class, **mlp_kwargs.get("layer_kwargs") or {})
    width = widths[-1] if widths else obs_dim
    return nn.Sequential(torso, HEADS[head](width, num_actions, atoms or 1, linear))


def make_cnn_features(
    image_shape: Sequence[int],
    num_cells: Sequence[int] = (16, 32, 32),
    kernel_sizes: Sequence[int] = (5, 5, 5),
    strides: Sequence[int] = (2, 2, 2),
    activation_class: type[nn.Module] = nn.ReLU,
) -> tuple[nn.Module, int]:
    """``[*B, C, H, W]`` uint8 pixels -> ``[*B, F]`` features, and ``F``.

    The pixels are scaled to [0, 1] (:class:`~trl_cartpole.envs.pixels.ScaleImage`), then go
    through TorchRL's ``ConvNet`` (a convolution and ``activation_class`` per entry of
    ``num_cells``, flattened at the end). The defaults are the three 5x5, stride-2 convolutions
    of 16, 32 and 32 channels of the PyTorch DQN tutorial's first, pixel version (without its
    batch norm).

    :param image_shape: the image's ``[C, H, W]``; ``C`` is the first convolution's input.
    :param num_cells: ``ConvNet``'s: the output channels of each convolution. Default
        (16, 32, 32).
    :param kernel_sizes: each convolution's kernel size. Default (5, 5, 5).
    :param strides: each convolution's stride. Default (2, 2, 2).
    :param activation_class: the activation after each convolution. Default ``nn.ReLU``.
    :returns: ``nn.Sequential(ScaleImage(), ConvNet)`` (TorchRL's ``ConvNet``) and the width
        ``F`` of its flattened output.
    :raises ValueError: when the image is smaller than the convolutions take (naming the
        smallest height and width they do).
    """
    smallest = smallest_image_side(kernel_sizes, strides)
    if len(image_shape) != 3 or min(image_shape[1:]) < smallest:
        raise ValueError(
            f"torso='cnn': the image [C, H, W] = {list(image_shape)} is smaller than the "
            f"convolutions take (kernel_sizes={list(kernel_sizes)}, strides={list(strides)}: "
            f"at least {smallest}x{smallest}); render a larger image or give smaller kernels "
            "or strides in cnn_kwargs"
        )
    conv = ConvNet(
        in_features=image_shape[0],
        num_cells=list(num_cells),
        kernel_sizes=list(kernel_sizes),
        strides=list(strides),
        activation_class=activation_class,
    )
    features = nn.Sequential(ScaleImage(), conv)
    with torch.device("meta"):  # the flattened size, found on shapes only
        width = conv(torch.zeros(1, *image_shape)).shape[-1]
    return features, width


def smallest_image_side(kernel_sizes: Sequence[int], strides: Sequence[int]) -> int:
    """The smallest side an image needs for unpadded convolutions of these kernels and strides
    to leave one pixel: each layer takes ``out = (in - k) // s + 1``, so ``in >= (out - 1) s + k``.

    Example::

        >>> from trl_cartpole.parts.models import smallest_image_side
        >>> smallest_image_side((5, 5, 5), (2, 2, 2))
        29
    """
    side = 1
    for kernel, stride in reversed(list(zip(kernel_sizes, strides, strict=False))):
        side = (side - 1) * stride + kernel
    return side


def _widths(num_cells: Sequence[int] | int | None, mlp_kwargs: dict[str, Any]) -> list[int]:
    """The hidden layers' widths, read as TorchRL's ``MLP`` reads ``num_cells`` and ``depth``.

    A list is the widths (``[]``: no hidden layer, the head reads the input); an int needs
    ``depth`` (``depth`` layers of that width; ``MLP`` raises without it); None is ``depth``
    layers of 32, or none.
    """
    depth = mlp_kwargs.pop("depth", None)
    if num_cells is None:
        return [32] * (depth or 0)
    if isinstance(num_cells, int):
        if depth is None:
            raise ValueError(
                f"num_cells={num_cells} is one width: give depth= too (as TorchRL's MLP "
                f"requires), or the widths as a list, e.g. num_cells=[{num_cells}, {num_cells}]"
            )
        return [num_cells] * depth
    if depth is not None and depth != len(num_cells):
        raise ValueError(f"depth={depth} but num_cells has {len(num_cells)} widths")
    return list(num_cells)


# The keywords of TorchRL's MLP that make_q_actor hands to the torso (the rest go to the actor),
# and those the factory sets itself: the input and output sizes, the layer type, the last
# activation (the head follows the torso).
_MLP_KEYWORDS = frozenset(inspect.signature(MLP.__init__).parameters) - {"self"}
_MLP_SET_HERE = frozenset({"in_features", "out_features", "layer_class", "activate_last_layer"})


def make_q_actor(
    observation_spec: TensorSpec | nn.Module | None = None,
    spec: TensorSpec | None = None,
    *,
    module: nn.Module | None = None,
    num_cells: Sequence[int] | int | None = None,
    activation_class: type[nn.Module] | str = nn.Tanh,
    head: str = "plain",
    device: str | torch.device | None = None,
    noisy: bool = False,
    noisy_std: float = 0.5,
    support: torch.Tensor | None = None,
    in_keys: Sequence[str] | None = None,
    torso: str | nn.Module = "mlp",
    cnn_kwargs: dict[str, Any] | None = None,
    **kwargs: Any,
) -> QValueActor | DistributionalQValueActor:
    """Return TorchRL's ``QValueActor`` reading ``in_keys`` and writing the greedy ``"action"``.

    The Q-network is built from ``observation_spec`` unless ``module`` is given. The arguments
    are TorchRL's where a TorchRL class has them, with its defaults (``MLP``'s: no hidden
    layer, ``nn.Tanh``); ``head``, ``noisy``, ``noisy_std``, ``support``, ``torso`` and
    ``cnn_kwargs`` are this project's own switches. The plain head gives TorchRL's layout
    exactly: ``QValueActor(MLP(in_features, num_actions, num_cells=num_cells,
    activation_class=...))``, so its ``state_dict`` loads into an actor built with TorchRL
    alone.

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

    :param observation_spec: the env's full observation spec (a ``Composite`` holding the
        entry ``in_keys`` names), from which the Q-network is built. An ``nn.Module`` passed
        here is taken as ``module``, ``QValueActor``'s first argument.
    :param spec: the env's action spec, the actor's ``spec``: one discrete action
        (``OneHot`` or ``Categorical``, or a ``Composite`` holding it under ``"action"``).
    :param module: ``QValueActor``'s: your whole Q-network, ``[*B, obs] -> [*B, num_actions]``
        (``[*B, atoms, num_actions]`` with ``support``); nothing is built.
    :param num_cells: ``MLP``'s: a list of hidden widths (``[]``: no hidden layer), or an int
        with ``depth=``. Default None, ``MLP``'s: no hidden layer.
    :param activation_class: ``MLP``'s, or its name (``"relu"``, ``"tanh"``, ``"elu"``,
        ``"gelu"``, as a config gives it). Default ``nn.Tanh``, ``MLP``'s.
    :param head: ``"plain"`` (default) or ``"dueling"``: :class:`DuelingHead` (Wang et al.
        2016; TorchRL 0.14 has dueling networks only for images).
    :param device: the actor's device. Default: the spec's.
    :param noisy: every linear layer is TorchRL's ``NoisyLinear`` (Fortunato et al. 2018).
    :param noisy_std: the ``NoisyLinear`` layers' ``std_init``. Default 0.5, the paper's.
    :param support: a ``DistributionalQValueActor`` over these atoms (C51): a tensor ``[atoms]``
        of returns. Default None: a ``QValueActor``.
    :param in_keys: the observation entry the network reads. Default: ``["observation"]`` (as
        ``QValueActor``); with ``torso="cnn"``, the spec's one image entry (``"pixels"``).
    :param torso: ``"mlp"`` (default: the observation goes straight to the MLP), ``"cnn"`` (a
        ``[C, H, W]`` uint8 image through :func:`make_cnn_features`), or your own
        ``nn.Module`` mapping the observation to features ``[*B, F]``, under the MLP and head.
    :param cnn_kwargs: with ``torso="cnn"``, :func:`make_cnn_features`'s ``num_cells``,
        ``kernel_sizes``, ``strides`` (``ConvNet``'s names).
    :param kwargs: any other keyword of ``MLP`` (``depth``, ``norm_class``, ``dropout``...)
        goes to it, and any other keyword to the actor (``action_space``, ``safe``...).
    """
    if isinstance(observation_spec, nn.Module):  # QValueActor's first argument is the module
        if module is not None:
            raise TypeError("a module passed first is QValueActor's module=; pass one of them")
        module, observation_spec = observation_spec, None
    if spec is None:
        raise TypeError("make_q_actor() needs spec= (the env's action_spec)")
    check_head(head)
    if isinstance(activation_class, str):
        if activation_class not in ACTIVATIONS:
            raise ValueError(
                f"activation_class={activation_class!r}; choose one of {sorted(ACTIVATIONS)} "
                "or pass a torch.nn class"
            )
        activation_class = ACTIVATIONS[activation_class]
    if cnn_kwargs is not None and torso != "cnn":
        raise TypeError(f"cnn_kwargs are the CNN torso's: pass torso='cnn' (torso={torso!r})")
    if in_keys is None:
        in_keys = _default_in_keys(observation_spec, torso)
    mlp_kwargs = {key: kwargs.pop(key) for key in list(kwargs) if key in _MLP_KEYWORDS}
    if module is None:
        module = _build_q_network(
            observation_spec,
            _action_count(spec),
            in_keys,
            torso,
            cnn_kwargs,
            num_cells,
            activation_class,
            head,
            noisy,
            noisy_std,
            None if support is None else support.numel(),
            mlp_kwargs,
        )
    elif mlp_kwargs or num_cells is not None or head != "plain" or noisy or torso != "mlp":
        raise TypeError(
            "module= is your whole Q-network, so the arguments that build one (num_cells, head, "
            "noisy, torso, MLP keywords) would build nothing; pass your layers as torso= instead"
        )
    return _q_value_actor(module, spec, list(in_keys), support, device, kwargs)


def _default_in_keys(observation_spec: TensorSpec | None, torso: str | nn.Module) -> list[str]:
    """``["observation"]``, or for a CNN torso the spec's one image entry (``[C, H, W]``)."""
    if torso == "cnn" and isinstance(observation_spec, Composite):
        images = [
            key
            for key in observation_spec.keys(True, True)
            if len(observation_spec[key].shape) >= 3
        ]
        if len(images) == 1:
            return [images[0]]
    return ["observation"]


def _q_value_actor(
    module: nn.Module,
    spec: TensorSpec,
    in_keys: list[str],
    support: torch.Tensor | None,
    device: str | torch.device | None,
    kwargs: dict[str, Any],
) -> QValueActor | DistributionalQValueActor:
    """TorchRL's actor around the Q-network, on ``device`` (default: the spec's)."""
    if device is None:  # the spec's device, as documented
        device = getattr(spec, "device", None)
    if device is not None:
        module, spec = module.to(device), spec.to(device)
    if support is None:
        return QValueActor(module, in_keys=in_keys, spec=spec, **kwargs)
    support = support if device is None else support.to(device)
    actor = DistributionalQValueActor(module, support=support, in_keys=in_keys, spec=spec, **kwargs)
    return use_first_greedy_action(actor)


def _build_q_network(
    observation_spec: TensorSpec | None,
    num_actions: int,
    in_keys: Sequence[str],
    torso: str | nn.Module,
    cnn_kwargs: dict[str, Any] | None,
    num_cells: Sequence[int] | int | None,
    activation_class: type[nn.Module],
    head: str,
    noisy: bool,
    noisy_std: float,
    atoms: int | None,
    mlp_kwargs: dict[str, Any],
) -> nn.Module:
    """The torso (none, the CNN, or the caller's module), then the MLP and the head."""
    if observation_spec is None:
        raise TypeError(
            "make_q_actor() needs observation_spec (the env's, to size the network) or "
            "module= (your own Q-network)"
        )
    features = None
    if isinstance(torso, nn.Module):
        features, obs_dim = torso, _output_width(torso, observation_spec, in_keys)
    elif torso == "cnn":
        features, obs_dim = make_cnn_features(
            _image_shape(observation_spec, in_keys),
            activation_class=activation_class,
            **(cnn_kwargs or {}),
        )
    elif torso == "mlp":
        obs_dim = _input_size(observation_spec, in_keys)
    else:
        raise ValueError(f"torso={torso!r}: choose 'mlp', 'cnn' or an nn.Module of your own")
    network = make_q_network(
        obs_dim,
        num_actions,
        num_cells,
        activation_class,
        head,
        noisy,
        noisy_std,
        atoms,
        **mlp_kwargs,
    )
    return network if features is None else nn.Sequential(features, network)


def _output_width(torso: nn.Module, observation_spec: TensorSpec, in_keys: Sequence[str]) -> int:
    """The feature width ``F`` of ``torso`` on one observation of ``observation_spec``."""
    key = _input_key(observation_spec, in_keys)
    parameter = next(torso.parameters(), None)
    observation = observation_spec[key].zero()  # [*spec]
    if parameter is not None:
        observation = observation.to(parameter.device)
    training = torso.training
    torso.eval()  # no running statistics updated by this probe (BatchNorm)
    try:
        with torch.no_grad():
            features = torso(observation)  # [*spec, F]
    finally:
        torso.train(training)
    return features.shape[-1]


def _input_key(observation_spec: TensorSpec, in_keys: Sequence[str]) -> str:
    """The one entry of ``observation_spec`` the network reads (``in_keys``)."""
    if len(in_keys) != 1:
        raise ConfigError(f"in_keys={list(in_keys)}: the Q-network reads one observation entry")
    key = in_keys[0]
    keys = (
        list(observation_spec.keys(True, True)) if isinstance(observation_spec, Composite) else []
    )
    if key not in keys:
        raise ConfigError(
            f"observation_spec has no entry {key!r} (it has {keys}); pass the env's "
            "observation_spec (a Composite) and the key of its observation as in_keys"
        )
    return key


def _input_size(observation_spec: TensorSpec, in_keys: Sequence[str]) -> int:
    """The width of the one vector observation ``in_keys`` names in ``observation_spec``."""
    key = _input_key(observation_spec, in_keys)
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
            f"torso='cnn' reads one [C, H, W] image entry; in_keys={list(in_keys)} and the "
            f"observation spec has {keys} (an env with from_pixels=True has 'pixels')"
        )
    return tuple(observation_spec[key].shape[-3:])  # a batched env's spec leads with [E]


def _action_count(action_spec: TensorSpec) -> int:
    """The number of discrete actions of ``action_spec`` (``OneHot`` or ``Categorical``, or a
    ``Composite`` holding one under ``"action"``)."""
    if isinstance(action_spec, Composite) and "action" in action_spec.keys():  # noqa: SIM118
        action_spec = action_spec["action"]
    if not isinstance(action_spec, (OneHot, Categorical)):
        raise ConfigError(
            f"spec is {type(action_spec).__name__}; a Q-value actor needs one discrete "
            "action (TorchRL OneHot or Categorical, a Gymnasium Discrete space)"
        )
    return action_spec.space.n


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

"""A trained policy as a plain network: observations in, action values out, for ONNX or .pt2.

:func:`greedy_q_network` turns the Q-actor of a checkpoint into an ``nn.Module`` mapping a
float32 observation ``[batch, obs_dim]`` (a policy from pixels: uint8 frames ``[batch, frames,
h, w]``, input ``pixels``) to action values ``[batch, num_actions]``: the env's
``ObservationNorm`` comes first, noisy layers use their mean weights (the noise is off in
evaluation, ``ExplorationType.DETERMINISTIC``) and a C51 network returns the expected value
over its support. The greedy action is the arg-max of those values. :func:`export_onnx` and
:func:`export_program` write it with a dynamic batch dimension, atomically.
"""

from __future__ import annotations

import copy
import logging
import warnings
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import torch
from torch import nn
from torchrl.envs import EnvBase, ObservationNorm, TransformedEnv
from torchrl.modules import DistributionalQValueActor, NoisyLinear, QValueActor

from trl_cartpole.envs.pixels import PIXELS_KEY
from trl_cartpole.errors import ConfigError
from trl_cartpole.policy.formats import check_onnx_installed
from trl_cartpole.policy.load import load_trained_policy
from trl_cartpole.store.files import write_atomic

__all__ = [
    "GreedyQNetwork",
    "export_onnx",
    "export_program",
    "greedy_q_network",
    "greedy_q_network_of",
]

INPUT_NAME = "observation"
OUTPUT_NAME = "action_values"


class GreedyQNetwork(nn.Module):
    """``[batch, obs_dim]`` raw observations -> ``[batch, num_actions]`` action values.

    ``loc``/``scale`` ``[obs_dim]`` are the env's ``ObservationNorm`` (None: no normalisation);
    with ``standard_normal`` it computes ``(obs - loc) / scale``, else ``obs * scale + loc``, as
    the transform does. With ``support`` ``[atoms]`` the network's output ``[batch, atoms,
    num_actions]`` are logits and the values are sum_i z_i softmax_i.
    """

    def __init__(
        self,
        network: nn.Module,
        obs_dim: int | tuple[int, ...],
        num_actions: int,
        loc: torch.Tensor | None = None,
        scale: torch.Tensor | None = None,
        standard_normal: bool = True,
        support: torch.Tensor | None = None,
        input_name: str = INPUT_NAME,
        input_dtype: torch.dtype = torch.float32,
    ) -> None:
        super().__init__()
        self.network = network
        self.obs_dim, self.num_actions = obs_dim, num_actions
        # one observation's shape and dtype: [obs_dim] float32, or [frames, h, w] uint8 pixels
        self.input_shape = (obs_dim,) if isinstance(obs_dim, int) else tuple(obs_dim)
        self.input_name, self.input_dtype = input_name, input_dtype
        self.normalize = loc is not None
        self.standard_normal = bool(standard_normal)  # ObservationNorm holds it as a tensor
        self.distributional = support is not None
        if self.normalize:
            self.register_buffer("loc", _per_feature(loc, obs_dim))  # [obs_dim]
            self.register_buffer("scale", _per_feature(scale, obs_dim))  # [obs_dim]
        if self.distributional:
            self.register_buffer("support", support.detach().clone())  # [atoms]

    def forward(self, observation: torch.Tensor) -> torch.Tensor:
        x = observation  # [batch, obs_dim]
        if self.normalize:
            x = (x - self.loc) / self.scale if self.standard_normal else x * self.scale + self.loc
        out = self.network(x)  # [batch, num_actions], or [batch, atoms, num_actions] logits
        if not self.distributional:
            return out
        probs = torch.softmax(out, dim=-2)  # [batch, atoms, num_actions]
        return (probs * self.support.unsqueeze(-1)).sum(-2)  # [batch, num_actions]


def _per_feature(stat: torch.Tensor, obs_dim: int) -> torch.Tensor:
    """A normalisation statistic (``[]``, ``[1]`` or ``[1, obs_dim]``) as ``[obs_dim]`` float32."""
    return stat.detach().reshape(-1).expand(obs_dim).to(torch.float32).clone()


def greedy_q_network(checkpoint: str | Path) -> GreedyQNetwork:
    """The policy of ``checkpoint`` (a run directory or a checkpoint) as a :class:`GreedyQNetwork`.

    The module is in eval mode without gradients; ``obs_dim`` and ``num_actions`` are its
    attributes. Raises a one-line ``ConfigError`` for a path that is not a checkpoint.
    """
    trained = load_trained_policy(checkpoint)
    try:
        return greedy_q_network_of(trained.actor, trained.env)
    finally:
        trained.env.close()


def greedy_q_network_of(
    actor: QValueActor | DistributionalQValueActor, env: EnvBase
) -> GreedyQNetwork:
    """:func:`greedy_q_network` for an ``actor`` and the (transformed) ``env`` it acts in."""
    network = _deterministic(_q_network(actor))
    key = actor.module[0].in_keys[0]  # "observation", or "pixels" for a policy from pixels
    spec = env.observation_spec[key]
    pixels = key == PIXELS_KEY
    obs_dim = tuple(spec.shape[-3:]) if pixels else spec.shape[-1]
    num_actions = env.action_spec.space.n
    norm = _observation_norm(env)
    support = actor.support if isinstance(actor, DistributionalQValueActor) else None
    module = GreedyQNetwork(
        network,
        obs_dim,
        num_actions,
        loc=None if norm is None else norm.loc,
        scale=None if norm is None else norm.scale,
        standard_normal=True if norm is None else norm.standard_normal,
        support=support,
        input_name=key,
        input_dtype=spec.dtype,
    )
    return module.eval().requires_grad_(False)


def _q_network(actor: nn.Module) -> nn.Module:
    """The network of a Q-actor: the module of its first ``TensorDictModule`` (obs -> values)."""
    first = actor.module[0]  # TensorDictModule(network, ["observation"] -> ["action_value"])
    if list(first.in_keys) not in (["observation"], [PIXELS_KEY]):
        raise ConfigError(
            f"the actor's first module reads {list(first.in_keys)}; export expects a Q-actor "
            "reading 'observation' or 'pixels' (trl_cartpole.parts.models.make_q_actor)"
        )
    return first.module


def _deterministic(network: nn.Module) -> nn.Module:
    """A copy of ``network`` with each ``NoisyLinear`` replaced by an ``nn.Linear`` of its means."""
    network = copy.deepcopy(network).cpu()
    for parent in list(network.modules()):
        for name, child in list(parent.named_children()):
            if isinstance(child, NoisyLinear):
                plain = nn.Linear(child.in_features, child.out_features, child.bias_mu is not None)
                with torch.no_grad():
                    plain.weight.copy_(child.weight_mu)
                    if child.bias_mu is not None:
                        plain.bias.copy_(child.bias_mu)
                setattr(parent, name, plain)
    return network


def _observation_norm(env: EnvBase) -> ObservationNorm | None:
    """The ``ObservationNorm`` among ``env``'s transforms (None: observations are raw)."""
    norms = []
    while isinstance(env, TransformedEnv):
        norms += [t for t in env.transform if isinstance(t, ObservationNorm)]
        env = env.base_env
    if len(norms) > 1:
        raise ConfigError(f"the env has {len(norms)} ObservationNorm transforms; export folds one")
    return norms[0] if norms else None


def _example(module: nn.Module, obs_dim: int | tuple[int, ...]) -> tuple[torch.Tensor]:
    """An example input ``[2, *shape]`` (2, not 1, so the batch size is not specialised)."""
    shape = (obs_dim,) if isinstance(obs_dim, int) else tuple(obs_dim)
    return (torch.zeros(2, *shape, dtype=getattr(module, "input_dtype", torch.float32)),)


def _batch_dim() -> dict[str, dict[int, torch.export.Dim]]:
    # keyed by GreedyQNetwork.forward's argument, whatever the ONNX input is named
    return {"observation": {0: torch.export.Dim("batch", min=1)}}


@contextmanager
def _quiet_onnx_exporter() -> Iterator[None]:
    """Hide the exporter's own noise: torchvision ops skipped, a deprecation inside torch."""
    logger = logging.getLogger("torch.onnx")
    level = logger.level
    logger.setLevel(logging.ERROR)
    try:
        with warnings.catch_warnings():
            warnings.filterwarnings("ignore", message=".*LeafSpec", category=FutureWarning)
            yield
    finally:
        logger.setLevel(level)


def export_onnx(module: nn.Module, obs_dim: int | tuple[int, ...], path: str | Path) -> Path:
    """Write ``module`` as ONNX to ``path``, with a dynamic batch dimension.

    Input ``observation`` ``[batch, obs_dim]`` float32 (a policy from pixels: ``pixels``
    ``[batch, frames, h, w]`` uint8, ``obs_dim`` the tuple of its shape), output ``action_values``
    ``[batch, num_actions]``. Raises a one-line ``ConfigError`` when the ``onnx`` or
    ``onnxscript`` package is missing or too old for this torch's exporter.
    """
    check_onnx_installed()

    def write(tmp: Path) -> None:
        try:
            with _quiet_onnx_exporter():
                torch.onnx.export(
                    module,
                    _example(module, obs_dim),
                    str(tmp),
                    input_names=[getattr(module, "input_name", INPUT_NAME)],
                    output_names=[OUTPUT_NAME],
                    dynamic_shapes=_batch_dim(),
                    external_data=False,  # one self-contained file
                    verbose=False,
                )
        except ImportError as error:  # an onnxscript older than this torch's exporter needs
            raise ConfigError(
                f"torch.onnx.export cannot import {error.name or error} (onnx/onnxscript too "
                f"old for torch {torch.__version__}); pip install -U -e '.[export]'"
            ) from None

    return write_atomic(path, write)


def export_program(module: nn.Module, obs_dim: int | tuple[int, ...], path: str | Path) -> Path:
    """Write ``module`` as a ``torch.export`` program (``.pt2``) to ``path``, batch dynamic.

    ``torch.export.load(path).module()`` maps ``[batch, obs_dim]`` to ``[batch, num_actions]``.
    """
    program = torch.export.export(module, _example(module, obs_dim), dynamic_shapes=_batch_dim())
    return write_atomic(path, lambda tmp: torch.export.save(program, tmp))

"""One gradient step of DQN: loss, backward, gradient clipping, optimizer step, new noise.

``make_update`` closes over the loss module and the optimizer and returns a function of the
sampled batch only, with no Python-side state, so ``torch.compile`` can take it whole.
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Iterable
from functools import partial
from typing import Any

import torch
from tensordict import TensorDict, TensorDictBase
from torch import nn

from trl_cartpole.compat import cpu_computes_bfloat16
from trl_cartpole.parts.models import reset_network_noise

__all__ = [
    "autocast_context",
    "choose_autocast",
    "make_optimizer",
    "make_update",
    "native_bfloat16",
    "tapered_lr",
]


def make_optimizer(
    params: Iterable[nn.Parameter],
    lr: float = 1e-3,
    *,
    amsgrad: bool = False,
    weight_decay: float = 1e-2,
    eps: float = 1e-8,
    **adamw_kwargs: Any,
) -> torch.optim.AdamW:
    """PyTorch's AdamW (Loshchilov & Hutter 2019), with ``AdamW``'s defaults.

    PyTorch's fused implementation unless ``fused=`` is given: one kernel for all parameters
    instead of a Python loop over them, the same update up to float rounding.

    Example::

        >>> from torch import nn
        >>> from trl_cartpole import make_optimizer
        >>> optimizer = make_optimizer(nn.Linear(4, 2).parameters(), lr=1e-3)
        >>> type(optimizer).__name__, optimizer.defaults["amsgrad"]
        ('AdamW', False)

    :param adamw_kwargs: go to ``AdamW`` (``betas``, ``fused``, ...).
    """
    adamw_kwargs.setdefault("fused", True)
    return torch.optim.AdamW(
        params, lr=lr, amsgrad=amsgrad, weight_decay=weight_decay, eps=eps, **adamw_kwargs
    )


def tapered_lr(lr_start: float, lr_end: float, frames: int, decay_frames: int) -> float:
    """The learning rate after ``frames`` frames: linear from ``lr_start`` to ``lr_end`` at
    ``decay_frames``, then ``lr_end`` (a lever of the pixel-Atari literature: late updates
    that move the policy less).

    Computed from the frames alone, so a resumed run continues the taper where it stopped.

    Example::

        >>> from trl_cartpole.parts.optim import tapered_lr
        >>> tapered_lr(1e-3, 1e-4, 5_000, 10_000), tapered_lr(1e-3, 1e-4, 20_000, 10_000)
        (0.00055, 0.0001)
    """
    return lr_start + (lr_end - lr_start) * min(1.0, frames / decay_frames)


def native_bfloat16(device: str | torch.device = "cpu") -> tuple[bool, str]:
    """Whether ``device`` computes bfloat16 natively, and the hardware said in words.

    A CPU does where oneDNN reports bfloat16 support (AVX-512 BF16 or AMX); without it torch
    emulates bfloat16, and a Nature-CNN update took 7x as long as in float32 (docs/atari.md).
    A CUDA device does where ``torch.cuda.is_bf16_supported()`` says so (Ampere and later).
    """
    device = torch.device(device)
    if device.type == "cuda":
        name = torch.cuda.get_device_name(device)
        return torch.cuda.is_bf16_supported(), name
    capability = torch.backends.cpu.get_cpu_capability()
    if cpu_computes_bfloat16():
        return True, f"this CPU ({capability}, with bfloat16 instructions)"
    return False, f"this CPU ({capability}, no bfloat16 instructions)"


def choose_autocast(requested: str, device: str | torch.device = "cpu") -> tuple[str, str | None]:
    """``optim.autocast`` made concrete: ``("bfloat16" | "none", the line to say or None)``.

    ``auto`` is bfloat16 where ``device`` computes it natively (:func:`native_bfloat16`), float32
    (``"none"``) elsewhere, said in one line; ``bfloat16`` asked for where it is emulated is
    kept, with a line that says it will be slow; ``none`` says nothing.
    """
    if requested == "none":
        return "none", None
    native, hardware = native_bfloat16(device)
    if requested == "auto":
        chosen = "bfloat16" if native else "none"
        kind = "bfloat16" if native else "float32"
        return chosen, f"optim.autocast=auto: the update runs in {kind} on {hardware}"
    if requested == "bfloat16" and not native:
        return requested, (
            f"optim.autocast=bfloat16 on {hardware}: torch emulates bfloat16 there, and the "
            "update takes several times as long as in float32 (optim.autocast=auto picks "
            "float32 here)"
        )
    return requested, None


def autocast_context(
    device_type: str, dtype: torch.dtype | None
) -> Callable[[], contextlib.AbstractContextManager]:
    """``() -> torch.autocast(device_type, dtype)``, or a context that does nothing for None.

    Not a disabled ``torch.autocast``: that one still puts its enter and exit calls into a
    compiled graph, which keeps AOTAutograd from caching the graph on disk.
    """
    if dtype is None:
        return contextlib.nullcontext
    return partial(torch.autocast, device_type, dtype)


def make_update(
    loss_module: Callable[[TensorDictBase], TensorDictBase],
    optimizer: torch.optim.Optimizer,
    grad_clip: str = "norm",
    max_grad: float = 10.0,
    noisy_network: nn.Module | None = None,
    autocast_dtype: torch.dtype | None = None,
) -> Callable[[TensorDictBase], TensorDict]:
    """Return ``update(batch) -> TensorDict(loss=[], grad_norm=[])``.

    One gradient step per call: ``loss_module(batch)["loss"]``, backward, gradient clipping,
    ``optimizer.step()``. ``grad_norm`` is measured before clipping. TorchRL has no such
    function: this is the body of its examples' training loops. The defaults are the default
    config's (``optim.grad_clip``, ``optim.max_grad``).

    Example::

        >>> from trl_cartpole import (make_dqn_loss, make_env, make_optimizer, make_q_actor,
        ...                           make_replay_buffer, make_update)
        >>> env = make_env("CartPole-v1", seed=0)
        >>> actor = make_q_actor(env.observation_spec, env.action_spec)
        >>> buffer = make_replay_buffer(batch_size=8, n_steps=1)
        >>> indices = buffer.extend(env.rollout(20, break_when_any_done=False))
        >>> update = make_update(make_dqn_loss(actor), make_optimizer(actor.parameters()))
        >>> sorted(update(buffer.sample()).keys())
        ['grad_norm', 'loss']

    :param loss_module: the loss (:func:`~trl_cartpole.parts.losses.make_dqn_loss`), or a
        function of it (:func:`~trl_cartpole.fast.loss.fuse_dqn_loss`), whose output's
        ``"loss"`` is differentiated.
    :param optimizer: the optimizer stepped after each backward pass; the gradients clipped are
        those of its parameter groups.
    :param grad_clip: ``"value"`` clamps each gradient element to ``[-max_grad, max_grad]``
        (the tutorial's ``clip_grad_value_(..., 100)``); ``"norm"`` rescales the whole gradient
        to an L2 norm of at most ``max_grad``; ``"none"`` leaves it. Default ``"norm"``, the
        config's ``optim.grad_clip``.
    :param max_grad: the bound of ``grad_clip``. Default 10.0, the config's ``optim.max_grad``.
    :param noisy_network: its ``NoisyLinear`` noise is resampled after the optimizer step, once
        per update as in Fortunato et al. (2018, section 3.1); None: no noise to resample.
    :param autocast_dtype: the loss computed under ``torch.autocast`` in this type
        (``torch.bfloat16``: the products and convolutions in bfloat16, the parameters, their
        gradients and AdamW in float32, Micikevicius et al. 2018); a loss module's outputs must
        then be read in float32 (:class:`~trl_cartpole.fast.loss.FusedDQNLoss` does).
        None: float32 throughout.
    :returns: this project's function ``update(batch) -> TensorDict(loss=[], grad_norm=[])``,
        with no Python-side state, so ``torch.compile`` can take it whole.
    """
    params = [p for group in optimizer.param_groups for p in group["params"]]
    autocast = autocast_context(params[0].device.type if params else "cpu", autocast_dtype)
    if grad_clip not in ("value", "norm", "none"):
        raise ValueError(f"optim.grad_clip={grad_clip!r}; choose 'value', 'norm' or 'none'")

    def update(batch: TensorDictBase) -> TensorDict:
        optimizer.zero_grad(set_to_none=True)
        with autocast():
            loss = loss_module(batch)["loss"]  # [] (weighted mean over the batch)
        loss.backward()
        if grad_clip == "norm":
            grad_norm = nn.utils.clip_grad_norm_(params, max_grad, foreach=True)
        else:
            grad_norm = nn.utils.get_total_norm([p.grad for p in params if p.grad is not None])
            if grad_clip == "value":
                nn.utils.clip_grad_value_(params, max_grad)
        optimizer.step()
        if noisy_network is not None:
            reset_network_noise(noisy_network)
        return TensorDict(loss=loss.detach(), grad_norm=grad_norm.detach())

    return update

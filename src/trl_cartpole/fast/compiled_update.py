"""One DQN update as one compiled function: loss, gradient, clipping and AdamW in one graph.

:func:`~trl_cartpole.parts.optim.make_update` runs an update as PyTorch runs it eagerly:
about 40 operator calls, each dispatched from Python at a few microseconds, for about
20 MFLOP of arithmetic on the default's 2x128 MLP (batch 128). Here the whole update is one
function of plain tensors that ``torch.compile`` (``fullgraph=True``) turns into one C++
kernel set, as LeanRL does with CleanRL's DQN:

    loss, g  = value and gradient of FusedDQNLoss's loss in the online parameters
               (``torch.func.grad_and_value``; the loss is ``DQNLoss``'s, Mnih et al. 2015)
    g        = clipped as ``clip_grad_norm_`` or ``clip_grad_value_`` clip it
    theta    = PyTorch's own functional AdamW step (``torch.optim.adam.adam`` with decoupled
               weight decay, Loshchilov & Hutter 2019) on the optimizer's own state tensors

The objects stay TorchRL's and PyTorch's: the parameters are the ``DQNLoss``'s (the actor's),
updated in place; the optimizer is the stock ``AdamW`` whose ``state`` holds the moments this
function updates (so its ``state_dict`` saves and loads as before); the target network is moved
by the stock ``SoftUpdate``/``HardUpdate`` outside this function; ``td_error`` is written into the
sample for a prioritized buffer as ``DQNLoss`` writes it. The learning rate is a tensor input,
read from the optimizer's parameter group at each call, so a taper needs no recompilation.

The result equals the eager update's within float rounding, not bitwise (Inductor orders and
fuses the arithmetic its own way; tested). :func:`make_lean_update` returns None where it does
not apply (what :func:`~trl_cartpole.fast.loss.fuse_dqn_loss` refuses, an optimizer that
is not one group of ``Adam``/``AdamW``, buffers in the network); a sample with one of TorchRL's
loss masks is handed to the eager update.
"""

from __future__ import annotations

import itertools
import types
from collections.abc import Callable

import torch
from tensordict import TensorDict, TensorDictBase
from torch import nn
from torch.func import functional_call, grad_and_value
from torch.optim.adam import adam

from trl_cartpole.fast.loss import FusedDQNLoss, fuse_dqn_loss
from trl_cartpole.parts.optim import autocast_context, make_update

__all__ = ["make_lean_update"]

Tensors = list[torch.Tensor]

# Dynamo's guards re-checked before each call: the tensors' metadata (dtype, shape, strides) and
# the global state (grad mode, autocast) only; checking the rest cost about 40 us of a 0.6 ms
# update. What the others guarded is held fixed instead: each update function has a code object
# of its own (:func:`_own_code`; Dynamo keeps compiled graphs per code object, so one built with
# other constants or another network is never reused), the optimizer settings it compiled are
# compared at each call (:func:`_fixed_settings`), and so are the sample's entries (the keys of
# ``inputs``, whose guards are dropped too: a sample with importance weights or n-step lengths
# the first did not have would have them ignored).
_COMPILE_OPTIONS = {"guard_filter_fn": torch.compiler.keep_portable_guards_unsafe}
_INSTANCES = itertools.count()


def make_lean_update(
    loss_module: nn.Module,
    optimizer: torch.optim.Optimizer,
    grad_clip: str = "norm",
    max_grad: float = 10.0,
    autocast_dtype: torch.dtype | None = None,
) -> Callable[[TensorDictBase], TensorDict] | None:
    """``update(batch) -> TensorDict(loss=[], grad_norm=[])`` compiled whole, or None.

    The same call form and result as :func:`~trl_cartpole.parts.optim.make_update`'s, within
    float rounding (``grad_norm`` measured before clipping; ``td_error`` written into
    ``batch``). The first call compiles (a few seconds; Inductor's on-disk cache makes a later
    process's compile shorter).

    Example::

        >>> from trl_cartpole import (make_dqn_loss, make_env, make_lean_update, make_optimizer,
        ...                           make_q_actor, make_replay_buffer)
        >>> env = make_env("CartPole-v1", seed=0)
        >>> actor = make_q_actor(env.observation_spec, env.action_spec)
        >>> buffer = make_replay_buffer(batch_size=8, n_steps=1)
        >>> indices = buffer.extend(env.rollout(20, break_when_any_done=False))
        >>> update = make_lean_update(make_dqn_loss(actor), make_optimizer(actor.parameters()))
        >>> sorted(update(buffer.sample()).keys())
        ['grad_norm', 'loss']

    :param loss_module: a TorchRL ``DQNLoss`` that :func:`fuse_dqn_loss` covers.
    :param optimizer: ``torch.optim.AdamW`` or ``Adam`` over exactly the loss's online
        parameters, in one parameter group.
    :param grad_clip: ``"norm"``, ``"value"`` or ``"none"``, as ``make_update``'s.
    :param max_grad: the bound of ``grad_clip``.
    :param autocast_dtype: the loss under ``torch.autocast`` in this type, as ``make_update``'s.
    :returns: the compiled update, or None where it does not apply (use ``make_update``).
    """
    if grad_clip not in ("value", "norm", "none"):
        raise ValueError(f"optim.grad_clip={grad_clip!r}; choose 'value', 'norm' or 'none'")
    fused = fuse_dqn_loss(loss_module)
    if fused is None or not _plain_adam(optimizer):
        return None
    params = optimizer.param_groups[0]["params"]  # the actor's parameters, stepped in place
    named = {id(tensor): name for name, tensor in fused._online.named_parameters()}
    if len(named) != len(params) or any(id(p) not in named for p in params):
        return None  # the optimizer steps other tensors than the loss's online parameters
    if any(True for _ in fused._online.buffers()):
        return None  # a network with buffers (batch norm): not a function of its parameters
    names = [named[id(p)] for p in params]
    target_params = [dict(fused._target.named_parameters())[name] for name in names]
    step = torch.compile(
        _own_code(
            _update_function(
                fused, names, optimizer.param_groups[0], grad_clip, max_grad, autocast_dtype
            )
        ),
        fullgraph=True,
        dynamic=False,
        options=_COMPILE_OPTIONS,
    )
    eager = make_update(fused, optimizer, grad_clip, max_grad, autocast_dtype=autocast_dtype)
    built_with = _fixed_settings(optimizer)
    input_keys: list[tuple[str, ...]] = []  # the sample entries of the first call

    def update(batch: TensorDictBase) -> TensorDict:
        if fused.masked(batch):
            return eager(batch)  # TorchRL's own masked reduction, eagerly
        if _fixed_settings(optimizer) != built_with:
            raise ValueError(
                "the optimizer's betas, eps, weight_decay, amsgrad or parameter groups changed "
                "after make_lean_update compiled them: call make_lean_update again"
            )
        fused.run_pre_hooks(batch)
        inputs = fused.inputs(batch)
        if not input_keys:
            input_keys.append(tuple(inputs))
        elif tuple(inputs) != input_keys[0]:
            raise ValueError(
                f"this sample gives the loss {sorted(inputs)}, and the update was compiled for "
                f"{sorted(input_keys[0])} (n-step lengths, importance weights): one update "
                "serves samples of one kind; make another for the other"
            )
        group = optimizer.param_groups[0]
        state = _adam_state(optimizer, params, group["amsgrad"])
        lr = torch.tensor(group["lr"], dtype=torch.float32, device=params[0].device)
        loss, grad_norm, td_error = step(  # lr an input: a taper recompiles nothing
            [p.detach() for p in params],
            [p.detach() for p in target_params],
            *state,
            inputs,
            lr,
        )
        batch.set(loss_module.tensor_keys.priority, td_error, inplace=True)
        return TensorDict(loss=loss, grad_norm=grad_norm)

    return update


def _own_code(function: Callable) -> Callable:
    """``function`` with a code object of its own (the same bytecode, a numbered name), so that
    Dynamo's graphs compiled for it serve no other closure of the same source."""
    code = function.__code__
    code = code.replace(co_name=f"{code.co_name}_{next(_INSTANCES)}")
    return types.FunctionType(
        code, function.__globals__, code.co_name, function.__defaults__, function.__closure__
    )


def _fixed_settings(optimizer: torch.optim.Optimizer) -> tuple:
    """What the compiled function holds fixed of ``optimizer``: its groups and the first
    group's settings other than the learning rate."""
    group = optimizer.param_groups[0]
    return (
        len(optimizer.param_groups),
        tuple(group["betas"]),
        group["eps"],
        group["weight_decay"],
        group["amsgrad"],
        group.get("decoupled_weight_decay", False),
        group["maximize"],
    )


def _plain_adam(optimizer: torch.optim.Optimizer) -> bool:
    """One parameter group of stock ``Adam``/``AdamW``, not maximizing, real parameters."""
    if type(optimizer) not in (torch.optim.Adam, torch.optim.AdamW):
        return False
    if len(optimizer.param_groups) != 1:
        return False
    group = optimizer.param_groups[0]
    return not group["maximize"] and not any(p.is_complex() for p in group["params"])


def _adam_state(
    optimizer: torch.optim.Optimizer, params: Tensors, amsgrad: bool
) -> tuple[Tensors, Tensors, Tensors, Tensors]:
    """The optimizer's ``exp_avg``, ``exp_avg_sq``, ``max_exp_avg_sq`` and ``step`` tensors of
    ``params``, created as ``Adam._init_group`` creates them where the first step has not."""
    for p in params:
        state = optimizer.state[p]
        if not state:
            state["step"] = torch.tensor(0.0, dtype=torch.float32, device=p.device)
            state["exp_avg"] = torch.zeros_like(p, memory_format=torch.preserve_format)
            state["exp_avg_sq"] = torch.zeros_like(p, memory_format=torch.preserve_format)
            if amsgrad:
                state["max_exp_avg_sq"] = torch.zeros_like(p, memory_format=torch.preserve_format)
    states = [optimizer.state[p] for p in params]
    return (
        [s["exp_avg"] for s in states],
        [s["exp_avg_sq"] for s in states],
        [s["max_exp_avg_sq"] for s in states] if amsgrad else [],
        [s["step"] for s in states],
    )


def _update_function(
    fused: FusedDQNLoss,
    names: list[str],
    group: dict,
    grad_clip: str,
    max_grad: float,
    autocast_dtype: torch.dtype | None,
) -> Callable:
    """The update as a function of tensors only (what ``torch.compile`` takes whole).

    Of ``(params, target_params, exp_avgs, exp_avg_sqs, max_exp_avg_sqs, steps, inputs, lr)``
    it returns ``(loss [], grad_norm [], td_error [B, 1])`` and steps ``params`` and the state
    tensors in place. The group's constant hyper-parameters (betas, eps, weight decay) are
    read once here (the update refuses to run once they change, :func:`_fixed_settings`), as
    are the loss's switches (``double_dqn``, the action space) and the networks' layers at the
    first call; the learning rate and gamma, tensors, are read at each call.
    """
    beta1, beta2 = group["betas"]
    eps, weight_decay, amsgrad = group["eps"], group["weight_decay"], group["amsgrad"]
    decoupled = group.get("decoupled_weight_decay", False)  # True for AdamW
    autocast = autocast_context(group["params"][0].device.type, autocast_dtype)

    def update(params, target_params, exp_avgs, exp_avg_sqs, max_exp_avg_sqs, steps, inputs, lr):
        def target(observation):  # [B, *obs] -> [B, A]
            return functional_call(
                fused._target, dict(zip(names, target_params, strict=True)), observation
            )

        def loss_of(online_params):  # -> (loss [], td_error [B, 1]), differentiated in the first
            def online(observation):  # [B, *obs] -> [B, A]
                return functional_call(
                    fused._online, dict(zip(names, online_params, strict=True)), observation
                )

            with autocast():
                return fused.compute(online, target, inputs)

        grads, (loss, td_error) = grad_and_value(loss_of, has_aux=True)(params)
        grad_norm = nn.utils.get_total_norm(grads)  # [] L2 norm, before clipping
        if grad_clip == "norm":  # torch.nn.utils.clip_grads_with_norm_'s rule
            scale = torch.clamp(max_grad / (grad_norm + 1e-6), max=1.0)
            grads = [g * scale for g in grads]
        elif grad_clip == "value":
            grads = [g.clamp(-max_grad, max_grad) for g in grads]
        with torch.no_grad():
            adam(
                params,
                grads,
                exp_avgs,
                exp_avg_sqs,
                max_exp_avg_sqs,
                steps,
                foreach=False,
                capturable=True,  # step and lr as tensors: no graph break, no recompilation
                amsgrad=amsgrad,
                beta1=beta1,
                beta2=beta2,
                lr=lr,
                weight_decay=weight_decay,
                eps=eps,
                maximize=False,
                decoupled_weight_decay=decoupled,
            )
        return loss.detach(), grad_norm.detach(), td_error

    return update

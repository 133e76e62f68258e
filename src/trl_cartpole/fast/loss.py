"""``DQNLoss.forward``'s arithmetic on plain tensors: the same loss, in less time.

TorchRL's ``DQNLoss`` clones the sampled TensorDict, swaps the online and the target parameters
into its value network (``to_module``) for each pass, and writes actions and values into
TensorDicts on the way; on CartPole's small MLP that bookkeeping costs about as much as the
arithmetic (2.06 ms of an update against 1.60 ms fused, docs/results/speed.md).
:class:`FusedDQNLoss` computes the same expression directly on the sample's
tensors, with two copies of the Q-network whose parameters *are* the loss's online and target
parameters (the same tensors: the optimizer's steps and the target updater's copies reach
them), and TorchRL's own ``QValueModule`` action rules. Same inputs, same operations in the
same order: the loss, its gradients and the ``td_error`` it writes back are bitwise equal to
``DQNLoss``'s (tested on the presets it covers), so a run learns exactly as before.

The loss module stays the stock ``DQNLoss`` (saved, loaded and updated as before); this is a
function of it the trainer calls. Losses it does not cover (C51's, noisy layers, a custom
value estimator, action masks, a reduction other than ``mean``, forward hooks after the
loss) get ``None`` from :func:`fuse_dqn_loss`; a sample carrying one of TorchRL's loss-mask
entries is handed to the loss module itself; the loss module's forward pre-hooks (such as
:func:`make_dqn_loss`'s n-step discount check) run before each call, as a call would run them.
"""

from __future__ import annotations

import copy
from collections.abc import Callable

import torch
from tensordict import TensorDict, TensorDictBase
from torch import nn
from torch.nn import functional as F
from torchrl.modules import NoisyLinear, QValueModule
from torchrl.objectives import DQNLoss
from torchrl.objectives.value import TD0Estimator

from trl_cartpole.compat import (
    forward_hooks_set,
    forward_pre_hooks,
    greedy_action_rule,
    greedy_value_rule,
    loss_mask_keys,
)

__all__ = ["FusedDQNLoss", "fuse_dqn_loss"]

_DISTANCES = {"smooth_l1": F.smooth_l1_loss, "l2": F.mse_loss, "l1": F.l1_loss}


def fuse_dqn_loss(loss_module: nn.Module) -> FusedDQNLoss | None:
    """A :class:`FusedDQNLoss` of ``loss_module``, or None where it does not apply.

    :param loss_module: the loss the trainer would call, a TorchRL ``DQNLoss`` over a
        ``QValueActor`` (the network, then TorchRL's ``QValueModule``) with the TD(0) estimator,
        as :func:`make_dqn_loss` builds it.
    :returns: the fused function, or None for anything else (its caller keeps the loss module).
    """
    if type(loss_module) is not DQNLoss:  # C51's loss, or a subclass with its own forward
        return None
    network = loss_module.value_network
    estimator = loss_module.value_estimator
    modules = getattr(network, "module", None)
    if (
        modules is None
        or len(modules) != 2
        or not isinstance(modules[-1], QValueModule)
        or modules[-1].action_mask_key is not None
        or len(modules[0].in_keys) != 1
        or any(isinstance(layer, NoisyLinear) for layer in network.modules())
        or type(estimator) is not TD0Estimator
        or estimator.average_rewards
        or loss_module.loss_function not in _DISTANCES
        or loss_module.reduction != "mean"
        or loss_module.action_space not in ("one_hot", "categorical")
        or forward_hooks_set(loss_module)
    ):
        return None
    return FusedDQNLoss(loss_module)


class FusedDQNLoss:
    """``loss(sample) -> TensorDict(loss=[])``, writing ``td_error`` ``[B, 1]`` into ``sample``,
    as ``DQNLoss`` does (Mnih et al. 2015; van Hasselt et al. 2016 with ``double_dqn``)::

        Q(s, a)  = the online network at s, at the action taken            [B]
        y        = r + gamma^k (1 - terminated) Q_target(s', a*)           [B]
        a*       = argmax_a Q_target(s', a), or argmax_a Q(s', a) (double)
        td_error = (Q(s, a) - y)^2;  loss = mean of distance(Q(s, a), y),
                   weighted by ``priority_weight`` when the sample has it

    ``k`` is the sample's ``steps_to_next_obs`` (n-step returns), 1 without it.
    """

    def __init__(self, loss_module: DQNLoss) -> None:
        self.loss_module = loss_module
        network = loss_module.value_network
        body, self._q_value = network.module[0], network.module[-1]
        params_key = ("module", "0", "module")
        self._online = _bound_copy(body.module, loss_module.value_network_params.get(params_key))
        self._target = _bound_copy(
            body.module, loss_module.target_value_network_params.get(params_key)
        )
        self._observation_key = body.in_keys[0]
        self._next_observation_key = ("next", *_as_tuple(self._observation_key))
        self._choose = greedy_action_rule(self._q_value)
        self._value_of_choice = greedy_value_rule(self._q_value)
        self._distance = _DISTANCES[loss_module.loss_function]
        keys, estimator_keys = loss_module.tensor_keys, loss_module.value_estimator.tensor_keys
        self._keys = keys
        self._reward_key = ("next", *_as_tuple(estimator_keys.reward))
        self._terminated_key = ("next", *_as_tuple(estimator_keys.terminated))
        self._done_key = ("next", *_as_tuple(estimator_keys.done))
        self._steps_key = estimator_keys.steps_to_next_obs
        self._mask_keys = loss_mask_keys(loss_module)

    def __call__(self, sample: TensorDictBase) -> TensorDict:
        if self.masked(sample):
            return self.loss_module(sample)  # masked positions: TorchRL's own reduction
        self.run_pre_hooks(sample)
        loss, td_error = self.compute(self._online, self._target, self.inputs(sample))
        sample.set(self._keys.priority, td_error, inplace=True)
        return TensorDict(loss=loss)

    def run_pre_hooks(self, sample: TensorDictBase) -> None:
        """The loss module's forward pre-hooks, as ``loss_module(sample)`` runs them."""
        loss_module = self.loss_module
        for hook in forward_pre_hooks(loss_module):
            hook(loss_module, (sample,))

    def masked(self, sample: TensorDictBase) -> bool:
        """Whether ``sample`` carries one of TorchRL's loss masks (left to the loss module)."""
        return any(sample.get(key, None) is not None for key in self._mask_keys)

    def inputs(self, sample: TensorDictBase) -> dict[str, torch.Tensor]:
        """The plain tensors of ``sample`` the loss reads (``steps`` and ``weights`` when
        present and used)."""
        inputs = {
            "observation": sample.get(self._observation_key),  # [B, *obs]
            "action": sample.get(self._keys.action),  # [B] or [B, 1] (categorical), [B, A]
            "next_observation": sample.get(self._next_observation_key),  # [B, *obs]
            "reward": sample.get(self._reward_key),  # [B, 1]
        }
        terminated = sample.get(self._terminated_key, None)
        inputs["terminated"] = (  # TorchRL's TD(0) falls back to done
            sample.get(self._done_key) if terminated is None else terminated
        )  # [B, 1]
        steps = sample.get(self._steps_key, None)
        if steps is not None:
            inputs["steps"] = steps  # [B, 1] n-step lengths k
        weights = sample.get(self._keys.priority_weight, None)
        if self.loss_module.use_prioritized_weights in (True, "auto") and weights is not None:
            inputs["weights"] = weights  # [B] importance-sampling weights
        return inputs

    def compute(
        self,
        online: Callable[[torch.Tensor], torch.Tensor],
        target: Callable[[torch.Tensor], torch.Tensor],
        inputs: dict[str, torch.Tensor],
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """``(loss [], td_error [B, 1])`` of :meth:`inputs`, with ``online`` and ``target``
        the two networks' ``observation -> values`` (the class docstring's equations)."""
        action = inputs["action"]
        values = online(inputs["observation"]).float()  # [B, A] (float32 under autocast too)
        if self.loss_module.action_space == "categorical":
            if action.ndim != values.ndim:
                action = action.unsqueeze(-1)
            taken = torch.gather(values, -1, index=action).squeeze(-1)  # [B]
        else:
            taken = (values * action.to(torch.float)).sum(-1)  # [B]
        td_target = self._td_target(online, target, inputs)  # [B]
        with torch.no_grad():
            td_error = (taken - td_target).pow(2).unsqueeze(-1)  # [B, 1]
        loss = self._distance(taken, td_target, reduction="none")  # [B]
        weights = inputs.get("weights")
        if weights is not None:
            if weights.shape != loss.shape:
                raise ValueError(
                    f"Tensor and weights shapes must match, but got {loss.shape} and "
                    f"{weights.shape}"
                )  # TorchRL's own check and words
            return (loss * weights).sum() / weights.sum(), td_error
        return loss.mean(), td_error

    @torch.no_grad()
    def _td_target(self, online, target, inputs: dict[str, torch.Tensor]) -> torch.Tensor:
        """``r + gamma^k (1 - terminated) Q_target(s', a*)``, ``[B]`` (TorchRL's TD(0))."""
        next_observation = inputs["next_observation"]
        target_values = target(next_observation).float()  # [B, A]
        if self.loss_module.double_dqn:
            next_action = self._choose(online(next_observation).float())
            if self.loss_module.action_space == "categorical":
                if next_action.ndim != target_values.ndim:
                    next_action = next_action.unsqueeze(-1)
                next_value = torch.gather(target_values, -1, index=next_action)  # [B, 1]
            else:
                next_value = (target_values * next_action).sum(-1, keepdim=True)  # [B, 1]
        else:
            next_value = self._value_of_choice(target_values, self._choose(target_values))
        reward = inputs["reward"]  # [B, 1]
        gamma = self.loss_module.value_estimator.gamma
        steps = inputs.get("steps")
        if steps is not None:
            gamma = gamma ** steps.view_as(reward)
        not_terminated = (~inputs["terminated"]).int()
        return (reward + gamma * not_terminated * next_value).squeeze(-1)


def _bound_copy(module: nn.Module, params: TensorDictBase) -> nn.Module:
    """A copy of ``module`` whose parameters and buffers are the tensors of ``params``."""
    bound = copy.deepcopy(module)
    params.to_module(bound)
    return bound


def _as_tuple(key: str | tuple[str, ...]) -> tuple[str, ...]:
    return key if isinstance(key, tuple) else (key,)

"""DQN loss and target-network updater factories, and the priorities a loss assigns.

The TD target is y = r + gamma^k * (1 - terminated) * max_a Q_target(s', a) (Mnih et al. 2015),
with k = 1, or the n-step window's length (``steps_to_next_obs``) when the replay buffer stores
n-step transitions. With ``double_dqn`` it is r + gamma^k * (1 - terminated) *
Q_target(s', argmax_a Q_online(s', a)) (van Hasselt et al. 2016). Only ``terminated`` stops
bootstrapping: a time-limit truncation keeps it.

For a ``DistributionalQValueActor`` the loss is ``DistributionalDQNLoss`` (C51, Bellemare et
al. 2017, algorithm 1): the target distribution r + gamma^k z on the target network's
distribution at the online network's greedy next action (so double DQN is built in),
projected onto the support, and the cross-entropy to it.
"""

from __future__ import annotations

import math
from typing import Any

import torch
from tensordict import TensorDictBase
from torch import nn
from torchrl.data import ReplayBuffer
from torchrl.envs import ExplorationType
from torchrl.modules import DistributionalQValueActor, NoisyLinear, QValueActor
from torchrl.objectives import DistributionalDQNLoss, DQNLoss, HardUpdate, SoftUpdate
from torchrl.objectives.utils import TargetNetUpdater

from trl_cartpole import defaults
from trl_cartpole.parts.compat import soft_update_pairs
from trl_cartpole.parts.replay import DEFAULT_GAMMA, N_STEP_GAMMA_KEY, n_step_gamma

__all__ = [
    "FusedSoftUpdate",
    "check_discounts",
    "make_dqn_loss",
    "make_target_updater",
]

# This project's defaults, the default config's loss section (tests/test_defaults.py holds
# them together).
DEFAULT_LOSS_FUNCTION = defaults.LOSS_FUNCTION
DEFAULT_TAU = defaults.TAU
DEFAULT_HARD_UPDATE_INTERVAL = defaults.HARD_UPDATE_INTERVAL


def make_dqn_loss(
    value_network: QValueActor | DistributionalQValueActor,
    *args: Any,
    gamma: float | None = None,
    loss_function: str | None = None,
    delay_value: bool = True,
    double_dqn: bool | None = None,
    replay_buffer: ReplayBuffer | None = None,
    **loss_kwargs: Any,
) -> DQNLoss | DistributionalDQNLoss:
    """Return TorchRL's ``DQNLoss`` (or ``DistributionalDQNLoss``) for ``value_network``.

    The arguments are ``DQNLoss``'s, with its meanings, keywords after ``value_network`` as in
    ``DQNLoss``. Defaults, ours beside TorchRL's, are given with each argument.

    One discount: an n-step buffer (:func:`~trl_cartpole.parts.replay.make_replay_buffer`) sums
    rewards with its own gamma, and the loss bootstraps with gamma ** k, so the two must agree.
    Importance weights in the batch (``"priority_weight"``) are applied by both losses:
    loss = sum_i w_i l_i / sum_i w_i.

    TorchRL runs a loss's forward under its ``deterministic_sampling_mode``
    (``DETERMINISTIC``), which would switch ``NoisyLinear`` noise off; for a network with noisy
    layers it is set to ``RANDOM``, so the networks train through their noise (Fortunato et al.
    2018, algorithm 1).

    Example::

        >>> from trl_cartpole import make_dqn_loss, make_env, make_q_actor
        >>> env = make_env("CartPole-v1")
        >>> actor = make_q_actor(env.observation_spec, env.action_spec)
        >>> loss = make_dqn_loss(actor, gamma=0.99, double_dqn=True)
        >>> type(loss).__name__, loss.double_dqn
        ('DQNLoss', True)

    :param value_network: the Q-value actor (:func:`~trl_cartpole.parts.models.make_q_actor`);
        a ``DistributionalQValueActor`` gets a ``DistributionalDQNLoss``.
    :param args: refused: the arguments after ``value_network`` are keywords, as in
        ``DQNLoss``; a positional one raises ``TypeError`` naming the keyword.
    :param gamma: the discount. Default: the replay buffer's n-step discount when
        ``replay_buffer`` is given, else the default config's ``loss.gamma`` (0.995);
        TorchRL's value estimator defaults to 0.99. It is set with
        ``loss.make_value_estimator(gamma=...)``, TorchRL's way.
    :param loss_function: ``"smooth_l1"`` (Huber, as the PyTorch DQN tutorial) by default;
        TorchRL's ``"l2"``. A ``DistributionalDQNLoss`` has none.
    :param delay_value: ``True`` (a target network), as TorchRL.
    :param double_dqn: ``False``, as TorchRL. A ``DistributionalDQNLoss`` has none (it is
        always double).
    :param replay_buffer: the n-step buffer the loss learns from: the loss takes the buffer's
        gamma (a different ``gamma`` raises ``ValueError`` naming both); without it, the loss
        checks the first n-step batch it sees and raises the same error there.
    :param loss_kwargs: go to the loss's constructor (``action_space``, ``reduction``, ...).
    :returns: TorchRL's ``DQNLoss``, or ``DistributionalDQNLoss`` for a
        ``DistributionalQValueActor``.
    :raises ValueError: when ``gamma`` differs from the n-step buffer's (at the first n-step
        batch without ``replay_buffer``), or when ``loss_function`` or ``double_dqn`` is passed
        for a ``DistributionalDQNLoss``.
    """
    if args:
        raise TypeError(
            "make_dqn_loss() takes value_network, then keywords (as DQNLoss): "
            f"make_dqn_loss(value_network, gamma={args[0]!r})"
        )
    buffer_gamma = None if replay_buffer is None else n_step_gamma(replay_buffer)
    if gamma is None:
        gamma = DEFAULT_GAMMA if buffer_gamma is None else buffer_gamma
    elif buffer_gamma is not None:
        check_discounts(gamma, buffer_gamma)
    if isinstance(value_network, DistributionalQValueActor):
        ignored = [
            name
            for name, value in (("loss_function", loss_function), ("double_dqn", double_dqn))
            if value is not None
        ]
        if ignored:
            raise ValueError(
                f"{' and '.join(ignored)}: DistributionalDQNLoss has no such argument (C51's "
                "target is always double, its loss a cross-entropy); leave it out"
            )
        loss = DistributionalDQNLoss(
            value_network, gamma=gamma, delay_value=delay_value, **loss_kwargs
        )
    else:
        loss = DQNLoss(
            value_network,
            loss_function=DEFAULT_LOSS_FUNCTION if loss_function is None else loss_function,
            delay_value=delay_value,
            double_dqn=bool(double_dqn),
            **loss_kwargs,
        )
        loss.make_value_estimator(gamma=gamma)
    if any(isinstance(module, NoisyLinear) for module in value_network.modules()):
        loss.deterministic_sampling_mode = ExplorationType.RANDOM
    if replay_buffer is None:  # the buffer is not known: check the first n-step batch instead
        _check_first_batch_discount(loss, gamma)
    return loss


def check_discounts(loss_gamma: float, buffer_gamma: float) -> None:
    """Raise ``ValueError`` unless the loss's and the n-step buffer's discounts are equal."""
    if not math.isclose(loss_gamma, buffer_gamma, rel_tol=0.0, abs_tol=1e-9):
        raise ValueError(
            f"the loss's gamma={loss_gamma} differs from the replay buffer's n-step "
            f"gamma={buffer_gamma}: the TD target would mix two discounts; build both with "
            "the same gamma (make_dqn_loss(..., replay_buffer=buffer) takes the buffer's)"
        )


def _check_first_batch_discount(loss: nn.Module, gamma: float) -> None:
    """Check the n-step discount of the first batch the loss sees, then remove the check.

    An n-step buffer built by ``make_replay_buffer`` marks each sample with its discount
    (``N_STEP_GAMMA_KEY``); a batch without the mark (a one-step buffer) passes.
    """

    def check(module: nn.Module, args: tuple[Any, ...]) -> None:
        handle.remove()
        batch = args[0] if args else None
        if isinstance(batch, TensorDictBase) and N_STEP_GAMMA_KEY in batch.keys():  # noqa: SIM118
            check_discounts(gamma, batch.get(N_STEP_GAMMA_KEY).reshape(-1)[0].item())

    handle = loss.register_forward_pre_hook(check)


class FusedSoftUpdate(SoftUpdate):
    """TorchRL's ``SoftUpdate``, theta' <- theta' + tau (theta - theta'), in one fused call.

    ``SoftUpdate.step`` lerps the target parameters tensordict by tensordict, about 0.2-0.3 ms
    per step for the default 128-128 network; one ``torch._foreach_lerp_`` over all of them
    does the same arithmetic (``Tensor.lerp_`` per tensor) in about 0.06 ms
    (docs/performance.md). The sources and targets are the ones ``SoftUpdate.init_`` selected,
    in the same order.
    """

    def step(self) -> None:
        if not self.initialized:
            return super().step()  # raises: init_() first
        sources, targets = soft_update_pairs(self)
        torch._foreach_lerp_(targets, sources, 1 - self.eps)


def make_target_updater(
    loss_module: DQNLoss | DistributionalDQNLoss,
    *args: Any,
    eps: float | None = None,
    tau: float | None = None,
    value_network_update_interval: int | None = None,
    hard_update_interval: int | None = None,
    kind: str | None = None,
) -> TargetNetUpdater:
    """Return TorchRL's ``SoftUpdate`` or ``HardUpdate`` of ``loss_module``'s target network.

    The arguments are TorchRL's, with its meanings; which updater is built follows from them.
    With none of them: the default config's, a ``HardUpdate`` copying every 50 updates
    (``value_network_update_interval=49``). TorchRL has no default updater; its ``SoftUpdate``
    needs ``eps`` or ``tau`` and ``HardUpdate`` defaults to ``value_network_update_interval=1000``.
    Call ``.step()`` once per gradient update.

    Example::

        >>> from trl_cartpole import make_dqn_loss, make_env, make_q_actor, make_target_updater
        >>> env = make_env("CartPole-v1")
        >>> loss = make_dqn_loss(make_q_actor(env.observation_spec, env.action_spec))
        >>> make_target_updater(loss, tau=0.01).eps
        0.99
        >>> make_target_updater(loss, value_network_update_interval=3).value_network_update_interval
        3

    :param loss_module: the loss (:func:`make_dqn_loss`) whose target network is updated.
    :param args: ``kind``, taken as the second positional argument too: its earlier form
        ``make_target_updater(loss, "soft", tau=0.01)``.
    :param eps: ``SoftUpdate``'s: ``eps = 1 - tau``. With ``eps`` or ``tau``, a soft update
        (Lillicrap et al. 2016), built as :class:`FusedSoftUpdate`, a ``SoftUpdate`` doing the
        same arithmetic in one fused call.
    :param tau: ``SoftUpdate``'s: theta' <- tau theta + (1 - tau) theta' at each ``.step()``.
        Default 0.02 with ``kind="soft"`` (TorchRL's ``SoftUpdate``: eps or tau required).
    :param value_network_update_interval: ``HardUpdate``'s, counted as TorchRL counts, so the
        copy happens on every ``(value_network_update_interval + 1)``-th ``.step()``
        (``value_network_update_interval=3`` copies at steps 4, 8, 12).
    :param hard_update_interval: this project's alias (the config's
        ``loss.hard_update_interval``) for a copy on every ``hard_update_interval``-th step
        (3: steps 3, 6, 9), i.e. ``value_network_update_interval = hard_update_interval - 1``.
    :param kind: ``"soft"`` or ``"hard"`` (this project's): pick the updater with the default
        config's setting for the rest (``tau=0.02``; a copy every 50 updates).
    :returns: TorchRL's ``HardUpdate``, or :class:`FusedSoftUpdate` (a ``SoftUpdate``).
    """
    if args:
        if len(args) > 1 or args[0] not in ("soft", "hard") or kind is not None:
            raise TypeError(
                "make_target_updater() takes loss_module, then keywords (as SoftUpdate and "
                "HardUpdate): tau= or eps= (soft), value_network_update_interval= (hard), or "
                "kind='soft' / 'hard'"
            )
        kind = args[0]
    soft = eps is not None or tau is not None
    hard = value_network_update_interval is not None or hard_update_interval is not None
    if kind not in (None, "soft", "hard"):
        raise ValueError(f"kind={kind!r}; choose 'soft' or 'hard'")
    if (soft and hard) or (kind == "soft" and hard) or (kind == "hard" and soft):
        raise ValueError(
            "a target updater is either soft (eps or tau: SoftUpdate) or hard "
            "(value_network_update_interval or hard_update_interval: HardUpdate), not both"
        )
    if value_network_update_interval is not None and hard_update_interval is not None:
        raise ValueError(
            "value_network_update_interval and hard_update_interval name the same setting "
            "(hard_update_interval = value_network_update_interval + 1); pass one"
        )
    if soft or kind == "soft":
        if eps is None and tau is None:
            tau = DEFAULT_TAU
        return FusedSoftUpdate(loss_module, eps=eps, tau=tau)
    if value_network_update_interval is None:
        interval = (
            DEFAULT_HARD_UPDATE_INTERVAL if hard_update_interval is None else hard_update_interval
        )
        if interval < 1:
            raise ValueError(f"hard_update_interval={interval} must be >= 1")
        value_network_update_interval = interval - 1
    return HardUpdate(loss_module, value_network_update_interval=value_network_update_interval)

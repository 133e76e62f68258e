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
import weakref
from typing import Any

import torch
from tensordict import TensorDictBase
from torch import nn
from torchrl.data import ReplayBuffer
from torchrl.envs import ExplorationType
from torchrl.modules import DistributionalQValueActor, NoisyLinear, QValueActor
from torchrl.objectives import DistributionalDQNLoss, DQNLoss, HardUpdate, SoftUpdate
from torchrl.objectives.utils import TargetNetUpdater

from trl_cartpole.compat import tensor_version
from trl_cartpole.parts.replay import N_STEP_GAMMA_KEY, n_step_gamma

__all__ = [
    "check_discounts",
    "make_dqn_loss",
    "make_target_updater",
]


def make_dqn_loss(
    value_network: QValueActor | DistributionalQValueActor,
    *,
    gamma: float | None = None,
    loss_function: str | None = None,
    delay_value: bool = True,
    double_dqn: bool | None = None,
    replay_buffer: ReplayBuffer | None = None,
    **loss_kwargs: Any,
) -> DQNLoss | DistributionalDQNLoss:
    """Return TorchRL's ``DQNLoss`` (or ``DistributionalDQNLoss``) for ``value_network``.

    The arguments are ``DQNLoss``'s, with its meanings and defaults, keywords after
    ``value_network`` as in ``DQNLoss``.

    One discount: an n-step buffer (:func:`~trl_cartpole.parts.replay.make_replay_buffer`) sums
    rewards with its own gamma, and the loss bootstraps with gamma ** k, so the two must agree.
    The loss checks every n-step batch it is called on against the discount it uses at that
    moment (its value estimator's, or ``DistributionalDQNLoss.gamma``), so
    ``loss.make_value_estimator(gamma=...)``, TorchRL's way, is read too, and a mismatch raises
    ``ValueError`` naming both on every call. Importance weights in the batch
    (``"priority_weight"``) are applied by both losses: loss = sum_i w_i l_i / sum_i w_i.

    TorchRL runs a loss's forward under its ``deterministic_sampling_mode``
    (``DETERMINISTIC``), which would switch ``NoisyLinear`` noise off; for a network with noisy
    layers it is set to ``RANDOM``, so the networks train through their noise (Fortunato et al.
    2018, algorithm 1).

    State: a loss whose discount was set here (``gamma=``, ``replay_buffer=``)
    has made its value estimator, so its ``state_dict`` holds ``_value_estimator.gamma``, as a
    stock ``DQNLoss`` after ``make_value_estimator(gamma=...)``; a fresh stock ``DQNLoss``
    makes its estimator on its first call, so call its ``make_value_estimator(gamma=...)``
    before a strict ``load_state_dict``. Left to TorchRL's discount, the states are alike.

    Example::

        >>> from trl_cartpole import make_dqn_loss, make_env, make_q_actor
        >>> env = make_env("CartPole-v1")
        >>> actor = make_q_actor(env.observation_spec, env.action_spec)
        >>> loss = make_dqn_loss(actor, double_dqn=True)
        >>> type(loss).__name__, loss.double_dqn, loss.loss_function
        ('DQNLoss', True, 'l2')

    :param value_network: the Q-value actor (:func:`~trl_cartpole.parts.models.make_q_actor`);
        a ``DistributionalQValueActor`` gets a ``DistributionalDQNLoss``.
    :param gamma: the discount, set with ``loss.make_value_estimator(gamma=...)``, TorchRL's
        way (``DistributionalDQNLoss``: its ``gamma``). Default: the replay buffer's n-step
        discount with ``replay_buffer``; else TorchRL's, 0.99, left to the loss.
    :param loss_function: Default None: ``DQNLoss``'s, ``"l2"`` (``"smooth_l1"``: Huber, as
        the PyTorch DQN tutorial). A ``DistributionalDQNLoss`` has none.
    :param delay_value: ``True`` (a target network), as TorchRL.
    :param double_dqn: ``False``, as TorchRL. A ``DistributionalDQNLoss`` has none (it is
        always double).
    :param replay_buffer: the n-step buffer the loss learns from: the loss takes the buffer's
        gamma (a different ``gamma`` raises ``ValueError`` naming both).
    :param loss_kwargs: go to the loss's constructor (``action_space``, ``reduction``, ...).
    :returns: TorchRL's ``DQNLoss``, or ``DistributionalDQNLoss`` for a
        ``DistributionalQValueActor``.
    :raises ValueError: when ``gamma`` differs from the n-step buffer's (at construction with
        ``replay_buffer``, and at every call on an n-step batch of another discount), or when
        ``loss_function`` or ``double_dqn`` is passed for a ``DistributionalDQNLoss``.
    """
    buffer_gamma = None if replay_buffer is None else n_step_gamma(replay_buffer)
    if gamma is not None and buffer_gamma is not None:
        check_discounts(gamma, buffer_gamma)
    if gamma is None:  # None left: TorchRL's, 0.99, left to the loss
        gamma = buffer_gamma
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
            value_network,
            gamma=0.99 if gamma is None else gamma,
            delay_value=delay_value,
            **loss_kwargs,
        )
    else:
        loss = DQNLoss(
            value_network,
            loss_function="l2" if loss_function is None else loss_function,
            delay_value=delay_value,
            double_dqn=bool(double_dqn),
            **loss_kwargs,
        )
        if gamma is not None:  # None: TorchRL's estimator, made on the loss's first call
            loss.make_value_estimator(gamma=gamma)
    if any(isinstance(module, NoisyLinear) for module in value_network.modules()):
        loss.deterministic_sampling_mode = ExplorationType.RANDOM
    loss.register_forward_pre_hook(_check_n_step_discount)
    return loss


def check_discounts(loss_gamma: float, buffer_gamma: float) -> None:
    """Raise ``ValueError`` unless the loss's and the n-step buffer's discounts are equal."""
    if not math.isclose(loss_gamma, buffer_gamma, rel_tol=0.0, abs_tol=1e-6):  # float32
        raise ValueError(
            f"the loss's gamma={loss_gamma:g} differs from the replay buffer's n-step "
            f"gamma={buffer_gamma:g}: the TD target would mix two discounts; use one gamma "
            "for both (make_dqn_loss(..., replay_buffer=buffer) takes the buffer's)"
        )


def discount_tensor(loss: nn.Module) -> torch.Tensor:
    """The discount ``loss`` bootstraps with now: its value estimator's ``gamma`` (TorchRL's
    default estimator is made if the loss has none yet, as its first call would), or a
    ``DistributionalDQNLoss``'s own ``gamma``."""
    return loss.gamma if isinstance(loss, DistributionalDQNLoss) else loss.value_estimator.gamma


# Each loss module's discount as last read: (its gamma tensor, that tensor's version, the value)
_DISCOUNT_READS: weakref.WeakKeyDictionary[nn.Module, tuple[torch.Tensor, int, float]] = (
    weakref.WeakKeyDictionary()
)


def _check_n_step_discount(loss: nn.Module, args: tuple[Any, ...]) -> None:
    """A forward pre-hook: an n-step batch's discount must be the one ``loss`` uses.

    An n-step buffer built by ``make_replay_buffer`` marks each sample with its discount
    (``N_STEP_GAMMA_KEY``); a batch without the mark (a one-step buffer) passes. The loss's
    discount is read again only when its estimator or gamma tensor has changed since the last
    call; the batch's is one number read per call.
    """
    batch = args[0] if args else None
    if not isinstance(batch, TensorDictBase):
        return
    marked = batch.get(N_STEP_GAMMA_KEY, None)  # [*B, 1]
    if marked is None:
        return
    gamma_tensor = discount_tensor(loss)
    version = tensor_version(gamma_tensor)  # moves on each in-place write
    cached = _DISCOUNT_READS.get(loss)  # (tensor, version, value)
    if cached is not None and cached[0] is gamma_tensor and cached[1] == version:
        loss_gamma = cached[2]
    else:
        loss_gamma = float(gamma_tensor)
        _DISCOUNT_READS[loss] = (gamma_tensor, version, loss_gamma)
    check_discounts(loss_gamma, float(marked.reshape(-1)[0]))


def make_target_updater(
    loss_module: DQNLoss | DistributionalDQNLoss,
    *,
    kind: str | None = None,
    eps: float | None = None,
    tau: float | None = None,
    value_network_update_interval: float | None = None,
) -> TargetNetUpdater:
    """Return TorchRL's ``SoftUpdate`` or ``HardUpdate`` of ``loss_module``'s target network.

    The arguments are TorchRL's, with its meanings and defaults. ``kind`` picks the updater
    (``"soft"``: Polyak averaging, Lillicrap et al. 2016; ``"hard"``: a periodic copy, Mnih et
    al. 2015) and reads only that updater's arguments, so a config may hold both; without
    ``kind``, ``eps`` or ``tau`` give a ``SoftUpdate`` and anything else a ``HardUpdate``.
    ``HardUpdate`` copies on every ``(value_network_update_interval + 1)``-th ``.step()``
    (TorchRL's count: 0 copies on every step); its default is 1000. ``SoftUpdate`` needs
    ``eps`` or ``tau`` (theta' <- tau theta + (1 - tau) theta'). Call ``.step()`` once per
    gradient update.

    Example::

        >>> from trl_cartpole import make_dqn_loss, make_env, make_q_actor, make_target_updater
        >>> env = make_env("CartPole-v1")
        >>> loss = make_dqn_loss(make_q_actor(env.observation_spec, env.action_spec))
        >>> make_target_updater(loss, tau=0.01).eps
        0.99
        >>> make_target_updater(loss).value_network_update_interval  # HardUpdate's
        1000

    :param loss_module: the loss (:func:`make_dqn_loss`) whose target network is updated.
    :param kind: ``"hard"`` or ``"soft"``; None: soft with ``eps`` or ``tau``, else hard.
    :param eps: ``SoftUpdate``'s: ``eps = 1 - tau``.
    :param tau: ``SoftUpdate``'s: theta' <- tau theta + (1 - tau) theta' at each ``.step()``.
    :param value_network_update_interval: ``HardUpdate``'s, counted as TorchRL counts: a copy
        on every ``(value_network_update_interval + 1)``-th ``.step()``. Default 1000.
    :returns: TorchRL's ``HardUpdate`` or ``SoftUpdate``.
    """
    if kind is None:
        soft = eps is not None or tau is not None
        if soft and value_network_update_interval is not None:
            raise ValueError(
                "a target updater is either soft (eps or tau: SoftUpdate) or hard "
                "(value_network_update_interval: HardUpdate), not both; or name it with kind="
            )
        kind = "soft" if soft else "hard"
    if kind == "soft":
        if eps is None and tau is None:
            raise TypeError("a soft target update needs tau= or eps= (as TorchRL's SoftUpdate)")
        return SoftUpdate(loss_module, eps=eps, tau=tau)
    if kind != "hard":
        raise ValueError(f"kind={kind!r}; choose 'soft' or 'hard'")
    if value_network_update_interval is None:
        return HardUpdate(loss_module)
    if value_network_update_interval < 0:
        raise ValueError(f"value_network_update_interval={value_network_update_interval} < 0")
    return HardUpdate(loss_module, value_network_update_interval=value_network_update_interval)

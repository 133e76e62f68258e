"""DQN loss and target-network updater factories.

The TD target is y = r + gamma * (1 - terminated) * max_a Q_target(s', a) (Mnih et al. 2015);
with ``double_dqn`` it is r + gamma * (1 - terminated) * Q_target(s', argmax_a Q_online(s', a))
(van Hasselt et al. 2016). Only ``terminated`` stops bootstrapping: a time-limit truncation
keeps it.
"""

from __future__ import annotations

from torchrl.modules import QValueActor
from torchrl.objectives import DQNLoss, HardUpdate, SoftUpdate
from torchrl.objectives.utils import TargetNetUpdater

__all__ = ["make_dqn_loss", "make_target_updater"]


def make_dqn_loss(
    actor: QValueActor,
    gamma: float = 0.99,
    loss_function: str = "smooth_l1",
    double_dqn: bool = False,
) -> DQNLoss:
    """Return a ``DQNLoss`` with a delayed (target) copy of ``actor`` and a TD(0) estimator."""
    loss = DQNLoss(
        actor,
        loss_function=loss_function,
        delay_value=True,
        double_dqn=double_dqn,
    )
    loss.make_value_estimator(gamma=gamma)
    return loss


def make_target_updater(
    loss: DQNLoss, kind: str = "soft", tau: float = 0.005, hard_update_interval: int = 100
) -> TargetNetUpdater:
    """Return ``SoftUpdate`` (theta' <- tau theta + (1 - tau) theta') or ``HardUpdate``.

    Call ``.step()`` once per gradient update. The hard update copies the online weights on
    every ``hard_update_interval``-th call: TorchRL's ``HardUpdate`` copies on call
    ``value_network_update_interval + 1``, so it is given ``hard_update_interval - 1``.
    """
    if kind == "soft":
        return SoftUpdate(loss, tau=tau)
    if kind == "hard":
        return HardUpdate(loss, value_network_update_interval=hard_update_interval - 1)
    raise ValueError(f"loss.target_update={kind!r}; choose 'soft' or 'hard'")

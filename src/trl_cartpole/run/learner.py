"""The learner: sample minibatches, take gradient steps, write priorities, move the target.

One call of :meth:`Learner.step` is the "update" part of one DQN iteration (Mnih et al. 2015,
algorithm 1): ``count`` minibatches from the replay buffer, each one gradient step on the TD
loss (``update``: loss, backward, clipping, optimizer, new network noise), then the new
priorities for a prioritized buffer, written TorchRL's way (``update_tensordict_priority``:
the loss's ``td_error``, Schaul et al. 2016) and one step of the target
network's updater (``SoftUpdate`` or ``HardUpdate``).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import torch
from tensordict import TensorDict, TensorDictBase
from torchrl.data import TensorDictReplayBuffer
from torchrl.objectives import DistributionalDQNLoss, DQNLoss
from torchrl.objectives.utils import TargetNetUpdater

from trl_cartpole.errors import TrainingFailed
from trl_cartpole.parts.replay import is_prioritized, sample_minibatches
from trl_cartpole.run.progress import Progress

__all__ = ["Learner", "UpdateReport"]


@dataclass
class UpdateReport:
    """What the updates of one :meth:`Learner.step` measured, one entry per update."""

    losses: list[float] = field(default_factory=list)
    grad_norms: list[float] = field(default_factory=list)
    last_sample: TensorDictBase | None = None  # [batch_size], the last minibatch
    prioritized: bool = False  # the samples carry importance weights ("priority_weight")

    def __len__(self) -> int:
        return len(self.losses)


class Learner:
    """Gradient updates on replayed minibatches, and the target network that follows them."""

    def __init__(
        self,
        buffer: TensorDictReplayBuffer,
        loss: DQNLoss | DistributionalDQNLoss,
        target_updater: TargetNetUpdater,
        optimizer: torch.optim.Optimizer,
        update: Callable[[TensorDictBase], TensorDict],
        autocast: str = "none",
    ) -> None:
        self.buffer, self.loss, self.target_updater = buffer, loss, target_updater
        self.autocast = autocast  # the update's number type: "bfloat16" or "none" (float32)
        self.optimizer = optimizer  # (stepped inside ``update``; saved with the training state)
        self.update = update  # make_update(...): one gradient step, possibly torch.compile'd
        self.prioritized = is_prioritized(buffer)
        self.last_report = UpdateReport(prioritized=self.prioritized)  # of the last step

    def step(self, count: int, progress: Progress) -> UpdateReport:
        """Take ``count`` updates; raise :class:`TrainingFailed` on a non-finite TD loss.

        The losses and gradient norms stay tensors until the last update, then are read in
        one go (no host read per update), except with a prioritized buffer: there each loss is
        checked before its ``td_error`` becomes priorities (a NaN priority would break the
        next draw). A non-finite loss is reported with its update, which is where
        ``progress.updates`` stops.
        """
        report = UpdateReport(prioritized=self.prioritized)
        measured: list[torch.Tensor] = []  # [2] per update: loss, grad_norm
        first_update = progress.updates + 1
        for sample in sample_minibatches(self.buffer, count):  # sample: [batch_size]
            metrics = self.update(sample)
            if self.prioritized:
                self._check_finite(metrics["loss"].item(), progress.updates + 1, progress)
                if self.loss.tensor_keys.priority not in sample.keys(True):
                    raise TrainingFailed(
                        f"the loss wrote no {self.loss.tensor_keys.priority!r} into the sample, "
                        "so no priorities can be updated (a compiled update must write it back)"
                    )
                self.buffer.update_tensordict_priority(sample)  # the loss wrote "td_error"
            self.target_updater.step()
            progress.updates += 1
            measured.append(torch.stack((metrics["loss"], metrics["grad_norm"])))
            report.last_sample = sample
        if measured:
            report.losses, report.grad_norms = torch.stack(measured).T.tolist()  # [2, count]
        for index, loss in enumerate(report.losses):
            self._check_finite(loss, first_update + index, progress)
        self.last_report = report
        return report

    @staticmethod
    def _check_finite(loss: float, update: int, progress: Progress) -> None:
        """Raise :class:`TrainingFailed` naming ``update`` if ``loss`` is not finite; the
        run's update count then ends at that update."""
        if not math.isfinite(loss):
            progress.updates = update
            raise TrainingFailed(
                f"TD loss is {loss} at update {update} (frame {progress.frames}); training stopped"
            )

    def state_dict(self) -> dict[str, Any]:
        """The hard update's call counter (the networks and optimizer are saved on their own)."""
        return {"hard_update_counter": getattr(self.target_updater, "counter", None)}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        if state["hard_update_counter"] is not None:
            self.target_updater.counter = state["hard_update_counter"]

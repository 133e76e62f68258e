"""What moves after each collected batch: epsilon, the network's noise, the sampler's beta, the
learning rate.

Built by :func:`trl_cartpole.run.build.build_components` from the config, so the loop steps it
without reading the config.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import nn
from torchrl.data import ReplayBuffer
from torchrl.modules import EGreedyModule

from trl_cartpole.parts.models import reset_network_noise
from trl_cartpole.parts.optim import tapered_lr
from trl_cartpole.parts.replay import annealed_beta

__all__ = ["Schedules"]


@dataclass
class Schedules:
    """The per-batch schedules of a run; each part is None where the run has no such schedule."""

    exploration: EGreedyModule | None  # epsilon, stepped by the frames collected
    noisy_network: nn.Module | None  # NoisyLinear layers: new noise for the next batch
    prioritized_buffer: ReplayBuffer | None  # its sampler's beta, annealed to 1
    beta_start: float = 0.4
    beta_anneal_frames: int = 1
    tapered_optimizer: torch.optim.Optimizer | None = None  # its lr tapered to lr_end
    lr_start: float = 0.0
    lr_end: float = 0.0
    lr_decay_frames: int = 1

    def step(self, batch_frames: int, frames: int) -> None:
        """After a batch of ``batch_frames`` frames, ``frames`` in all: anneal epsilon, draw new
        network noise, anneal beta (Schaul et al. 2016, section 3.4), taper the learning rate."""
        if self.exploration is not None:
            self.exploration.step(batch_frames)
        if self.noisy_network is not None:
            reset_network_noise(self.noisy_network)  # fresh noise for the next collected batch
        if self.prioritized_buffer is not None:
            self.prioritized_buffer.sampler.beta = annealed_beta(
                self.beta_start, frames, self.beta_anneal_frames
            )
        if self.tapered_optimizer is not None:
            lr = tapered_lr(self.lr_start, self.lr_end, frames, self.lr_decay_frames)
            for group in self.tapered_optimizer.param_groups:
                group["lr"] = lr

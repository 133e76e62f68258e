"""Epsilon-greedy exploration: the tutorial's exponential schedule and TorchRL's linear one.

``schedule="none"`` builds no module: noisy networks explore through their parameter noise.
"""

from __future__ import annotations

from typing import Any

import torch
from torchrl.data import TensorSpec
from torchrl.modules import EGreedyModule

__all__ = ["ExponentialEGreedyModule", "make_exploration"]


class ExponentialEGreedyModule(EGreedyModule):
    """``EGreedyModule`` whose epsilon decays exponentially with the frames seen.

    eps(t) = eps_end + (eps_init - eps_end) * exp(-t / decay_frames), the schedule of the
    PyTorch DQN tutorial (``EPS_START=0.9, EPS_END=0.05, EPS_DECAY=1000``). The frame counter
    is a buffer, so it is saved and restored with the module's ``state_dict``.
    """

    def __init__(
        self,
        spec: TensorSpec,
        eps_init: float = 0.9,
        eps_end: float = 0.05,
        decay_frames: int = 1000,
        **kwargs,
    ) -> None:
        super().__init__(spec, float(eps_init), float(eps_end), decay_frames, **kwargs)
        self.register_buffer("frames", torch.zeros((), dtype=torch.int64, device=self.eps.device))

    def step(self, frames: int = 1) -> None:
        """Advance the schedule by ``frames`` environment frames."""
        self.frames += frames
        decay = torch.exp(-self.frames.to(torch.float64) / self.annealing_num_steps)
        self.eps.copy_(self.eps_end + (self.eps_init - self.eps_end) * decay)


def make_exploration(
    action_spec: TensorSpec,
    schedule: str = "linear",
    eps_init: float = 1.0,
    eps_end: float = 0.05,
    annealing_num_steps: int = 3000,
    device: str = "cpu",
    **egreedy_kwargs: Any,
) -> EGreedyModule | None:
    """Return the epsilon-greedy module; the loop must call ``.step(frames)`` after each batch.

    The defaults are the default config's ``exploration`` section (``eps_start`` and
    ``decay_frames`` there are ``eps_init`` and ``annealing_num_steps`` here, TorchRL's
    ``EGreedyModule`` names); ``egreedy_kwargs`` go to its constructor (``action_key``,
    ``action_mask_key``, ...).

    ``schedule="none"`` returns None (the policy is the greedy actor itself).

    ``schedule="linear"`` is TorchRL's ``EGreedyModule``: eps falls by
    ``(eps_init - eps_end) / annealing_num_steps`` per frame down to ``eps_end``.
    ``schedule="exponential"`` is :class:`ExponentialEGreedyModule`, with
    ``annealing_num_steps`` its time constant.
    """
    if schedule == "none":
        return None
    spec = action_spec.to(device)
    if schedule == "exponential":
        return ExponentialEGreedyModule(
            spec, eps_init, eps_end, annealing_num_steps, device=device, **egreedy_kwargs
        )
    if schedule == "linear":
        return EGreedyModule(
            spec,
            float(eps_init),
            float(eps_end),
            annealing_num_steps,
            device=device,
            **egreedy_kwargs,
        )
    raise ValueError(f"exploration.schedule={schedule!r}; choose 'exponential', 'linear' or 'none'")

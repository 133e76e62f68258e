"""Epsilon-greedy exploration: the tutorial's exponential schedule and TorchRL's linear one.

``schedule="none"`` builds no module: noisy networks explore through their parameter noise.
"""

from __future__ import annotations

from typing import Any

import torch
from torchrl.data import TensorSpec
from torchrl.modules import EGreedyModule

from trl_cartpole import choices

__all__ = ["SCHEDULES", "ExponentialEGreedyModule", "make_exploration"]

SCHEDULES = choices.SCHEDULES


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
    spec: TensorSpec,
    eps_init: float = 1.0,
    eps_end: float = 0.1,
    annealing_num_steps: int = 1000,
    *,
    schedule: str = "linear",
    device: str | torch.device | None = None,
    **egreedy_kwargs: Any,
) -> EGreedyModule | None:
    """Return TorchRL's ``EGreedyModule``; the loop calls ``.step(frames)`` after each batch.

    The arguments are ``EGreedyModule``'s, in its order and with its meanings and defaults
    (1.0 -> 0.1 over 1 000 frames); ``schedule`` picks the module.

    Example::

        >>> from trl_cartpole import make_env, make_exploration
        >>> spec = make_env("CartPole-v1").action_spec
        >>> explore = make_exploration(spec, 1.0, 0.05, 100)
        >>> explore.step(50)
        >>> round(explore.eps.item(), 3)
        0.525

    :param spec: the env's action spec, ``EGreedyModule``'s ``spec``.
    :param schedule: ``"linear"`` (default): TorchRL's ``EGreedyModule``, eps falls by
        ``(eps_init - eps_end) / annealing_num_steps`` per frame down to ``eps_end``;
        ``"exponential"``: :class:`ExponentialEGreedyModule`, the PyTorch DQN tutorial's
        schedule, with ``annealing_num_steps`` its time constant; ``"none"``: returns None
        (noisy networks explore through their weights).
    :param device: the module's device. Default: the spec's.
    :param egreedy_kwargs: go to ``EGreedyModule`` (``action_key``, ``action_mask_key``, ...).
    """
    if schedule not in SCHEDULES:
        raise ValueError(f"schedule={schedule!r}: choose one of {list(SCHEDULES)}")
    if schedule == "none":
        return None
    if device is not None:
        spec = spec.to(device)
    module = ExponentialEGreedyModule if schedule == "exponential" else EGreedyModule
    return module(
        spec, float(eps_init), float(eps_end), annealing_num_steps, device=device, **egreedy_kwargs
    )

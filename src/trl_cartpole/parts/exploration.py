"""Epsilon-greedy exploration: the tutorial's exponential schedule and TorchRL's linear one.

``schedule="none"`` builds no module: noisy networks explore through their parameter noise.
"""

from __future__ import annotations

import numbers
from typing import Any

import torch
from torchrl.data import TensorSpec
from torchrl.modules import EGreedyModule

from trl_cartpole import defaults
from trl_cartpole.parts.earlier_forms import resolve_alias
from trl_cartpole.parts.tuned import resolve

__all__ = ["SCHEDULES", "ExponentialEGreedyModule", "make_exploration"]

SCHEDULES = defaults.SCHEDULES


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
    spec: TensorSpec | None = None,
    eps_init: float | None = None,
    eps_end: float | None = None,
    annealing_num_steps: int | None = None,
    *args: Any,
    schedule: str = "linear",
    device: str | torch.device | None = None,
    action_spec: TensorSpec | None = None,
    tuned: bool = False,
    **egreedy_kwargs: Any,
) -> EGreedyModule | None:
    """Return TorchRL's ``EGreedyModule``; the loop calls ``.step(frames)`` after each batch.

    The arguments are ``EGreedyModule``'s, in its order and with its meanings and defaults;
    ``schedule`` picks the module. ``tuned=True`` gives the ones left out the default
    config's ``exploration`` values (:mod:`trl_cartpole.parts.tuned`).

    Example::

        >>> from trl_cartpole import make_env, make_exploration
        >>> spec = make_env("CartPole-v1").action_spec
        >>> explore = make_exploration(spec, 1.0, 0.05, 100)
        >>> explore.step(50)
        >>> round(explore.eps.item(), 3)
        0.525
        >>> explore = make_exploration(spec)  # EGreedyModule's: 1.0 -> 0.1 over 1 000 frames
        >>> explore.step(1000)
        >>> round(explore.eps.item(), 3)
        0.1

    :param spec: the env's action spec, ``EGreedyModule``'s ``spec``.
    :param eps_init: epsilon at the start. Default 1.0, as ``EGreedyModule``
        (``tuned=True``: 1.0).
    :param eps_end: the final epsilon. Default 0.1, as ``EGreedyModule`` (``tuned=True``:
        0.05).
    :param annealing_num_steps: frames of the schedule (with ``"exponential"``, its time
        constant). Default 1000, as ``EGreedyModule`` (``tuned=True``: 3000).
    :param args: refused: an earlier form passed ``schedule`` before the epsilons; a fifth
        positional argument raises ``TypeError`` naming the keywords.
    :param schedule: ``"linear"`` (default): TorchRL's ``EGreedyModule``, eps falls by
        ``(eps_init - eps_end) / annealing_num_steps`` per frame down to ``eps_end``;
        ``"exponential"``: :class:`ExponentialEGreedyModule` (an ``EGreedyModule``), the
        PyTorch DQN tutorial's schedule, with ``annealing_num_steps`` its time constant;
        ``"none"``: returns None (noisy networks explore through their weights; the policy is
        the greedy actor itself).
    :param device: the module's device. Default: the spec's (TorchRL's too).
    :param action_spec: this project's earlier name for ``spec``, kept as an alias.
    :param tuned: fill the arguments left out with this project's tuned values (above).
    :param egreedy_kwargs: go to ``EGreedyModule``'s constructor (``action_key``,
        ``action_mask_key``, ...).
    :returns: TorchRL's ``EGreedyModule`` (``ExponentialEGreedyModule`` with
        ``schedule="exponential"``), or None with ``schedule="none"``.
    """
    if args:
        raise TypeError(
            "make_exploration() takes spec, eps_init, eps_end, annealing_num_steps "
            "(EGreedyModule's order), then keywords; an earlier form put the schedule first: "
            "write make_exploration(spec, "
            + ", ".join(
                f"{name}={value!r}"
                for name, value in zip(
                    ("schedule", "eps_init", "eps_end", "annealing_num_steps"),
                    (eps_init, eps_end, annealing_num_steps, *args),
                    strict=False,
                )
            )
            + ")"
        )
    spec = resolve_alias("spec", spec, "action_spec", action_spec)
    if spec is None:
        raise TypeError("make_exploration() needs spec (the env's action_spec)")
    eps_init = resolve("make_exploration", "eps_init", eps_init, tuned)
    eps_end = resolve("make_exploration", "eps_end", eps_end, tuned)
    annealing_num_steps = resolve(
        "make_exploration", "annealing_num_steps", annealing_num_steps, tuned
    )
    for name, value in (
        ("eps_init", eps_init),
        ("eps_end", eps_end),
        ("annealing_num_steps", annealing_num_steps),
    ):
        if isinstance(value, str) or not isinstance(value, numbers.Real):
            hint = f"schedule={value!r}" if value in SCHEDULES else f"{name}=<a number>"
            raise TypeError(
                f"make_exploration(): {name}={value!r} is not a number (the arguments after "
                f"spec are EGreedyModule's eps_init, eps_end, annealing_num_steps); write {hint}"
            )
    if schedule not in SCHEDULES:
        raise ValueError(f"schedule={schedule!r}: choose one of {list(SCHEDULES)}")
    if schedule == "none":
        return None
    if device is not None:
        spec = spec.to(device)
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
    raise ValueError(f"schedule={schedule!r}: choose one of {list(SCHEDULES)}")

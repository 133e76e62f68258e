"""What a run will hold in memory, known before its buffer and networks are allocated.

A replay buffer of ``buffer.max_size`` transitions and networks of ``network.num_cells`` are
allocated as the run goes (TorchRL's ``LazyTensorStorage`` fills on the first write); a size
that cannot fit would end in the allocator's traceback, or in the kernel's out-of-memory kill
hours into the run. :func:`check_fits_in_memory` refuses such a run before it starts, with a
lower bound: one transition as the env steps it (the buffer stores a little more: the policy's
outputs), and each network parameter in float32 five times over (the online and target
networks, the gradient, Adam's two moments; AMSGrad keeps a sixth copy).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import torch
from torchrl.envs import EnvBase

from trl_cartpole.envs.pixels import PIXELS_KEY
from trl_cartpole.errors import ConfigError
from trl_cartpole.storage.frames import pool_capacity

__all__ = [
    "MemoryNeed",
    "available_memory_bytes",
    "check_buffer_fits_on_disk",
    "check_fits_in_memory",
    "disk_bytes_under",
    "memory_need",
]

GIB = 1024**3


@dataclass(frozen=True)
class MemoryNeed:
    transitions: int  # the buffer's capacity
    transition_bytes: int  # one transition as the env steps it
    parameters: int  # parameters of the online network
    copies_per_parameter: int  # float32 copies kept per parameter during training

    @property
    def buffer_bytes(self) -> int:
        return self.transitions * self.transition_bytes

    @property
    def network_bytes(self) -> int:
        return self.parameters * 4 * self.copies_per_parameter

    @property
    def total_bytes(self) -> int:
        return self.buffer_bytes + self.network_bytes


def memory_need(
    env: EnvBase,
    transitions: int,
    make_actor: Callable[[str], torch.nn.Module],
    amsgrad: bool = True,
    frames_stored_once: bool = False,
) -> MemoryNeed:
    """The lower bound of what the buffer and networks take; ``make_actor(device)`` builds the
    actor, here on PyTorch's ``meta`` device (shapes only, nothing allocated).

    ``frames_stored_once`` (``buffer.storage=frames``): a transition's two pixel stacks
    ``[k, H, W]`` take ``2 k`` slots of 8 bytes and one frame of the pool, whose first
    capacity (:func:`~trl_cartpole.storage.frames.pool_capacity`) is counted."""
    step = env.fake_tensordict()  # [*env.batch_size]: one step of each env, with "next"
    envs = max(step.batch_size.numel(), 1)
    per_transition = step.bytes() // envs
    if frames_stored_once:
        stacks = [step.get(key) for key in (PIXELS_KEY, ("next", PIXELS_KEY))]
        per_transition -= sum(stack.numel() * stack.element_size() for stack in stacks) // envs
        depth, height, width = stacks[0].shape[-3:]
        pool_frames = pool_capacity(transitions) * height * width
        per_transition += 2 * depth * 8 + -(-pool_frames // max(transitions, 1))
    with torch.device("meta"):
        actor = make_actor("meta")
    parameters = sum(parameter.numel() for parameter in actor.parameters())
    return MemoryNeed(transitions, per_transition, parameters, 6 if amsgrad else 5)


def available_memory_bytes(meminfo: Path = Path("/proc/meminfo")) -> int | None:
    """The kernel's estimate of memory available to a new process (``MemAvailable``), or None
    where there is no ``/proc/meminfo``."""
    try:
        for line in meminfo.read_text().splitlines():
            if line.startswith("MemAvailable:"):
                return int(line.split()[1]) * 1024  # kB
    except OSError:
        return None
    return None


def check_fits_in_memory(
    need: MemoryNeed, available: int | None, buffer_in_memory: bool = True
) -> None:
    """Raise a one-line ConfigError if ``need`` is more than the ``available`` bytes (without
    the buffer where it lives in files: ``buffer_in_memory=False``)."""
    total = need.total_bytes if buffer_in_memory else need.network_bytes
    if available is None or total <= available:
        return
    buffer = (
        f"the replay buffer {need.buffer_bytes / GIB:.1f} GiB (buffer.max_size="
        f"{need.transitions} x {need.transition_bytes} bytes), "
        if buffer_in_memory
        else ""
    )
    raise ConfigError(
        f"the run needs at least {total / GIB:.1f} GiB of memory and "
        f"{available / GIB:.1f} GiB is available: {buffer}the networks "
        f"{need.network_bytes / GIB:.1f} GiB ({need.parameters} parameters, with their target, "
        "gradients and optimizer state); lower "
        + ("buffer.max_size, set buffer.storage=memmap, or lower " if buffer_in_memory else "")
        + "network.num_cells"
    )


def disk_bytes_under(directory: Path) -> int:
    """Bytes the files under ``directory`` take on disk (their allocated blocks: a sparse
    file takes only what was written)."""
    if not directory.is_dir():
        return 0
    return sum(path.lstat().st_blocks * 512 for path in directory.rglob("*") if path.is_file())


def check_buffer_fits_on_disk(need: MemoryNeed, directory: Path, free: int) -> None:
    """Raise a one-line ConfigError if a memory-mapped buffer's files in ``directory`` cannot
    grow to their size in ``free`` bytes (what a stopped run left there counts as held): the
    files are sparse, and a write to a full disk through a memory map is a ``SIGBUS`` that
    kills the process, not an error (docs/reliability.md)."""
    if need.buffer_bytes - disk_bytes_under(directory) <= free:
        return
    raise ConfigError(
        f"buffer.storage=memmap needs {need.buffer_bytes / GIB:.1f} GiB for its files in "
        f"{directory} and {free / GIB:.1f} GiB is free there; lower buffer.max_size, free space on "
        "that disk, or choose another run_dir"
    )

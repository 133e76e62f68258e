"""Replay buffer factory: uniform or prioritized sampling, optionally over n-step transitions.

- Uniform: ``TensorDictReplayBuffer`` over a ``LazyTensorStorage`` with a ``RandomSampler``.
- Prioritized (Schaul et al. 2016, proportional variant): ``TensorDictPrioritizedReplayBuffer``
  samples i with P(i) = p_i / sum_k p_k, p_i = (td_error_i + eps) ** alpha (TorchRL's rule;
  ``DQNLoss``'s td_error is delta ** 2), and writes the
  importance weights w_i = (N P(i)) ** -beta / max_k w_k to ``"priority_weight"``, which
  ``DQNLoss`` and ``DistributionalDQNLoss`` apply. New transitions get the largest priority seen.
- n-step (Sutton 1988; Hessel et al. 2018): TorchRL's ``MultiStepTransform`` (through
  :class:`NStepTransform`) turns each stored transition into (s_t, a_t, R_t^(n), s_{t+k}),
  R_t^(n) = sum_{j<k} gamma^j r_{t+j}, k = min(n, steps to the episode's end);
  ``steps_to_next_obs`` = k makes the TD target bootstrap with gamma ** k.
  ``("next", "terminated")`` is taken from step t+k-1, so a window that ends in a termination
  does not bootstrap and one that ends in a truncation does. A window ends where its
  trajectory does, however the data is handed over (:func:`trajectory_ends`). ``fast=true``
  builds the same windows on the batch's tensors (:mod:`trl_cartpole.fast.n_step`).
"""

from __future__ import annotations

import warnings
from collections.abc import Iterator
from typing import Any

import torch
from tensordict import TensorDictBase
from torchrl.data import (
    LazyTensorStorage,
    ReplayBuffer,
    TensorDictPrioritizedReplayBuffer,
    TensorDictReplayBuffer,
)
from torchrl.data.replay_buffers import PrioritizedSampler, RandomSampler, Sampler, Storage
from torchrl.envs import Compose, MultiStepTransform, Transform

from trl_cartpole.compat import (
    cuda_segment_trees_available,
    held_steps,
    n_step_transform,
    set_held_steps,
)

__all__ = [
    "N_STEP_GAMMA_KEY",
    "NStepTransform",
    "annealed_beta",
    "extend_with_batch",
    "is_prioritized",
    "make_replay_buffer",
    "n_step_gamma",
    "sample_minibatches",
    "trajectory_ends",
]


# Each sample of an n-step buffer carries its discount under this key ([*B, 1], added when
# sampling, not stored; a tensor, so a stock loss takes the batch as it is), so the loss can
# check that it agrees.
N_STEP_GAMMA_KEY = "n_step_gamma"
# The entries of a step that are not its state: a step's ("next", key) equals the following
# step's key for every other entry both hold, unless a trajectory ended between them.
_NOT_STATE = {"reward", "done", "terminated", "truncated", "episode_reward"}
# The collector's trajectory ids ([*B, T], at the root only): a new id starts a trajectory.
TRAJECTORY_ID_KEY = ("collector", "traj_ids")
# Where a window must end (["next"], [*B, T, 1], set while extending and never stored).
WINDOW_END_KEY = "_window_end"


class NStepTransform(MultiStepTransform):
    """``MultiStepTransform`` whose windows end where a trajectory ends, however it is fed.

    ``MultiStepTransform`` reads the last dimension as time and ends a window only at
    ``("next", "done")``. Here a window also ends wherever the data shows that the next step
    belongs to another trajectory (:func:`trajectory_ends`): a reset, the seam between envs of
    a flattened batch (TorchRL's trainers extend with ``batch.reshape(-1)``), a second
    ``env.rollout()``. So ``[envs, T]`` as collected, the same batch flattened to
    ``[envs * T]``, and each env's ``[T]`` extended one at a time all store correct windows;
    flattened ones are cut at each seam (the rest of the window is in the next batch).

    Differences from the stock transform's output: ``("next", "terminated")`` follows the
    window's last step (it is left out of the done keys the stock transform keeps at step t),
    so a window that ends in a termination does not bootstrap and one cut short does;
    ``steps_to_next_obs`` is ``[*B, 1]`` like the reward (stock: ``[*B]``), so
    ``DistributionalDQNLoss`` broadcasts gamma ** k over the atoms (``DQNLoss`` reshapes it
    either way); a sampled batch is marked with the discount (``N_STEP_GAMMA_KEY``), which
    :func:`~trl_cartpole.parts.losses.make_dqn_loss` checks.
    """

    def __init__(self, n_steps: int, gamma: float) -> None:
        super().__init__(
            n_steps,
            gamma,
            done_key=WINDOW_END_KEY,
            done_keys=["done", "truncated", WINDOW_END_KEY],
        )

    def _inv_call(self, tensordict: TensorDictBase) -> TensorDictBase | None:
        """The windows by TorchRL's own ``MultiStepTransform._inv_call``, given the ends."""
        if not tensordict.batch_dims:
            raise ValueError("an n-step buffer extends with a batch [T] or [envs, T] in time order")
        held = held_steps(self)  # [*B, n] kept back from the previous extend, or None
        joined = tensordict if held is None else torch.cat([held, tensordict], -1)
        ends = trajectory_ends(joined)  # [*B, T', 1]
        data = tensordict.clone(False)
        data.set(("next", WINDOW_END_KEY), ends[..., joined.shape[-1] - tensordict.shape[-1] :, :])
        if held is not None:
            held.set(("next", WINDOW_END_KEY), ends[..., : held.shape[-1], :])
        out = super()._inv_call(data)
        set_held_steps(self, held_steps(self).exclude(("next", WINDOW_END_KEY)))
        if out is None:
            return None
        out = out.exclude(("next", WINDOW_END_KEY))
        steps = out.get("steps_to_next_obs")  # [*B]
        out.set("steps_to_next_obs", steps.reshape(out["next", "reward"].shape))
        return out.reshape(-1)  # [N, T'] windows of a vector env -> [N * T'] transitions

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        """Mark a sampled batch ``[*B]`` with this transform's discount ``[*B, 1]``."""
        gamma = torch.full((*tensordict.batch_size, 1), float(self.gamma), dtype=torch.float64)
        tensordict.set(N_STEP_GAMMA_KEY, gamma.to(tensordict.device or "cpu"))
        return tensordict


def trajectory_ends(steps: TensorDictBase) -> torch.Tensor:
    """``[*B, T, 1]`` bool: True where step t is the last of its trajectory in ``steps``.

    ``steps`` is ``[*B, T]``, read along its last dimension. Step t ends a trajectory when its
    ``("next", "done")`` is set, or when step t + 1 does not continue it: the collector's
    trajectory id changes, or an entry held both at the root and under ``"next"`` (the
    observation, ``step_count``, ``is_init``...) is not step t's ``("next", key)``. The last
    step ends only with ``done``: what follows it is not known yet. A ``truncated`` mark
    alone does not end a trajectory (TorchRL's trainers mark every step truncated when they
    flatten a batch); a real time limit sets ``done`` too.

    :raises ValueError: when ``steps`` holds no entry both at the root and under ``"next"``,
        so where one trajectory ends and another begins cannot be told.
    """
    ends = trajectory_ends_of_leaves(
        leaves_of(steps), steps.batch_size[:-1], steps.batch_size[-1], steps.device
    )
    return ends.unsqueeze(-1)


# a TensorDict's leaves by their full key, ("observation",) or ("next", "reward")
Leaves = dict[tuple[str, ...], torch.Tensor]


def leaves_of(data: TensorDictBase) -> Leaves:
    """The leaves of ``data`` by their full key as a tuple (``("next", "reward")``)."""
    return {
        key if isinstance(key, tuple) else (key,): value
        for key, value in data.items(include_nested=True, leaves_only=True)
    }


def trajectory_ends_of_leaves(
    steps: Leaves, batch: torch.Size, length: int, device: torch.device | None
) -> torch.Tensor:
    """:func:`trajectory_ends` of the leaves of ``[*batch, length]`` steps, ``[*B, T]`` bool."""
    shape = (*batch, length)
    time_dim = len(batch)
    ends = torch.zeros(shape, dtype=torch.bool)
    if ("next", "done") in steps:
        ends |= steps["next", "done"].reshape(*shape, -1).any(-1).cpu()
    if length < 2:
        return ends
    state_keys = [
        key[1:]
        for key in steps
        if key[0] == "next" and key[1:] in steps and not (len(key) == 2 and key[1] in _NOT_STATE)
    ]
    if not state_keys:
        raise ValueError(
            "n-step replay: the batch holds no entry both at its root and under 'next' (the "
            "observation, or StepCounter's step_count), so where one trajectory ends and the "
            "next begins cannot be told; extend with batches as env.rollout() or a collector "
            "yields them"
        )
    broken = torch.zeros((*batch, length - 1), dtype=torch.bool)  # [*B, T - 1]
    if TRAJECTORY_ID_KEY in steps:
        ids = steps[TRAJECTORY_ID_KEY].reshape(*shape, -1)  # [*B, T, 1]
        broken |= (ids[..., 1:, :] != ids[..., :-1, :]).any(-1).cpu()
    for key in state_keys:
        now = steps[key].narrow(time_dim, 1, length - 1)  # step t + 1's entry
        then = steps[("next", *key)].narrow(time_dim, 0, length - 1)  # step t's ("next", entry)
        same = now == then
        if now.is_floating_point():
            same = same | (now.isnan() & then.isnan())
        broken |= ~same.reshape(*broken.shape, -1).all(-1).cpu()
    ends[..., :-1] |= broken
    return ends.to(device or "cpu")


def n_step_gamma(buffer: ReplayBuffer) -> float | None:
    """The discount of ``buffer``'s n-step transform (None for a one-step buffer)."""
    transform = n_step_transform(buffer)
    return None if transform is None else float(transform.gamma)


def is_prioritized(buffer: ReplayBuffer) -> bool:
    """Whether ``buffer`` samples with TorchRL's ``PrioritizedSampler`` (or a subclass)."""
    return isinstance(buffer.sampler, PrioritizedSampler)


def make_replay_buffer(
    *,
    storage: Storage | None = None,
    sampler: Sampler | None = None,
    batch_size: int | None = None,
    transform: Transform | None = None,
    max_size: int | None = None,
    device: str | torch.device = "cpu",
    prioritized: bool = False,
    alpha: float | None = None,
    beta: float | None = None,
    eps: float | None = None,
    n_steps: int = 1,
    gamma: float | None = None,
    **buffer_kwargs: Any,
) -> TensorDictReplayBuffer:
    """Return TorchRL's ``TensorDictReplayBuffer`` (``TensorDictPrioritizedReplayBuffer``).

    Keyword arguments only, as TorchRL's buffers. The arguments are TorchRL's, with their
    meanings, behaviour and defaults: a buffer built from TorchRL's arguments alone stores the
    one-step transitions it is given, holds 1 000 of them and samples the batch size given to
    ``sample``.

    Priorities, TorchRL's way: after ``loss(sample)``, ``buffer.update_tensordict_priority(
    sample)`` stores ``(td_error + eps) ** alpha`` for each sampled index. ``DQNLoss`` writes
    ``td_error`` = delta ** 2 (``DistributionalDQNLoss`` the cross-entropy), so alpha acts on
    delta ** 2: Schaul et al.'s exponent on |delta| is ``2 * alpha`` (their 0.6 is
    ``alpha=0.3`` here; the config's ``buffer.alpha`` is this same argument).

    With ``n_steps > 1`` give the loss the same discount:
    ``make_dqn_loss(actor, replay_buffer=buffer)``. Each ``extend`` then stores the
    transitions whose n-step window is complete; the last ``n_steps`` frames wait for the next
    ``extend``. A window ends where its trajectory does, however the data comes: ``[T]`` or
    ``[envs, T]`` as collected, a batch flattened from several envs (as TorchRL's trainers
    store it: each window is cut at the seam between two envs), a new ``env.rollout()``
    (:class:`NStepTransform`).

    Example::

        >>> from trl_cartpole import make_replay_buffer
        >>> buffer = make_replay_buffer(max_size=10_000, batch_size=64)
        >>> type(buffer).__name__, buffer.batch_size
        ('TensorDictReplayBuffer', 64)

    :param storage: Default ``LazyTensorStorage(max_size, device=device)`` (TorchRL:
        ``ListStorage(1_000)``); it allocates on the first ``extend`` from the batch's layout,
        so it serves any env.
    :param sampler: Default ``RandomSampler()``, uniform with replacement, as TorchRL. Your
        own sampler (a ``PrioritizedSampler`` included) is used as given; refused with
        ``prioritized=True``, which brings its own.
    :param batch_size: Default None, as TorchRL: given to ``sample``.
    :param transform: yours, as given (TorchRL: none); with ``n_steps > 1`` it follows
        ``NStepTransform`` in the ``Compose`` and sees each extended batch before it.
    :param max_size: the default storage's capacity. Default 1 000, the capacity of TorchRL's
        default storage.
    :param device: ``LazyTensorStorage``'s, for the default storage. Default ``"cpu"``.
    :param prioritized: ``True``: ``TensorDictPrioritizedReplayBuffer`` (Schaul et al. 2016,
        proportional), TorchRL's ``PrioritizedSampler`` with ``alpha``, ``beta`` and ``eps``.
        Default False.
    :param alpha: the priority exponent, ``PrioritizedSampler``'s: required with
        ``prioritized=True``, as there; refused without it, as TorchRL's
        plain buffer refuses it.
    :param beta: the importance-sampling exponent, ``PrioritizedSampler``'s: required with
        ``prioritized=True``; refused without it.
    :param eps: added to ``td_error`` before the exponent, ``PrioritizedSampler``'s. Default
        1e-8, as there; refused without ``prioritized=True``.
    :param n_steps: this project's; default 1: one-step transitions, as TorchRL. With
        ``n_steps > 1`` the buffer's transform is ``Compose(NStepTransform(n_steps, gamma),
        transform)``, TorchRL's ``MultiStepTransform`` storing R_t^(n) = sum_{j<k} gamma^j
        r_{t+j} (Sutton 1988).
    :param gamma: the n-step discount. Default 0.99, the discount of a ``DQNLoss`` left to its
        defaults; refused without ``n_steps > 1``.
    :param buffer_kwargs: go to the buffer's constructor (``prefetch``, ``pin_memory``,
        ``priority_key``, ...). ``sampler_device`` (the priority trees' device, with
        ``prioritized=True``): default ``None``, TorchRL's, where the installed TorchRL has CUDA
        trees; else ``"cpu"``, the trees TorchRL documents for that case (its 0.14.1 PyPI wheel
        has none, and raises at the first sample from a CUDA storage instead).
    :returns: TorchRL's ``TensorDictReplayBuffer``, or ``TensorDictPrioritizedReplayBuffer``
        with ``prioritized=True``.
    :raises ValueError: when ``sampler`` is given with ``prioritized=True``, ``alpha``,
        ``beta`` or ``eps`` without it, or ``gamma`` without ``n_steps > 1``.
    :raises TypeError: with ``prioritized=True`` but no ``alpha`` or ``beta``.
    """
    _check_n_steps(n_steps, gamma)
    if storage is None:
        storage = LazyTensorStorage(1_000 if max_size is None else max_size, device=device)
    elif max_size is not None:
        raise ValueError(
            "max_size sizes the default storage; with storage= given, size that storage instead"
        )
    n_step = NStepTransform(n_steps, 0.99 if gamma is None else gamma) if n_steps > 1 else None
    transforms = [t for t in (n_step, transform) if t is not None]
    combined = Compose(*transforms) if n_step is not None else transform
    if prioritized:
        if sampler is not None:
            raise ValueError(
                "prioritized=True brings its own PrioritizedSampler; pass sampler= or "
                "prioritized=True, not both"
            )
        if alpha is None or beta is None:
            raise TypeError(
                "prioritized=True needs alpha= and beta= (TorchRL's PrioritizedSampler "
                "requires them): Schaul et al.'s alpha=0.3 here (on delta ** 2), beta=0.4"
            )
        if buffer_kwargs.get("sampler_device") is None and not cuda_segment_trees_available():
            # TorchRL's documented default for a CUDA storage on a build without CUDA trees
            buffer_kwargs["sampler_device"] = "cpu"
        return TensorDictPrioritizedReplayBuffer(
            alpha=alpha,
            beta=beta,
            eps=1e-8 if eps is None else eps,
            storage=storage,
            batch_size=batch_size,
            transform=combined,
            **buffer_kwargs,
        )
    _refuse_sampler_arguments(alpha=alpha, beta=beta, eps=eps)
    return TensorDictReplayBuffer(
        storage=storage,
        sampler=RandomSampler() if sampler is None else sampler,
        batch_size=batch_size,
        transform=combined,
        **buffer_kwargs,
    )


def _check_n_steps(n_steps: int, gamma: float | None) -> None:
    if n_steps < 1:
        raise ValueError(f"n_steps={n_steps} must be >= 1 (1: one-step transitions)")
    if gamma is not None and n_steps == 1:
        raise ValueError(
            f"gamma={gamma} discounts n-step returns, and n_steps=1 stores one-step "
            "transitions; pass n_steps > 1 with it, or give gamma to the loss alone"
        )


def _refuse_sampler_arguments(**arguments: float | None) -> None:
    """The prioritized sampler's arguments given to a buffer with another sampler: refused."""
    given = [name for name, value in arguments.items() if value is not None]
    if given:
        raise ValueError(
            f"{', '.join(given)}: the prioritized sampler's; pass prioritized=True with them, "
            "or your own sampler=PrioritizedSampler(...)"
        )


def annealed_beta(beta_start: float, frames: int, anneal_frames: int) -> float:
    """The importance-sampling exponent: linear from ``beta_start`` to 1 at ``anneal_frames``.

    Schaul et al. (2016, section 3.4) anneal beta to 1 by the end of learning, when unbiased
    updates matter most.
    """
    return beta_start + (1.0 - beta_start) * min(1.0, frames / anneal_frames)


def extend_with_batch(buffer: TensorDictReplayBuffer, batch: TensorDictBase) -> None:
    """Store a collected batch, ``[T]`` (one env) or ``[N, T]`` (a vector env of N envs).

    An n-step buffer's transform needs each env's steps in time order, so it gets the batch
    as collected and flattens its windows itself; any other buffer gets ``[N * T]``.
    """
    buffer.extend(batch if n_step_transform(buffer) is not None else batch.reshape(-1))


def sample_minibatches(buffer: TensorDictReplayBuffer, count: int) -> Iterator[TensorDictBase]:
    """Yield ``count`` minibatches ``[batch_size]`` for the updates after one collected batch.

    A uniform buffer (sampling with replacement) draws all ``count * batch_size`` indices in
    one call and splits them: the same distribution as ``count`` calls, for the overhead of one
    (about 0.3 ms saved per extra update, docs/results/speed.md). A prioritized buffer samples
    one minibatch at a time, since each update rewrites the priorities the next draw uses.
    """
    if count == 1 or is_prioritized(buffer):
        for _ in range(count):
            yield buffer.sample()
        return
    with warnings.catch_warnings():  # TorchRL warns that the call's batch size prevails
        warnings.simplefilter("ignore", UserWarning)
        drawn = buffer.sample(buffer.batch_size * count)  # [count * batch_size]
    yield from drawn.split(buffer.batch_size)

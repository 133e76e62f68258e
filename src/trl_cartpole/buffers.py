"""Replay buffer factory: uniform or prioritized sampling, optionally over n-step transitions.

- Uniform: ``TensorDictReplayBuffer`` over a ``LazyTensorStorage`` with a ``RandomSampler``.
- Prioritized (Schaul et al. 2016, proportional variant): ``TensorDictPrioritizedReplayBuffer``
  samples i with P(i) = p_i / sum_k p_k, p_i = (|delta_i| + eps) ** alpha, and writes the
  importance weights w_i = (N P(i)) ** -beta / max_k w_k to ``"priority_weight"``, which
  ``DQNLoss`` and ``DistributionalDQNLoss`` apply. New transitions get the largest priority seen.
- n-step (Sutton 1988; Hessel et al. 2018): TorchRL's ``MultiStepTransform`` (through
  :class:`NStepTransform`) turns each stored transition into (s_t, a_t, R_t^(n), s_{t+k}),
  R_t^(n) = sum_{j<k} gamma^j r_{t+j}, k = min(n, steps to the episode's end);
  ``steps_to_next_obs`` = k makes the TD target bootstrap with gamma ** k.
  ``("next", "terminated")`` is taken from step t+k-1, so a window that ends in a termination
  does not bootstrap and one that ends in a truncation does.
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
from torchrl.data.replay_buffers import RandomSampler, Sampler, Storage
from torchrl.envs import Compose, MultiStepTransform, Transform

from trl_cartpole.compat import install_segment_trees_if_missing, replay_transform
from trl_cartpole.config import LossConfig

__all__ = [
    "N_STEP_GAMMA_KEY",
    "NStepTransform",
    "annealed_beta",
    "extend_with_batch",
    "make_replay_buffer",
    "n_step_gamma",
    "sample_minibatches",
]


# The default config's loss.gamma: the discount of both the n-step buffer and the loss.
DEFAULT_GAMMA = LossConfig.gamma
# Each sample of an n-step buffer carries its discount under this key ([*B, 1], added when
# sampling, not stored), so a loss built apart from the buffer can check that it agrees.
N_STEP_GAMMA_KEY = "n_step_gamma"


class NStepTransform(MultiStepTransform):
    """``MultiStepTransform`` whose output fits both DQN losses.

    ``("next", "terminated")`` follows the window's last step (it is left out of the done
    keys the transform keeps at step t), and ``steps_to_next_obs`` is shaped ``[*B, 1]`` like
    the reward, so ``DistributionalDQNLoss`` broadcasts gamma ** k over the atoms (TorchRL
    writes it ``[*B]``; ``DQNLoss`` reshapes it either way). A sampled batch is marked with the
    discount (``N_STEP_GAMMA_KEY``), which :func:`~trl_cartpole.losses.make_dqn_loss` checks.
    """

    def __init__(self, n_steps: int, gamma: float) -> None:
        super().__init__(n_steps, gamma, done_keys=["done", "truncated"])

    def _inv_call(self, tensordict: TensorDictBase) -> TensorDictBase | None:
        out = super()._inv_call(tensordict)
        if out is not None:
            steps = out.get("steps_to_next_obs")  # [*B]
            out.set("steps_to_next_obs", steps.reshape(out["next", "reward"].shape))
            out = out.reshape(-1)  # [N, T'] windows of a vector env -> [N * T'] transitions
        return out

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        """Mark a sampled batch ``[*B]`` with this transform's discount ``[*B, 1]``."""
        gamma = torch.full((*tensordict.batch_size, 1), float(self.gamma), dtype=torch.float64)
        tensordict.set(N_STEP_GAMMA_KEY, gamma.to(tensordict.device or "cpu"))
        return tensordict


def n_step_gamma(buffer: ReplayBuffer) -> float | None:
    """The discount of ``buffer``'s n-step transform (None for a one-step buffer)."""
    transform = replay_transform(buffer)
    if transform is None:
        return None
    steps = [t for t in transform if isinstance(t, MultiStepTransform)]
    return float(steps[0].gamma) if steps else None


def make_replay_buffer(
    *,
    storage: Storage | None = None,
    sampler: Sampler | None = None,
    batch_size: int = 512,
    transform: Transform | None = None,
    max_size: int = 50_000,
    device: str | torch.device = "cpu",
    prioritized: bool = False,
    alpha: float = 0.6,
    beta: float = 0.4,
    eps: float = 1e-6,
    n_steps: int = 3,
    gamma: float = DEFAULT_GAMMA,
    **buffer_kwargs: Any,
) -> TensorDictReplayBuffer:
    """Return TorchRL's ``TensorDictReplayBuffer`` (``TensorDictPrioritizedReplayBuffer``).

    The arguments are TorchRL's, with their meanings; ``buffer_kwargs`` go to the buffer's
    constructor (``prefetch``, ``pin_memory``, ``priority_key``, ...). Defaults, ours beside
    TorchRL's:

    - ``storage``: ``LazyTensorStorage(max_size, device=device)`` (TorchRL: ``ListStorage``);
      it allocates on the first ``extend`` from the batch's layout, so it serves any env.
      ``max_size`` (50 000) and ``device`` ("cpu") are ``LazyTensorStorage``'s.
    - ``sampler``: ``RandomSampler()``, uniform with replacement, as TorchRL and its DQN
      example. With ``prioritized`` the buffer is ``TensorDictPrioritizedReplayBuffer``
      (Schaul et al. 2016, proportional) with TorchRL's ``alpha``, ``beta`` and ``eps``
      (0.6, 0.4, 1e-6; TorchRL requires alpha and beta and defaults eps to 1e-8); it brings its
      own sampler, so ``sampler`` is refused with it.
    - ``batch_size``: 512 (TorchRL: None, given at ``sample``).
    - ``transform``: none of its own. ``n_steps > 1`` (3 by default; TorchRL has no n-step
      default) prepends TorchRL's ``MultiStepTransform(n_steps, gamma)`` as
      :class:`NStepTransform`: R_t^(n) = sum_{j<k} gamma^j r_{t+j} (Sutton 1988), with the
      default config's ``gamma`` (0.995). ``n_steps=1`` stores one-step transitions.

    Give the loss the same discount: ``make_dqn_loss(actor, replay_buffer=buffer)``.

    With ``prioritized``, update the priorities after each gradient step with
    ``buffer.update_priority(batch["index"], priority)``. With ``n_steps > 1`` each ``extend``
    stores the transitions whose n-step window is complete (extend with ``[T]`` or ``[envs, T]``
    in time order); the last ``n_steps`` frames wait for the next ``extend``.

    Example::

        >>> from trl_cartpole import make_replay_buffer
        >>> buffer = make_replay_buffer(max_size=10_000, batch_size=64, n_steps=1)
        >>> type(buffer).__name__, buffer.batch_size
        ('TensorDictReplayBuffer', 64)
    """
    storage = LazyTensorStorage(max_size, device=device) if storage is None else storage
    n_step = NStepTransform(n_steps, gamma) if n_steps > 1 else None
    transforms = [t for t in (n_step, transform) if t is not None]
    combined = Compose(*transforms) if transforms else None
    if prioritized:
        if sampler is not None:
            raise ValueError(
                "prioritized=True brings its own PrioritizedSampler; pass sampler= or "
                "prioritized=True, not both"
            )
        install_segment_trees_if_missing()
        return TensorDictPrioritizedReplayBuffer(
            alpha=alpha,
            beta=beta,
            eps=eps,
            storage=storage,
            batch_size=batch_size,
            transform=combined,
            **buffer_kwargs,
        )
    return TensorDictReplayBuffer(
        storage=storage,
        sampler=RandomSampler() if sampler is None else sampler,
        batch_size=batch_size,
        transform=combined,
        **buffer_kwargs,
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
    buffer.extend(batch if replay_transform(buffer) is not None else batch.reshape(-1))


def sample_minibatches(buffer: TensorDictReplayBuffer, count: int) -> Iterator[TensorDictBase]:
    """Yield ``count`` minibatches ``[batch_size]`` for the updates after one collected batch.

    A uniform buffer (sampling with replacement) draws all ``count * batch_size`` indices in
    one call and splits them: the same distribution as ``count`` calls, for the overhead of one
    (about 0.3 ms saved per extra update, docs/performance.md). A prioritized buffer samples
    one minibatch at a time, since each update rewrites the priorities the next draw uses.
    """
    if count == 1 or isinstance(buffer, TensorDictPrioritizedReplayBuffer):
        for _ in range(count):
            yield buffer.sample()
        return
    with warnings.catch_warnings():  # TorchRL warns that the call's batch size prevails
        warnings.simplefilter("ignore", UserWarning)
        drawn = buffer.sample(buffer.batch_size * count)  # [count * batch_size]
    yield from drawn.split(buffer.batch_size)

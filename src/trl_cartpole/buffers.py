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

from tensordict import TensorDictBase
from torchrl.data import (
    LazyTensorStorage,
    TensorDictPrioritizedReplayBuffer,
    TensorDictReplayBuffer,
)
from torchrl.data.replay_buffers import RandomSampler
from torchrl.envs import MultiStepTransform

from trl_cartpole.compat import install_segment_trees_if_missing, replay_transform

__all__ = [
    "NStepTransform",
    "annealed_beta",
    "extend_with_batch",
    "make_replay_buffer",
    "sample_minibatches",
]


class NStepTransform(MultiStepTransform):
    """``MultiStepTransform`` whose output fits both DQN losses.

    ``("next", "terminated")`` follows the window's last step (it is left out of the done
    keys the transform keeps at step t), and ``steps_to_next_obs`` is shaped ``[*B, 1]`` like
    the reward, so ``DistributionalDQNLoss`` broadcasts gamma ** k over the atoms (TorchRL
    writes it ``[*B]``; ``DQNLoss`` reshapes it either way).
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


def make_replay_buffer(
    max_size: int = 50_000,
    batch_size: int = 512,
    device: str = "cpu",
    *,
    prioritized: bool = False,
    alpha: float = 0.6,
    beta: float = 0.4,
    eps: float = 1e-6,
    n_steps: int = 3,
    gamma: float = 0.995,
    **buffer_kwargs: Any,
) -> TensorDictReplayBuffer:
    """Return a replay buffer of capacity ``max_size`` sampling ``batch_size`` transitions.

    The defaults are the default config's (``buffer`` section; ``gamma`` is ``loss.gamma``).
    The names are TorchRL's: ``max_size`` of ``LazyTensorStorage``; ``alpha``, ``beta`` and
    ``eps`` of ``TensorDictPrioritizedReplayBuffer``; ``n_steps`` and ``gamma`` of
    ``MultiStepTransform``. ``buffer_kwargs`` go to the buffer's constructor
    (``prefetch``, ...).

    The storage allocates lazily on the first ``extend`` from the collected batch's layout, so
    the same factory serves any env. Uniform sampling is with replacement (``RandomSampler``),
    as TorchRL's DQN example does. With ``prioritized``, update the priorities after each
    gradient step with ``buffer.update_priority(batch["index"], priority)``. With
    ``n_steps > 1`` each ``extend`` stores the transitions whose n-step window is complete; the
    last ``n_steps`` frames wait for the next ``extend``.
    """
    storage = LazyTensorStorage(max_size, device=device)
    transform = NStepTransform(n_steps, gamma) if n_steps > 1 else None
    if prioritized:
        install_segment_trees_if_missing()
        return TensorDictPrioritizedReplayBuffer(
            alpha=alpha,
            beta=beta,
            eps=eps,
            storage=storage,
            batch_size=batch_size,
            transform=transform,
            **buffer_kwargs,
        )
    return TensorDictReplayBuffer(
        storage=storage,
        sampler=RandomSampler(),
        batch_size=batch_size,
        transform=transform,
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

"""``MultiStepTransform``'s n-step windows computed on a batch's tensors, not its TensorDicts.

Measured gain (docs/results/speed.md): the store phase of a default CartPole run in about 0.6 of
the stock transform's time.

TorchRL's ``MultiStepTransform`` (through :class:`~trl_cartpole.parts.replay.NStepTransform`)
builds each stored transition (s_t, a_t, R_t^(n), s_{t+k}), R_t^(n) = sum_{j<k} gamma^j
r_{t+j}, k = min(n, steps to the window's end) (Sutton 1988), with about 60 TensorDict
operations per extend: concatenations, clones, exclusions, a gather, renames. On a batch of 32
CartPole envs that bookkeeping is most of the store phase. Here the same windows are built with
one ``torch`` call per entry and TorchRL's own reward sum (``_get_reward``, the same
convolution), so every stored number is bitwise the stock transform's (tested against it), and
the steps held back for the next extend are the same views.

Entries are handled by their place, as ``MultiStepTransform`` handles them: the root entries
(observation, action...) are step t's; under ``"next"`` the done entries the transform is given
stay step t's, the reward becomes R_t^(n) (step t's own kept as ``"original_reward"``) and the
rest (the next observation, ``terminated``) are read at step t + k - 1. Added:
``steps_to_next_obs`` = k, ``gamma`` = gamma ** k and ``nonterminal`` = k > 1.
"""

from __future__ import annotations

from collections.abc import Collection, Mapping

import torch
from tensordict import TensorDict, TensorDictBase

from trl_cartpole.compat import held_steps, n_step_returns, n_step_transform, set_held_steps
from trl_cartpole.parts.replay import (
    WINDOW_END_KEY,
    Leaves,
    NStepTransform,
    leaves_of,
    trajectory_ends_of_leaves,
)

__all__ = ["WindowedNStepTransform", "n_step_windows", "tensordict_of", "use_windowed_n_steps"]


class WindowedNStepTransform(NStepTransform):
    """:class:`NStepTransform` whose windows are built by :func:`n_step_windows`; an extend it
    does not cover (another reward key, a mask entry, nested done keys) takes the stock path."""

    def _inv_call(self, tensordict: TensorDictBase) -> TensorDictBase | None:
        held = held_steps(self)  # [*B, n] kept back from the previous extend, or None
        new = leaves_of(tensordict)
        old = None if held is None else leaves_of(held)
        if not tensordict.batch_dims or not self._windows_apply(new, old):
            return super()._inv_call(tensordict)
        time_dim = tensordict.batch_dims - 1
        steps = new
        if old is not None:  # [*B, n + T]
            steps = {key: torch.cat([old[key], value], time_dim) for key, value in new.items()}
        length = next(iter(steps.values())).shape[time_dim]
        batch = tensordict.batch_size[:-1]
        ends = trajectory_ends_of_leaves(steps, batch, length, tensordict.device)
        keep = min(self.n_steps, length)
        kept = {key: value.narrow(time_dim, length - keep, keep) for key, value in steps.items()}
        set_held_steps(self, tensordict_of(kept, (*batch, keep), tensordict.device))
        if length <= self.n_steps:
            return None
        done_keys = [key for key in self.done_keys if key != WINDOW_END_KEY]
        windows = n_step_windows(
            steps, tensordict.batch_dims, ends, self.n_steps, self.gamma, done_keys
        )
        size = batch.numel() * (length - self.n_steps)
        return tensordict_of(windows, (size,), tensordict.device)

    def _windows_apply(self, new: Leaves, held: Leaves | None) -> bool:
        """Whether :func:`n_step_windows` covers this extend: the reward at ``("next",
        "reward")`` only, no mask entry, done entries held directly under ``"next"``, and the
        same entries as the held-back steps."""
        return (
            list(self.reward_keys) == ["reward"]
            and ("next", "reward") in new
            and all(isinstance(key, str) for key in self.done_keys)
            and (self.mask_key if isinstance(self.mask_key, tuple) else (self.mask_key,)) not in new
            and (held is None or held.keys() == new.keys())
        )


def use_windowed_n_steps(buffer) -> None:
    """Make ``buffer``'s :class:`NStepTransform` (if any) a :class:`WindowedNStepTransform`:
    the same object and state, its windows built on tensors from the next extend on."""
    transform = n_step_transform(buffer)
    if type(transform) is NStepTransform:
        transform.__class__ = WindowedNStepTransform


def tensordict_of(leaves: Mapping[tuple[str, ...], torch.Tensor], batch_size, device):
    """A TensorDict of ``leaves`` (full keys as tuples) with this batch size and device."""
    nested: dict = {}
    for key, value in leaves.items():
        level = nested
        for part in key[:-1]:
            level = level.setdefault(part, {})
        level[key[-1]] = value
    return TensorDict(nested, batch_size=batch_size, device=device)


def n_step_windows(
    steps: Leaves,
    batch_dims: int,
    window_ends: torch.Tensor,
    n_steps: int,
    gamma: float,
    kept_done_keys: Collection[str],
) -> Leaves:
    """The transitions of the first ``T - n_steps`` steps of ``steps``, flattened to ``[N]``.

    :param steps: the leaves of ``[*B, T]`` steps in time order along dim ``batch_dims - 1``
        (the held-back steps and the new ones, joined).
    :param batch_dims: the number of batch dimensions of ``steps`` (``len(B) + 1``).
    :param window_ends: ``[*B, T]`` bool, True where a window must end after step t.
    :param n_steps: n, the window's length.
    :param gamma: the discount.
    :param kept_done_keys: the entries under ``"next"`` kept at step t (the transform's
        ``done_keys``), not read at the window's last step.
    :returns: the leaves of the ``[N]`` transitions, N = prod(B) * (T - n_steps), in the
        order ``MultiStepTransform`` followed by ``reshape(-1)`` gives them.
    """
    time_dim = batch_dims - 1
    reward = steps["next", "reward"]  # [*B, T, 1]
    length = reward.shape[time_dim]
    kept = length - n_steps
    # TorchRL's sum: R [*B, T, 1] and k - 1 [*B, T] (0 where the window ends at t)
    summed, time_to_obs = n_step_returns(gamma, reward, window_ends, n_steps)
    steps_now = torch.arange(length, dtype=time_to_obs.dtype, device=time_to_obs.device)
    last = steps_now.expand_as(time_to_obs) + time_to_obs  # [*B, T]: the window's last step
    window_length = time_to_obs + 1  # k [*B, T]
    window = {  # [*B, T] entries the stock transform adds
        ("steps_to_next_obs",): window_length,
        ("gamma",): gamma**window_length,
        ("nonterminal",): time_to_obs != 0,
    }
    out: Leaves = {}
    for key, value in steps.items():
        if key[0] != "next" or key[1] in kept_done_keys:
            out[key] = value
        elif key == ("next", "reward"):
            out["next", "original_reward"] = value
            out[key] = summed
        else:  # read at the window's last step
            index = last.reshape(*last.shape, *(1,) * (value.ndim - batch_dims))
            out[key] = torch.gather(value, time_dim, index.expand_as(value))
    out.update(window)
    first = {key: value.narrow(time_dim, 0, kept) for key, value in out.items()}
    steps_shape = first["next", "reward"].shape  # [*B, T - n, 1]: k shaped as the reward
    first["steps_to_next_obs",] = first["steps_to_next_obs",].reshape(steps_shape)
    return {
        key: value.reshape(-1, *value.shape[batch_dims:]) for key, value in first.items()
    }  # [N, *feature]

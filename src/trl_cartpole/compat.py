"""Every private TorchRL name this project reads, and every stand-in for a TorchRL part.

TorchRL's private attributes can move between releases without notice. Reading them only here
means one file to fix when one moves, and ``tests/test_compat.py`` has a test per name that fails
on a TorchRL version where it moved. Written against torchrl 0.14.1.

Private names read (each through one function below), TorchRL's first:

- ``Collector._carrier``: the in-process collector's last observation and running counters
  (the env's mid-episode step), saved for an exact resume; a multi-process collector's
  workers' carriers are read and written by that name through its ``get_distant_attr`` and
  ``map_fn`` (tested with worker processes in tests/test_worker_state.py);
- ``RayCollector._sync``: whether a Ray collector asks every actor for a batch and waits for all
  (its actors then idle between batches, when a checkpoint reads them);
- ``VecGymEnvTransform._memo``: the last step of a Gymnasium vector env's same-step autoreset,
  which decides what the next ``reset()`` returns;
- ``ReplayBuffer._transform`` and ``MultiStepTransform._buffer``: the n-step window the
  transform holds back until it is complete;
- ``torchrl.data.postprocs.postprocs._get_reward``: ``MultiStepTransform``'s discounted sum of
  a window's rewards, which the n-step windows built on tensors call so that their returns
  are the transform's, bit for bit (:func:`n_step_returns`);
- ``GymWrapper._env``: the Gymnasium env behind the wrapper (rendering, pickling its state);
- ale-py's ``AtariEnv._action_set``: the game's actions, by the index the agent picks (a
  restored game is given its last action again: :mod:`trl_cartpole.store.env_state`);
- ``BaseCollector._weight_sync_schemes``: the shared-memory weight-sync schemes a multi-process
  collector's ``shutdown()`` leaves open (the process hung at exit);
- ``QValueModule.action_func_mapping``: the rule that turns action values into a one-hot action;
- ``EnvBase._step`` / ``_reset`` of a transform's parent: the game stepped inside one of its
  transforms (NOOP starts, frame skip, FIRE), as TorchRL's own ``FrameSkipTransform`` does;
  ``torchrl.envs.transforms.utils._set_missing_tolerance``, which lets such a transform see
  the step it is called inside;
- ``TensorStorage._storage`` / ``_init`` / ``_len``: a storage's tensors, allocated from a row
  and its fill set, for the storages that write their own checkpoints; ``ReplayBuffer._writer``
  ``_cursor`` and ``Storage._last_cursor`` / ``_set_last_cursor``: the row of the last write,
  which TorchRL's storage checkpointers do not restore;
- ``nn.Module._forward_hooks`` / ``_forward_pre_hooks``: the hooks a fused loss must run as
  ``loss(sample)`` does; ``Tensor._version``: whether a tensor was written in place;
- ``torch.ops.mkldnn._is_mkldnn_bf16_supported``: whether oneDNN computes bfloat16 on this CPU
  (AVX-512 BF16 or AMX; ``ONEDNN_MAX_CPU_ISA`` lowers it), where it is otherwise emulated;
- ``torchrl.data.replay_buffers.samplers.prioritized.CudaSumSegmentTreeFp32`` (and its Min and
  Fp64 siblings): ``None`` where
  the installed TorchRL has no CUDA priority trees (PyPI's 0.14.1 wheel), so that a prioritized
  buffer over a CUDA storage is given CPU trees (:func:`cuda_segment_trees_available`).

Other libraries' private names: Gymnasium's ``Env._np_random`` (an env's generator, None
until seeded, which the public ``np_random`` would create); Ray's ``ActorHandle._actor_id``
and ``ray._raylet``'s settings (re-read after the run sets its token); Python's
``threading._shutdown`` and ``atexit._run_exitfuncs``, the first steps of the interpreter's
exit (:func:`run_exit_steps`).

Stand-ins for TorchRL parts:

- :class:`TensorSumSegmentTree` / :class:`TensorMinSegmentTree`: pure-torch segment trees for
  the prioritized sampler where TorchRL's C++ extension does not load (the torchrl 0.14.1
  wheel's extension does not load against the CPU build of torch 2.13.0, an undefined C++
  symbol, which leaves ``SumSegmentTreeFp32`` and friends ``None``). They keep the priorities in
  one flat tensor: a query is a ``sum``/``min`` over a slice and ``scan_lower_bound`` a
  ``cumsum`` plus ``searchsorted``, O(capacity) instead of O(log capacity), about 0.1 ms for a
  50 000-entry buffer, small next to one gradient step;
- :func:`use_first_greedy_action`: a one-hot greedy rule that picks the first maximum on ties.
"""

from __future__ import annotations

import sys
from collections.abc import Callable
from functools import partial
from typing import Any

import numpy as np
import torch
from tensordict import TensorDictBase
from torch import nn
from torchrl.collectors import BaseCollector
from torchrl.data import ReplayBuffer
from torchrl.data.postprocs.postprocs import _get_reward
from torchrl.envs import Compose, EnvBase, MultiStepTransform
from torchrl.envs.transforms import VecGymEnvTransform
from torchrl.envs.transforms.utils import _set_missing_tolerance as set_missing_tolerance

__all__ = [
    "TensorMinSegmentTree",
    "TensorSumSegmentTree",
    "allocate_storage",
    "autoreset_state",
    "carrier_of",
    "close_weight_sync_schemes",
    "cpu_computes_bfloat16",
    "cuda_segment_trees_available",
    "forward_hooks_set",
    "forward_pre_hooks",
    "greedy_action_rule",
    "greedy_value_rule",
    "gym_env",
    "gym_generator",
    "held_steps",
    "install_segment_trees_if_missing",
    "loss_mask_keys",
    "n_step_returns",
    "n_step_transform",
    "parent_reset",
    "parent_step",
    "ray_actor_id",
    "reload_ray_settings",
    "restore_last_written_row",
    "run_exit_steps",
    "serial_envs",
    "set_autoreset_state",
    "set_gym_env",
    "set_held_steps",
    "set_missing_tolerance",
    "set_storage_length",
    "set_worker_carriers",
    "storage_tensors",
    "tensor_version",
    "use_first_greedy_action",
    "worker_carriers",
]


# --- the in-process collector's carrier ------------------------------------------------------


def carrier_of(collector: BaseCollector) -> TensorDictBase:
    """The tensordict a single-process ``Collector`` steps from next (updated in place)."""
    return collector._carrier


def worker_carriers(collector: BaseCollector) -> list[TensorDictBase]:
    """Each worker's carrier of a multi-process collector, copied through its pipe (the
    collector's ``get_distant_attr``, read while the workers wait between batches)."""
    return collector.get_distant_attr("_carrier")


def set_worker_carriers(collector: BaseCollector, carriers: list[TensorDictBase]) -> None:
    """Update each worker's carrier in place from ``carriers`` (the collector's ``map_fn``)."""
    collector.map_fn("_carrier.update", [(carrier,) for carrier in carriers])


def is_synchronous_ray_collector(collector: BaseCollector) -> bool:
    """Whether ``collector`` is TorchRL's ``RayCollector`` in its synchronous mode: each batch
    asks every actor for its part and waits for all, so the actors idle between batches."""
    if "ray" not in sys.modules:  # a RayCollector has imported Ray; no need to import it here
        return False
    from torchrl.collectors.distributed import RayCollector

    return isinstance(collector, RayCollector) and bool(collector._sync)


# --- Gymnasium envs behind TorchRL's GymWrapper ----------------------------------------------


PARTIAL_STEP_KEY = "_step"  # env.step steps only the envs marked True here (TorchRL's rollout)


def next_step_input(env: EnvBase, stepped: TensorDictBase) -> TensorDictBase:
    """What the policy reads after ``env.step``: ``env.step_mdp`` and the env's post-step-mdp
    hooks (its transforms'), as TorchRL's ``env.rollout`` makes it."""
    following = env.step_mdp(stepped)
    hooks = env._post_step_mdp_hooks
    if hooks is not None:
        _, following = hooks(stepped, following)
    return following


def gym_env(env: EnvBase) -> Any:
    """The Gymnasium env (or vector env) behind ``env``'s ``GymWrapper``."""
    return env.base_env._env


def ale_action_set(atari_env: Any) -> Any:
    """The ALE actions of ale-py's ``AtariEnv``, indexed as its ``step`` takes them."""
    return atari_env._action_set


def serial_envs(env: EnvBase) -> list[EnvBase]:
    """The envs a ``SerialEnv`` steps one after another (none before it first starts or after
    it closes). Read from the instance's own attributes: ``SerialEnv.__getattr__`` hands a
    missing name to its envs, and asks for ``_envs`` to do so (endless recursion when closed)."""
    return list(vars(env).get("_envs") or [])


def set_gym_env(env: EnvBase, gymnasium_env: Any) -> None:
    """Put ``gymnasium_env`` behind ``env``'s ``GymWrapper`` in place of its own."""
    env.base_env._env = gymnasium_env


def _vector_autoreset(env: EnvBase) -> VecGymEnvTransform | None:
    transform = getattr(env, "transform", None)
    for candidate in [] if transform is None else list(transform):
        if isinstance(candidate, VecGymEnvTransform):
            return candidate
    return None


def autoreset_state(env: EnvBase) -> Any | None:
    """The memo of TorchRL's vector-env autoreset bridge (None: ``env`` has no such bridge)."""
    transform = _vector_autoreset(env)
    return None if transform is None else transform._memo


def set_autoreset_state(env: EnvBase, memo: Any) -> bool:
    """Restore the autoreset memo of ``env``; False if ``env`` has no vector-env bridge."""
    transform = _vector_autoreset(env)
    if transform is None:
        return False
    transform._memo = memo
    return True


# --- the replay buffer's transform and the n-step window -------------------------------------


def n_step_transform(buffer: ReplayBuffer) -> MultiStepTransform | None:
    """The ``MultiStepTransform`` of ``buffer``'s transform (None for a one-step buffer)."""
    transform = buffer._transform
    parts = list(transform) if isinstance(transform, Compose) else [transform]
    steps = [t for t in parts if isinstance(t, MultiStepTransform)]
    return steps[0] if steps else None


def held_steps(transform: MultiStepTransform) -> TensorDictBase | None:
    """The last steps ``transform`` holds back from its previous ``extend`` (None: none yet)."""
    return transform._buffer


def set_held_steps(transform: MultiStepTransform, steps: TensorDictBase) -> None:
    """Give ``transform`` the steps it holds back for the next ``extend``."""
    transform._buffer = steps


def n_step_returns(
    gamma: float, reward: torch.Tensor, window_ends: torch.Tensor, n_steps: int
) -> tuple[torch.Tensor, torch.Tensor]:
    """``MultiStepTransform``'s window sums: ``(R [*B, T, 1], k - 1 [*B, T])``.

    R_t = sum_{j<k} gamma^j r_{t+j}, k = min(n_steps, steps to the next window end, inclusive),
    for ``reward`` ``[*B, T, 1]`` and ``window_ends`` ``[*B, T]`` bool (TorchRL's ``_get_reward``,
    whose ``max_steps`` is ``n_steps - 1``).
    """
    return _get_reward(gamma, reward, window_ends, n_steps - 1)


# --- collectors ------------------------------------------------------------------------------


def close_weight_sync_schemes(collector: BaseCollector) -> None:
    """Shut the weight-sync schemes a collector's ``shutdown()`` leaves open.

    TorchRL 0.14's multi-process shutdown stops the workers but not the shared-memory weight
    sync scheme; left to its ``__del__`` at interpreter exit, that starts a queue thread and the
    process hangs after training (seen with ``MultiSyncCollector``).
    """
    for scheme in (getattr(collector, "_weight_sync_schemes", None) or {}).values():
        scheme.shutdown()


# --- what DQNLoss reads: its loss masks, the greedy value rule -------------------------------


def loss_mask_keys(loss: nn.Module) -> list[Any]:
    """The sample entries TorchRL's losses read as masks of the positions to reduce over."""
    return list(loss._loss_mask_keys())


def greedy_action_rule(q_value: nn.Module) -> Callable[[torch.Tensor], torch.Tensor]:
    """``QValueModule``'s ``values -> greedy action`` for its action space."""
    return q_value.action_func_mapping[q_value.action_space]


def greedy_value_rule(q_value: nn.Module) -> Callable[[torch.Tensor, torch.Tensor], torch.Tensor]:
    """``QValueModule``'s ``(values, action) -> chosen value`` for its action space."""
    return q_value.action_value_func_mapping.get(
        q_value.action_space, q_value._default_action_value
    )


# --- the greedy tie-break --------------------------------------------------------------------


def use_first_greedy_action(actor: nn.Module) -> nn.Module:
    """Make the one-hot greedy action of ``actor`` pick the first maximum when values tie.

    TorchRL's Q-value modules build the one-hot action as ``value == value.max()``, which marks
    every tied action. C51 distributions that saturate on the support tie exactly, and a
    two-hot action then breaks ``DistributionalDQNLoss`` (a run crashed on it). The module's
    own categorical rule (the arg-max of the expected values) is used instead.
    """
    for module in actor.modules():
        rules = getattr(module, "action_func_mapping", None)
        if rules is not None and "one_hot" in rules:
            categorical = rules["categorical"]

            def one_hot(value: torch.Tensor, _categorical=categorical) -> torch.Tensor:
                greedy = _categorical(value)  # [*B]
                return nn.functional.one_hot(greedy, value.shape[-1]).to(torch.long)

            rules["one_hot"] = one_hot
    return actor


# --- segment trees for the prioritized sampler -----------------------------------------------


def _as_index(index: Any) -> torch.Tensor | int:
    if isinstance(index, int | np.integer):
        return int(index)
    return torch.as_tensor(index, dtype=torch.long).reshape(-1)


class _TensorSegmentTree:
    """A flat ``[capacity]`` tensor with the segment trees' item access and ``query``."""

    neutral: float

    def __init__(self, capacity: int, dtype: torch.dtype = torch.float32) -> None:
        self.capacity = capacity
        self.dtype = dtype
        self.values = torch.full((capacity,), self.neutral, dtype=self.dtype)  # [capacity]

    def __len__(self) -> int:
        return self.capacity

    def __getitem__(self, index: Any) -> torch.Tensor | float:
        index = _as_index(index)
        value = self.values[index]
        return float(value) if isinstance(index, int) else value

    def __setitem__(self, index: Any, value: Any) -> None:
        index = _as_index(index)
        self.values[index] = torch.as_tensor(value, dtype=self.dtype).reshape(-1)

    def _slice(self, left: Any, right: Any) -> torch.Tensor:
        return self.values[int(left) : int(right)]


class TensorSumSegmentTree(_TensorSegmentTree):
    """Sum over index ranges and prefix-sum search, the interface of ``SumSegmentTree``."""

    neutral = 0.0

    def query(self, left: Any, right: Any) -> float:
        """Sum of the values at ``[left, right)``."""
        return float(self._slice(left, right).sum())

    def scan_lower_bound(self, mass: Any) -> torch.Tensor:
        """For each ``mass``, the first index whose prefix sum ``values[:i + 1]`` exceeds it."""
        prefix = self.values.cumsum(0)  # [capacity]
        mass = torch.as_tensor(mass, dtype=self.dtype)
        return torch.searchsorted(prefix, mass, right=True)


class TensorMinSegmentTree(_TensorSegmentTree):
    """Minimum over index ranges, the interface of ``MinSegmentTree``."""

    neutral = float("inf")

    def query(self, left: Any, right: Any) -> float:
        """Minimum of the values at ``[left, right)`` (``inf`` when empty)."""
        values = self._slice(left, right)
        return float(values.min()) if values.numel() else self.neutral


def cuda_segment_trees_available() -> bool:
    """Whether the installed TorchRL has ``PrioritizedSampler``'s CUDA trees (PyPI's 0.14.1
    wheel has not: a sampler over a CUDA storage then raises at its first use, where its
    docstring says it keeps the CPU trees)."""
    from torchrl.data.replay_buffers.samplers import prioritized

    names = [
        f"Cuda{kind}SegmentTree{precision}"
        for kind in ("Sum", "Min")
        for precision in ("Fp32", "Fp64")
    ]
    return all(getattr(prioritized, name, None) is not None for name in names)


def install_segment_trees_if_missing() -> bool:
    """Give TorchRL's ``PrioritizedSampler`` the trees above if its C++ ones did not load.

    Called once, by ``import trl_cartpole.parts`` (which every factory's import runs): where
    TorchRL's extension loaded it changes nothing; where it did not, TorchRL's module names
    ``SumSegmentTreeFp32``, ``MinSegmentTreeFp32`` (and ``Fp64``), ``None`` there, become these
    stand-ins, so every ``PrioritizedSampler`` of the process works, a user's own included,
    whichever factory ran first. Returns whether the stand-ins were installed.
    """
    from torchrl.data.replay_buffers.samplers import prioritized

    if prioritized.SumSegmentTreeFp32 is not None:
        return False
    for precision, dtype in (("Fp32", torch.float32), ("Fp64", torch.float64)):
        setattr(
            prioritized, f"SumSegmentTree{precision}", partial(TensorSumSegmentTree, dtype=dtype)
        )
        setattr(
            prioritized, f"MinSegmentTree{precision}", partial(TensorMinSegmentTree, dtype=dtype)
        )
    return True


# --- a transform's parent env, stepped inside the transform ----------------------------------


def parent_step(parent: EnvBase, tensordict: TensorDictBase) -> TensorDictBase:
    """One step of a transform's ``parent`` env (its ``_step``, no step counting or checks), as
    TorchRL's ``FrameSkipTransform`` repeats an action."""
    return parent._step(tensordict)


def parent_reset(parent: EnvBase, tensordict: TensorDictBase) -> TensorDictBase:
    """A reset of a transform's ``parent`` env (its ``_reset``)."""
    return parent._reset(tensordict)


# --- storages that write their own checkpoints -----------------------------------------------


def storage_tensors(storage: Any) -> TensorDictBase:
    """A ``TensorStorage``'s TensorDict of all its rows (allocated ones, filled or not)."""
    return storage._storage


def allocate_storage(storage: Any, row: TensorDictBase) -> None:
    """Allocate a lazy storage's tensors from one ``row`` (what its first write would do)."""
    storage._init(row)


def set_storage_length(storage: Any, filled: int) -> None:
    """Say how many rows of ``storage`` hold data (a loaded checkpoint's)."""
    storage._len = filled


def restore_last_written_row(buffer: Any) -> None:
    """Give a loaded buffer's storage the row of its last write (``_last_cursor``).

    TorchRL's storage checkpointers do not restore it, so a state saved again before the next
    write (a resumed run's ending, or a window of n steps still filling) warned "last_cursor is
    None". It is the row before the writer's cursor (the next row to write).
    """
    storage, writer = buffer.storage, getattr(buffer, "_writer", None)
    cursor = getattr(writer, "_cursor", None)
    if getattr(storage, "_last_cursor", 0) is None and len(storage) > 0 and cursor is not None:
        storage._set_last_cursor((int(cursor) - 1) % storage.max_size)


# --- torch modules and tensors ---------------------------------------------------------------


def forward_hooks_set(module: nn.Module) -> bool:
    """Whether ``module`` has forward hooks (which a call of ``module`` would run)."""
    return bool(module._forward_hooks)


def forward_pre_hooks(module: nn.Module) -> list[Callable[..., Any]]:
    """``module``'s forward pre-hooks, in the order a call of ``module`` runs them."""
    return list(module._forward_pre_hooks.values())


def tensor_version(tensor: torch.Tensor) -> int:
    """A counter that moves on each in-place write of ``tensor``."""
    return tensor._version


# --- Gymnasium, Ray, the interpreter ----------------------------------------------------------


def gym_generator(unwrapped: Any) -> np.random.Generator | None:
    """A Gymnasium env's own generator, None until it is seeded (``np_random`` would make one)."""
    return unwrapped._np_random


def ray_actor_id(actor: Any) -> str:
    """A Ray actor handle's id, in hex, as Ray's errors name it."""
    return actor._actor_id.hex()


def reload_ray_settings() -> None:
    """Make an imported Ray read its settings and auth token from the environment again."""
    from ray._raylet import AuthenticationTokenLoader, Config

    Config.initialize("")  # what Ray's own _enable_token_auth does
    AuthenticationTokenLoader.instance().reset_cache()


def run_exit_steps() -> None:
    """What Python's exit does before it frees the modules: join the non-daemon threads (after
    the hooks that tell pools to stop), then run the ``atexit`` functions."""
    import atexit
    import threading

    threading._shutdown()  # type: ignore[attr-defined]  # Py_FinalizeEx's first step
    atexit._run_exitfuncs()


def cpu_computes_bfloat16() -> bool:
    """Whether oneDNN computes bfloat16 on this CPU (AVX-512 BF16, AMX), not emulates it."""
    return bool(
        torch.backends.mkldnn.is_available() and torch.ops.mkldnn._is_mkldnn_bf16_supported()
    )

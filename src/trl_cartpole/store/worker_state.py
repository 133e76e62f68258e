"""What each collector worker process holds, saved and restored through TorchRL's worker pipes.

A multi-process collector (TorchRL's ``MultiSyncCollector``) keeps its envs, its inner
collector's carrier and the torch RNG its epsilon-greedy draws come from inside each worker
process; a checkpoint taken in the training process cannot see them. To resume such a run
exactly, each worker's env ends with :class:`WorkerSnapshot`, a TorchRL transform that passes
data through unchanged and whose methods run in the worker: ``snapshot()`` returns the worker's
Gymnasium env state (as :mod:`trl_cartpole.store.env_state` stores it: data, never pickled),
its vector env's autoreset memo and its torch RNG state; ``restore()`` puts them back.

The training process calls them with the collector's own ``map_fn`` and reads and writes each
worker's carrier with ``get_distant_attr`` / ``map_fn`` (TorchRL's remote-call methods on its
worker pipes, and on its Ray actors: ``RayCollector`` has both, calling each actor's
``cascade_execute``), between two batches, when every worker of a synchronous collector waits
for the next ``continue`` (a synchronous ``RayCollector`` asks its actors for nothing between
two batches). A ``MultiAsyncCollector``'s workers and an asynchronous ``RayCollector``'s actors
collect ahead, so they have no such moment: their resumed runs start new episodes.
"""

from __future__ import annotations

from typing import Any

import torch
from tensordict import TensorDict
from torchrl.collectors import BaseCollector, MultiSyncCollector
from torchrl.envs import Transform

from trl_cartpole.compat import (
    is_synchronous_ray_collector,
    set_worker_carriers,
    worker_carriers,
)
from trl_cartpole.store.env_state import (
    autoreset_snapshot,
    env_snapshot,
    restore_autoreset,
    restore_env_snapshot,
)

__all__ = ["WorkerSnapshot", "restore_worker_states", "worker_states"]

# The path, from a worker's inner collector, to its env's last transform (WorkerEnvFactory
# appends WorkerSnapshot last).
SNAPSHOT_PATH = "env.transform[-1]"


class WorkerSnapshot(Transform):
    """A pass-through transform, last in a collector worker's env, that snapshots the worker.

    ``snapshot()`` and ``restore()`` run in the worker process (module doc); the transform
    changes no data, spec or step.
    """

    def __init__(self) -> None:
        super().__init__(in_keys=[], out_keys=[])

    def snapshot(self) -> dict[str, Any]:
        """``{"env": ..., "autoreset": ..., "torch_rng": ByteTensor}`` of this worker."""
        env = self.container
        return {
            "env": env_snapshot(env),
            "autoreset": autoreset_snapshot(env),
            "torch_rng": torch.get_rng_state(),
        }

    def restore(self, state: dict[str, Any]) -> bool:
        """Put a :meth:`snapshot` back; False (and nothing changed) if it holds no env state."""
        env = self.container
        if not restore_env_snapshot(env, state["env"]):
            return False
        if state["autoreset"] is not None:
            restore_autoreset(env, state["autoreset"])
        torch.set_rng_state(state["torch_rng"])
        return True


def _reachable(collector: BaseCollector) -> bool:
    """Whether ``collector``'s workers (processes or Ray actors) wait between batches."""
    return isinstance(collector, MultiSyncCollector) or is_synchronous_ray_collector(collector)


def worker_states(collector: BaseCollector) -> list[dict[str, Any]] | None:
    """Each worker's :meth:`WorkerSnapshot.snapshot` plus its carrier (a dict of tensors), or
    None for a collector whose workers are not reached (module doc)."""
    if not _reachable(collector):
        return None
    snapshots = collector.map_fn(f"{SNAPSHOT_PATH}.snapshot")
    carriers = worker_carriers(collector)
    return [
        {**snapshot, "carrier": carrier.clone().to_dict()}
        for snapshot, carrier in zip(snapshots, carriers, strict=True)
    ]


def restore_worker_states(collector: BaseCollector, states: list[dict[str, Any]] | None) -> bool:
    """Put :func:`worker_states` back into a new collector's workers; False if they cannot take
    them (another kind of collector, another number of workers, or envs stored as no data)."""
    if states is None or not _reachable(collector) or len(states) != collector.num_workers:
        return False
    if not all(state["env"] is not None for state in states):
        return False
    restored = collector.map_fn(
        f"{SNAPSHOT_PATH}.restore",
        [({key: value for key, value in state.items() if key != "carrier"},) for state in states],
    )
    if not all(restored):
        return False
    carriers = worker_carriers(collector)
    set_worker_carriers(
        collector,
        [
            TensorDict(state["carrier"], batch_size=carrier.batch_size)
            for state, carrier in zip(states, carriers, strict=True)
        ],
    )
    return True

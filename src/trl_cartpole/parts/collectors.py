"""Collector factory: TorchRL's ``Collector``, in this process or spread over workers.

One worker on the local backend is the single-process ``Collector``: it steps the very policy
being trained. More workers, or the Ray backend, go through the backends of TorchRL's generic
``Collector(..., backend=..., num_collectors=N, sync=...)``:

- ``local``: ``MultiSyncCollector`` (``sync``: every worker contributes
  ``frames_per_batch / workers`` frames to each batch) or ``MultiAsyncCollector`` (each batch is
  one worker's ``frames_per_batch`` frames, whichever is ready first);
- ``ray``: ``torchrl.collectors.distributed.RayCollector``, one Ray actor per worker, on a
  running cluster (``ray_address``) or on a Ray instance started on this machine.

The workers hold copies of the policy: call ``collector.update_policy_weights_()`` after each
round of updates (:func:`needs_weight_sync`) to send them the learner's weights and buffers
(epsilon, network noise). A Ray actor that dies (its process killed, its node preempted) ends
the run: :func:`lost_worker` tells its error apart, and the loop checkpoints and stops.
"""

from __future__ import annotations

import os
import secrets
import socket
import sys
from collections.abc import Callable, Sequence
from typing import Any

import torch
from tensordict.nn import TensorDictModuleBase
from torchrl.collectors import BaseCollector, Collector
from torchrl.envs import EnvBase

from trl_cartpole import choices
from trl_cartpole.compat import close_weight_sync_schemes, ray_actor_id, reload_ray_settings
from trl_cartpole.errors import ConfigError

__all__ = [
    "BACKENDS",
    "check_ray_address",
    "check_ray_resources",
    "default_ray_init_config",
    "guard_local_ray_with_a_token_of_its_own",
    "is_distributed",
    "lost_worker",
    "make_collector",
    "needs_weight_sync",
    "ray_placement",
    "shutdown_collector",
    "whole_batches",
]

BACKENDS = choices.COLLECTOR_BACKENDS
# Each Ray collector actor reserves this much of a node (TorchRL's default reserves 2 GiB).
RAY_ACTOR_OPTIONS = {"num_cpus": 1, "memory": 512 * 1024**2}


def is_distributed(workers: int, backend: str) -> bool:
    """Whether collection runs outside the training process (worker processes or Ray actors)."""
    return workers > 1 or backend != "local"


def default_ray_init_config(address: str | None, workers: int) -> dict[str, Any]:
    """``ray.init`` arguments: connect to ``address``, or start Ray here on 127.0.0.1.

    A local instance declares at least one CPU per worker (more workers than cores then share
    the cores rather than wait for a free one) and asks for the loopback address, which Ray
    may still rewrite to the machine's own (docs/scaling.md). ``address="local"`` is Ray's way
    to always start a new instance: with ``address=None``, ``ray.init`` would instead join
    ``RAY_ADDRESS`` or whatever cluster the last ``ray start`` on this machine recorded in
    ``/tmp/ray/ray_current_cluster``.
    """
    quiet = {"log_to_driver": False, "logging_level": "warning", "include_dashboard": False}
    if address is not None:
        return {"address": address, **quiet}
    return {
        "address": "local",
        "num_cpus": max(workers, os.cpu_count() or 1),
        "_node_ip_address": "127.0.0.1",
        **quiet,
    }


def guard_local_ray_with_a_token_of_its_own() -> None:
    """Token authentication for the Ray instance a run starts, with a token made for it.

    Ray 2.60 turns token authentication on for a new local instance and, finding no token,
    writes one to ``~/.ray/auth_token`` with the user's umask: mode 644, readable by every user
    of the machine, and the same for every later instance. Its ports listen on every interface
    whatever ``_node_ip_address`` says (Ray has no setting to bind them to the loopback), so the
    token is the guard. Made here and put in ``os.environ`` (``RAY_AUTH_TOKEN``), it reaches the
    Ray processes the run starts through their environment, which only their owner can read
    (``/proc/PID/environ`` is mode 0400), and no file. ``RAY_AUTH_MODE`` and ``RAY_AUTH_TOKEN``
    set by the user are kept.
    """
    os.environ.setdefault("RAY_AUTH_MODE", "token")
    os.environ.setdefault("RAY_AUTH_TOKEN", secrets.token_hex(32))
    if "ray._raylet" in sys.modules:  # Ray read its settings at import: make it read them again
        reload_ray_settings()


def whole_batches(frames: int, frames_per_batch: int) -> int:
    """``frames`` rounded up to a whole number of batches: what the collector really collects."""
    return -(-frames // frames_per_batch) * frames_per_batch if frames > 0 else frames


def make_collector(
    create_env_fn: EnvBase | Callable[[], EnvBase] | Sequence[Callable[[], EnvBase]],
    policy: TensorDictModuleBase,
    *,
    frames_per_batch: int,
    total_frames: int = -1,
    init_random_frames: int | None = None,
    device: str | torch.device | None = None,
    sync: bool = True,
    backend: str = "local",
    ray_address: str | None = None,
    remote_configs: dict[str, Any] | None = None,
    ray_init_config: dict[str, Any] | None = None,
    **collector_kwargs: Any,
) -> BaseCollector:
    """Return a collector yielding batches of ``frames_per_batch`` transitions.

    The policy runs under ``ExplorationType.RANDOM``, so epsilon-greedy is active. A batch is
    ``[T]`` or ``[envs, T]`` for one worker; ``[workers, envs, T]`` (``envs`` absent for single
    envs) for a synchronous multi-worker batch. The arguments after ``policy`` are keywords,
    as ``Collector`` takes them, with ``Collector``'s defaults.

    Example::

        >>> from trl_cartpole import make_collector, make_env, make_q_actor
        >>> env = make_env("CartPole-v1", seed=0)
        >>> actor = make_q_actor(env.observation_spec, env.action_spec)
        >>> collector = make_collector(env, actor, frames_per_batch=8, total_frames=16)
        >>> [batch.numel() for batch in collector]
        [8, 8]
        >>> collector.shutdown()

    :param create_env_fn: what TorchRL's ``Collector`` takes: the env itself or a callable
        that builds it (one local worker: collection in this process), or a list of env
        constructors, one per worker (picklable, each seeding its own envs).
    :param policy: the policy the collector steps (workers and Ray actors step copies of it).
    :param frames_per_batch: the transitions in each batch. Required, as ``Collector``'s.
    :param total_frames: the frames to collect, rounded up to whole batches
        (:func:`whole_batches`), as TorchRL would do with a warning. Default ``-1``, endless,
        as ``Collector``.
    :param init_random_frames: the first ``init_random_frames`` frames come from the env's
        uniform random policy; rounded up to whole batches. Default None: none, as
        ``Collector``.
    :param device: the collector's device. Default None: ``Collector``'s, the policy's.
    :param sync: with several workers, ``True`` (default): every worker contributes
        ``frames_per_batch / workers`` frames to each batch (``MultiSyncCollector`` on the
        local backend); ``False``: each batch is one worker's ``frames_per_batch`` frames,
        whichever is ready first (``MultiAsyncCollector``).
    :param backend: ``"local"`` (default: this process, or worker processes for a list of
        constructors) or ``"ray"`` (``torchrl.collectors.distributed.RayCollector``, one Ray
        actor per env constructor).
    :param ray_address: with ``backend="ray"``, the running cluster to join; None: a Ray
        instance started on this machine (:func:`default_ray_init_config`).
    :param remote_configs: the Ray options of each actor (``RayCollector``'s argument:
        ``num_cpus``, ``memory``, ``resources``...); None: :data:`RAY_ACTOR_OPTIONS` (TorchRL:
        1 CPU and 2 GiB per Ray actor).
    :param ray_init_config: ``RayCollector``'s too: adds to or replaces the ``ray.init``
        arguments of :func:`default_ray_init_config` (e.g.
        ``{"runtime_env": {"py_modules": [...]}}``).
    :param collector_kwargs: go to TorchRL's ``Collector`` (``storing_device``,
        ``compile_policy``, ``split_trajs``, ...).
    :returns: TorchRL's ``Collector`` (with ``backend="process"`` or ``"ray"`` for several
        workers or Ray actors).
    """
    if backend not in BACKENDS:
        raise ConfigError(f"backend={backend!r}: choose one of {list(BACKENDS)}")
    common = {
        "frames_per_batch": frames_per_batch,
        "total_frames": whole_batches(total_frames, frames_per_batch),
        "init_random_frames": whole_batches(init_random_frames or 0, frames_per_batch) or None,
        "device": device,
        # the Q-policy needs no env transform registered
        "auto_register_policy_transforms": False,
        **collector_kwargs,
    }
    if isinstance(create_env_fn, EnvBase) or (callable(create_env_fn) and backend == "local"):
        if backend != "local":
            raise ValueError(
                "backend='ray': each Ray actor builds its own env, so pass env constructors "
                "(callables), not a built env"
            )
        return Collector(create_env_fn, policy, **common)
    create_env_fn = _env_constructors(create_env_fn)
    if backend == "local":
        return Collector(
            create_env_fn,
            policy,
            backend="process",
            num_collectors=len(create_env_fn),
            sync=sync,
            **common,
        )
    return _ray_collector(
        create_env_fn, policy, sync, ray_address, remote_configs, ray_init_config, common
    )


def _env_constructors(create_env_fn: Any) -> list[Callable[[], EnvBase]]:
    """One env constructor per worker or Ray actor (a single callable is one)."""
    if callable(create_env_fn):  # one Ray actor
        create_env_fn = [create_env_fn]
    if not isinstance(create_env_fn, Sequence) or not all(map(callable, create_env_fn)):
        raise TypeError(
            "create_env_fn: pass an env, a callable that builds one, or a list of such "
            f"callables (one per worker), not {type(create_env_fn).__name__}"
        )
    return list(create_env_fn)


def _ray_collector(
    create_env_fn: list[Callable[[], EnvBase]],
    policy: TensorDictModuleBase,
    sync: bool,
    ray_address: str | None,
    remote_configs: dict[str, Any] | None,
    ray_init_config: dict[str, Any] | None,
    common: dict[str, Any],
) -> BaseCollector:
    """TorchRL's ``Collector(backend="ray")``: one Ray actor per env constructor, on the
    cluster at ``ray_address`` or a Ray instance started on this machine."""
    if ray_address is not None:
        check_ray_address(ray_address)
    else:
        guard_local_ray_with_a_token_of_its_own()
    actor_options = RAY_ACTOR_OPTIONS if remote_configs is None else remote_configs
    if ray_address is not None and resources_wanted(actor_options, len(create_env_fn)):
        check_ray_resources(ray_address, actor_options, len(create_env_fn))
    try:
        auto_register = common.pop("auto_register_policy_transforms")
        collector = Collector(
            create_env_fn,
            policy,
            backend="ray",
            num_collectors=len(create_env_fn),
            sync=sync,
            backend_options={
                "ray_init_config": {
                    **default_ray_init_config(ray_address, len(create_env_fn)),
                    **(ray_init_config or {}),
                },
                "remote_configs": actor_options,
                "collector_kwargs": {"auto_register_policy_transforms": auto_register},
            },
            **common,
        )
    except ConnectionError as error:  # ray.init found no cluster (or was refused by it)
        reason = str(error).splitlines()[0]
        raise ConfigError(
            f"collector.ray_address={ray_address!r}: cannot join a Ray cluster there ({reason}); "
            "start one with `ray start --head`, fix the address, or set RAY_AUTH_MODE=token "
            "(and the cluster's token) if the cluster uses token authentication"
        ) from None
    collector.update_policy_weights_(policy)  # registers the learner's policy as the source
    return collector


def resources_wanted(
    remote_configs: dict[str, Any] | list[dict[str, Any]], actors: int
) -> dict[str, float]:
    """The custom resources ``actors`` actors ask for in all (``remote_configs["resources"]``:
    one dict for every actor, or one per actor)."""
    per_actor = remote_configs if isinstance(remote_configs, list) else [remote_configs] * actors
    wanted: dict[str, float] = {}
    for options in per_actor:
        for name, amount in (options.get("resources") or {}).items():
            wanted[name] = wanted.get(name, 0.0) + amount
    return wanted


def check_ray_resources(
    address: str, remote_configs: dict[str, Any] | list[dict[str, Any]], actors: int
) -> None:
    """Raise a one-line ConfigError unless the Ray cluster at ``address`` holds the custom
    resources that ``actors`` actors ask for (``remote_configs["resources"]``, per actor).

    Ray would otherwise wait without end for a node that has them (TorchRL's ``RayCollector``
    blocks in its constructor). The check joins the cluster and leaves it again (about 2 s),
    or asks the Ray session this process already has.
    """
    import ray

    wanted = resources_wanted(remote_configs, actors)
    joined_here = not ray.is_initialized()  # a caller's own Ray session is left as it is
    try:
        if joined_here:
            ray.init(**default_ray_init_config(address, actors))
        held = ray.cluster_resources()
    except ConnectionError:
        return  # make_collector's own join says what is wrong with the address
    finally:
        if joined_here:
            ray.shutdown()
    short = {name: amount for name, amount in wanted.items() if held.get(name, 0.0) < amount}
    if short:
        needs = ", ".join(f"{name}={amount:g}" for name, amount in short.items())
        has = ", ".join(f"{name}={held.get(name, 0.0):g}" for name in short)
        raise ConfigError(
            f"collector.ray_resources: the {actors} Ray actors need {needs} in all and the "
            f"cluster has {has}; start nodes with `ray start --resources='{{\"NAME\": N}}'`, "
            "lower the amounts or fix the names"
        )


def check_ray_address(address: str, timeout: float = 5.0) -> None:
    """Raise a one-line ConfigError unless ``host:port`` accepts a TCP connection.

    ``ray.init`` retries an address where nothing listens for minutes before failing; this
    fails in seconds instead. Other forms (``auto``, ``ray://...``) are left to Ray.
    """
    host, _, port = address.rpartition(":")
    if not host or not port.isdigit() or "://" in address:
        return
    try:
        socket.create_connection((host, int(port)), timeout=timeout).close()
    except OSError as error:
        raise ConfigError(
            f"collector.ray_address={address!r}: nothing answers there ({error}); start the "
            "cluster's head with `ray start --head --port=PORT` or fix the address"
        ) from None


def needs_weight_sync(collector: BaseCollector, policy: TensorDictModuleBase) -> bool:
    """Whether ``collector`` steps a copy of ``policy`` that must be sent the new weights.

    A single-process ``Collector`` steps ``policy`` itself; worker processes and Ray actors
    step copies. (TorchRL's ``RayCollector`` keeps the learner's ``policy`` as its
    ``.policy`` while its actors step their own: it is told by its ``remote_collectors``.)
    """
    if hasattr(collector, "remote_collectors"):  # Ray actors
        return True
    return getattr(collector, "policy", None) is not policy


def _node_id_of(_actor: Any) -> str:
    """Run inside a Ray actor (``__ray_call__``): the id of the node it lives on."""
    import ray

    return ray.get_runtime_context().get_node_id()


def ray_placement(collector: BaseCollector) -> dict[str, Any] | None:
    """Where a Ray run lives: ``{"learner_node": id, "collector_nodes": [id per actor]}``.

    The learner is this process (the Ray driver, on the node it joined); each collector actor
    says its node. Ray node ids are those ``ray.nodes()`` lists as ``NodeID``. None for a
    collector that is not a ``RayCollector``.
    """
    if not hasattr(collector, "remote_collectors"):
        return None
    import ray

    actors = collector.remote_collectors
    return {
        "learner_node": ray.get_runtime_context().get_node_id(),
        "collector_nodes": ray.get([actor.__ray_call__.remote(_node_id_of) for actor in actors]),
    }


def shutdown_collector(collector: BaseCollector) -> None:
    """``collector.shutdown()``, then close the weight-sync schemes it leaves open.

    TorchRL 0.14's multi-process shutdown stops the workers but not the shared-memory weight
    sync scheme; left to its ``__del__`` at interpreter exit, that starts a queue thread and the
    process hangs after training (seen with ``MultiSyncCollector``).
    """
    collector.shutdown()
    close_weight_sync_schemes(collector)


# How long a live actor may take to answer whether it is alive (it may be mid-batch).
RAY_ALIVE_TIMEOUT_S = 30.0


def _dead_actor_error(collector: BaseCollector, ray_exceptions: Any) -> BaseException | None:
    """The ``RayActorError`` of the first of ``collector``'s Ray actors that no longer
    answers, or None when every one does (or ``collector`` has none). The actors are asked at
    once and waited for together, ``RAY_ALIVE_TIMEOUT_S`` at most; one that has not answered by
    then is busy, not dead."""
    actors = getattr(collector, "remote_collectors", None) or []
    if not actors:
        return None
    import ray

    probes = [actor.__ray_ready__.remote() for actor in actors]
    answered, _ = ray.wait(probes, num_returns=len(probes), timeout=RAY_ALIVE_TIMEOUT_S)
    for probe in probes:
        if probe not in answered:
            continue
        try:
            ray.get(probe)
        except ray_exceptions.RayActorError as dead:
            return dead
        except Exception:  # any other answer names no dead actor
            continue
    return None


# The fields of Ray's ActorDiedError message ("\tpid: 1234"), between its first line and the reason.
RAY_ACTOR_FIELDS = ("class_name", "actor_id", "pid", "name", "namespace", "ip")


def lost_worker(error: BaseException, collector: BaseCollector) -> str | None:
    """``"Ray collector actor 2 of 2 (pid 1234, ip 10.0.0.3) died: <Ray's reason>"`` if ``error``
    is Ray's word that one of ``collector``'s actors is gone (``RayActorError``), or any other
    error while one of them no longer answers (a weight push to a dead actor fails in gloo
    first), else None.
    The actor is named by its place among the collector's actors while the collector still
    lists them, else by Ray's actor id."""
    ray_exceptions = sys.modules.get("ray.exceptions")  # Ray not imported: no Ray actor
    if ray_exceptions is None:
        return None
    if not isinstance(error, ray_exceptions.RayActorError):
        # a weight push to a dead actor fails first in torch.distributed's transport (gloo's
        # "Connection closed by peer"): ask the actors, and take a dead one's error
        error = _dead_actor_error(collector, ray_exceptions)
        if error is None:
            return None
    lines = [line.strip() for line in str(error).splitlines() if line.strip()] or ["(no reason)"]
    fields, reasons = {}, []
    for line in lines[1:]:
        key, _, value = line.partition(": ")
        if key in RAY_ACTOR_FIELDS:
            fields[key] = value
        else:
            reasons.append(line)
    actors = [ray_actor_id(actor) for actor in getattr(collector, "remote_collectors", [])]
    if error.actor_id in actors:
        which = f"{actors.index(error.actor_id) + 1} of {len(actors)}"
    else:
        which = str(error.actor_id or fields.get("actor_id", "?"))
    where = ", ".join(f"{key} {fields[key]}" for key in ("pid", "ip") if key in fields)
    return f"Ray collector actor {which}{f' ({where})' if where else ''} died: " + (
        reasons[0] if reasons else lines[0]
    )

"""Scaling out: worker processes, a Ray cluster, Hydra sweeps (docs/scaling.md)."""

from __future__ import annotations

import json
import os
import re
import secrets
import signal
import socket
import subprocess
import sys
import time
import warnings
from pathlib import Path
from types import SimpleNamespace

import pytest
import torch
from tensordict.nn import TensorDictSequential

import trl_cartpole
from tests.conftest import SMOKE_OVERRIDES, TIMING_KEYS, run_script
from trl_cartpole.config.schema import to_config
from trl_cartpole.config.validation import validate
from trl_cartpole.errors import ConfigError
from trl_cartpole.parts.collectors import (
    default_ray_init_config,
    lost_worker,
    make_collector,
    needs_weight_sync,
    shutdown_collector,
)
from trl_cartpole.parts.exploration import make_exploration
from trl_cartpole.run.envs import make_env_from_config, worker_env_constructors
from trl_cartpole.run.from_config import build_actor
from trl_cartpole.run.training import train
from trl_cartpole.store.checkpoint import resume_config
from trl_cartpole.tools.sweeps import expand_grid

# Two workers of 16 envs: the default's 32 envs, split.
TWO_WORKERS = ["collector.workers=2", "env.num_envs=16"]
SOLVE_BUDGET = 40_000  # frames, as tests/test_learning.py gives the single-process default


def _greedy_mismatch(batch) -> float:
    """Fraction of the batch's actions that are not the argmax of its Q-values (exploration)."""
    greedy = batch["action_value"].argmax(-1)
    return (greedy != batch["action"].argmax(-1)).float().mean().item()


def test_ray_actors_are_sent_the_learners_weights():
    """TorchRL's RayCollector keeps the learner's policy as ``.policy``, yet its actors step
    copies: the loop must still send them the weights (it did not: they played at random)."""

    class RayLike:  # what needs_weight_sync sees of a RayCollector
        def __init__(self, policy):
            self.policy, self.remote_collectors = policy, [object(), object()]

    class SingleProcess:  # a Collector stepping the learner's policy itself
        def __init__(self, policy):
            self.policy = policy

    policy = torch.nn.Linear(1, 1)
    assert needs_weight_sync(RayLike(policy), policy)
    assert not needs_weight_sync(SingleProcess(policy), policy)


def test_a_transport_error_names_the_ray_actor_that_no_longer_answers(monkeypatch):
    """A weight push to a killed actor fails first in gloo ("Connection closed by peer"), not
    with Ray's ``RayActorError``: the actors are asked, and the one that is dead is named (a busy
    one that times out is not); when every actor answers, the error is not a lost worker."""
    ray = pytest.importorskip("ray")
    from ray.exceptions import GetTimeoutError, RayActorError

    dead = RayActorError(
        actor_id="bb", error_msg="The actor died\n\tpid: 4242\n\tip: 10.0.0.3\n\tkilled by SIGKILL"
    )

    class Actor:  # what lost_worker sees of a Ray actor handle
        def __init__(self, actor_id, answer):
            self._actor_id = SimpleNamespace(hex=lambda: actor_id)
            self.__ray_ready__ = SimpleNamespace(remote=lambda: answer)

    def wait(probes, num_returns, timeout):
        assert timeout > 0 and num_returns == len(probes)  # one wait for all, never forever
        answered = [probe for probe in probes if not isinstance(probe, GetTimeoutError)]
        return answered, [probe for probe in probes if probe not in answered]

    def get(answer):
        if isinstance(answer, BaseException):
            raise answer
        return answer

    monkeypatch.setattr(ray, "wait", wait)
    monkeypatch.setattr(ray, "get", get)
    gloo = RuntimeError("[pair.cc:553] Connection closed by peer [127.0.0.1]:40600.")
    busy, alive = Actor("aa", GetTimeoutError()), Actor("cc", True)
    confused = Actor("dd", RuntimeError("Ray's own failure"))  # names no dead actor
    collector = SimpleNamespace(remote_collectors=[busy, confused, Actor("bb", dead), alive])
    assert lost_worker(gloo, collector) == (
        "Ray collector actor 3 of 4 (pid 4242, ip 10.0.0.3) died: killed by SIGKILL"
    )
    assert lost_worker(gloo, SimpleNamespace(remote_collectors=[busy, confused, alive])) is None
    assert lost_worker(gloo, SimpleNamespace()) is None  # not a Ray collector


def test_a_local_ray_instance_is_started_apart_from_any_other_on_the_machine():
    """``address="local"``: Ray starts a new instance, never joining RAY_ADDRESS or the cluster
    a ``ray start`` recorded in /tmp/ray/ray_current_cluster (machine-wide state)."""
    from ray._private.services import canonicalize_bootstrap_address

    config = default_ray_init_config(None, 2)
    assert config["address"] == "local" and config["num_cpus"] >= 2
    os.environ["RAY_ADDRESS"] = "10.0.0.1:6379"  # (conftest removes it again after the session)
    try:
        assert canonicalize_bootstrap_address(config["address"]) is None  # None: start one here
        assert canonicalize_bootstrap_address(None) == "10.0.0.1:6379"  # what None would join
    finally:
        del os.environ["RAY_ADDRESS"]
    assert default_ray_init_config("10.0.0.2:6379", 2)["address"] == "10.0.0.2:6379"


@pytest.mark.slow  # worker processes
@pytest.mark.parametrize("sync", [True, False], ids=["sync", "async"])
def test_workers_act_with_the_learners_weights_after_each_sync(compose, sync):
    """Parameters and buffers (epsilon) reach the workers with each update_policy_weights_()."""
    cfg = to_config(compose("env.num_envs=4", "collector.workers=2", "buffer.n_steps=1"))
    env = make_env_from_config(cfg.env, 0)
    actor = build_actor(cfg, env)
    exploration = make_exploration(env.action_spec, 1.0, 1.0, 1000, device="cpu")  # eps 1
    policy = TensorDictSequential(actor, exploration)
    collector = make_collector(
        worker_env_constructors(cfg), policy, frames_per_batch=32, total_frames=32 * 40, sync=sync
    )
    mismatches = []
    try:
        for index, batch in enumerate(collector):
            # sync: 2 workers x 4 envs x 4 steps; async: one worker's 4 envs x 8 steps
            assert batch.shape == ((2, 4, 4) if sync else (4, 8))
            mismatches.append(_greedy_mismatch(batch))
            if sync and index < 4:  # eps = 1: each worker draws its own random actions
                assert not torch.equal(batch[0]["action"], batch[1]["action"])
            if sync:  # the workers' Q-values are the learner's, whose weights move every round
                with torch.no_grad():
                    learner_q = actor(batch.select("observation").clone())["action_value"]
                torch.testing.assert_close(batch["action_value"], learner_q)
            with torch.no_grad():
                for parameter in actor.parameters():
                    parameter.add_(0.1 * torch.randn_like(parameter))
            if index == 3:
                exploration.eps.fill_(0.0)  # the learner turns exploration off
            collector.update_policy_weights_()
            if index == 9:
                break
    finally:
        shutdown_collector(collector)
    assert all(m > 0 for m in mismatches[:4])  # eps = 1: half the actions are random
    if sync:  # after the sync every batch is greedy
        assert mismatches[4:] == [0.0] * 6
    else:  # each asynchronous worker may deliver one batch it had started before the sync,
        # and a worker the machine starves may deliver it late: at most one stale batch each
        assert sum(m > 0 for m in mismatches[4:]) <= cfg.collector.workers


def test_each_worker_seeds_its_own_envs(compose):
    cfg = to_config(compose("env.num_envs=2", "collector.workers=3", "seed=7"))
    observations = []
    for create_env in worker_env_constructors(cfg):
        env = create_env()
        observations.append(env.reset()["observation"])  # [2, 4]
        env.close()
    starts = torch.cat(observations)  # [6, 4]: no two envs of the run start alike
    assert len({tuple(row.tolist()) for row in starts}) == 6
    again = worker_env_constructors(cfg)[1]()
    assert torch.equal(again.reset()["observation"], observations[1])  # seed 7 + 1 * 2
    again.close()


@pytest.mark.parametrize(
    ("overrides", "message"),
    [
        (["collector.workers=2"], "e.g. env.num_envs=16 (16 envs on each of 2 workers)"),
        (["collector.sync=false"], "collector.sync=false needs collector.workers > 1"),
        (
            [*TWO_WORKERS, "collector.sync=false"],
            "buffer.n_steps=3 needs each env's steps in order",
        ),
        (["collector.ray_address=127.0.0.1:6379"], "only read by the Ray backend"),
        (["collector.workers=0"], "collector.workers=0 must be >= 1"),
        (["collector.backend=spark"], "collector.backend='spark' is not a known option"),
        (["collector.ray_resources={gpu_node: 1}"], "is only read by the Ray backend"),
        (
            ["collector.backend=ray", "collector.ray_resources={gpu_node: 1}"],
            "the Ray instance a run starts on this machine has no custom resources",
        ),
        (
            ["collector.backend=ray", "collector.ray_runtime_env={pip: [gymnasium]}"],
            "collector.ray_runtime_env ships code to the nodes of a cluster",
        ),
        (
            [
                "collector.backend=ray",
                "collector.ray_address=10.0.0.2:6379",
                "collector.ray_resources={gpu_node: 0}",
            ],
            "collector.ray_resources.gpu_node=0.0 must be a positive number",
        ),
    ],
)
def test_impossible_scaling_configs_are_refused(compose, overrides, message):
    with pytest.raises(ConfigError, match=message.replace("(", r"\(").replace(")", r"\)")):
        validate(to_config(compose(*overrides)))


def test_the_ray_backend_without_ray_names_the_extra(compose, monkeypatch):
    import importlib.util

    find_spec = importlib.util.find_spec
    monkeypatch.setattr(
        importlib.util, "find_spec", lambda name, *a: None if name == "ray" else find_spec(name, *a)
    )
    with pytest.raises(ConfigError, match=re.escape('-e ".[distributed]" -c constraints.txt')):
        validate(to_config(compose("collector.backend=ray")))


@pytest.mark.parametrize(
    "backend",
    # two runs with worker processes (local: 17 s alone, 36 s beside other tests); ray: 2 x 20 s
    [pytest.param("local", marks=pytest.mark.slow), pytest.param("ray", marks=pytest.mark.slow)],
)
def test_a_run_with_synchronous_workers_repeats_itself(compose, tmp_path, backend):
    """Each worker seeds its envs and its exploration draws, so a seed is one run."""
    overrides = [o for o in SMOKE_OVERRIDES if not o.startswith("env.num_envs")]
    summaries = [
        train(
            compose(
                *overrides,
                "collector.workers=2",
                "env.num_envs=2",
                f"collector.backend={backend}",
                f"run_dir={tmp_path / str(run)}",
                "logger.plots=false",
            )
        )
        for run in range(2)
    ]
    for summary in summaries:
        del summary["eval_curve"]["seconds"], summary["eval_curve"]["rss_mb"]  # measurements
    first, second = ({k: v for k, v in s.items() if k not in TIMING_KEYS} for s in summaries)
    assert first == second


@pytest.mark.slow  # 30 s; the recorded runs of docs/scaling-measured.md solve 6/6, Ray below
def test_two_worker_processes_solve_cartpole(compose, tmp_path):
    summary = train(
        compose(
            *TWO_WORKERS,
            f"collector.total_frames={SOLVE_BUDGET}",
            f"run_dir={tmp_path}",
            "logger.progress_bar=false",
            "logger.plots=false",
        )
    )
    assert summary["solved"], summary
    assert summary["best_eval_return_mean"] >= 475.0
    assert summary["final_eval_return_mean"] >= 400.0


@pytest.mark.slow  # worker processes, twice per case
@pytest.mark.parametrize(("sync", "continued"), [("true", True), ("false", False)])
def test_a_run_with_workers_resumes_their_episodes_when_synchronous(
    compose, tmp_path, sync, continued
):
    overrides = [o for o in SMOKE_OVERRIDES if not o.startswith("collector.total_frames")]
    cfg = compose(
        *overrides,
        "collector.workers=2",
        f"collector.sync={sync}",
        "env.num_envs=2",
        "buffer.n_steps=1",
        "collector.total_frames=200",
        f"run_dir={tmp_path}",
    )
    assert train(cfg)["frames"] == 200
    last = tmp_path / "checkpoints" / "last"
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        resumed = train(resume_config(last, ["collector.total_frames=400"]), resume=last)
    fresh = [w for w in caught if "workers start new episodes" in str(w.message)]
    assert bool(fresh) is not continued  # asynchronous workers collect ahead: not saved
    assert resumed["frames"] == 400  # the workers collected only the 200 frames still due
    assert resumed["updates"] > 0


# --- a Ray cluster: a head on this machine, two remote collectors -----------------------------


def _free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


def _ray_cluster_env() -> dict[str, str]:
    """The environment of a test cluster: token authentication on, with a token made here (not
    read from ~/.ray, which a fresh machine lacks), no usage report."""
    return {
        **os.environ,
        "RAY_AUTH_MODE": "token",
        "RAY_AUTH_TOKEN": secrets.token_hex(32),
        "RAY_USAGE_STATS_ENABLED": "0",
    }


def _ray_start(env: dict[str, str], *options: str) -> subprocess.Popen:
    """``ray start --block OPTIONS`` in its own process group: stopping it stops the Ray
    processes it started and no other Ray."""
    return subprocess.Popen(
        [str(Path(sys.executable).with_name("ray")), "start", "--block", *options],
        env=env,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        start_new_session=True,
    )


def _ray_stop(node: subprocess.Popen) -> None:
    os.killpg(node.pid, signal.SIGTERM)  # the node and the Ray processes it started
    try:
        node.wait(timeout=5)
    except subprocess.TimeoutExpired:  # its graceful stop takes about 30 s: not needed here
        os.killpg(node.pid, signal.SIGKILL)
        node.wait()


def _start_ray_head(env: dict[str, str], temp_dir: Path, *options: str):
    """A Ray head on 127.0.0.1 at a free port; returns it and its address once its GCS
    accepts connections."""
    port = _free_port()
    head = _ray_start(
        env,
        "--head",
        "--node-ip-address=127.0.0.1",
        f"--port={port}",
        "--include-dashboard=false",
        f"--temp-dir={temp_dir}",
        *options,
    )
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline:
        try:
            socket.create_connection(("127.0.0.1", port), timeout=1).close()
            break
        except OSError:
            assert head.poll() is None, "ray start --head exited"
            time.sleep(0.5)
    return head, f"127.0.0.1:{port}"


@pytest.fixture(scope="module")
def ray_head(tmp_path_factory):
    """A Ray head started with ``ray start --block`` on 127.0.0.1, token authentication on."""
    pytest.importorskip("ray")
    env = _ray_cluster_env()
    head, address = _start_ray_head(env, tmp_path_factory.mktemp("ray"), "--num-cpus=2")
    yield {"address": address, "env": env}
    _ray_stop(head)


@pytest.mark.slow  # imports Ray in a subprocess
def test_a_ray_address_where_nothing_listens_is_one_line_and_exit_2(tmp_path):
    run_dir = tmp_path / "run"
    proc = run_script(
        "train.py",
        "collector.backend=ray",
        f"collector.ray_address=127.0.0.1:{_free_port()}",
        *TWO_WORKERS,
        f"run_dir={run_dir}",
    )
    lines = [line for line in proc.stderr.splitlines() if line.startswith("error:")]
    assert proc.returncode == 2 and len(lines) == 1, proc.stderr[-1500:]
    assert "nothing answers there" in lines[0] and "ray start --head" in lines[0]
    assert not run_dir.exists()  # refused before anything is written


@pytest.mark.slow  # a Ray head: 20 s to start
def test_two_ray_actors_on_a_local_head_solve_cartpole(ray_head, tmp_path):
    proc = run_script(
        "train.py",
        "collector.backend=ray",
        f"collector.ray_address={ray_head['address']}",
        *TWO_WORKERS,
        f"collector.total_frames={SOLVE_BUDGET}",
        f"run_dir={tmp_path}",
        "logger.progress_bar=false",
        "logger.plots=false",
        env=ray_head["env"],
        timeout=600,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["solved"], summary
    assert summary["final_eval_return_mean"] >= 400.0


# What a client of the cluster sees: each node's id and resources.
_LIST_NODES = """
import json, sys, ray
ray.init(address=sys.argv[1], logging_level="ERROR")
print(json.dumps([(n["NodeID"], n["Resources"]) for n in ray.nodes() if n["Alive"]]))
"""


def _cluster_nodes(address: str, env: dict[str, str]) -> list[tuple[str, dict[str, float]]]:
    listed = subprocess.run(
        [sys.executable, "-c", _LIST_NODES, address],
        env=env,
        capture_output=True,
        text=True,
        timeout=120,
        check=True,
    )
    return json.loads(listed.stdout.splitlines()[-1])


@pytest.fixture(scope="module")
def two_node_cluster(tmp_path_factory):
    """A head and a worker node started with ``ray start`` on this machine; the worker node is
    told apart by a custom resource, ``collector_node``, as a real cluster's worker would be."""
    pytest.importorskip("ray")
    env = _ray_cluster_env()
    head, address = _start_ray_head(env, tmp_path_factory.mktemp("ray"), "--num-cpus=1")
    worker = _ray_start(
        env,
        f"--address={address}",
        "--node-ip-address=127.0.0.1",
        "--num-cpus=2",
        '--resources={"collector_node": 2}',
    )
    try:
        deadline = time.monotonic() + 120
        while len(nodes := _cluster_nodes(address, env)) < 2:
            assert worker.poll() is None, "ray start --address exited"
            assert time.monotonic() < deadline, f"the worker node never joined: {nodes}"
            time.sleep(1)
        yield {"address": address, "env": env, "nodes": nodes}
    finally:
        _ray_stop(worker)
        _ray_stop(head)


@pytest.mark.slow  # two Ray nodes: 40 s to start
def test_the_actors_run_on_the_worker_node_and_the_learner_on_the_head(two_node_cluster, tmp_path):
    (head_id,) = [i for i, held in two_node_cluster["nodes"] if "node:__internal_head__" in held]
    (worker_id,) = [i for i, held in two_node_cluster["nodes"] if "collector_node" in held]
    assert head_id != worker_id
    proc = run_script(
        "train.py",
        *SMOKE_OVERRIDES,
        "collector.backend=ray",
        f"collector.ray_address={two_node_cluster['address']}",
        "collector.ray_resources={collector_node: 1}",
        # as docs/scaling.md tells: the package shipped by a path relative to the checkout
        "collector.ray_runtime_env={py_modules: [src/trl_cartpole]}",
        *TWO_WORKERS,
        "collector.frames_per_batch=32",
        "collector.total_frames=1024",
        f"run_dir={tmp_path}",
        env=two_node_cluster["env"],
        timeout=600,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["frames"] == 1024
    assert summary["ray_nodes"] == {
        "learner_node": head_id,
        "collector_nodes": [worker_id, worker_id],
    }


# Collectors on the cluster's worker node with this package shipped in Ray's runtime
# environment; prints where each actor imported trl_cartpole from.
_SHIPPED_PACKAGE = """
import json, sys
from pathlib import Path
import ray, trl_cartpole
from trl_cartpole.run.from_config import build_actor
from trl_cartpole.run.envs import make_env_from_config, worker_env_constructors
from trl_cartpole.parts.collectors import make_collector
from trl_cartpole.config.schema import Config

cfg = Config()
cfg.env.num_envs, cfg.collector.workers = 2, 2
actor = build_actor(cfg, make_env_from_config(cfg.env, seed=0))
collector = make_collector(
    worker_env_constructors(cfg), actor, frames_per_batch=8, total_frames=16,
    init_random_frames=0, backend="ray", ray_address=sys.argv[1],
    remote_configs={"num_cpus": 1, "resources": {"collector_node": 1}},
    ray_init_config={"runtime_env": {"py_modules": [str(Path(trl_cartpole.__file__).parent)]}},
)
files = ray.get([a.__ray_call__.remote(lambda self: __import__("trl_cartpole").__file__)
                 for a in collector.remote_collectors])
frames = sum(batch.numel() for batch in collector)
collector.shutdown()
print(json.dumps({"frames": frames, "files": files}))
"""


@pytest.mark.slow  # two Ray nodes
def test_the_package_shipped_in_a_runtime_env_is_what_the_actors_import(two_node_cluster):
    """``ray_init_config={"runtime_env": {"py_modules": [...]}}`` (``collector.ray_runtime_env``)
    uploads the package: the actors import Ray's copy, not this checkout's."""
    proc = subprocess.run(
        [sys.executable, "-c", _SHIPPED_PACKAGE, two_node_cluster["address"]],
        env=two_node_cluster["env"],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    shipped = json.loads(proc.stdout.splitlines()[-1])
    assert shipped["frames"] == 16
    here = str(Path(trl_cartpole.__file__).parent)
    assert len(shipped["files"]) == 2
    for file in shipped["files"]:
        assert "runtime_resources/py_modules_files" in file and not file.startswith(here), file


@pytest.mark.slow  # two Ray nodes
def test_actors_asking_for_a_resource_no_node_has_are_refused_in_one_line(
    two_node_cluster, tmp_path
):
    """Ray would wait without end for a node with the resource; the run stops at once."""
    proc = run_script(
        "train.py",
        *SMOKE_OVERRIDES,
        "collector.backend=ray",
        f"collector.ray_address={two_node_cluster['address']}",
        "collector.ray_resources={collector_node: 1.5}",  # 3 in all; the worker node has 2
        *TWO_WORKERS,
        "collector.frames_per_batch=32",
        f"run_dir={tmp_path / 'run'}",
        env=two_node_cluster["env"],
        timeout=300,
    )
    lines = [line for line in proc.stderr.splitlines() if line.startswith("error:")]
    assert proc.returncode == 2 and len(lines) == 1, proc.stderr[-1500:]
    assert "collector_node=3 in all" in lines[0] and "collector_node=2" in lines[0], lines[0]


# --- sweeps ---------------------------------------------------------------------------------


def test_the_grid_of_a_sweep_is_every_combination():
    jobs = expand_grid(["seed=0,1", "algo=dqn,double", "optim.lr=1e-3", "hydra.launcher.n_jobs=2"])
    assert jobs == [
        ["seed=0", "algo=dqn", "optim.lr=1e-3"],
        ["seed=0", "algo=double", "optim.lr=1e-3"],
        ["seed=1", "algo=dqn", "optim.lr=1e-3"],
        ["seed=1", "algo=double", "optim.lr=1e-3"],
    ]
    assert len(expand_grid(["seed=range(3)"])) == 3


@pytest.mark.slow  # a sweep of training subprocesses
def test_a_sweep_trains_every_job_in_its_own_directory_and_plot_compares_them(tmp_path):
    sweep_dir = tmp_path / "sweep"
    smoke = [o for o in SMOKE_OVERRIDES if not o.startswith("logger.progress_bar")]
    proc = run_script(
        "train.py",
        "-m",
        "seed=0,1",
        "algo=dqn,double",
        *smoke,
        "logger.plots=false",
        f"hydra.sweep.dir={sweep_dir}",
        timeout=600,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    summaries = [json.loads(p.read_text()) for p in sorted(sweep_dir.glob("*/summary.json"))]
    assert sorted((s["algo"], s["seed"]) for s in summaries) == [
        ("double", 0),
        ("double", 1),
        ("dqn", 0),
        ("dqn", 1),
    ]
    assert len({s["run_dir"] for s in summaries}) == 4
    assert all(Path(s["run_dir"]).parent == sweep_dir for s in summaries)
    plotted = run_script("plot.py", str(sweep_dir), f"out={tmp_path / 'comparison'}")
    assert plotted.returncode == 0, plotted.stderr
    table = (tmp_path / "comparison.md").read_text()
    assert "| CartPole-v1 dqn | 0/2 |" in table and "| CartPole-v1 double | 0/2 |" in table


@pytest.mark.slow  # a sweep subprocess
def test_a_bad_point_of_a_sweep_stops_it_before_any_training(tmp_path):
    sweep_dir = tmp_path / "sweep"
    proc = run_script("train.py", "-m", "seed=0,-1", f"hydra.sweep.dir={sweep_dir}")
    lines = [line for line in proc.stderr.splitlines() if line.startswith("error:")]
    assert proc.returncode == 2 and lines == ["error: seed=-1 must be >= 0"], proc.stderr[-1500:]
    assert not sweep_dir.exists()


# --- a Ray actor dies mid-run ---------------------------------------------------------------


def _descendants(pid: int) -> list[int]:
    """The processes below ``pid`` (children, theirs...), read from /proc."""
    parents: dict[int, list[int]] = {}
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:  # the process ended meanwhile
            continue
        parents.setdefault(int(fields[1]), []).append(int(stat.parent.name))
    found, todo = [], [pid]
    while todo:
        children = parents.get(todo.pop(), [])
        found += children
        todo += children
    return found


def _title(pid: int) -> str:
    """A process's command line, or "" once it has ended."""
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes().decode(errors="replace")
    except OSError:
        return ""


def _ray_actor_processes(pid: int) -> list[int]:
    """The collector actors' processes of the run in process ``pid`` (titled ``ray::Collector``;
    Ray's own agents are ``ray::DashboardAgent``, ``ray::RuntimeEnvAgent``...)."""
    return [child for child in _descendants(pid) if _title(child).startswith("ray::Collector")]


def _start_ray_run(run_dir: Path) -> subprocess.Popen:
    """A long ``collector.backend=ray`` run with two actors, returned once it trains on both."""
    proc = subprocess.Popen(
        [
            sys.executable,
            str(Path(__file__).parents[1] / "scripts" / "train.py"),
            "collector.backend=ray",
            *TWO_WORKERS,
            "collector.total_frames=200000",
            "checkpoint.interval_frames=0",  # no training state but the one the stop makes
            "eval.stop_when_solved=false",  # still training when it is stopped
            "logger.progress_bar=false",
            "logger.plots=false",
            f"run_dir={run_dir}",
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    marker = run_dir / "metrics" / "scalars" / "train" / "episode_return.csv"
    deadline = time.monotonic() + 180
    while not (marker.is_file() and len(_ray_actor_processes(proc.pid)) == 2):
        assert proc.poll() is None, proc.communicate()
        assert time.monotonic() < deadline, "the run did not start training on two actors"
        time.sleep(0.2)
    return proc


@pytest.mark.slow  # a local Ray instance, an actor killed, then a resume on a new one
@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="finds Ray's processes in /proc")
def test_a_killed_ray_actor_stops_the_run_with_a_checkpoint_that_resumes(tmp_path):
    # Before: Ray's traceback ("The actor is dead because its worker process has died"), exit 1,
    # no resume hint.
    pytest.importorskip("ray")
    run_dir = tmp_path / "run"
    proc = _start_ray_run(run_dir)
    killed = _ray_actor_processes(proc.pid)[0]
    os.kill(killed, signal.SIGKILL)
    _, stderr = proc.communicate(timeout=120)  # no hang
    lines = [line for line in stderr.splitlines() if line.startswith("error:")]
    assert proc.returncode == 75 and len(lines) == 1, stderr[-3000:]
    assert "Ray collector actor" in lines[0] and f"(pid {killed}," in lines[0], lines[0]
    assert "died" in lines[0]
    assert f"resume={run_dir}" in lines[0] and "Traceback" not in stderr
    from torchrl.checkpoint import Checkpoint

    from trl_cartpole.store.checkpoint import find_resume_checkpoint

    frames = Checkpoint.manifest(find_resume_checkpoint(run_dir))["metadata"]["counters"]["frames"]
    assert frames > 0
    resumed = run_script(
        "train.py", f"resume={run_dir}", f"collector.total_frames={frames + 4000}", timeout=300
    )
    assert resumed.returncode == 0, resumed.stderr[-3000:]
    assert json.loads((run_dir / "summary.json").read_text())["frames"] >= frames + 4000
    # the actors' envs were not read once one was lost: new episodes, and the warning says why
    assert "after a worker or Ray actor was lost" in resumed.stdout + resumed.stderr


# --- the run's own Ray instance stays closed ------------------------------------------------

_START_LOCAL_RAY = """
import sys, ray
from trl_cartpole.parts.collectors import (
    default_ray_init_config, guard_local_ray_with_a_token_of_its_own,
)
guard_local_ray_with_a_token_of_its_own()
ray.init(**default_ray_init_config(None, 1))
print(ray.get_runtime_context().gcs_address, flush=True)
sys.stdin.read()  # until the test closes it
"""

_JOIN = "import ray; ray.init(address={address!r}); print(ray.cluster_resources()['CPU'])"


def _without_ray_settings(home: Path, **extra: str) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if not k.startswith("RAY_")}
    return {**env, "HOME": str(home), "RAY_USAGE_STATS_ENABLED": "0", **extra}


@pytest.mark.slow  # a local Ray instance and three processes that import Ray
def test_the_runs_own_ray_instance_refuses_a_client_without_its_token(tmp_path):
    # Before: Ray wrote the token to ~/.ray/auth_token, mode 644 (every user could read it), and
    # every later local instance used the same one.
    pytest.importorskip("ray")
    home = tmp_path / "home"
    home.mkdir()
    server = subprocess.Popen(
        [sys.executable, "-c", _START_LOCAL_RAY],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL,
        text=True,
        env=_without_ray_settings(home),
        start_new_session=True,
    )
    try:
        address = server.stdout.readline().strip()
        assert address, "the local Ray instance did not start"
        assert not (home / ".ray" / "auth_token").exists()  # no token file for others to read
        # The token is in the environment of the Ray processes the run started (the GCS server
        # first), which only their owner can read.
        gcs = next(p for p in _descendants(server.pid) if "gcs_server" in _title(p))
        environ = Path(f"/proc/{gcs}/environ")
        assert environ.stat().st_mode & 0o077 == 0
        variables = [item.split("=", 1) for item in environ.read_text().split("\0") if "=" in item]
        token = dict(variables)["RAY_AUTH_TOKEN"]
        join = [sys.executable, "-c", _JOIN.format(address=address)]
        refused = subprocess.run(
            join,
            capture_output=True,
            text=True,
            timeout=120,
            env=_without_ray_settings(home, RAY_AUTH_MODE="token", RAY_AUTH_TOKEN="0" * 64),
        )
        assert refused.returncode != 0, refused.stdout
        assert "auth" in refused.stderr.lower() or "token" in refused.stderr.lower()
        joined = subprocess.run(
            join,
            capture_output=True,
            text=True,
            timeout=120,
            env=_without_ray_settings(home, RAY_AUTH_MODE="token", RAY_AUTH_TOKEN=token),
        )
        assert joined.returncode == 0, joined.stderr[-2000:]  # the token is what was missing
    finally:
        server.stdin.close()
        try:
            server.wait(timeout=30)
        except subprocess.TimeoutExpired:
            os.killpg(server.pid, signal.SIGKILL)
            server.wait()


@pytest.mark.slow  # a local Ray instance and a signal to its driver
@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="finds Ray's processes in /proc")
def test_sigterm_to_a_run_on_ray_saves_a_checkpoint(tmp_path):
    # Before: ray.init's own SIGTERM handler (in C) printed a stack trace and killed the run,
    # with no checkpoint and no resume hint.
    pytest.importorskip("ray")
    run_dir = tmp_path / "run"
    proc = _start_ray_run(run_dir)
    os.kill(proc.pid, signal.SIGTERM)
    _, stderr = proc.communicate(timeout=120)
    assert proc.returncode == 143, stderr[-3000:]
    assert "stopped by SIGTERM" in stderr and f"resume={run_dir}" in stderr
    assert "SIGTERM received" not in stderr  # Ray's handler did not run
    from trl_cartpole.store.checkpoint import find_resume_checkpoint

    assert find_resume_checkpoint(run_dir).is_dir()

"""Run presets over seeds in separate processes and summarise them: the engine of the benchmarks.

Each (preset, seed) is one ``scripts/train.py`` process, each (peer, seed) one
``python -m benchmarks.peers.<peer>`` process (run from the repository root), one after another
by default so every run sees the same machine; a run whose ``summary.json`` already exists is
read, not repeated. The ``python -m benchmarks`` subcommands are command lines over these.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import queue
import re
import shutil
import statistics
import subprocess
import sys
import threading
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

from trl_cartpole.tools.comparison import median_to_solve

__all__ = [
    "ENV_MEDIAN_TARGETS",
    "ENV_TARGETS",
    "LUNARLANDER_BUDGET_SECONDS",
    "PEERS",
    "run_peer",
    "run_presets",
    "run_training",
    "seconds_per_frame",
    "speed_ratios",
    "sweep_arguments",
]

REPOSITORY = Path(__file__).resolve().parents[1]  # the checkout: benchmarks/ is not installed
TRAIN_SCRIPT = REPOSITORY / "scripts" / "train.py"
CONFIG_DIR = REPOSITORY / "configs"
# Every preset of configs/algo/ that is the default plus DQN improvements.
VARIANT_PRESETS = ("dqn", "double", "dueling", "noisy", "prioritized", "nstep", "c51", "rainbow")


# The env presets of configs/env/ with a target (docs/environments.md): the median over seeds of
# the best policy's final 100-episode greedy return must reach it.
# The final greedy return every seed of an env preset must reach, and (LunarLander) the median
# over seeds it must reach too (docs/environments.md).
ENV_TARGETS = {
    "acrobot": -80.0,
    "mountaincar": -105.0,
    "lunarlander": 200.0,
    "cartpole_pixels": 450.0,  # played on Gymnasium's render() frames
}
ENV_MEDIAN_TARGETS = {"lunarlander": 240.0, "cartpole_pixels": 475.0}
# and the pixel preset's budget: training seconds and peak memory of every seed
PIXEL_BUDGET = {"train_seconds": 1800.0, "peak_rss_mb": 4096.0}
# LunarLander's best policy at its target within this much training (docs/results/peers.md)
LUNARLANDER_BUDGET_SECONDS = 300.0


PEERS = {  # name -> module run as ``python -m`` (see benchmarks.peers)
    "tutorial_loop": "benchmarks.peers.tutorial_loop",
    "sb3_dqn": "benchmarks.peers.sb3_dqn",
    "tianshou_dqn": "benchmarks.peers.tianshou_dqn",
    "sbx_dqn": "benchmarks.peers.sbx_dqn",
}
# Peers whose packages cannot sit beside the project's (Tianshou 2.0.1 pins pandas<3 and needs
# numba; SBX needs JAX) run from a virtual environment of their own, made on first use: this
# project, the same torch build and these packages.
PEER_VENVS = {
    "tianshou_dqn": ["tianshou==2.0.1"],
    "sbx_dqn": [  # as resolved on 2026-12-03, pinned so the peer is the same one each time
        "sbx-rl==0.28.0",
        "stable-baselines3==2.9.2",
        "jax==0.10.2",
        "jaxlib==0.10.2",
        "flax==0.12.8",
        "optax==0.2.8",
        "tfp-nightly==0.26.0.dev20261027",
    ],
}
PEER_VENV_ROOT = Path("runs") / "peer-venvs"
# Peers whose library spreads over every core whatever its thread settings (XLA's CPU client):
# each run is pinned to a core of its own for its lifetime, as the others' one torch thread
# takes one core's work (``--jobs 2``: two such runs on two cores).
PINNED_PEERS = {"sbx_dqn"}
_FREE_CORES: queue.Queue[int] = queue.Queue()
for _core in sorted(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else []:
    _FREE_CORES.put(_core)
_PEER_VENV_LOCK = threading.Lock()  # --jobs 2 starts two runs of a peer at once: make it once


def provenance() -> dict[str, Any]:
    """When, at which commit and on which machine a result was measured (for results files)."""
    import datetime
    import platform

    cpu, vector_units = platform.processor() or "unknown CPU", []
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
            elif line.startswith("flags"):  # the float kernels torch picks depend on these
                flags = line.split(":", 1)[1].split()
                vector_units = sorted(f for f in flags if f.startswith(("avx", "fma", "amx")))
                break
    except OSError:
        pass
    commit = subprocess.run(
        ["git", "rev-parse", "HEAD"], cwd=REPOSITORY, capture_output=True, text=True, check=False
    ).stdout.strip()
    from trl_cartpole.run.summary import cpu_kernels

    machine = {"cpu": cpu, "cores": os.cpu_count(), "vector_units": vector_units}
    machine["kernels"] = cpu_kernels()  # what torch runs of those flags, if held below them
    return {
        "date": datetime.date.today().isoformat(),
        "commit": commit or "unknown",
        "machine": machine,
    }


def provenance_line(record: dict[str, Any]) -> str:
    """``Measured 2026-11-25 at commit abc1234 on <CPU> (2 cores).``"""
    machine = record["machine"]
    limits = machine.get("kernels", {}).get("limits", {})
    held = f", {', '.join(f'{k}={v}' for k, v in limits.items())}" if limits else ""
    return (
        f"Measured {record['date']} at commit `{record['commit'][:7]}` on {machine['cpu']} "
        f"({machine['cores']} cores{held})."
    )


def peer_python(peer: str) -> str:
    """The interpreter that runs ``peer``: this one, or its own virtual environment's.

    The environment is ``runs/peer-venvs/<peer>``; a ``.complete`` marker naming its packages is
    written once its install succeeded, so one cut off midway, or made for other pins, is made
    again. Runs of the benchmark's worker threads that ask at the same time wait for the first
    to make it.
    """
    if peer not in PEER_VENVS:
        return sys.executable
    venv = (REPOSITORY / PEER_VENV_ROOT / peer).resolve()
    python = venv / "bin" / "python"
    complete = venv / ".complete"  # the packages installed, once the install succeeded
    with _PEER_VENV_LOCK:
        if not complete.is_file() or complete.read_text().split() != _venv_packages(peer):
            _make_peer_venv(peer, venv)
    return str(python)


def _make_peer_venv(peer: str, venv: Path) -> None:
    """Make ``venv`` afresh: this project, the same torch build and ``PEER_VENVS[peer]``."""
    python = venv / "bin" / "python"
    shutil.rmtree(venv, ignore_errors=True)
    print(f"making {venv} for {peer} (once; a few minutes)", file=sys.stderr, flush=True)
    subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True)
    packages = _venv_packages(peer)  # the CPU torch build first
    install = [str(python), "-m", "pip", "install", "-q", *packages]
    subprocess.run([*install, "-e", str(REPOSITORY)], check=True)
    (venv / ".complete").write_text(" ".join(packages) + "\n")


def _venv_packages(peer: str) -> list[str]:
    """What ``peer``'s virtual environment is made of: the torch build of this one, and its pins."""
    import torch

    return [f"torch=={torch.__version__.split('+')[0]}", *PEER_VENVS[peer]]


def subprocess_env() -> dict[str, str]:
    """This environment with the repository root on ``PYTHONPATH``, so ``benchmarks`` imports."""
    paths = [str(REPOSITORY), *filter(None, os.environ.get("PYTHONPATH", "").split(os.pathsep))]
    return {**os.environ, "PYTHONPATH": os.pathsep.join(paths)}


def _run_once(command: list[str], run_dir: Path, core: int | None = None) -> dict[str, Any]:
    """Run ``command`` in the repository root unless ``run_dir/summary.json`` exists; return
    that summary. With ``core``, the process and every thread it starts run on that core
    only (set before it executes, so no thread escapes)."""
    summary_path = run_dir / "summary.json"
    if not summary_path.exists():
        subprocess.run(
            command,
            check=True,
            stdout=subprocess.DEVNULL,
            cwd=REPOSITORY,
            env=subprocess_env(),
            preexec_fn=None if core is None else lambda: os.sched_setaffinity(0, {core}),
        )
    return json.loads(summary_path.read_text())


def _run_folder(name: str) -> str:
    """A preset or peer as a run folder's name: every character but letters, digits, ``.`` and
    ``-`` made ``_`` (``dqn+fast=true`` -> ``dqn_fast_true``), a value Hydra's parser takes."""
    return re.sub(r"[^A-Za-z0-9.-]", "_", name)


def run_training(algo: str, seed: int, out: Path, overrides: Sequence[str] = ()) -> dict[str, Any]:
    """Train ``algo`` with ``seed`` into ``out/<algo>-seed<seed>`` and return its summary.

    ``algo`` is a preset, or a preset with overrides of its own joined by ``+``
    (``dqn+fast=true``: the dqn preset on the fast path), given after ``overrides``, in the
    folder :func:`_run_folder` names (``dqn_fast_true-seed0``).
    """
    preset, *own = algo.split("+")
    if not preset or not all(own):
        raise SystemExit(
            f"error: --algos {algo!r}: write a preset, then key=value pieces joined by +"
        )
    run_dir = (
        out / f"{_run_folder(algo)}-seed{seed}"
    ).resolve()  # the process runs in the repository root
    command = [
        sys.executable,
        str(TRAIN_SCRIPT),
        f"algo={preset}",
        f"seed={seed}",
        f"run_dir={run_dir}",
        "logger.progress_bar=false",
        *overrides,
        *own,
    ]
    return _run_once(command, run_dir)


def run_peer(peer: str, seed: int, out: Path, peer_args: Sequence[str] = ()) -> dict[str, Any]:
    """Run the peer ``peer`` (a key of ``PEERS``) with ``seed`` into ``out/<peer>-seed<seed>``."""
    run_dir = (out / f"{peer}-seed{seed}").resolve()
    command = [peer_python(peer), "-m", PEERS[peer], "--seed", str(seed), "--run-dir", str(run_dir)]
    if peer not in PINNED_PEERS or not hasattr(os, "sched_setaffinity"):  # macOS: no pinning
        return _run_once([*command, *peer_args], run_dir)
    core = _FREE_CORES.get()  # waits while every core holds a pinned run
    try:
        return _run_once([*command, *peer_args], run_dir, core=core)
    finally:
        _FREE_CORES.put(core)


def _job_count(text: str) -> int:
    if int(text) < 1:
        raise argparse.ArgumentTypeError(
            f"--jobs {text}: run at least one process at a time (--jobs 1)"
        )
    return int(text)


def sweep_arguments(seeds: Sequence[int], out: str) -> argparse.ArgumentParser:
    """The arguments every subcommand shares, as a parent parser with these defaults:
    ``--seeds``, ``--jobs`` (>= 1), ``--out`` and trailing Hydra overrides."""
    parser = argparse.ArgumentParser(add_help=False)
    parser.add_argument("--seeds", nargs="+", type=int, default=list(seeds))
    parser.add_argument("--jobs", type=_job_count, default=1, help="runs at a time")
    parser.add_argument("--out", type=Path, default=Path(out), help="output directory")
    parser.add_argument("overrides", nargs="*", help="Hydra overrides (key=value) for every run")
    return parser


def run_presets(
    algos: Sequence[str],
    seeds: Sequence[int],
    out: Path,
    overrides: Sequence[str] = (),
    peers: Sequence[str] = (),
    peer_args: Sequence[str] = (),
    jobs: int = 1,
) -> dict[str, list[dict[str, Any]]]:
    """``{algo or peer: [summary per seed]}``, every run in its own process.

    ``jobs`` processes run at a time (1: one after another, so every run sees the same idle
    machine; more overlap runs, slowing each a little but all alike). The runs go seed by seed,
    every preset and peer on a seed before the next seed, so a machine that drifts over the
    benchmark slows them all alike.
    """
    folders = [_run_folder(name) for name in [*algos, *peers]]
    if len(set(folders)) < len(folders):
        raise SystemExit(f"error: --algos {' '.join(algos)}: two entries would share a run folder")
    tasks = [(run_training, algo, overrides) for algo in algos]
    tasks += [(run_peer, peer, peer_args) for peer in peers]
    with ThreadPoolExecutor(max_workers=jobs) as pool:
        futures: dict[str, list[Any]] = {name: [] for _, name, _ in tasks}
        for seed in seeds:
            for run, name, extra in tasks:
                futures[name].append(pool.submit(run, name, seed, out, extra))
        return {name: [future.result() for future in runs] for name, runs in futures.items()}


def seconds_per_frame(runs: Sequence[dict[str, Any]]) -> float:
    """Median over seeds of training seconds per collected frame (evaluation excluded)."""
    return statistics.median(r["train_seconds"] / r["frames"] for r in runs)


def speed_ratios(
    results: dict[str, list[dict[str, Any]]], ours: str, peers: Sequence[str]
) -> dict[str, float | None]:
    """``{peer: median seconds_to_solve of peer / that of ours}``.

    ``inf`` when the peer did not solve most seeds and ours did, ``0`` the other way round,
    ``None`` when neither did (no ratio to speak of).
    """
    mine = median_to_solve([r["seconds_to_solve"] for r in results[ours]])
    ratios: dict[str, float | None] = {}
    for peer in peers:
        theirs = median_to_solve([r["seconds_to_solve"] for r in results[peer]])
        if math.isinf(mine):
            ratios[peer] = None if math.isinf(theirs) else 0.0
        else:
            ratios[peer] = theirs / mine
    return ratios


def command_parser(
    prog: str,
    description: str,
    modules: dict[str, Any],
    parents: Callable[[Any], list[argparse.ArgumentParser]] = lambda module: [],
) -> argparse.ArgumentParser:
    """``prog <command>``: one subcommand per module of ``modules`` (its docstring the help, its
    ``add_arguments`` the options, its ``main`` what runs), with ``parents(module)``'s arguments
    (``python -m benchmarks`` and ``python -m maintain``)."""
    parser = argparse.ArgumentParser(
        prog=prog, description=description, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    subparsers = parser.add_subparsers(dest="subcommand", required=True, metavar="COMMAND")
    for name, module in modules.items():
        subparser = subparsers.add_parser(
            name,
            parents=parents(module),
            help=module.__doc__.splitlines()[0],
            description=module.__doc__,
            formatter_class=argparse.RawDescriptionHelpFormatter,
        )
        module.add_arguments(subparser)
        subparser.set_defaults(main=module.main)
    return parser

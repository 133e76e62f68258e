"""Compare finished runs: load their summaries, group them by config, tabulate them.

``scripts/plot.py`` and the benchmark tools (``python -m benchmarks``) read runs through these
functions: runs whose configs differ only in seed and run directory form one group, reported
by solve rate, interquartile means with bootstrap intervals, medians and slowest seeds.
"""

from __future__ import annotations

import json
import math
import statistics
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from omegaconf import OmegaConf

from trl_cartpole.config.schema import flat_fields
from trl_cartpole.errors import ConfigError
from trl_cartpole.report.console import solve_status
from trl_cartpole.report.interval_estimates import Estimate, interval_estimate

__all__ = [
    "expand_sweep_dirs",
    "group_runs",
    "iqm_to_solve",
    "load_runs",
    "markdown_table",
    "median_to_solve",
    "read_summary",
]


def _unsolved_as_inf(values: Sequence[float | None]) -> list[float]:
    """Frames or seconds to solve per seed, an unsolved seed (``None``) as ``inf``."""
    return [math.inf if value is None else value for value in values]


def median_to_solve(values: Sequence[float | None]) -> float:
    """Median over seeds with an unsolved seed counted as infinitely slow.

    The result is finite when more than half of the seeds solved; ``inf`` otherwise.
    """
    return statistics.median(_unsolved_as_inf(values))


def iqm_to_solve(values: Sequence[float | None]) -> Estimate:
    """Interquartile mean over seeds and its 95 % interval, an unsolved seed infinitely slow.

    The value is finite when at most a quarter of the seeds did not solve; ``inf`` otherwise.
    """
    return interval_estimate(_unsolved_as_inf(values))


def _format(value: float, digits: int) -> str:
    return "not solved" if math.isinf(value) else f"{value:.{digits}f}"


def _median_of(runs: Sequence[dict[str, Any]], key: str, digits: int) -> str:
    values = [r[key] for r in runs if r.get(key) is not None]
    return f"{statistics.median(values):.{digits}f}" if values else "-"


def _estimate(values: Sequence[float | None], digits: int) -> tuple[str, str, str]:
    """IQM [95% CI], median and slowest (largest) of frames or seconds to solve."""
    estimate = iqm_to_solve(values)
    iqm_text = "not solved" if math.isinf(estimate.value) else str(estimate)
    slowest = max(_unsolved_as_inf(values))
    return iqm_text, _format(median_to_solve(values), digits), _format(slowest, digits)


def markdown_table(results: dict[str, list[dict[str, Any]]], label: str = "preset") -> str:
    """Two tables. The first, one row per preset: solve rate; frames and seconds to solve as the
    interquartile mean with its 95 % stratified bootstrap interval, the median and the slowest
    seed (an unsolved seed counts as infinitely slow); the final greedy return's IQM and
    interval; and the medians of wall time, throughput and peak memory
    (:mod:`trl_cartpole.report.interval_estimates`). The second, each seed's frames and seconds
    to solve, apart so that their lists do not squeeze the first one's columns."""
    lines = [
        f"| {label} | solved | frames_to_solve IQM [95% CI] | median | slowest | "
        "seconds_to_solve IQM [95% CI] | median | slowest | "
        "final 100-ep greedy return IQM [95% CI] | "
        "median wall seconds | collect frames/s | updates/s | peak RSS MiB |",
        "| --- " * 13 + "|",
    ]
    per_seed = [
        f"| {label} | frames_to_solve per seed | seconds_to_solve per seed |",
        "| --- | --- | --- |",
    ]
    for algo, runs in results.items():
        frames = [r["frames_to_solve"] for r in runs]
        seconds = [r["seconds_to_solve"] for r in runs]
        final = interval_estimate([r["final_eval_return_mean"] for r in runs])
        lines.append(
            f"| {algo} | {_solved_cell(runs)} | "
            f"{' | '.join(_estimate(frames, 0))} | {' | '.join(_estimate(seconds, 1))} | "
            f"{final} | "
            f"{statistics.median(r['wall_seconds'] for r in runs):.1f} | "
            f"{_median_of(runs, 'collect_frames_per_second', 0)} | "
            f"{_median_of(runs, 'updates_per_second', 0)} | {_median_of(runs, 'peak_rss_mb', 0)} |"
        )
        per_seed.append(
            f"| {algo} | {', '.join('-' if f is None else str(f) for f in frames)} | "
            f"{', '.join('-' if s is None else f'{s:.1f}' for s in seconds)} |"
        )
    return "\n".join(lines) + "\n\n" + "\n".join(per_seed)


def _solved_cell(runs: list[dict[str, Any]]) -> str:
    """``solved/runs``, and how many of the solved did not hold it: a final evaluation below the
    threshold (the run's own verdict, :func:`~trl_cartpole.report.console.solve_status`)."""
    solved = [r for r in runs if r["solved"]]
    not_held = [r for r in solved if solve_status(r) == "not held"]
    cell = f"{len(solved)}/{len(runs)}"
    return f"{cell} ({len(not_held)} not held)" if not_held else cell


# Fields that differ between seeds of one config, not between configs.
PER_RUN_FIELDS = ("seed", "run_dir")


def expand_sweep_dirs(run_dirs: Sequence[Path]) -> list[Path]:
    """Each directory, or for a sweep directory (no ``config.yaml`` of its own) its job folders."""
    expanded: list[Path] = []
    for run_dir in run_dirs:
        if run_dir.is_dir() and not (run_dir / "config.yaml").is_file():
            jobs = sorted(child for child in run_dir.iterdir() if (child / "config.yaml").is_file())
            expanded.extend(jobs or [run_dir])
        else:
            expanded.append(run_dir)
    return expanded


def load_runs(run_dirs: Sequence[Path]) -> list[dict[str, Any]]:
    """``[{"run_dir", "summary", "config"}]`` for each directory holding a ``summary.json``.

    A sweep directory (``python scripts/train.py -m ...``) stands for its jobs' directories.

    Directories without one (a run still going, or one that failed) or whose summary predates
    ``eval_curve`` are skipped with a line on stderr.
    """
    runs = []
    for run_dir in expand_sweep_dirs(run_dirs):
        summary_path, config_path = run_dir / "summary.json", run_dir / "config.yaml"
        if not summary_path.is_file() or not config_path.is_file():
            print(f"skipped {run_dir}: no summary.json/config.yaml", file=sys.stderr)
            continue
        summary = read_summary(summary_path)
        if "eval_curve" not in summary:
            print(f"skipped {run_dir}: summary.json has no eval_curve (older run)", file=sys.stderr)
            continue
        runs.append({"run_dir": run_dir, "summary": summary, "config": _read_config(config_path)})
    return runs


# What the comparison reads of a summary.json: key -> the types its value may have.
_NUMBER = (int, float)
SUMMARY_FIELDS: dict[str, tuple[type, ...]] = {
    "solved": (bool,),
    "solve_threshold": (*_NUMBER, type(None)),  # None: an env with no threshold
    "frames_to_solve": (int, type(None)),
    "seconds_to_solve": (*_NUMBER, type(None)),
    "final_eval_return_mean": _NUMBER,
    "wall_seconds": _NUMBER,
}


def _damaged(path: Path, what: str) -> ConfigError:
    return ConfigError(f"{path} is damaged ({what}); re-run that run or leave its directory out")


def read_summary(path: Path) -> dict[str, Any]:
    """A run's ``summary.json``, checked for what the comparison reads; damage is a one-line
    :class:`ConfigError` naming the file (a summary older than ``eval_curve`` is returned as is
    for the caller to skip)."""
    try:
        summary = json.loads(path.read_text())
    except (UnicodeDecodeError, json.JSONDecodeError) as error:
        raise _damaged(path, f"not JSON: {error}") from None
    if not isinstance(summary, dict):
        raise _damaged(path, f"a JSON {type(summary).__name__}, not an object")
    if "eval_curve" not in summary:
        return summary  # older than the evaluation curve: the caller skips it
    for key, types in SUMMARY_FIELDS.items():
        if key not in summary:
            raise _damaged(path, f"no {key!r}")
        value = summary[key]
        if not isinstance(value, types) or (isinstance(value, bool) and bool not in types):
            raise _damaged(path, f"{key!r} is {value!r}")
    _check_eval_curve(path, summary["eval_curve"])
    return summary


def _check_eval_curve(path: Path, curve: Any) -> None:
    """``eval_curve``: equally long, non-empty lists of numbers under frames and returns (and
    seconds, where the run recorded them)."""
    if not isinstance(curve, dict) or not {"frames", "returns"} <= set(curve):
        raise _damaged(path, "'eval_curve' lacks its frames and returns")
    lengths = set()
    for key in ("frames", "returns", "seconds"):
        values = curve.get(key, curve["frames"])
        if not isinstance(values, list) or not all(
            isinstance(v, _NUMBER) and not isinstance(v, bool) and math.isfinite(v) for v in values
        ):
            raise _damaged(path, f"'eval_curve.{key}' is not a list of finite numbers")
        lengths.add(len(values))
    if len(lengths) != 1 or 0 in lengths:
        raise _damaged(path, "'eval_curve' lists are empty or of different lengths")


def _read_config(path: Path) -> dict[str, Any]:
    """A run's ``config.yaml`` as a dict; damage is a one-line :class:`ConfigError`."""
    try:
        config = OmegaConf.to_container(OmegaConf.load(path))
    except Exception as error:  # YAML's and OmegaConf's errors alike
        raise _damaged(path, str(error).splitlines()[0]) from None
    if not isinstance(config, dict):
        raise _damaged(path, "not a mapping of settings")
    return config


def group_runs(runs: Sequence[dict[str, Any]]) -> dict[str, list[dict[str, Any]]]:
    """Group runs whose configs are equal but for the seed and run directory.

    A group is labelled by its env and ``algo.name``; when several groups share that label,
    the fields that tell them apart are appended (``CartPole-v1 dqn optim.lr=0.0005``). A seed
    counts once in its group: of two runs of one config and seed (a repeat), the one whose
    directory sorts last (the newest) is kept, the other skipped with a line on stderr.
    """
    groups: dict[tuple, list[dict[str, Any]]] = {}
    flats: dict[tuple, dict[str, Any]] = {}
    for run in runs:
        flat = {k: v for k, v in flat_fields(run["config"]).items() if k not in PER_RUN_FIELDS}
        key = tuple(sorted(flat.items(), key=lambda item: item[0]))
        groups.setdefault(key, []).append(run)
        flats[key] = flat
    base_labels = {key: f"{flat['env.id']} {flat['algo.name']}" for key, flat in flats.items()}
    labelled = {}
    for key, members in groups.items():
        label = base_labels[key]
        clashes = [other for other in groups if other != key and base_labels[other] == label]
        if clashes:
            differing = sorted(
                field
                for field, value in flats[key].items()
                if any(flats[other].get(field) != value for other in clashes)
            )
            label += " " + " ".join(f"{field}={flats[key][field]}" for field in differing)
        labelled[label] = _one_run_a_seed(label, members)
    return labelled


def _one_run_a_seed(label: str, members: list[dict[str, Any]]) -> list[dict[str, Any]]:
    kept: dict[Any, dict[str, Any]] = {}
    for run in sorted(members, key=lambda run: str(run["run_dir"])):
        seed = flat_fields(run["config"])["seed"]
        if seed in kept:
            print(
                f"skipped {kept[seed]['run_dir']}: seed {seed} of {label} again, counted once "
                f"(as {run['run_dir']})",
                file=sys.stderr,
            )
        kept[seed] = run
    return sorted(kept.values(), key=lambda run: flat_fields(run["config"])["seed"])

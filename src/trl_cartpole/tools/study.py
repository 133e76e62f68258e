"""An Optuna study over the trials of :mod:`trl_cartpole.tools.tuning`: storage, pruning, results.

Needs the ``tune`` extra (``pip install -e ".[tune]"``). The study is stored in ``storage``
(``sqlite:///runs/tune/<study>/study.db`` by default: a stopped study resumes, and the
processes of ``jobs`` share it; any database URL Optuna takes, e.g. PostgreSQL, for workers on
several machines). Sampling is TPE (``optuna.samplers.TPESampler``), pruning Optuna's
``MedianPruner`` (once 5 trials are complete, a trial stops when its running score is below
the median of the earlier trials' at the same step, from a quarter of its frame budget on: the
first evaluations, right after the random warm-up, say little about where a run ends). A trial
whose run fails (a non-finite loss, a sampled combination the config refuses) is recorded as
failed and the study goes on. Trials are counted to ``trials`` finished (complete, pruned or
failed) across all processes; parallel workers may finish a few more.
"""

from __future__ import annotations

import contextlib
import multiprocessing
import shutil
import sqlite3
import sys
import warnings
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from trl_cartpole.config.compose import compose_config
from trl_cartpole.config.presets import preset_dirs
from trl_cartpole.errors import ConfigError, TrainingFailed, install_hint
from trl_cartpole.tools.tuning import (
    OBJECTIVES,
    load_search_space,
    suggest,
    trial_score,
    variant_switch_defaults,
    write_preset,
)

try:
    import optuna
except ImportError:  # the tune extra
    optuna = None

__all__ = ["StudyResult", "run_study"]

FINISHED = ("COMPLETE", "PRUNED", "FAIL")


@dataclass
class StudyResult:
    best_value: float
    best_params: dict[str, Any]
    finished: int
    pruned: int
    summary: str
    preset: Path


SQLITE_HEADER = b"SQLite format 3\x00"  # the first 16 bytes of every SQLite database file
OPTUNA_TABLES = {"studies", "trials", "version_info"}  # tables every Optuna RDB storage has


def check_sqlite_storage(url: str) -> None:
    """Refuse, in one line and before Optuna writes to it, an SQLite ``storage`` that is damaged
    or belongs to another program (Optuna would add its tables to any database it opens)."""
    if not url.startswith("sqlite:///"):
        return
    path = Path(url.removeprefix("sqlite:///"))
    if not path.exists() or path.stat().st_size == 0:
        return  # a new study
    fix = "move it away or name another storage="
    with path.open("rb") as file:
        if file.read(len(SQLITE_HEADER)) != SQLITE_HEADER:
            raise ConfigError(f"storage={url} is not an SQLite database (damaged?); {fix}")
    try:
        with contextlib.closing(sqlite3.connect(f"file:{path}?mode=ro", uri=True)) as db:
            tables = {row[0] for row in db.execute("SELECT name FROM sqlite_master")}
            check = db.execute("PRAGMA quick_check").fetchall()
    except sqlite3.DatabaseError as error:
        check = [(str(error),)]
    if check != [("ok",)]:
        raise ConfigError(f"storage={url} is a damaged SQLite database ({check[0][0]}); {fix}")
    if tables and not OPTUNA_TABLES.issubset(tables):
        shown = ", ".join(sorted(tables)[:5])
        raise ConfigError(
            f"storage={url} is another program's SQLite database (tables {shown}), not an "
            f"Optuna study; {fix}"
        )


def check_study_space(study: Any, space: dict[str, Any], storage: str) -> None:
    """Refuse to continue a study whose trials were sampled over other parameters."""
    tuned = {name for trial in _finished(study) for name in trial.params}
    if tuned and tuned != set(space):
        raise ConfigError(
            f"study {study.study_name!r} in {storage} was tuned over {', '.join(sorted(tuned))}; "
            f"this search space is over {', '.join(sorted(space))}: name another study="
        )


def _storage(url: str) -> Any:
    """An RDB storage that waits for SQLite's lock when several processes write."""
    if url.startswith("sqlite:///"):
        Path(url.removeprefix("sqlite:///")).parent.mkdir(parents=True, exist_ok=True)
        return optuna.storages.RDBStorage(url, engine_kwargs={"connect_args": {"timeout": 60}})
    return url


def _pruner(name: Any, warmup_steps: int = 0) -> Any:
    """``median``, ``none``, or an ``optuna.pruners`` object (one process only).

    ``median`` prunes no trial at a step (frames) below ``warmup_steps``.
    """
    if not isinstance(name, str):
        return name
    if name == "none":
        return optuna.pruners.NopPruner()
    return optuna.pruners.MedianPruner(
        n_startup_trials=5, n_warmup_steps=warmup_steps, n_min_trials=1
    )


def _finished(study: Any) -> list[Any]:
    states = [getattr(optuna.trial.TrialState, name) for name in FINISHED]
    return study.get_trials(deepcopy=False, states=states)


def _work(spec: dict[str, Any]) -> None:
    """One worker: trials until the study holds ``spec['trials']`` finished ones."""
    optuna.logging.set_verbosity(optuna.logging.WARNING)
    study = optuna.load_study(
        study_name=spec["study_name"],
        storage=_storage(spec["storage"]),
        sampler=optuna.samplers.TPESampler(),
        pruner=_pruner(spec["pruner"], spec["prune_after_frames"]),
    )
    space = spec["space"]
    study_dir = Path(spec["study_dir"])

    def objective(trial: Any) -> float:
        params = suggest(trial, space)
        trial_dir = study_dir / f"trial-{trial.number:04d}"

        def report(step: int, value: float) -> None:
            trial.report(value, step)
            if trial.should_prune():
                raise optuna.TrialPruned()

        try:
            return trial_score(
                spec["config_dir"],
                spec["overrides"],
                params,
                spec["seeds"],
                trial_dir,
                report,
                spec["objective"],
            )
        finally:
            shutil.rmtree(trial_dir, ignore_errors=True)  # a trial's runs are not kept

    def enough(study: Any, _trial: Any) -> None:
        if len(_finished(study)) >= spec["trials"]:
            study.stop()

    def tell(study: Any, trial: Any) -> None:
        if trial.state == optuna.trial.TrialState.PRUNED:
            value = f"pruned at step {trial.last_step}"
        elif trial.state == optuna.trial.TrialState.FAIL:
            value = "failed (its error is logged above)"
        else:
            value = f"score {trial.value:.1f}"
        print(
            f"trial {trial.number}: {value} ({len(_finished(study))}/{spec['trials']})",
            file=sys.stderr,
            flush=True,
        )

    if len(_finished(study)) < spec["trials"]:
        study.optimize(objective, callbacks=[tell, enough], catch=(TrainingFailed, ConfigError))


def run_study(
    config_dir: str | Path,
    overrides: Sequence[str],
    trials: int,
    out: str | Path,
    jobs: int = 1,
    storage: str | None = None,
    study_name: str | None = None,
    space_path: str | Path | None = None,
    seeds: Sequence[int] = (0,),
    pruner: Any = "median",
    objective: str = "return",
) -> StudyResult:
    """Run (or continue) a study to ``trials`` finished trials; write the best as a preset."""
    if optuna is None:
        raise ConfigError(f"tuning needs Optuna: {install_hint('tune')}")
    cfg = compose_config(config_dir, list(overrides))
    preset = next((arg.split("=", 1)[1] for arg in overrides if arg.startswith("env=")), "cartpole")
    space = load_search_space(space_path or _preset_space(config_dir, overrides, preset))
    study_name = study_name or preset
    storage = storage or f"sqlite:///{Path('runs') / 'tune' / study_name / 'study.db'}"
    if storage.startswith("sqlite:///"):  # the plots go beside the database
        study_dir = Path(storage.removeprefix("sqlite:///")).parent
    else:
        study_dir = Path("runs") / "tune" / study_name
    optuna.logging.set_verbosity(optuna.logging.WARNING)
    _open_study(study_name, storage, objective, space)
    spec = {
        "study_name": study_name,
        "storage": storage,
        "pruner": pruner,
        "prune_after_frames": cfg.collector.total_frames // 4,
        "space": space,
        "study_dir": str(study_dir),
        "config_dir": str(config_dir),
        "overrides": [arg for arg in overrides if not arg.startswith("seed=")],
        "seeds": list(seeds),
        "trials": trials,
        "objective": objective,
    }
    if not isinstance(pruner, str) and jobs > 1:
        raise ConfigError("a pruner object works with jobs=1 only; name one for several jobs")
    _run_trials(spec, jobs)
    study = optuna.load_study(study_name=study_name, storage=_storage(storage))
    finished = _finished(study)
    pruned = sum(t.state == optuna.trial.TrialState.PRUNED for t in finished)
    failed = sum(t.state == optuna.trial.TrialState.FAIL for t in finished)
    if not any(t.state == optuna.trial.TrialState.COMPLETE for t in finished):
        raise ConfigError(
            f"study {study_name!r} has no complete trial ({pruned} pruned, {failed} failed); "
            "run more trials or widen the search space"
        )
    best = study.best_trial
    base_file = Path(config_dir) / "env" / f"{preset}.yaml"
    base = _preset_body(base_file)
    header = [
        f"{cfg.env.id} tuned by trl-cartpole tune (study {study_name}, trial {best.number}: "
        f"score {best.value:.1f})",
        f"base preset env={preset}; tuned over {', '.join(space)}",
        f"score: {_score_words(objective, cfg.collector.total_frames)}, "
        f"seeds {', '.join(map(str, seeds))}; {len(finished)} trials, {pruned} pruned",
        f"tuning overrides: {' '.join(overrides) or 'none'}",
    ]
    path = write_preset(out, base, best.params, header, variant_switch_defaults(config_dir))
    _save_plots(study, study_dir)
    lines = [
        f"study {study_name} ({storage}): {len(finished)} trials finished, {pruned} pruned, "
        f"{failed} failed",
        f"best trial {best.number}: score {best.value:.1f}",
        *(f"  {name} = {value}" for name, value in best.params.items()),
        f"plots: {study_dir / 'history.png'}, {study_dir / 'importances.png'}",
    ]
    return StudyResult(best.value, dict(best.params), len(finished), pruned, "\n".join(lines), path)


def _preset_space(config_dir: str | Path, overrides: Sequence[str], preset: str) -> Path:
    """The preset's search space: the package's ``tune/<preset>.yaml``, or a presets=
    directory's."""
    candidates = [
        Path(d) / "tune" / f"{preset}.yaml" for d in [config_dir, *preset_dirs(overrides)]
    ]
    return next((path for path in candidates if path.exists()), candidates[0])


def _open_study(study_name: str, storage: str, objective: str, space: dict[str, Any]) -> None:
    """Create the study (or check the one stored: its direction and its search space)."""
    if objective not in OBJECTIVES:
        raise ConfigError(f"objective={objective!r}; choose one of {', '.join(OBJECTIVES)}")
    direction = OBJECTIVES[objective]
    check_sqlite_storage(storage)
    study = optuna.create_study(
        study_name=study_name, storage=_storage(storage), direction=direction, load_if_exists=True
    )
    if study.direction.name.lower() != direction:
        raise ConfigError(
            f"study {study_name!r} in {storage} was made to {study.direction.name.lower()} its "
            f"score; objective={objective} needs one that is to {direction}: name another study="
        )
    check_study_space(study, space, storage)


def _run_trials(spec: dict[str, Any], jobs: int) -> None:
    """Run the study's trials in this process (``jobs=1``) or in ``jobs`` spawned processes
    (each trains with its own interpreter and torch threads)."""
    if jobs <= 1:
        _work(spec)
        return
    context = multiprocessing.get_context("spawn")
    workers = [context.Process(target=_work, args=(spec,)) for _ in range(jobs)]
    try:
        for worker in workers:
            worker.start()
        for worker in workers:
            worker.join()
    finally:  # a stopped study stops its workers too
        for worker in workers:
            if worker.is_alive():
                worker.terminate()
                worker.join()
    failed = [worker.exitcode for worker in workers if worker.exitcode != 0]
    if failed:
        raise ConfigError(
            f"{len(failed)} of {jobs} tuning workers exited with status {failed[0]}; "
            "run with --jobs 1 to see the error"
        )


def _score_words(objective: str, total_frames: int) -> str:
    """What a trial's score is, for the preset's header."""
    if objective == "frames":
        return f"mean frames to solve (unsolved: {2 * total_frames}) within {total_frames} frames"
    if objective == "seconds":
        return (
            "mean training seconds to solve (unsolved: twice its training seconds) "
            f"within {total_frames} frames"
        )
    return f"mean greedy return over the evaluations of {total_frames} frames"


def _preset_body(path: Path) -> dict[str, Any]:
    """A preset file's settings (its ``# @package`` line and comments dropped)."""
    from omegaconf import OmegaConf

    if not path.is_file():
        return {}
    return OmegaConf.to_container(OmegaConf.load(path))


def _save_plots(study: Any, study_dir: Path) -> None:
    """Optuna's optimisation history and parameter importances as PNG files."""
    import matplotlib

    matplotlib.use("Agg")
    from optuna.visualization import matplotlib as plots

    study_dir.mkdir(parents=True, exist_ok=True)
    figures = {"history.png": plots.plot_optimization_history}
    complete = [t for t in study.trials if t.state == optuna.trial.TrialState.COMPLETE]
    if len(complete) >= 2:  # importances need two complete trials
        figures["importances.png"] = plots.plot_param_importances
    for name, plot in figures.items():
        try:
            with warnings.catch_warnings():  # Optuna marks its matplotlib plots experimental
                warnings.simplefilter("ignore", optuna.exceptions.ExperimentalWarning)
                warnings.simplefilter("ignore", UserWarning)  # e.g. importances all equal
                axes = plot(study)
        except (ValueError, RuntimeError):  # e.g. every parameter constant so far
            continue
        axes.figure.savefig(study_dir / name, dpi=100, bbox_inches="tight")
        matplotlib.pyplot.close(axes.figure)

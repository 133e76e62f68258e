"""What a run prints: nothing from libraries by habit, and a short ending that tells the truth.

:func:`quiet_libraries` keeps TorchRL's INFO lines (spec checks, storage sizes) off the console
while a run trains, unless ``logger.verbose=true``. :func:`ending` is the run's last words:
whether it solved (and whether the best policy's final check met the threshold too), where the
run is, and the next commands, written with the interpreter that is running so they work when
pasted.
"""

from __future__ import annotations

import logging
import os
import re
import shlex
import shutil
import sys
import warnings
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from trl_cartpole.config.presets import env_presets_for, preset_of_run

__all__ = [
    "command",
    "ending",
    "python_command",
    "quiet_libraries",
    "set_scripts_dir",
    "shown_path",
    "verdict",
]

ENTRY_POINT = "trl-cartpole"
# Set when a command was started as ``python scripts/NAME.py`` (a clone's way): the commands
# this process prints then name the scripts too; otherwise they name ``trl-cartpole NAME``.
_started_from: dict[str, Path | None] = {"scripts": None}

LIBRARY_LOGGERS = ("torchrl", "tensordict")
# What ``compile=true`` prints once per run and means nothing to a user: torch's Dynamo skips
# the ``record_function`` profiler ranges TorchRL's losses open (logged as a warning), and
# tensordict reads a Dynamo setting torch has deprecated (a FutureWarning).
DYNAMO_PROFILER_LOGGER = "torch._dynamo.variables.ctx_manager"
DYNAMO_PROFILER_MESSAGE = "Profiler record function"
TENSORDICT_DYNAMO_WARNING = r".*inline_inbuilt_nn_modules is deprecated"


# the colour codes Gymnasium puts around its warnings (raw in a redirected log)
ANSI_ESCAPE = re.compile(r"\x1b\[[0-9;]*m")


def one_line_warnings() -> Any:
    """A ``warnings.formatwarning`` that shows a warning as ``warning: <its first line>``,
    colour codes removed, each text once: no file, line number, category or source line."""
    shown: set[str] = set()

    def format_warning(message: Any, category: type, filename: str, lineno: int, line=None) -> str:
        text = ANSI_ESCAPE.sub("", str(message)).strip()
        text = text.splitlines()[0].strip() if text else category.__name__
        if text in shown:
            return ""
        shown.add(text)
        return f"warning: {text}\n"

    return format_warning


def _not_profiler_note(record: logging.LogRecord) -> bool:
    return not str(record.msg).startswith(DYNAMO_PROFILER_MESSAGE)


@contextmanager
def quiet_libraries(verbose: bool = False) -> Iterator[None]:
    """Inside the block, TorchRL's and tensordict's loggers show warnings only (all if verbose),
    the two habitual notes of a compiled update are not shown, and a warning is one line
    (:func:`one_line_warnings`) (each unless verbose)."""
    loggers = [logging.getLogger(name) for name in LIBRARY_LOGGERS]
    levels = [logger.level for logger in loggers]
    for logger in loggers:
        logger.setLevel(logging.INFO if verbose else logging.WARNING)
    # blocks nest (the script's around train()'s): the inner one decides, the outer one's
    # state comes back on exit
    dynamo = logging.getLogger(DYNAMO_PROFILER_LOGGER)
    was_filtered = _not_profiler_note in dynamo.filters
    (dynamo.addFilter if not verbose else dynamo.removeFilter)(_not_profiler_note)
    format_warning = warnings.formatwarning
    if not verbose:  # a recording warnings.catch_warnings (pytest's) formats nothing: unaffected
        warnings.formatwarning = one_line_warnings()
    try:
        with warnings.catch_warnings():
            warnings.filterwarnings(
                "default" if verbose else "ignore",
                message=TENSORDICT_DYNAMO_WARNING,
                category=FutureWarning,
            )
            yield
    finally:
        warnings.formatwarning = format_warning
        (dynamo.addFilter if was_filtered else dynamo.removeFilter)(_not_profiler_note)
        for logger, level in zip(loggers, levels, strict=True):
            logger.setLevel(level)


def python_command() -> str:
    """How to call this interpreter from the current directory: ``python`` if that is it.

    ``python`` only when the ``python`` on PATH lives in this interpreter's own ``bin``
    directory (an activated virtual environment): a venv's interpreter links to the system
    one, so comparing resolved paths would send the user to a Python without the package.
    """
    executable = Path(sys.executable).absolute()
    on_path = shutil.which("python")
    if on_path and Path(on_path).absolute().parent == executable.parent:
        return "python"
    return shlex.quote(shown_path(executable))


def set_scripts_dir(scripts: str | Path | None) -> None:
    """Print later commands as ``python SCRIPTS/NAME.py`` (None: as ``trl-cartpole NAME``)."""
    _started_from["scripts"] = None if scripts is None else Path(scripts)


def entry_point_command() -> str:
    """How to call the ``trl-cartpole`` command of this interpreter from here.

    ``trl-cartpole`` when the one on PATH is this environment's; else its path
    (``.venv/bin/trl-cartpole``); else ``python -m trl_cartpole`` (the package not installed).
    """
    beside = Path(sys.executable).absolute().parent / ENTRY_POINT
    on_path = shutil.which(ENTRY_POINT)
    if on_path and Path(on_path).absolute() == beside:
        return ENTRY_POINT
    if beside.exists():
        return shlex.quote(shown_path(beside))
    return f"{python_command()} -m trl_cartpole"


def command(name: str) -> str:
    """The command line that runs subcommand ``name`` (``train``, ``evaluate``...), started
    the way this process was: ``python scripts/train.py`` or ``trl-cartpole train``."""
    scripts = _started_from["scripts"]
    if scripts is not None:
        return f"{python_command()} {shlex.quote(shown_path(scripts))}/{name}.py"
    return f"{entry_point_command()} {name}"


def shown_path(path: str | Path) -> str:
    """``path`` relative to the current directory when it lies below it, else absolute."""
    path = Path(path).absolute()
    try:
        return str(path.relative_to(Path.cwd()))
    except ValueError:
        return str(path)


def verdict(summary: dict[str, Any]) -> str:
    """One line: env, the algorithm (its preset and the switches the run changed) and seed, then
    solved or not and the best policy's final check."""
    label = summary.get("variant") or summary["algo"]
    return f"{summary['env_id']} [{label}, seed {summary['seed']}]: {_outcome(summary)}"


def solve_status(summary: dict[str, Any]) -> str:
    """A run's one verdict on its env's threshold, the same in the ending, ``summary.json``'s
    ``solve_status`` and the comparison tables: ``solved`` (an evaluation reached the threshold
    and the best policy's final episodes hold it), ``not held`` (reached once, the final
    episodes fall below), ``not solved``, or ``no threshold`` (the env has none)."""
    threshold = summary.get("solve_threshold")
    if threshold is None:
        return "no threshold"
    if not summary["solved"]:
        return "not solved"
    return "solved" if summary["final_eval_return_mean"] >= threshold else "not held"


def _outcome(summary: dict[str, Any]) -> str:
    threshold = summary.get("solve_threshold")
    evaluations = len(summary["eval_curve"]["frames"])
    kept = f"the best policy of {evaluations} evaluation{'s' * (evaluations != 1)}"
    candidates = summary.get("candidates")
    if candidates:  # eval.candidates: the best few played again, the best over those kept
        kept = (
            f"the best policy (of the {len(candidates)} best of {evaluations} evaluations, the "
            "best over new episodes)"
        )
    final = (
        f"{kept} returned "
        f"{summary['final_eval_return_mean']:.1f} +/- {summary['final_eval_return_std']:.1f} "
        f"over {summary['final_eval_episodes']} new episodes"
    )
    status = solve_status(summary)
    if status == "no threshold":
        return f"{summary['frames']} frames, no solve threshold for this env; {final}"
    if status == "not solved":
        return (
            f"not solved in {summary['frames']} frames (threshold {threshold:g}, best evaluation "
            f"{summary['best_eval_return_mean']:.1f}); {final}"
        )
    when = f"{summary['frames_to_solve']} frames, {summary['seconds_to_solve']:.1f} s of training"
    trained = summary.get("train_seconds", 0.0)
    if trained > 1.2 * summary["seconds_to_solve"] + 5:  # trained on after solving (its budget)
        when += f" (of {_duration(trained)} in all)"
    if status == "solved":
        return f"solved at {when}; {final} (>= {threshold:g})"
    return (
        f"reached {threshold:g} once at {when}, but {final}, below {threshold:g}: not held "
        "(try more frames or another seed)"
    )


def _duration(seconds: float) -> str:
    """``48 s``, ``5.3 min``, ``2.0 h``."""
    if seconds < 120:
        return f"{seconds:.0f} s"
    return f"{seconds / 60:.1f} min" if seconds < 7200 else f"{seconds / 3600:.1f} h"


def _what_to_try(summary: dict[str, Any], overrides: Sequence[str], pixels: bool) -> list[str]:
    """For a run that ended short of its target, commands that run as printed: the env's tuned
    preset (when the run used another, and learnt from the same observations), then the same
    run continued to twice its frames (resumed from its last state where it saved one)."""
    presets = [] if pixels else env_presets_for(summary["env_id"])
    algo = preset_of_run("algo", overrides) or summary["algo"]
    lines = ["try:"]
    if presets and preset_of_run("env", overrides) not in presets:
        lines.append(
            f"  {_run_with_env('train')} env={presets[0]} algo={algo}   # tuned for "
            f"{summary['env_id']}"
        )
    frames = f"collector.total_frames={2 * summary['frames']}"
    run_dir = Path(summary["run_dir"])
    if (run_dir / "checkpoints" / "last").is_dir():
        again = f"resume={shlex.quote(shown_path(run_dir))} {frames}"
        lines.append(f"  {_run_with_env('train')} {again}   # this run, on to twice the frames")
    else:
        kept = [
            shlex.quote(arg)
            for arg in overrides
            if not arg.startswith(("collector.total_frames=", "run_dir=", "resume="))
        ]
        lines.append(f"  {' '.join([_run_with_env('train'), *kept, frames])}   # twice the frames")
    return lines


def ending(
    summary: dict[str, Any],
    overrides: Sequence[str] = (),
    plots: bool = True,
    pixels: bool = False,
) -> str:
    """The lines a finished run prints: the verdict, the run directory and what to try next.

    ``overrides`` is the run's command line (the commands to try are built from it), ``plots``
    whether it drew its plots (``logger.plots``), ``pixels`` whether it learnt from pixels."""
    run = shlex.quote(shown_path(summary["run_dir"]))
    files = ["durations.png", "dashboard.png"] if plots else []
    lines = [
        verdict(summary),
        f"run directory: {run} ({', '.join([*files, 'summary.json', 'checkpoints/'])})",
    ]
    if summary.get("solve_threshold") is not None and not summary["solved"]:
        lines += _what_to_try(summary, overrides, pixels)
    if summary.get("checkpoint"):
        episodes = summary.get("final_eval_episodes", 100)  # what evaluate plays, as the run did
        lines += [
            "next:",
            f"  {_run_with_env('evaluate')} checkpoint={run}   # {episodes} greedy episodes",
            f"  {_run_with_env('render')} checkpoint={run}     # a GIF of the agent",
            f"  {_run_with_env('export')} checkpoint={run} output={run}/policy.pt2  # or .onnx",
        ]
    return "\n".join(lines)


def _run_with_env(name: str) -> str:
    """:func:`command` with this process's ``PYTHONPATH`` before it, when one is set: a user's
    own env module (``env.id=module:Class``) is found the way the run found it."""
    path = os.environ.get("PYTHONPATH")
    return f"PYTHONPATH={shlex.quote(path)} {command(name)}" if path else command(name)

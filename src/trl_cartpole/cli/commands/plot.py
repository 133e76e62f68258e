"""Compare runs: eval return against frames and seconds, one median line per config.

usage: trl-cartpole plot RUN_DIR [RUN_DIR ...] [out=comparison]

A sweep directory (``trl-cartpole train -m ...``) stands for all its runs. Run directories
(shell globs welcome: ``runs/ablations/*``) whose configs differ only in seed and run
directory are one config: drawn as the median over its seeds with an interquartile band.
Writes ``OUT.png`` (two panels: against training frames and against training seconds,
evaluation excluded), ``OUT-profiles.png`` (performance profiles: the fraction of runs solved
by each frame count, and with a final return above each value) and ``OUT.md`` (per config:
solve rate; frames and seconds to solve as interquartile mean with its 95 % stratified
bootstrap interval, median and slowest seed; the final return's interquartile mean and
interval), and prints the table.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from trl_cartpole.config.help import parse_args
from trl_cartpole.errors import ConfigError
from trl_cartpole.report.console import command


@dataclass
class PlotArgs:
    out: str = "comparison"  # output prefix: OUT.png, OUT-profiles.png, OUT.md


def _is_option(arg: str) -> bool:
    """``out=...`` or a dashed flag; a path is a run directory, ``=`` in its name or not (a
    run with an override is named ``...-double_dqn=true-...``)."""
    if arg.startswith("-"):
        return True
    key = arg.split("=", 1)[0]
    return "=" in arg and "/" not in key and not Path(arg).exists()


def main(argv: list[str]) -> None:
    run_dirs = [Path(arg) for arg in argv if not _is_option(arg)]
    args = parse_args(PlotArgs, [arg for arg in argv if _is_option(arg)], __doc__, command("plot"))
    if not run_dirs:
        raise ConfigError(
            "name the run or sweep directories to compare (trl-cartpole plot DIR ...)"
        )
    from trl_cartpole.report.plotting import plot_comparison, plot_profiles
    from trl_cartpole.tools.comparison import group_runs, load_runs, markdown_table

    groups = group_runs(load_runs(run_dirs))
    if not groups:
        raise ConfigError("none of the directories holds a finished run (summary.json)")
    curves = {"Frames": {}, "Training seconds": {}}
    for label, runs in groups.items():
        evals = [run["summary"]["eval_curve"] for run in runs]
        curves["Frames"][label] = [(e["frames"], e["returns"]) for e in evals]
        curves["Training seconds"][label] = [(e["seconds"], e["returns"]) for e in evals]
    thresholds = {  # each env's own: runs of several envs draw each, labelled
        run["summary"].get("env_id", ""): run["summary"]["solve_threshold"]
        for runs in groups.values()
        for run in runs
        if run["summary"].get("solve_threshold") is not None
    }
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    image = plot_comparison(curves, out.with_suffix(".png"), thresholds)
    summaries = {label: [run["summary"] for run in runs] for label, runs in groups.items()}
    profiles = plot_profiles(
        {label: [s["frames_to_solve"] for s in runs] for label, runs in summaries.items()},
        {label: [s["final_eval_return_mean"] for s in runs] for label, runs in summaries.items()},
        out.with_name(f"{out.name}-profiles.png"),
    )
    table = markdown_table(summaries, label="config")
    out.with_suffix(".md").write_text(
        f"{table}\n\n![comparison]({image.name})\n\n![performance profiles]({profiles.name})\n"
    )
    print(table)
    print(f"written: {image}, {profiles}, {out.with_suffix('.md')}")

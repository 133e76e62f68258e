"""Every DQN variant preset on CartPole-v1 over seeds: the table and plot of docs/ablations.md.

    python -m benchmarks ablate [--algos dqn double ...] [--seeds 0 1 2 3 4]
        [--out runs/ablations] [--doc docs/ablations.md] [key=value ...]

Runs each preset once per seed (``scripts/train.py`` in its own process, ``--jobs`` at a time;
finished runs are reused), then writes ``OUT/results.json`` and the plot of greedy evaluation
return against frames (median and interquartile band over seeds, one panel per preset) to
``OUT/ablations.png``. With ``--doc`` (the project's own page: ``--doc docs/ablations.md``)
the plot goes to the doc's ``images/`` and the table between its ``ablation`` markers.
"""

from __future__ import annotations

import argparse
import json
from collections.abc import Sequence
from pathlib import Path

from matplotlib.figure import Figure

from benchmarks.harness import VARIANT_PRESETS, provenance, provenance_line, run_presets
from trl_cartpole.report.plotting import draw_median_band, savefig_atomic
from trl_cartpole.tools.comparison import markdown_table

SEEDS, OUT = [0, 1, 2, 3, 4], "runs/ablations"
BEGIN, END = "<!-- ablation:begin -->", "<!-- ablation:end -->"


def plot_seed_groups(
    curves: dict[str, list[tuple[Sequence[int], Sequence[float]]]],
    path: str | Path,
    threshold: float | None = None,
    ylabel: str = "Mean greedy return (eval)",
) -> Path:
    """One panel per group: each seed's curve, their median and interquartile band.

    ``curves`` maps a group name (a preset) to one ``(frames, values)`` per seed; every seed
    is held at its last value up to the longest run of the group (see :func:`hold_last`).
    """
    path = Path(path)
    columns = min(4, len(curves))
    rows = -(-len(curves) // columns)
    fig = Figure(figsize=(4 * columns, 3.2 * rows))
    axes = fig.subplots(rows, columns, squeeze=False, sharey=True)
    for ax, (name, seeds) in zip(axes.flat, curves.items(), strict=False):
        for frames, values in seeds:
            ax.step(frames, values, where="post", color="grey", alpha=0.35, linewidth=0.8)
        draw_median_band(ax, "median, interquartile band", seeds)
        if threshold is not None:
            ax.axhline(threshold, color="black", linestyle="--", linewidth=0.8)
        ax.set_title(name)
        ax.set_xlabel("Frames")
        ax.grid(alpha=0.3)
    for ax in axes[:, 0]:
        ax.set_ylabel(ylabel)
    for ax in list(axes.flat)[len(curves) :]:
        ax.set_visible(False)
    axes.flat[0].legend(loc="lower right", fontsize="small")
    fig.tight_layout()
    savefig_atomic(fig, path)
    return path


def write_between_markers(doc: Path, block: str) -> None:
    """Replace the text between BEGIN and END in ``doc`` (appending the markers if absent)."""
    text = doc.read_text() if doc.exists() else "# Ablations\n"
    if BEGIN in text and END in text:
        head, rest = text.split(BEGIN, 1)
        tail = rest.split(END, 1)[1]
    else:
        head, tail = text.rstrip("\n") + "\n\n", "\n"
    doc.write_text(f"{head}{BEGIN}\n{block}\n{END}{tail}")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--algos", nargs="+", default=list(VARIANT_PRESETS))
    parser.add_argument(
        "--doc", type=Path, default=None, help="a Markdown page to write the table into"
    )


def main(args: argparse.Namespace) -> None:
    results = run_presets(args.algos, args.seeds, args.out, args.overrides, jobs=args.jobs)
    (args.out / "results.json").write_text(json.dumps(results, indent=2) + "\n")
    curves = {
        algo: [(r["eval_curve"]["frames"], r["eval_curve"]["returns"]) for r in runs]
        for algo, runs in results.items()
    }
    image = (
        args.out / "ablations.png"
        if args.doc is None
        else args.doc.parent / "images" / "ablations.png"
    )
    image.parent.mkdir(parents=True, exist_ok=True)
    threshold = next(iter(results.values()))[0]["solve_threshold"]
    plot_seed_groups(curves, image, threshold=threshold)
    table = markdown_table(results)
    print(table)
    print(f"written: {args.out / 'results.json'}, {image}")
    if args.doc is None:
        return
    seeds = " ".join(str(seed) for seed in args.seeds)
    block = (
        f"{provenance_line(provenance())} Seeds {seeds}; command: "
        f"`python -m benchmarks ablate --doc {args.doc}"
        f"{''.join(' ' + o for o in args.overrides)} --seeds {seeds}`.\n\n{table}\n\n"
        f"![eval return against frames per preset]({image.relative_to(args.doc.parent)})"
    )
    write_between_markers(args.doc, block)

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
from pathlib import Path

from benchmarks.harness import VARIANT_PRESETS, provenance, provenance_line, run_presets
from trl_cartpole.report.plotting import plot_seed_groups
from trl_cartpole.tools.comparison import markdown_table

SEEDS, OUT = [0, 1, 2, 3, 4], "runs/ablations"
BEGIN, END = "<!-- ablation:begin -->", "<!-- ablation:end -->"


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

"""Median frames and seconds to solve over seeds, per preset, optionally against peer DQNs.

    python -m benchmarks run --algos dqn tutorial --seeds 0 1 2 3 4
        [--peers tutorial_loop sb3_dqn tianshou_dqn] [--jobs 1] [--out runs/benchmark]
        [key=value ...]

Each (preset, seed) is one ``scripts/train.py`` run, each (peer, seed) one
``python -m benchmarks.peers.<peer>`` run, in their own processes (``--jobs`` at a time;
1, the default, keeps the machine's noise the same for all). Every run evaluates greedily over
``--eval-episodes`` episodes every ``--eval-interval`` frames with the training clock stopped
(``benchmarks.peers.protocol``). ``tianshou_dqn`` runs from its own virtual environment,
``runs/peer-venvs/tianshou_dqn``, made on its first use (``benchmarks.harness.peer_python``).
The table of medians (solve rate, frames and seconds to
solve, collection frames/s, updates/s, peak RSS) is printed and written to ``OUT/results.md``
and ``OUT/results.json``, followed by the ratios: each peer's median seconds_to_solve over the
first preset's, and seconds per frame of ``tutorial`` against ``tutorial_loop``.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import math

from benchmarks.harness import (
    PEERS,
    markdown_table,
    run_presets,
    seconds_per_frame,
    speed_ratios,
)

SEEDS, OUT = [0, 1, 2, 3, 4], "runs/benchmark"


def ratio_lines(results: dict, algos: list[str], peers: list[str]) -> list[str]:
    """The ratios the table's medians give, one line each."""
    ours = algos[0]
    lines = []
    for peer, ratio in speed_ratios(results, ours, peers).items():
        if ratio is None:
            lines.append(f"- {peer} and {ours}: neither solved most seeds")
        elif math.isinf(ratio):
            solved = sum(bool(run["solved"]) for run in results[peer])
            lines.append(
                f"- {peer} solved {solved} of {len(results[peer])} seeds: no median to compare"
            )
        else:
            lines.append(f"- {peer} needs {ratio:.1f}x the seconds to solve of {ours} (medians)")
    if "tutorial" in results and "tutorial_loop" in results:
        ours, theirs = (
            seconds_per_frame(results["tutorial"]),
            seconds_per_frame(results["tutorial_loop"]),
        )
        lines.append(
            f"- seconds per frame: tutorial {1e3 * ours:.2f} ms, tutorial_loop "
            f"{1e3 * theirs:.2f} ms (tutorial_loop / tutorial = {theirs / ours:.2f})"
        )
    return lines


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--algos", nargs="+", default=["dqn"])
    parser.add_argument("--peers", nargs="*", default=[], choices=sorted(PEERS))
    parser.add_argument("--peer-frames", type=int, default=150_000, help="peers' frame budget")
    parser.add_argument("--eval-interval", type=int, default=1000)
    parser.add_argument("--eval-episodes", type=int, default=20)


def main(args: argparse.Namespace) -> None:
    if "sb3_dqn" in args.peers and importlib.util.find_spec("stable_baselines3") is None:
        raise SystemExit(
            "error: --peers sb3_dqn needs Stable-Baselines3: pip install -e '.[bench]'"
        )
    protocol = [f"eval.interval_frames={args.eval_interval}", f"eval.episodes={args.eval_episodes}"]
    peer_args = [
        f"--total-frames={args.peer_frames}",
        f"--eval-interval={args.eval_interval}",
        f"--eval-episodes={args.eval_episodes}",
    ]
    results = run_presets(
        args.algos,
        args.seeds,
        args.out,
        [*protocol, *args.overrides],
        peers=args.peers,
        peer_args=peer_args,
        jobs=args.jobs,
    )
    text = "\n".join([markdown_table(results), "", *ratio_lines(results, args.algos, args.peers)])
    print(text)
    (args.out / "results.md").write_text(text + "\n")
    (args.out / "results.json").write_text(json.dumps(results, indent=2) + "\n")

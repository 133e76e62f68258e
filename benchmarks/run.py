"""Median frames and seconds to solve over seeds, per preset, optionally against peer DQNs.

    python -m benchmarks run --algos dqn tutorial --seeds 0 1 2 3 4
        [--peers tutorial_loop sb3_dqn sbx_dqn tianshou_dqn] [--eval-interval 1000 [2500]]
        [--jobs 1] [--out runs/benchmark] [key=value ...]

docs/performance.md's 20-seed table, both protocols, on seeds no preset was tuned on (recorded
at b68e802, when the default ran the project's fused rewrites: ``fast=true`` today):

    python -m benchmarks run --algos dqn --peers sb3_dqn --eval-interval 1000 2500
        --seeds $(seq 100 119) --out runs/perf20 --record docs/results/performance.json

An ``--algos`` entry is a preset, or a preset with overrides of its own joined by ``+``:
``dqn+fast=true`` is the dqn preset on the fast path. The same table with the fast path beside
the default and SBX beside Stable-Baselines3 (not yet recorded):

    python -m benchmarks run --algos dqn dqn+fast=true --peers sb3_dqn sbx_dqn
        --eval-interval 1000 2500 --seeds $(seq 100 119) --out runs/perf20
        --record docs/results/performance.json

The other env presets against Stable-Baselines3 with rl-zoo3's settings for that env
(``--env``: our side trains ``env=<preset>`` and stops once solved, the peer plays
``--env-id`` of the preset; both sides get the same frame cap, ``--peer-frames``):

    python -m benchmarks run --env acrobot --peers sb3_dqn --eval-interval 2500
        --peer-frames 150000 --seeds $(seq 100 109) --out runs/race-acrobot
        --record docs/results/race_acrobot.json

Each (preset, seed) is one ``scripts/train.py`` run, each (peer, seed) one
``python -m benchmarks.peers.<peer>`` run, in their own processes (``--jobs`` at a time;
1, the default, keeps the machine's noise the same for all). Every run evaluates greedily over
``--eval-episodes`` episodes every ``--eval-interval`` frames with the training clock stopped
(``benchmarks.peers.protocol``); several ``--eval-interval`` values run every (preset, seed)
once per protocol, in ``OUT/every-N``, with a table each. ``tianshou_dqn`` and ``sbx_dqn`` run
from virtual environments of their own, ``runs/peer-venvs/<peer>``, made on first use
(``benchmarks.harness.peer_python``). The table (solve rate, frames and seconds to solve,
collection frames/s, updates/s, peak RSS) is printed and written to ``OUT/results.md`` and
``OUT/results.json``, followed by the ratios: each peer's median seconds_to_solve over the
first preset's, the same on the interquartile means with their 95 % intervals, and seconds
per frame of ``tutorial`` against ``tutorial_loop``.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import math
import sys
from pathlib import Path

from benchmarks.harness import PEERS, provenance, run_presets, seconds_per_frame, speed_ratios
from trl_cartpole.tools.comparison import iqm_to_solve, markdown_table

SEEDS, OUT = [0, 1, 2, 3, 4], "runs/benchmark"
# env presets raced with --env: preset -> the Gymnasium id the peers play
RACE_ENVS = {
    "acrobot": "Acrobot-v1",
    "mountaincar": "MountainCar-v0",
    "lunarlander": "LunarLander-v3",
}


def ratio_lines(results: dict, algos: list[str], peers: list[str]) -> list[str]:
    """The ratios the table's medians give, one line each: every other preset and peer against
    the first preset."""
    ours, others = algos[0], [*algos[1:], *peers]
    lines = []
    for other, ratio in speed_ratios(results, ours, others).items():
        if ratio is None:
            lines.append(f"- {other} and {ours}: neither solved most seeds")
        elif math.isinf(ratio):
            solved = sum(bool(run["solved"]) for run in results[other])
            lines.append(
                f"- {other} solved {solved} of {len(results[other])} seeds: no median to compare"
            )
        else:
            lines.append(f"- {other} needs {ratio:.1f}x the seconds to solve of {ours} (medians)")
    lines += iqm_ratio_lines(results, ours, others)
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


def iqm_ratio_lines(results: dict, ours: str, peers: list[str]) -> list[str]:
    """Each peer's interquartile mean of seconds to solve over ours, with the 95 % intervals
    (an unsolved seed is infinitely slow) and whether the intervals are apart."""
    mine = iqm_to_solve([run["seconds_to_solve"] for run in results[ours]])
    lines = []
    for peer in peers:
        theirs = iqm_to_solve([run["seconds_to_solve"] for run in results[peer]])
        if not math.isfinite(mine.value):
            verdict = f"{ours} left more than a quarter of its seeds unsolved"
        elif not math.isfinite(theirs.value):
            verdict = f"{peer} left more than a quarter of its seeds unsolved"
        else:
            apart = theirs.low > mine.high or mine.low > theirs.high
            intervals = "apart" if apart else "overlap"
            verdict = f"{theirs.value / mine.value:.1f}x, intervals {intervals}"
        lines.append(f"- IQM seconds to solve: {peer} {theirs} against {ours} {mine}: {verdict}")
    return lines


def protocol_text(results: dict, algos: list[str], peers: list[str]) -> str:
    """One protocol's table and the ratios under it."""
    return "\n".join([markdown_table(results), "", *ratio_lines(results, algos, peers)])


def write_record(path: Path, command: str, protocols: dict[int, dict]) -> None:
    """``path`` (docs/results/*.json): the command, when and where it ran, and per evaluation
    interval every run's summary; ``python -m maintain docs`` renders the tables from it."""
    record = {
        **provenance(),
        "command": command,
        "protocols": {str(interval): results for interval, results in protocols.items()},
    }
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(record, indent=2) + "\n")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--algos", nargs="+", default=["dqn"])
    parser.add_argument("--peers", nargs="*", default=[], choices=sorted(PEERS))
    parser.add_argument("--peer-frames", type=int, default=150_000, help="peers' frame budget")
    parser.add_argument(
        "--eval-interval", type=int, nargs="+", default=[1000], help="one protocol per value"
    )
    parser.add_argument("--eval-episodes", type=int, default=20)
    parser.add_argument(
        "--env",
        choices=sorted(RACE_ENVS),
        help="race on this env preset instead of CartPole (stop once solved, at its threshold)",
    )
    parser.add_argument(
        "--record", type=Path, help="also write every summary to this results file (docs/results)"
    )


def main(args: argparse.Namespace) -> None:
    if "sb3_dqn" in args.peers and importlib.util.find_spec("stable_baselines3") is None:
        raise SystemExit(
            "error: --peers sb3_dqn needs Stable-Baselines3: pip install -e '.[bench]'"
        )
    texts, protocols = [], {}
    for interval in args.eval_interval:
        out = args.out if len(args.eval_interval) == 1 else args.out / f"every-{interval}"
        protocols[interval] = _protocol_results(args, interval, out)
        text = protocol_text(protocols[interval], args.algos, args.peers)
        (out / "results.md").write_text(text + "\n")
        texts.append(f"### Evaluation every {interval} frames\n\n{text}")
    print("\n\n".join(texts))
    if len(args.eval_interval) > 1:
        (args.out / "results.md").write_text("\n\n".join(texts) + "\n")
    if args.record is not None:
        write_record(args.record, "python -m benchmarks run " + " ".join(sys.argv[2:]), protocols)


def _protocol_results(args: argparse.Namespace, interval: int, out: Path) -> dict:
    """Run every (preset or peer, seed) under one evaluation interval; write its results.json."""
    protocol = [f"eval.interval_frames={interval}", f"eval.episodes={args.eval_episodes}"]
    peer_args = [
        f"--total-frames={args.peer_frames}",
        f"--eval-interval={interval}",
        f"--eval-episodes={args.eval_episodes}",
    ]
    if args.env is not None:  # the preset's env, to the first evaluation at its threshold
        protocol += [
            f"env={args.env}",
            "eval.stop_when_solved=true",
            f"collector.total_frames={args.peer_frames}",  # the same cap for both sides
        ]
        peer_args.append(f"--env-id={RACE_ENVS[args.env]}")
    results = run_presets(
        args.algos,
        args.seeds,
        out,
        [*protocol, *args.overrides],
        peers=args.peers,
        peer_args=peer_args,
        jobs=args.jobs,
    )
    out.mkdir(parents=True, exist_ok=True)
    (out / "results.json").write_text(json.dumps(results, indent=2) + "\n")
    return results

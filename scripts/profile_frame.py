"""Where a training frame's time goes: py-spy samples of one run, sorted into the loop's phases.

    python scripts/profile_frame.py [--rate 200] [--out runs/profile] [key=value ...]

(``--train-script OTHER_CHECKOUT/scripts/train.py`` with ``PYTHONPATH=OTHER_CHECKOUT/src``
profiles another version, as the "before" breakdown of docs/performance.md.)

Runs ``scripts/train.py`` with the overrides under ``py-spy record`` (the ``bench`` extra
installs py-spy), then prints a markdown table: seconds and share of the training time per
phase (``trl_cartpole.profiling.PHASES``), and the evaluation and setup seconds beside it
(evaluation is left out of ``seconds_to_solve``). The raw samples stay in
``OUT/stacks.txt`` for a flame graph.
"""

from __future__ import annotations

import argparse
import shutil
import subprocess
import sys
from pathlib import Path

from trl_cartpole.benchmarking import TRAIN_SCRIPT
from trl_cartpole.profiling import frame_breakdown, parse_raw_stacks

OUTSIDE_TRAINING = ("evaluation (clock stopped)", "setup (envs, networks, buffer)")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rate", type=int, default=200, help="samples per second")
    parser.add_argument("--out", type=Path, default=Path("runs/profile"))
    parser.add_argument(
        "--train-script", type=Path, default=TRAIN_SCRIPT, help="another checkout's train.py"
    )
    parser.add_argument("overrides", nargs="*", help="Hydra overrides for the profiled run")
    args = parser.parse_args()
    py_spy = shutil.which("py-spy") or str(Path(sys.executable).parent / "py-spy")
    if not Path(py_spy).exists():
        raise SystemExit("error: py-spy is not installed; pip install -e '.[bench]'")
    args.out.mkdir(parents=True, exist_ok=True)
    stacks_path = args.out / "stacks.txt"
    command = [sys.executable, str(args.train_script), f"run_dir={args.out / 'run'}"]
    command += ["logger.progress_bar=false", *args.overrides]
    record = [py_spy, "record", "-r", str(args.rate), "-f", "raw", "-o", str(stacks_path), "--"]
    subprocess.run([*record, *command], check=True, stdout=subprocess.DEVNULL)
    phases = frame_breakdown(parse_raw_stacks(stacks_path.read_text().splitlines()))
    training = {name: n for name, n in phases.items() if name not in OUTSIDE_TRAINING}
    total = sum(training.values())
    print("| phase | seconds | share of training time |")
    print("| --- | --- | --- |")
    for name, samples in training.items():
        print(f"| {name} | {samples / args.rate:.2f} | {100 * samples / total:.1f} % |")
    print(f"| **training total** | {total / args.rate:.2f} | 100 % |")
    for name in OUTSIDE_TRAINING:
        print(f"| {name}, not in training time | {phases.get(name, 0) / args.rate:.2f} | - |")


if __name__ == "__main__":
    main()

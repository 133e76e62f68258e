"""Where a training frame's time goes: py-spy samples of one run, sorted into the loop's phases.

    python scripts/profile_frame.py [--rate 200] [--out runs/profile] [key=value ...]

``--checkout DIR`` profiles another checkout's ``scripts/train.py`` with its own ``src/`` (the
"before" breakdown of docs/performance.md: ``git worktree add DIR <commit>``).

Runs ``scripts/train.py`` with the overrides under ``py-spy record`` (the ``bench`` extra
installs py-spy), then prints a markdown table: seconds and share of the training time per
phase (``trl_cartpole.profiling.PHASES``), and the evaluation and setup seconds beside it
(evaluation is left out of ``seconds_to_solve``). The raw samples stay in
``OUT/stacks.txt`` for a flame graph.
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
from pathlib import Path

from trl_cartpole.benchmarking import TRAIN_SCRIPT
from trl_cartpole.profiling import frame_breakdown, parse_raw_stacks

OUTSIDE_TRAINING = (
    "evaluation (clock stopped)",
    "setup (envs, networks, buffer)",
    "checkpointing",  # written with the clock stopped
)


def record_stacks(args: argparse.Namespace) -> Path:
    """Run the training under ``py-spy record`` and return the raw stacks file."""
    py_spy = shutil.which("py-spy") or str(Path(sys.executable).parent / "py-spy")
    if not Path(py_spy).exists():
        raise SystemExit("error: py-spy is not installed; pip install -e '.[bench]'")
    args.out.mkdir(parents=True, exist_ok=True)
    stacks_path = args.out / "stacks.txt"
    train_script, env = TRAIN_SCRIPT, dict(os.environ)
    if args.checkout is not None:  # its scripts/train.py importing its own src/
        train_script = args.checkout / "scripts" / "train.py"
        env["PYTHONPATH"] = str(args.checkout / "src")
    command = [sys.executable, str(train_script), f"run_dir={args.out / 'run'}"]
    command += ["logger.progress_bar=false", *args.overrides]
    record = [py_spy, "record", "-r", str(args.rate), "-f", "raw", "-o", str(stacks_path), "--"]
    subprocess.run([*record, *command], check=True, stdout=subprocess.DEVNULL, env=env)
    return stacks_path


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rate", type=int, default=200, help="samples per second")
    parser.add_argument("--out", type=Path, default=Path("runs/profile"))
    parser.add_argument("--checkout", type=Path, help="profile another checkout's train.py")
    parser.add_argument("--stacks", type=Path, help="only sort an existing py-spy raw file")
    parser.add_argument("overrides", nargs="*", help="Hydra overrides for the profiled run")
    args = parser.parse_args()
    stacks_path = args.stacks or record_stacks(args)
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

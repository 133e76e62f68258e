"""Tune hyperparameters with Optuna and write the best trial as a preset (docs/tuning.md).

usage: python scripts/tune.py --trials N --out FILE [--jobs J] [--storage URL] [--study NAME]
           [--space FILE] [--seeds S ...] [key=value ...]

The trailing key=value overrides are train.py's (env=lunarlander collector.total_frames=300000);
the search space is configs/tune/<env preset>.yaml unless --space names one. --trials is the
study's total of finished trials: running again with the same storage and a larger N continues
the study. --out configs/env/NAME.yaml makes env=NAME a preset of scripts/train.py.

examples:
  python scripts/tune.py --trials 30 --out configs/env/cartpole_tuned.yaml
  python scripts/tune.py --trials 60 --jobs 2 --out configs/env/lunarlander_tuned.yaml \\
      env=lunarlander collector.total_frames=300000
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from trl_cartpole.cli import run_cli
from trl_cartpole.console import python_command, shown_path

ROOT = Path(__file__).resolve().parent.parent
CONFIG_DIR = ROOT / "configs"


def parse(argv: list[str]) -> argparse.Namespace:
    parser = argparse.ArgumentParser(
        prog="python scripts/tune.py",
        description=__doc__.split("\n\n")[0],
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog=__doc__.split("\n\n", 2)[2],
    )
    parser.add_argument("--trials", type=int, required=True, help="finished trials in the study")
    parser.add_argument("--out", type=Path, required=True, help="the preset YAML to write")
    parser.add_argument("--jobs", type=int, default=1, help="processes working on the study")
    parser.add_argument(
        "--storage",
        default=None,
        help="Optuna storage URL; default sqlite:///runs/tune/STUDY/study.db",
    )
    parser.add_argument("--study", default=None, help="study name; default: the env preset")
    parser.add_argument("--space", type=Path, default=None, help="search space YAML")
    parser.add_argument("--seeds", type=int, nargs="+", default=[0], help="seeds of each trial")
    parser.add_argument(
        "--pruner",
        default="median",
        choices=["median", "none"],
        help="median: stop a trial whose running score is below the median of earlier trials "
        "at the same step (after 5 trials, from a quarter of the frame budget on)",
    )
    args, overrides = parser.parse_known_args(argv)
    unknown = [arg for arg in overrides if "=" not in arg]
    if unknown:
        parser.error(f"unrecognized arguments: {' '.join(unknown)}")
    args.overrides = overrides
    return args


def main(argv: list[str]) -> None:
    args = parse(argv)
    from trl_cartpole.study import run_study

    result = run_study(
        config_dir=CONFIG_DIR,
        overrides=args.overrides,
        trials=args.trials,
        out=args.out,
        jobs=args.jobs,
        storage=args.storage,
        study_name=args.study,
        space_path=args.space,
        seeds=args.seeds,
        pruner=args.pruner,
    )
    print(result.summary)
    preset = args.out.resolve()
    name = preset.stem
    if preset.parent == (CONFIG_DIR / "env").resolve():
        print(
            f"preset: {shown_path(preset)}; train with it: "
            f"{python_command()} scripts/train.py env={name}"
        )
    else:
        print(
            f"preset: {shown_path(preset)}; scripts/train.py takes presets by name from "
            f"configs/env/ (copy it there, then env={name})"
        )


if __name__ == "__main__":
    sys.exit(run_cli(main))

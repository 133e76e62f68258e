"""``python -m benchmarks <subcommand>``: the benchmark command lines, run from the repository root.

Every subcommand takes ``--seeds``, ``--jobs``, ``--out`` and trailing Hydra ``key=value``
overrides (``benchmarks.harness.sweep_arguments``); ``python -m benchmarks <subcommand> --help``
shows its own options and defaults. Put the overrides before an option that takes a list
(``--seeds 0 1``), or after ``--``.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

from benchmarks import (
    ablate,
    atari,
    checkpoint_cost,
    envs,
    memory,
    profile,
    run,
    scaling,
    update_cost,
    wall,
    weight_sync,
)
from benchmarks.harness import command_parser, sweep_arguments
from trl_cartpole.report.console import quiet_libraries

SUBCOMMANDS = {
    "run": run,
    "ablate": ablate,
    "envs": envs,
    "scaling": scaling,
    "update-cost": update_cost,
    "profile": profile,
    "wall": wall,
    "memory": memory,
    "weight-sync": weight_sync,
    "atari": atari,
    "checkpoint-cost": checkpoint_cost,
}


def build_parser() -> argparse.ArgumentParser:
    return command_parser(
        "python -m benchmarks",
        __doc__,
        SUBCOMMANDS,
        parents=lambda module: [sweep_arguments(module.SEEDS, module.OUT)],
    )


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    with quiet_libraries():  # no TorchRL INFO lines from the subcommands run in this process
        args.main(args)
    return 0


if __name__ == "__main__":
    sys.exit(main())

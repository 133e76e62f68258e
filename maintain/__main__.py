"""``python -m maintain <command>``: the maintainer's commands, run from the repository root.

- ``docs``: rewrite every generated block of the docs from its one source (``--check``: write
  nothing, exit 1 if one is stale);
- ``readme``: run the README's quick start and next steps, time them, record the results file
  the README's blocks come from (``--check-run RUN_DIR``: compare a run with the recorded one);
- ``lock``: write ``constraints.txt`` from this environment (``--check``: exit 1 if it differs).
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

from benchmarks.harness import command_parser
from maintain import docs, lock, readme
from trl_cartpole.report.console import quiet_libraries

COMMANDS = {"docs": docs, "readme": readme, "lock": lock}


def build_parser() -> argparse.ArgumentParser:
    return command_parser("python -m maintain", __doc__, COMMANDS)


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    with quiet_libraries():
        args.main(args)
    return 0


if __name__ == "__main__":
    sys.exit(main())

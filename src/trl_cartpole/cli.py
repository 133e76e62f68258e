"""Command-line plumbing shared by the scripts: compose the Hydra config, report bad input.

Bad input (an unknown key, a wrong type, an impossible value, an unknown env) ends the
program with one line on stderr and exit status 2, before any training. Set
``HYDRA_FULL_ERROR=1`` to get the full traceback instead.
"""

from __future__ import annotations

import os
import sys
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from hydra import compose, initialize_config_dir
from hydra.errors import HydraException
from omegaconf import DictConfig
from omegaconf.errors import OmegaConfBaseException

from trl_cartpole.config import ConfigError, register_configs

__all__ = ["compose_config", "run_cli"]

EXIT_BAD_INPUT = 2


def compose_config(config_dir: str | Path, overrides: Sequence[str]) -> DictConfig:
    """Compose ``config_dir/config.yaml`` over the typed schema with command-line overrides."""
    register_configs()
    with initialize_config_dir(config_dir=str(Path(config_dir).resolve()), version_base="1.3"):
        return compose(config_name="config", overrides=list(overrides))


_NOISE = (
    "To append to your config",
    "full_key:",
    "object_type=",
    "reference_type=",
    "Config search path",
    "provider=",
)


def _one_line(error: BaseException) -> str:
    """Join the informative lines of ``error`` and its cause into one line."""
    parts: list[str] = []
    current: BaseException | None = error
    while current is not None:
        for line in str(current).splitlines():
            line = line.strip().rstrip(".:")
            if line and not line.startswith(_NOISE) and line not in parts:
                parts.append(line)
        current = current.__cause__
    return ": ".join(parts) if parts else type(error).__name__


def run_cli(main: Callable[[list[str]], Any], argv: Sequence[str] | None = None) -> int:
    """Run ``main(argv)``; turn configuration errors into one line on stderr and exit code 2."""
    argv = list(sys.argv[1:] if argv is None else argv)
    try:
        main(argv)
    except (ConfigError, HydraException, OmegaConfBaseException) as error:
        if os.environ.get("HYDRA_FULL_ERROR") == "1":
            raise
        print(f"error: {_one_line(error)}", file=sys.stderr)
        return EXIT_BAD_INPUT
    return 0

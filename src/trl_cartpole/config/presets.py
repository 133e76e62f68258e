"""Where presets are found: the package's own, then the user's directories of presets.

The presets (``algo=``, ``env=``, the tuning spaces) ship inside the package, in
``trl_cartpole/configs`` (a clone's ``configs/`` is a link to it), so an installed wheel has
them. A user adds their own with ``presets=DIR`` on the command line (repeatable) or the
``TRL_CARTPOLE_PRESETS`` environment variable (directories separated by ``os.pathsep``): each
directory is laid out like ``configs/`` (``DIR/env/NAME.yaml`` makes ``env=NAME``) and is
searched after the package's, through Hydra's search path. Imports no torch.
"""

from __future__ import annotations

import os
import re
from collections.abc import Sequence
from pathlib import Path

from trl_cartpole.errors import ConfigError

__all__ = [
    "PRESETS_DIR",
    "PRESETS_ENV_VAR",
    "env_presets_for",
    "preset_dirs",
    "with_search_path",
]

PRESETS_DIR = Path(__file__).resolve().parent.parent / "configs"
PRESETS_ENV_VAR = "TRL_CARTPOLE_PRESETS"
PRESETS_KEY = "presets="


def preset_dirs(overrides: Sequence[str]) -> list[Path]:
    """The user's preset directories: ``presets=DIR`` arguments, then the environment's."""
    named = [arg[len(PRESETS_KEY) :] for arg in overrides if arg.startswith(PRESETS_KEY)]
    from_env = [part for part in os.environ.get(PRESETS_ENV_VAR, "").split(os.pathsep) if part]
    dirs = []
    for text in [*named, *from_env]:
        path = Path(text).expanduser().resolve()
        if not path.is_dir():
            source = "presets=" if text in named else f"{PRESETS_ENV_VAR}="
            raise ConfigError(
                f"{source}{text!r} is not a directory; name a directory laid out like the "
                "package's presets (DIR/env/NAME.yaml, DIR/algo/NAME.yaml)"
            )
        dirs.append(path)
    return dirs


def with_search_path(overrides: Sequence[str]) -> list[str]:
    """``overrides`` with ``presets=DIR`` replaced by Hydra's ``hydra.searchpath`` override."""
    dirs = preset_dirs(overrides)
    rest = [arg for arg in overrides if not arg.startswith(PRESETS_KEY)]
    if not dirs:
        return rest
    return [*rest, f"hydra.searchpath=[{','.join(f'file://{d}' for d in dirs)}]"]


def env_presets_for(env_id: str) -> list[str]:
    """The names of the shipped ``configs/env/`` presets that train ``env_id`` (state vectors
    first), read from each preset's ``id:`` line."""
    found = [
        path.stem
        for path in sorted((PRESETS_DIR / "env").glob("*.yaml"))
        if re.search(rf"^\s+id:\s*{re.escape(env_id)}\s*$", path.read_text(), re.MULTILINE)
    ]
    return sorted(found, key=lambda name: "pixels" in name)


def preset_of_run(group: str, overrides: Sequence[str]) -> str | None:
    """The ``group`` preset a run of ``overrides`` used: its ``group=NAME`` override, else the
    root config's default (``configs/config.yaml``: ``algo: dqn``, ``env: cartpole``)."""
    chosen = [arg.split("=", 1)[1] for arg in overrides if arg.startswith(f"{group}=")]
    if chosen:
        return chosen[-1]
    found = re.search(rf"^\s+- {group}: (\S+)", (PRESETS_DIR / "config.yaml").read_text(), re.M)
    return found.group(1) if found else None

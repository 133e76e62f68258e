"""Write files so that a reader (or a crash) never sees half of one.

Every file a run writes goes to a temporary name in the same directory first and is renamed
into place (``os.replace`` is atomic on POSIX), so a process killed at any moment leaves the
previous version or the new one, never a mix.
"""

from __future__ import annotations

import json
import os
import shutil
from collections.abc import Callable
from pathlib import Path
from typing import Any

__all__ = [
    "free_bytes",
    "megabytes",
    "tree_bytes",
    "write_atomic",
    "write_json_atomic",
    "write_text_atomic",
]


def write_atomic(path: str | Path, write: Callable[[Path], Any]) -> Path:
    """Call ``write(tmp)`` for a temporary sibling of ``path``, then rename it to ``path``.

    The temporary name keeps the suffix, for writers that pick a format from it.
    """
    path = Path(path)
    tmp = path.with_name(f".{path.stem}.tmp{path.suffix}")
    try:
        write(tmp)
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)
    return path


def write_text_atomic(path: str | Path, text: str) -> Path:
    """Write ``text`` to ``path`` atomically."""
    return write_atomic(path, lambda tmp: tmp.write_text(text))


def write_json_atomic(path: str | Path, payload: Any) -> Path:
    """Write ``payload`` as indented JSON to ``path`` atomically."""
    return write_text_atomic(path, json.dumps(payload, indent=2) + "\n")


def free_bytes(path: str | Path) -> int:
    """Bytes free to this user on the filesystem that holds ``path`` (or its nearest parent)."""
    path = Path(path).absolute()
    while not path.exists():
        path = path.parent
    return shutil.disk_usage(path).free


def tree_bytes(path: str | Path, new_only: bool = False) -> int:
    """The total size of the files under ``path`` (0 if it does not exist); with ``new_only``,
    of those with no other name (a hard link shares another checkpoint's bytes)."""
    sizes = (file.stat() for file in Path(path).rglob("*") if file.is_file())
    return sum(stat.st_size for stat in sizes if not new_only or stat.st_nlink == 1)


def megabytes(size: int) -> str:
    """``size`` bytes in MB with one decimal, as the disk messages write it."""
    return f"{size / 1e6:.1f} MB"


def check_checkpoint_exists(path: str | Path) -> None:
    """Raise a one-line ConfigError if ``path`` (a ``checkpoint=`` argument) does not exist.

    Torch-free, so a command answers a mistyped path before its heavy imports (about 0.3 s
    instead of the seconds torch and TorchRL take to import).
    """
    from trl_cartpole.errors import ConfigError

    if not Path(path).exists():
        raise ConfigError(
            f"checkpoint={str(path)!r} does not exist; pass the run directory training printed "
            "(or runs/latest) or a checkpoint in it"
        )

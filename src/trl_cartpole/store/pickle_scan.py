"""Refuse a checkpoint that could run code when loaded, and forbid unpickling while loading.

A checkpoint is a directory of JSON files and raw tensor files, but two libraries underneath
still unpickle on load: TorchRL's replay buffer reads ``prefetch.pkl`` with ``pickle.load``,
and tensordict reads a non-tensor leaf's ``other.pickle`` (tensordict 0.14 only warns), from a
directory or from inside a zip archive (``state.tdz``, or any file where a directory was
expected). A pickle runs whatever callable it names, so a checkpoint from anywhere else could
run code on ``resume=``, ``evaluate.py``, ``render.py`` or ``export.py`` (the hazard that made
``torch.load`` default to ``weights_only=True``). The integrity record does not help: whoever
alters a checkpoint rewrites it too. Three guards:

- :func:`refuse_code`, before anything is loaded, refuses a checkpoint holding a symbolic link
  (a loader would follow it out of the checkpoint), a zip archive (tensordict's archive format,
  which this project never writes), or a pickle that uses any opcode able to fetch or call an
  object (``GLOBAL``, ``STACK_GLOBAL``, ``REDUCE``, ``BUILD``, ``INST``, ``OBJ``, ``NEWOBJ``,
  the extension-registry and persistent-id opcodes), read with :mod:`pickletools`, which parses
  without executing: with the remaining opcodes a pickle builds only dicts, lists, tuples,
  strings and numbers. TorchRL's own ``prefetch.pkl`` (``{'version': 1, 'capacity': 0,
  'queue': ()}`` without prefetching) passes.
- :func:`no_unpickling`, around the load itself, turns tensordict's warning that it is about to
  unpickle a non-tensor leaf into a refusal, whatever path led there.
- ``.pt`` files are read by ``torch.load(weights_only=True)``, safe by design.
"""

from __future__ import annotations

import contextlib
import os
import pickletools
import warnings
import zipfile
from collections.abc import Iterator
from pathlib import Path

from trl_cartpole.errors import ConfigError

__all__ = ["executable_opcode", "no_unpickling", "refuse_code"]

PICKLE_SUFFIXES = (".pkl", ".pickle")
# Every opcode that can look up a global, call an object or hand data to a hook.
CODE_OPCODES = frozenset(
    {
        "GLOBAL",
        "STACK_GLOBAL",
        "REDUCE",
        "BUILD",
        "INST",
        "OBJ",
        "NEWOBJ",
        "NEWOBJ_EX",
        "EXT1",
        "EXT2",
        "EXT4",
        "PERSID",
        "BINPERSID",
    }
)


def executable_opcode(data: bytes) -> str | None:
    """What in pickle ``data`` could run code (e.g. ``"builtins.exec"``); None for plain data.

    A pickle that cannot be parsed is reported too: it is not plain data.
    """
    strings: list[str] = []  # the last strings pushed: STACK_GLOBAL's module and name
    try:
        for opcode, argument, _ in pickletools.genops(data):
            if opcode.name in CODE_OPCODES:
                if opcode.name == "GLOBAL":
                    return str(argument).replace(" ", ".")
                if opcode.name == "STACK_GLOBAL" and len(strings) >= 2:
                    return ".".join(strings[-2:])
                return f"opcode {opcode.name}"
            if isinstance(argument, str):
                strings.append(argument)
    except (ValueError, EOFError) as error:
        return f"an unparsable pickle ({error})"
    return None


def _what_runs_code(file: Path) -> str | None:
    if file.is_symlink():
        return f"a symbolic link to {os.readlink(file)}, which a loader would follow"
    if not file.is_file():
        return None
    # (A .memmap file is only ever mapped as raw numbers; not checked, so that a tensor whose
    # bytes happen to end like a zip directory is never taken for one.)
    if not file.name.endswith(".memmap") and zipfile.is_zipfile(file):
        return "a zip archive, whose pickled leaves tensordict would load"
    if file.name.endswith(PICKLE_SUFFIXES):
        return executable_opcode(file.read_bytes())
    return None


def refuse_code(path: str | Path) -> None:
    """Raise a one-line :class:`ConfigError` if the checkpoint at ``path`` could run code."""
    path = Path(path)
    for root, directories, files in os.walk(path, followlinks=False):
        for name in [*directories, *files]:
            file = Path(root) / name
            found = _what_runs_code(file)
            if found is not None:
                raise _refusal(path, file.relative_to(path), found)


def _refusal(path: Path, file: Path | str, found: str) -> ConfigError:
    return ConfigError(
        f"checkpoint={str(path)!r} was refused: {file} would run code ({found}) when loaded, "
        "which a trl_cartpole checkpoint never does; it was altered or comes from elsewhere. "
        "Nothing was loaded; use a checkpoint you wrote"
    )


# tensordict's FutureWarning just before it unpickles a non-tensor leaf (allow_pickle=None)
UNPICKLE_WARNING = "TensorDict.load_memmap is loading a pickled non-tensor field"


@contextlib.contextmanager
def no_unpickling(path: str | Path) -> Iterator[None]:
    """Load inside this: tensordict's unpickling of a non-tensor leaf becomes a refusal."""
    with warnings.catch_warnings():
        warnings.filterwarnings("error", message=UNPICKLE_WARNING, category=FutureWarning)
        try:
            yield
        except FutureWarning as warning:
            if UNPICKLE_WARNING not in str(warning):
                raise
            raise _refusal(
                Path(path), "a non-tensor leaf", "a pickle tensordict was about to load"
            ) from None

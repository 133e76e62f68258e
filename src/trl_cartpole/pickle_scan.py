"""Refuse a checkpoint that holds a pickle able to run code, before anything in it is loaded.

A checkpoint is a directory of JSON files and raw tensor files, but two libraries underneath
still unpickle on load: TorchRL's replay buffer reads ``prefetch.pkl`` with ``pickle.load``,
and tensordict reads a non-tensor leaf's ``other.pickle`` (tensordict 0.14 only warns). A
pickle runs whatever callable it names, so a checkpoint from anywhere else could run code on
``resume=``, ``evaluate.py``, ``render.py`` or ``export.py`` (the hazard that made
``torch.load`` default to ``weights_only=True``). The integrity record does not help: whoever
alters a checkpoint rewrites it too.

:func:`refuse_code` reads every pickle in a checkpoint with :mod:`pickletools` (which parses
without executing) and refuses one that uses any opcode able to fetch or call an object
(``GLOBAL``, ``STACK_GLOBAL``, ``REDUCE``, ``BUILD``, ``INST``, ``OBJ``, ``NEWOBJ``, the
extension-registry and persistent-id opcodes): with only the remaining opcodes a pickle can
build dicts, lists, tuples, strings and numbers, nothing else. TorchRL's own ``prefetch.pkl``
(``{'version': 1, 'capacity': 0, 'queue': ()}`` without prefetching) passes. It also refuses a
tensordict ``meta.json`` that names a class to import (``_tensorclass_type``), which this
project never writes. ``.pt`` files are read by ``torch.load(weights_only=True)``, safe by
design, and are not scanned.
"""

from __future__ import annotations

import json
import pickletools
from pathlib import Path

from trl_cartpole.errors import ConfigError

__all__ = ["executable_opcode", "refuse_code"]

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


def refuse_code(path: str | Path) -> None:
    """Raise a one-line :class:`ConfigError` if the checkpoint at ``path`` could run code."""
    path = Path(path)
    for file in sorted(path.rglob("*")):
        if not file.is_file():
            continue
        found = None
        if file.name.endswith(PICKLE_SUFFIXES):
            found = executable_opcode(file.read_bytes())
        elif file.name == "meta.json" and "_tensorclass_type" in _read_json(file):
            found = f"the class {_read_json(file)['_tensorclass_type']!r} to import"
        if found is not None:
            raise ConfigError(
                f"checkpoint={str(path)!r} was refused: {file.relative_to(path)} would run code "
                f"({found}) when loaded, which a trl_cartpole checkpoint never does; it was "
                "altered or comes from elsewhere. Nothing was loaded; use a checkpoint you wrote"
            )


def _read_json(file: Path) -> dict:
    try:
        value = json.loads(file.read_bytes())
    except ValueError:
        return {}
    return value if isinstance(value, dict) else {}

"""``--help`` for the scripts, written from the dataclasses that define their arguments.

Every field's one-line meaning is the comment on its line (or the comment lines just above
it) in the dataclass's source, so the schema stays the one place a field is documented:
``trl_cartpole.config.schema`` for ``train.py``, each script's ``...Args`` dataclass for the others.
"""

from __future__ import annotations

import ast
import dataclasses
import inspect
import io
import re
import sys
import textwrap
import tokenize
import typing
from collections.abc import Sequence
from pathlib import Path
from typing import Any, TypeVar

import yaml
from omegaconf import OmegaConf

from trl_cartpole.config.messages import did_you_mean
from trl_cartpole.errors import ConfigError

__all__ = ["HELP_FLAGS", "field_help", "parse_args", "shown_value", "wants_help"]

HELP_FLAGS = ("-h", "--help")
T = TypeVar("T")


def wants_help(argv: Sequence[str]) -> bool:
    """True when the command line asks for help (``-h`` or ``--help``)."""
    return any(arg in HELP_FLAGS for arg in argv)


def _own_comments(cls: type) -> dict[str, str]:
    """``{field: comment}`` for the fields ``cls`` itself declares, read from its source.

    A field's meaning is the comment at the end of its line; a field without one takes the
    comment lines right above it. (So a comment is never split between two fields.)
    """
    source = textwrap.dedent(inspect.getsource(cls))
    comments: dict[int, tuple[str, bool]] = {}  # line: (text, the line holds only a comment)
    lines = source.splitlines()
    for token in tokenize.generate_tokens(io.StringIO(source).readline):
        if token.type == tokenize.COMMENT:
            row = token.start[0]
            alone = not lines[row - 1][: token.start[1]].strip()
            comments[row] = (token.string.lstrip("#").strip(), alone)
    body = ast.parse(source).body[0].body
    found: dict[str, str] = {}
    for node in (node for node in body if isinstance(node, ast.AnnAssign)):
        text, alone = comments.get(node.end_lineno, ("", True))
        if not text or alone:  # no trailing comment: the comment lines right above
            above, row = [], node.lineno - 1
            while row in comments and comments[row][1]:
                above.insert(0, comments[row][0])
                row -= 1
            text = " ".join(above)
        found[node.target.id] = text
    return found


def _comments(cls: type) -> dict[str, str]:
    """``{field: comment}`` for every field of dataclass ``cls``, inherited ones included."""
    found: dict[str, str] = {}
    for klass in reversed(cls.__mro__):
        if dataclasses.is_dataclass(klass) and klass is not object:
            found.update(_own_comments(klass))
    return found


def _type_name(annotation: Any) -> str:
    text = str(annotation) if not isinstance(annotation, type) else annotation.__name__
    return text.replace("typing.", "").replace("NoneType", "None").replace(" | None", "|None")


def shown_value(value: Any) -> str:
    """``value`` as it is written on the command line (``null``, ``true``, ``[128,128]``)."""
    if value is None:
        return "null"
    if isinstance(value, bool):
        return str(value).lower()
    if isinstance(value, list | tuple):
        return "[" + ",".join(shown_value(item) for item in value) + "]"
    return str(value)


def _default(f: dataclasses.Field) -> Any:
    if f.default is not dataclasses.MISSING:
        return f.default
    if f.default_factory is not dataclasses.MISSING:
        return f.default_factory()
    return "???"


def field_help(cls: type, prefix: str = "") -> list[tuple[str, str, str, str]]:
    """``(key, type, default, meaning)`` for every leaf field of dataclass ``cls``, nested first."""
    rows: list[tuple[str, str, str, str]] = []
    comments = _comments(cls)
    hints = typing.get_type_hints(cls)
    for f in dataclasses.fields(cls):
        kind = hints[f.name]
        if dataclasses.is_dataclass(kind):
            rows.extend(field_help(kind, f"{prefix}{f.name}."))
            continue
        rows.append(
            (f"{prefix}{f.name}", _type_name(kind), shown_value(_default(f)), comments[f.name])
        )
    return rows


def format_fields(rows: list[tuple[str, str, str, str]], width: int = 100) -> str:
    """The rows of :func:`field_help` as text: ``key=default (type)`` then the meaning, wrapped.

    A blank line separates the sections (``env.``, ``loss.``...).
    """
    lines: list[str] = []
    section = None
    for key, kind, default, meaning in rows:
        if "." in key and key.split(".")[0] != section:
            section = key.split(".")[0]
            lines.append("")
        head = f"  {key}={default} ({kind})"
        text = f"{head:<44} {meaning}" if len(head) < 44 else f"{head} {meaning}"
        lines.extend(textwrap.wrap(text, width, subsequent_indent=" " * 45))
    return "\n".join(lines)


def parse_args(
    schema: type[T],
    argv: Sequence[str],
    usage: str,
    command: str | None = None,
    positional: str | None = None,
) -> T:
    """``key=value`` arguments merged onto dataclass ``schema``; ``--help`` prints and exits 0.

    ``usage`` (the script's docstring) is printed above the table of fields. ``positional``
    names the field a lone argument fills (``evaluate runs/latest`` is
    ``checkpoint=runs/latest``). A dashed argument, a lone one, an unknown key or a wrong type
    raises a one-line :class:`ConfigError` naming ``command`` (default: the usage line's) and
    the form that works; :func:`trl_cartpole.cli.main.run_cli` reports it with exit status 2.
    """
    if wants_help(argv):
        print(f"{usage.strip()}\n\narguments (key=default (type) meaning):")
        print(format_fields(field_help(schema)))
        raise SystemExit(0)
    command = command or _usage_command(usage)
    given = OmegaConf.create()
    for arg in _key_value_arguments(argv, schema, command, positional):
        try:
            given.merge_with_dotlist([arg])
        except (yaml.YAMLError, ValueError) as error:  # YAML cannot read the value
            reason = str(error).splitlines()[0]
            raise ConfigError(
                f"{arg!r} is not key=value with a value YAML can read ({reason}); quote text "
                "that holds YAML's signs (\"'text, with signs'\")"
            ) from None
    return OmegaConf.to_object(OmegaConf.merge(OmegaConf.structured(schema), given))


def _usage_command(usage: str) -> str:
    """The command a usage docstring names (``trl-cartpole evaluate``)."""
    found = re.search(r"usage: (\S+ \S+)", usage)
    return found.group(1) if found else "this command"


def _key_value_arguments(
    argv: Sequence[str], schema: type, command: str, positional: str | None
) -> list[str]:
    """``argv`` as ``key=value`` arguments of ``schema``'s fields, or a one-line refusal."""
    keys = [field.name for field in dataclasses.fields(schema)]
    lone_taken = positional is None or any(arg.startswith(f"{positional}=") for arg in argv)
    arguments = []
    for index, arg in enumerate(argv):
        if arg.startswith("-"):
            key, _, value = arg.lstrip("-").partition("=")
            following = argv[index + 1] if index + 1 < len(argv) else ""
            value = value or ("" if "=" in following else following)
            raise ConfigError(
                f"arguments are key=value here, without dashes: write {key}={value or 'VALUE'}"
            )
        if "=" not in arg:
            if lone_taken:
                raise ConfigError(
                    f"{arg!r} is not key=value; write KEY={arg} with one of the keys of "
                    f"`{command} --help`"
                )
            arguments.append(f"{positional}={arg}")
            lone_taken = True
            continue
        key = arg.split("=", 1)[0]
        if key.split(".")[0] not in keys:
            raise ConfigError(
                f"{key} is not an argument of {command}{did_you_mean(key, keys)}; "
                f"`{command} --help` lists them"
            )
        arguments.append(arg)
    return arguments


def preset_lines(config_dirs: Sequence[Path], group: str, width: int = 100) -> list[str]:
    """One line per preset of ``<dir>/<group>/``: its name and the first line of its comment.

    A preset of a later directory of ``config_dirs`` with the name of an earlier one is not
    listed again (Hydra takes the first one found on its search path).
    """
    lines, seen = [], set()
    paths = [path for d in config_dirs for path in sorted((Path(d) / group).glob("*.yaml"))]
    for path in paths:
        if path.stem in seen:
            continue
        seen.add(path.stem)
        comments = [
            line.lstrip("# ").strip()
            for line in path.read_text().splitlines()
            if line.startswith("#") and "@package" not in line
        ]
        line = f"  {group}={path.stem:<12} {comments[0] if comments else ''}".rstrip()
        lines.append(line if len(line) <= width else line[: width - 3] + "...")
    return lines


def print_train_help(usage: str, config_dirs: Sequence[Path], schema: type) -> None:
    """``train --help``: usage, the presets of each config group, then every field."""
    out = [usage.strip(), "", "presets (the package's, then presets= directories):"]
    for group in ("algo", "env"):
        out.extend(preset_lines(config_dirs, group))
    out += ["", "fields (key=default (type) meaning), each one an override key=value:"]
    out.append(format_fields(field_help(schema)))
    print("\n".join(out), file=sys.stdout)

"""Hydra's and OmegaConf's composition errors, said in this project's words.

Composition fails in Hydra's terms (``Could not override 'seeed': Key 'seeed' not in
'Config'``, ``LexerNoViableAltException``...). :func:`explain` turns the ones a user meets
first into one line naming the key or preset, with the closest known name ("did you mean") and
the form that works; any other error keeps its own words.
"""

from __future__ import annotations

import difflib
import re
from collections.abc import Iterable, Sequence

from trl_cartpole.config.schema import Config, flat_fields

__all__ = ["did_you_mean", "explain"]

# The keys a command line may set besides the schema's fields.
_COMMAND_KEYS = ("algo", "env", "presets", "resume")


# Names users reach for that the schema calls otherwise (the leaf of a dotted key).
SYNONYMS = {
    "learning_rate": "lr",
    "discount": "gamma",
    "epsilon": "eps",
    "buffer_size": "max_size",
    "replay_size": "max_size",
    "frames": "total_frames",
    "steps": "total_frames",
}


def did_you_mean(word: str, known: Iterable[str]) -> str:
    """``" (did you mean 'seed'?)"`` for the closest of ``known``, or ``""``.

    A dotted key is matched first by its synonym (:data:`SYNONYMS`: ``optim.learning_rate`` is
    ``optim.lr``), then among the keys of its own section, then among all."""
    known = list(known)
    section, _, leaf = word.rpartition(".")
    synonym = f"{section}.{SYNONYMS[leaf]}" if section and leaf in SYNONYMS else SYNONYMS.get(leaf)
    if synonym in known:
        return f" (did you mean {synonym!r}?)"
    same_section = [key for key in known if section and key.rpartition(".")[0] == section]
    for candidates in (same_section, known):
        close = difflib.get_close_matches(word, candidates, n=1, cutoff=0.6)
        if close:
            return f" (did you mean {close[0]!r}?)"
    return ""


def _keys() -> list[str]:
    return [*flat_fields(Config()), *_COMMAND_KEYS]


def explain(
    message: str, command: str = "trl-cartpole train", argv: Sequence[str] = ()
) -> str | None:
    """The project's one line for a composition error's one-line ``message``, or None.

    ``argv`` (the command line) gives the value of a dashed ``--key VALUE``."""
    header = re.search(
        r"In '(\w+)/([^']+)': ConfigKeyError raised while composing config: Key '(\w+)' not in",
        message,
    )
    if header and header.group(1) == header.group(3):
        group, name = header.group(1), header.group(2)
        return (
            f"the preset {group}/{name}.yaml sets {group}: inside the {group} group; make "
            "'# @package _global_' its first line, as the shipped presets do"
        )
    unknown = re.search(r"Could not override '([^']+)': Key '[^']+' not in '\w*Config'", message)
    if unknown:
        key = unknown.group(1)
        return (
            f"{key} is not a setting{did_you_mean(key, _keys())}; `{command} --help` lists "
            "every key"
        )
    dashed = re.search(r"LexerNoViableAltException: (--?[\w.]+)(=[^\s:]*)?", message)
    if dashed:
        flag = dashed.group(1)
        value = (dashed.group(2) or "").lstrip("=")
        following = list(argv)[list(argv).index(flag) + 1 :] if flag in argv else []
        if not value and following and "=" not in following[0]:
            value = following[0]  # --seed 1
        return (
            f"arguments are key=value here, without dashes: write {flag.lstrip('-')}="
            f"{value or 'VALUE'}"
        )
    preset = re.search(
        r"Could not find '(\w+)/([^']+)': Available options in '\w+': (.*)$", message
    )
    if preset:
        group, name = preset.group(1), preset.group(2)
        options = [option.strip() for option in preset.group(3).split(":") if option.strip()]
        return (
            f"{group}={name!r} is not a preset{did_you_mean(name, options)}; choose one of "
            f"{options} (configs/{group}/), or a YAML file of your own under presets=DIR"
        )
    wrong_type = re.search(
        r"Value '(.*)' of type '\w+' could not be converted to (\w+)",
        message,
    )
    if wrong_type:
        value, kind = wrong_type.groups()
        named = re.search(r"Error merging override ([\w.]+)=", message)
        keys = (
            [named.group(1)]
            if named
            else [arg.split("=", 1)[0] for arg in argv if arg.split("=", 1)[-1] == value]
        )
        kind = {"Integer": "an integer", "Float": "a number", "Boolean": "true or false"}.get(
            kind, kind.lower()
        )
        key = keys[0] if keys else "a value"
        return f"{key}={value!r} is not {kind}; write {key}=<{kind}>"
    missing = re.search(r"has missing mandatory value: ([\w.]+)", message)
    if missing:
        key = missing.group(1)
        example = "runs/latest (a run directory or a checkpoint)" if key == "checkpoint" else "..."
        return f"{key}= is needed: add {key}={example}"
    return None

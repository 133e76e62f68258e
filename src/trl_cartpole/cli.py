"""Command-line plumbing shared by the scripts: compose the Hydra config, report bad input.

Bad input (an unknown key, a wrong type, an impossible value, an unknown env, a bad
checkpoint) ends the program with one line on stderr and exit status 2, before any training.
An interrupted run exits with 128 + the signal (130 for Ctrl-C) after one line saying how to
resume; a numerical fault exits with 1. Set ``HYDRA_FULL_ERROR=1`` to get the full traceback
instead.
"""

from __future__ import annotations

import os
import re
import sys
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from hydra import compose, initialize_config_dir
from hydra.errors import HydraException
from omegaconf import DictConfig, OmegaConf
from omegaconf.errors import OmegaConfBaseException

from trl_cartpole.cli_help import shown_value
from trl_cartpole.config import flat_fields, register_configs, to_config
from trl_cartpole.console import python_command, quiet_libraries
from trl_cartpole.errors import ConfigError, TrainingFailed, TrainingInterrupted
from trl_cartpole.run_control import install_unbreakable_console

__all__ = [
    "changes_from_presets",
    "compose_config",
    "compose_run_config",
    "run_cli",
    "split_resume",
]

EXIT_BAD_INPUT = 2
EXIT_FAILED = 1
EXIT_KEYBOARD_INTERRUPT = 130


def compose_config(config_dir: str | Path, overrides: Sequence[str]) -> DictConfig:
    """Compose ``config_dir/config.yaml`` over the typed schema with command-line overrides."""
    register_configs()
    with initialize_config_dir(config_dir=str(Path(config_dir).resolve()), version_base="1.3"):
        return compose(config_name="config", overrides=list(overrides))


# Fields that do not change what is learnt: left out of a run directory's name.
_NOT_IN_NAME = ("seed", "run_dir", "num_threads", "env.id", "logger.", "checkpoint.")
_UNSAFE = re.compile(r"[^A-Za-z0-9._=,+-]")


def changes_from_presets(cfg: DictConfig, presets: DictConfig, limit: int = 60) -> str:
    """``double_dqn=true,lr=0.001``: the fields where ``cfg`` differs from ``presets``.

    Each is named by its last key; the text is safe in a path and at most ``limit`` characters
    (``+N`` stands for the changes that did not fit).
    """
    ours, theirs = flat_fields(to_config(cfg)), flat_fields(to_config(presets))
    changed = [
        f"{key.rsplit('.', 1)[-1]}={_UNSAFE.sub('', shown_value(value).replace(',', 'x'))}"
        for key, value in ours.items()
        if value != theirs.get(key) and not key.startswith(_NOT_IN_NAME)
    ]
    text = ""
    for index, change in enumerate(changed):
        rest = len(changed) - index
        candidate = f"{text},{change}" if text else change
        if len(candidate) > limit - (0 if rest == 1 else 4):
            return f"{text},+{rest}" if text else f"+{rest}"
        text = candidate
    return text


def compose_run_config(config_dir: str | Path, overrides: Sequence[str]) -> DictConfig:
    """:func:`compose_config`; unless ``run_dir=`` is given, name the run by its changes.

    ``runs/CartPole-v1-dqn-double_dqn=true-seed0-<time>``: the fields set on the command line
    that differ from the chosen presets (``algo=``, ``env=``) go into the name.
    """
    cfg = compose_config(config_dir, overrides)
    if any(arg.startswith("run_dir=") for arg in overrides):
        return cfg
    groups = [arg for arg in overrides if arg.split("=", 1)[0] in ("algo", "env", "seed")]
    changes = changes_from_presets(cfg, compose_config(config_dir, groups))
    if changes:
        pattern = OmegaConf.to_container(cfg)["run_dir"]  # unresolved: runs/${env.id}-...
        cfg.run_dir = pattern.replace("-seed${seed}", f"-{changes}-seed${{seed}}")
    return cfg


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


def split_resume(argv: Sequence[str]) -> tuple[str | None, list[str]]:
    """Take ``resume=PATH`` out of the overrides: ``(PATH or None, the other overrides)``."""
    resume = [arg.split("=", 1)[1] for arg in argv if arg.startswith("resume=")]
    others = [arg for arg in argv if not arg.startswith("resume=")]
    if len(resume) > 1:
        raise ConfigError("resume= is given more than once; pass one run directory")
    return (resume[0] if resume else None), others


def run_cli(main: Callable[[list[str]], Any], argv: Sequence[str] | None = None) -> int:
    """Run ``main(argv)``; report bad input, interrupts and faults in one line with its code."""
    argv = list(sys.argv[1:] if argv is None else argv)
    # for the rest of the process: the messages below and Python's last flush at exit too
    install_unbreakable_console()
    try:
        with quiet_libraries():
            main(argv)
    except (ConfigError, HydraException, OmegaConfBaseException) as error:
        if os.environ.get("HYDRA_FULL_ERROR") == "1":
            raise
        print(f"error: {_one_line(error)}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except TrainingInterrupted as interrupted:
        print(str(interrupted), file=sys.stderr)
        return interrupted.exit_code
    except TrainingFailed as failure:
        print(f"error: {failure}", file=sys.stderr)
        return EXIT_FAILED
    except KeyboardInterrupt:
        print(
            "interrupted outside a safe point (or twice): exited at once; the newest complete "
            f"checkpoint is intact ({python_command()} scripts/train.py resume=RUN_DIR)",
            file=sys.stderr,
        )
        return EXIT_KEYBOARD_INTERRUPT
    return 0

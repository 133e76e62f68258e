"""Hydra composition: the presets and command-line overrides onto the typed schema, and the
name a run directory takes from what the command line changed."""

from __future__ import annotations

import re
from collections.abc import Sequence
from pathlib import Path

from hydra import compose, initialize_config_dir
from omegaconf import DictConfig, OmegaConf

from trl_cartpole.config.help import shown_value
from trl_cartpole.config.presets import PRESETS_DIR, with_search_path
from trl_cartpole.config.schema import Config, flat_fields, register_configs, to_config
from trl_cartpole.config.validation import check_boolean_overrides

__all__ = ["changes_from_presets", "compose_config", "compose_run_config", "variant_label"]


def compose_config(
    config_dir: str | Path = PRESETS_DIR, overrides: Sequence[str] = ()
) -> DictConfig:
    """Compose ``config_dir/config.yaml`` over the typed schema with command-line overrides.

    ``presets=DIR`` among the overrides (and ``TRL_CARTPOLE_PRESETS``) adds a directory of the
    user's presets to the search path (:mod:`trl_cartpole.config.presets`).
    """
    register_configs()
    check_boolean_overrides(overrides)
    with initialize_config_dir(config_dir=str(Path(config_dir).resolve()), version_base="1.3"):
        return compose(config_name="config", overrides=with_search_path(overrides))


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


def compose_run_config(
    config_dir: str | Path = PRESETS_DIR, overrides: Sequence[str] = ()
) -> DictConfig:
    """:func:`compose_config`; unless ``run_dir=`` is given, name the run by its changes.

    ``runs/CartPole-v1-dqn-double_dqn=true-seed0-<time>``: the fields set on the command line
    that differ from the chosen presets (``algo=``, ``env=``) go into the name.
    """
    cfg = compose_config(config_dir, overrides)
    if any(arg.startswith("run_dir=") for arg in overrides):
        return cfg
    groups = [
        arg for arg in overrides if arg.split("=", 1)[0] in ("algo", "env", "seed", "presets")
    ]
    changes = changes_from_presets(cfg, compose_config(config_dir, groups))
    if changes:
        pattern = OmegaConf.to_container(cfg)["run_dir"]  # unresolved: runs/${env.id}-...
        cfg.run_dir = pattern.replace("-seed${seed}", f"-{changes}-seed${{seed}}")
    return cfg


# The variant switches a run's label names when they differ from its algo preset's.
_VARIANT_WORDS = {
    "loss.double_dqn": lambda on: "double DQN" if on else "no double DQN",
    "network.head": lambda head: f"{head} head",
    "network.noisy": lambda on: "noisy layers" if on else "no noisy layers",
    "network.distributional": lambda on: "C51" if on else "no C51",
    "buffer.prioritized": lambda on: "prioritized replay" if on else "uniform replay",
    "buffer.n_steps": lambda steps: f"{steps}-step returns",
}


def variant_label(cfg: Config) -> str:
    """The run's algorithm as its ending names it: the algo preset's name, and the variant
    switches where the run differs from that preset (``dqn + double DQN, dueling head`` for the
    pixel preset, whose env preset turns them on). A preset of the user's own directory is
    compared with the schema's defaults."""
    path = PRESETS_DIR / "algo" / f"{cfg.algo.name}.yaml"
    preset = OmegaConf.structured(Config)
    if path.is_file():
        preset = OmegaConf.merge(preset, OmegaConf.load(path))
    ours, theirs = flat_fields(cfg), flat_fields(to_config(preset))
    changed = [
        words(ours[key]) for key, words in _VARIANT_WORDS.items() if ours[key] != theirs[key]
    ]
    return f"{cfg.algo.name} + {', '.join(changed)}" if changed else cfg.algo.name

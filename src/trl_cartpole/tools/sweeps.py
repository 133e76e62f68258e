"""Sweeps: ``python scripts/train.py -m seed=0,1,2,3 algo=dqn,double`` through Hydra's multirun.

Hydra's sweeper expands the comma lists into their grid; its launcher runs the jobs. With the
``sweeps`` extra installed (``hydra-joblib-launcher``) the launcher is Hydra's joblib launcher:
the jobs run in parallel processes, one per core (``hydra.launcher.n_jobs=N`` to change); without
it, Hydra's basic launcher runs them one after another, and the sweep says so. Every job trains in
its own directory ``runs/sweeps/<time>/<job>-<env>-<algo>-seed<seed>`` (Hydra's sweep dir, see
``configs/config.yaml``), so ``python scripts/plot.py runs/sweeps/<time>`` compares them.

Every point of the grid is composed and validated before the first job starts: a bad value
anywhere stops the sweep with one line, before anything is trained.
"""

from __future__ import annotations

import importlib.util
import itertools
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from hydra import initialize_config_dir
from hydra.core.global_hydra import GlobalHydra
from hydra.core.hydra_config import HydraConfig
from hydra.core.override_parser.overrides_parser import OverridesParser
from omegaconf import DictConfig

from trl_cartpole.config.compose import compose_config
from trl_cartpole.config.presets import with_search_path
from trl_cartpole.config.schema import register_configs, to_config
from trl_cartpole.config.validation import validate
from trl_cartpole.errors import install_hint

__all__ = ["MULTIRUN_FLAGS", "expand_grid", "is_multirun", "run_sweep", "sweep_job"]

MULTIRUN_FLAGS = ("-m", "--multirun")
JOBLIB_LAUNCHER = "hydra_plugins.hydra_joblib_launcher"


def is_multirun(argv: Sequence[str]) -> bool:
    """Whether the command line asks for a Hydra multirun (``-m`` / ``--multirun``)."""
    return any(arg in MULTIRUN_FLAGS for arg in argv)


def _is_hydra_override(key: str) -> bool:
    return key == "hydra" or key.startswith(("hydra.", "hydra/"))


def expand_grid(overrides: Sequence[str]) -> list[list[str]]:
    """The overrides of every job of the sweep: the grid of the comma lists (and ``range()``).

    ``["seed=0,1", "algo=dqn,double", "optim.lr=1e-3"]`` gives four jobs, each with one seed,
    one algo and the learning rate. Overrides of Hydra's own config (``hydra.*``) are left out.
    """
    axes: list[list[str]] = []
    for override in OverridesParser.create().parse_overrides(list(overrides)):
        key = override.get_key_element()
        if _is_hydra_override(override.key_or_group):
            continue
        if override.is_sweep_override():
            axes.append([f"{key}={value}" for value in override.sweep_string_iterator()])
        else:
            axes.append([override.input_line])
    return [list(job) for job in itertools.product(*axes)]


def sweep_job(cfg: DictConfig) -> dict[str, Any]:
    """One job of the sweep: train into Hydra's job directory; return the run's summary."""
    from trl_cartpole.run.training import train  # import in the job's process only

    cfg.run_dir = HydraConfig.get().runtime.output_dir
    return train(cfg)


def run_sweep(config_dir: str | Path, overrides: Sequence[str]) -> list[dict[str, Any]]:
    """Validate every job, then run the grid with Hydra's multirun; return the summaries.

    Raises ``ConfigError`` (or Hydra's error) for the first job whose config cannot run.
    """
    overrides = [arg for arg in overrides if arg not in MULTIRUN_FLAGS]
    for job in expand_grid(overrides):
        validate(to_config(compose_config(config_dir, job)))
    chose_launcher = any(arg.startswith("hydra/launcher=") for arg in overrides)
    if not chose_launcher:
        if importlib.util.find_spec(JOBLIB_LAUNCHER) is not None:
            overrides = ["hydra/launcher=joblib", *overrides]
        else:
            print(
                "sweep jobs run one after another: Hydra's joblib launcher is not installed "
                f"({install_hint('sweeps')} runs them in parallel)",
                file=sys.stderr,
            )
    if not any(arg.startswith("logger.progress_bar=") for arg in overrides):
        overrides = [*overrides, "logger.progress_bar=false"]  # parallel bars would interleave
    overrides = with_search_path(overrides)  # presets=DIR: the user's presets
    register_configs()
    with initialize_config_dir(config_dir=str(Path(config_dir).resolve()), version_base="1.3"):
        hydra = GlobalHydra.instance().hydra
        batches = hydra.multirun(config_name="config", task_function=sweep_job, overrides=overrides)
    return [job.return_value for batch in batches for job in batch]

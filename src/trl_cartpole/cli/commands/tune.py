"""Tune hyperparameters with Optuna and write the best trial as a preset (docs/tuning.md).

usage: trl-cartpole tune trials=N out=FILE [jobs=J] [storage=URL] [study=NAME] [space=FILE]
           [seeds=[0,1]] [pruner=median|none] [objective=return|frames|seconds]
           [train's key=value ...]

Every other key=value is train's (env=lunarlander collector.total_frames=300000); the search
space is the env preset's tune/<preset>.yaml unless space= names one. trials= is the study's
total of finished trials: running again with the same storage and a larger N continues the
study. out=DIR/env/NAME.yaml makes env=NAME a preset of train with presets=DIR (a clone's
configs/env/NAME.yaml needs no presets=).

examples:
  trl-cartpole tune trials=30 out=my_presets/env/cartpole_tuned.yaml
  trl-cartpole tune trials=60 jobs=2 out=my_presets/env/lunarlander_tuned.yaml \\
      env=lunarlander collector.total_frames=300000
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from pathlib import Path

from trl_cartpole.config.compose import compose_config
from trl_cartpole.config.help import parse_args
from trl_cartpole.config.presets import PRESETS_DIR, preset_dirs
from trl_cartpole.config.schema import to_config
from trl_cartpole.config.validation import validate
from trl_cartpole.errors import ConfigError
from trl_cartpole.report.console import command, shown_path
from trl_cartpole.tools.tuning import OBJECTIVES


@dataclass
class TuneArgs:
    trials: int = "???"  # finished trials in the study (a larger N continues it)
    out: str = "???"  # the preset YAML to write (DIR/env/NAME.yaml)
    jobs: int = 1  # processes working on the study
    storage: str | None = None  # Optuna storage URL; null: sqlite:///runs/tune/STUDY/study.db
    study: str | None = None  # study name; null: the env preset
    space: str | None = None  # search space YAML; null: the env preset's tune/<preset>.yaml
    seeds: list[int] = field(default_factory=lambda: [0])  # seeds of each trial
    # median: stop a trial whose running score is below the median of earlier trials at the
    # same step (after 5 trials, from a quarter of the frame budget on); none: never
    pruner: str = "median"
    # return: maximise the mean greedy return over the evaluations; frames: minimise the frames
    # to solve (an unsolved run counts twice the frame budget); seconds: minimise the training
    # seconds to solve (an unsolved run counts twice its training seconds; run it alone)
    objective: str = "return"


TUNE_KEYS = {f.name for f in dataclasses.fields(TuneArgs)}


def main(argv: list[str]) -> None:
    dashed = [arg for arg in argv if arg.startswith("--") and arg != "--help"]
    if dashed:
        key = dashed[0].lstrip("-").split("=", 1)[0]
        raise ConfigError(f"{dashed[0]}: arguments are key=value here ({key}=...)")
    own = [arg for arg in argv if arg.split("=", 1)[0] in TUNE_KEYS or arg in ("-h", "--help")]
    overrides = [arg for arg in argv if arg not in own]
    args = parse_args(TuneArgs, own, __doc__)
    if args.pruner not in ("median", "none"):
        raise ConfigError(f"pruner={args.pruner!r}; choose median or none")
    if args.objective not in OBJECTIVES:
        raise ConfigError(f"objective={args.objective!r}; choose one of {', '.join(OBJECTIVES)}")
    # the trials' base config is checked before Optuna, torch and TorchRL are imported
    validate(to_config(compose_config(PRESETS_DIR, overrides)))
    from trl_cartpole.tools.study import run_study

    result = run_study(
        config_dir=PRESETS_DIR,
        overrides=overrides,
        trials=args.trials,
        out=args.out,
        jobs=args.jobs,
        storage=args.storage,
        study_name=args.study,
        space_path=args.space,
        seeds=args.seeds,
        pruner=args.pruner,
        objective=args.objective,
    )
    print(result.summary)
    preset = Path(args.out).resolve()
    name, group_dir = preset.stem, preset.parent
    if group_dir.name != "env":
        print(
            f"preset: {shown_path(preset)}; train takes presets by name from DIR/env/: move it "
            f"to a directory DIR/env/, then {command('train')} presets=DIR env={name}"
        )
    elif group_dir.parent in (PRESETS_DIR, *preset_dirs(overrides)):
        print(f"preset: {shown_path(preset)}; train with it: {command('train')} env={name}")
    else:
        print(
            f"preset: {shown_path(preset)}; train with it: {command('train')} "
            f"presets={shown_path(group_dir.parent)} env={name}"
        )

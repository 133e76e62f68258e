"""Train a DQN agent until it solves its env (CartPole-v1 by default).

usage: trl-cartpole train [key=value ...]      (from a clone: python scripts/train.py ...)

examples:
  trl-cartpole train                                  # CartPole-v1, the tuned default
  trl-cartpole train seed=3 optim.lr=1e-3             # change any field below
  trl-cartpole train algo=double network.head=dueling # a variant preset, plus a switch
  trl-cartpole train env=acrobot                      # an env preset
  trl-cartpole train env.id=MountainCar-v0 env.num_envs=8  # any Gymnasium id
  trl-cartpole train presets=mine env=tuned           # your own preset: mine/env/tuned.yaml
  trl-cartpole train resume=RUN_DIR                   # continue a stopped run
  trl-cartpole train -m seed=0,1,2 algo=dqn,double    # a sweep, one run per combination
"""

from __future__ import annotations

import signal
import sys
from pathlib import Path

from trl_cartpole.cli.main import freeze_imported_objects, split_resume
from trl_cartpole.config.compose import compose_run_config
from trl_cartpole.config.help import print_train_help, wants_help
from trl_cartpole.config.presets import PRESETS_DIR, preset_dirs
from trl_cartpole.config.schema import Config, to_config
from trl_cartpole.config.validation import validate
from trl_cartpole.errors import TrainingInterrupted
from trl_cartpole.report.console import command, ending, shown_path, verdict


def main(argv: list[str]) -> None:
    if wants_help(argv):
        print_train_help(__doc__, [PRESETS_DIR, *preset_dirs(argv)], Config)
        return
    resume, overrides = split_resume(argv)
    from trl_cartpole.tools.sweeps import is_multirun

    if is_multirun(argv):
        _sweep(argv)
        return
    checkpoint = None
    if resume is None:
        # composed and checked before torch and TorchRL are imported: a typo costs no wait
        cfg = compose_run_config(PRESETS_DIR, overrides)
        validate(to_config(cfg))
    else:
        from trl_cartpole.store.checkpoint import find_resume_checkpoint, resume_config, run_dir_of

        checkpoint = find_resume_checkpoint(resume)
        if not any(arg.startswith("run_dir=") for arg in overrides):  # continue where it is
            overrides = [f"run_dir={run_dir_of(checkpoint)}", *overrides]
        print(f"resuming from {checkpoint}", flush=True)
        cfg = resume_config(checkpoint, overrides)
    try:
        from trl_cartpole.run.training import train

        freeze_imported_objects()
        summary = train(cfg, resume=checkpoint)
    except KeyboardInterrupt:  # not between two batches, where the loop saves: exited at once
        raise TrainingInterrupted(_interrupted(Path(cfg.run_dir)), signal.SIGINT) from None
    run_cfg = to_config(cfg)
    print(ending(summary, overrides, run_cfg.logger.plots, run_cfg.env.from_pixels))


def _interrupted(run_dir: Path) -> str:
    """What a Ctrl-C the loop could not save at leaves: the resume command where the run
    directory holds a complete training state, else that there is nothing to resume."""
    checkpoints = sys.modules.get("trl_cartpole.store.checkpoint")  # loaded once training is
    if (
        checkpoints is not None
        and run_dir.is_dir()
        and checkpoints.find_complete_checkpoints(run_dir)
    ):
        return (
            "interrupted before the loop could save: exited at once; its newest complete "
            f"checkpoint is intact: {command('train')} resume={shown_path(run_dir)}"
        )
    return "interrupted before the run saved a checkpoint: nothing to resume; run it again"


def _sweep(argv: list[str]) -> None:
    from trl_cartpole.tools.sweeps import run_sweep

    summaries = run_sweep(PRESETS_DIR, argv)
    for summary in summaries:
        print(f"{verdict(summary)}\n  run directory: {shown_path(summary['run_dir'])}")
    sweep_dir = shown_path(Path(summaries[0]["run_dir"]).parent)
    print(f"compare them: {command('plot')} {sweep_dir} out={sweep_dir}/comparison")

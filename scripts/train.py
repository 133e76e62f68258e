"""Train a DQN agent until it solves its env (CartPole-v1 by default).

usage: python scripts/train.py [key=value ...]

examples:
  python scripts/train.py                                  # CartPole-v1, the tuned default
  python scripts/train.py seed=3 optim.lr=1e-3             # change any field below
  python scripts/train.py algo=double network.head=dueling # a variant preset, plus a switch
  python scripts/train.py env=acrobot                      # an env preset (configs/env/)
  python scripts/train.py env.id=MountainCar-v0 env.num_envs=8  # any Gymnasium env id
  python scripts/train.py resume=RUN_DIR                   # continue a stopped run
  python scripts/train.py -m seed=0,1,2 algo=dqn,double    # a sweep, one run per combination
"""

from __future__ import annotations

import sys
from pathlib import Path

from trl_cartpole.cli import compose_run_config, run_cli, split_resume
from trl_cartpole.cli_help import print_train_help, wants_help
from trl_cartpole.config import Config
from trl_cartpole.console import ending, python_command, shown_path, verdict

CONFIG_DIR = Path(__file__).resolve().parent.parent / "configs"


def main(argv: list[str]) -> None:
    if wants_help(argv):
        print_train_help(__doc__, CONFIG_DIR, Config)
        return
    # imported after the help check, so that --help answers at once
    from trl_cartpole.checkpoint import find_resume_checkpoint, resume_config, run_dir_of
    from trl_cartpole.sweeps import is_multirun, run_sweep
    from trl_cartpole.training import train

    if is_multirun(argv):
        summaries = run_sweep(CONFIG_DIR, argv)
        for summary in summaries:
            print(f"{verdict(summary)}\n  run directory: {shown_path(summary['run_dir'])}")
        sweep_dir = shown_path(Path(summaries[0]["run_dir"]).parent)
        scripts = shown_path(Path(__file__).parent)
        compare = f"{scripts}/plot.py {sweep_dir} --out {sweep_dir}/comparison"
        print(f"compare them: {python_command()} {compare}")
        return
    resume, overrides = split_resume(argv)
    if resume is None:
        summary = train(compose_run_config(CONFIG_DIR, overrides))
    else:
        checkpoint = find_resume_checkpoint(resume)
        if not any(arg.startswith("run_dir=") for arg in overrides):  # continue where it is
            overrides = [f"run_dir={run_dir_of(checkpoint)}", *overrides]
        print(f"resuming from {checkpoint}", flush=True)
        summary = train(resume_config(checkpoint, overrides), resume=checkpoint)
    print(ending(summary, Path(__file__).parent))


if __name__ == "__main__":
    sys.exit(run_cli(main))

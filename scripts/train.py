"""Train DQN: ``python scripts/train.py [key=value ...]`` (Hydra overrides, see configs/).

``python scripts/train.py resume=RUN_DIR [collector.total_frames=N ...]`` continues a stopped
run from its newest checkpoint, with the config it was started with.
``python scripts/train.py -m seed=0,1,2,3 algo=dqn,double`` runs the grid as a Hydra sweep
(``trl_cartpole.sweeps``), each job in its own directory.
"""

from __future__ import annotations

import sys
from pathlib import Path

from trl_cartpole.checkpoint import find_resume_checkpoint, resume_config, run_dir_of
from trl_cartpole.cli import compose_config, run_cli, split_resume
from trl_cartpole.sweeps import is_multirun, run_sweep
from trl_cartpole.train import train

CONFIG_DIR = Path(__file__).resolve().parent.parent / "configs"


def _report(summary: dict) -> str:
    solved = (
        f"solved at {summary['frames_to_solve']} frames, {summary['seconds_to_solve']:.1f} s"
        if summary["solved"]
        else "not solved"
    )
    return (
        f"{summary['env_id']} [{summary['algo']}, seed {summary['seed']}]: {solved}; "
        f"best policy greedy return over {summary['final_eval_episodes']} episodes: "
        f"{summary['final_eval_return_mean']:.1f} +/- {summary['final_eval_return_std']:.1f}"
    )


def main(argv: list[str]) -> None:
    if is_multirun(argv):
        summaries = run_sweep(CONFIG_DIR, argv)
        for summary in summaries:
            print(f"{_report(summary)}\n  run directory: {summary['run_dir']}")
        sweep_dir = Path(summaries[0]["run_dir"]).parent
        print(f"compare them: python scripts/plot.py {sweep_dir} --out {sweep_dir}/comparison")
        return
    resume, overrides = split_resume(argv)
    if resume is None:
        summary = train(compose_config(CONFIG_DIR, overrides))
    else:
        checkpoint = find_resume_checkpoint(resume)
        if not any(arg.startswith("run_dir=") for arg in overrides):  # continue where it is
            overrides = [f"run_dir={run_dir_of(checkpoint)}", *overrides]
        print(f"resuming from {checkpoint}", flush=True)
        summary = train(resume_config(checkpoint, overrides), resume=checkpoint)
    print(f"{_report(summary)}\nrun directory: {summary['run_dir']}")


if __name__ == "__main__":
    sys.exit(run_cli(main))

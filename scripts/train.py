"""Train DQN: ``python scripts/train.py [key=value ...]`` (Hydra overrides, see configs/)."""

from __future__ import annotations

import sys
from pathlib import Path

from trl_cartpole.cli import compose_config, run_cli
from trl_cartpole.train import train

CONFIG_DIR = Path(__file__).resolve().parent.parent / "configs"


def main(argv: list[str]) -> None:
    summary = train(compose_config(CONFIG_DIR, argv))
    solved = (
        f"solved at {summary['frames_to_solve']} frames, {summary['seconds_to_solve']:.1f} s"
        if summary["solved"]
        else "not solved"
    )
    print(
        f"{summary['env_id']} [{summary['algo']}, seed {summary['seed']}]: {solved}; "
        f"best policy greedy return over {summary['final_eval_episodes']} episodes: "
        f"{summary['final_eval_return_mean']:.1f} +/- {summary['final_eval_return_std']:.1f}\n"
        f"run directory: {summary['run_dir']}"
    )


if __name__ == "__main__":
    sys.exit(run_cli(main))

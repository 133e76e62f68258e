"""Greedy evaluation of a checkpoint.

    python scripts/evaluate.py checkpoint=runs/.../checkpoints/best episodes=100 \
        [seed=N] [epsilon=0.05] [output=FILE]

Prints mean, std, min and max of the per-episode returns and writes them all as JSON
(default: ``evaluation.json`` beside the checkpoint directory). ``epsilon`` (default 0, greedy)
replaces each action by a random one with that probability.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass
from pathlib import Path

from omegaconf import OmegaConf

from trl_cartpole.cli import run_cli
from trl_cartpole.errors import ConfigError
from trl_cartpole.files import write_json_atomic
from trl_cartpole.policy_io import evaluate_checkpoint, policy_checkpoint


@dataclass
class EvaluateArgs:
    checkpoint: str = "???"
    episodes: int = 100
    seed: int | None = None
    output: str | None = None
    epsilon: float = 0.0


def main(argv: list[str]) -> None:
    args = OmegaConf.to_object(
        OmegaConf.merge(OmegaConf.structured(EvaluateArgs), OmegaConf.from_dotlist(argv))
    )
    if args.episodes < 1:
        raise ConfigError(f"episodes={args.episodes} must be >= 1")
    if not 0.0 <= args.epsilon <= 1.0:
        raise ConfigError(f"epsilon={args.epsilon} must lie in [0, 1]")
    result, cfg = evaluate_checkpoint(args.checkpoint, args.episodes, args.seed, args.epsilon)
    returns = result.returns
    report = {
        "checkpoint": args.checkpoint,
        "env_id": cfg["env"]["id"],
        "episodes": len(returns),
        "epsilon": args.epsilon,
        "mean": result.mean,
        "std": result.std,
        "min": min(returns),
        "max": max(returns),
        "returns": returns,
        "lengths": result.lengths,
    }
    checkpoint = policy_checkpoint(args.checkpoint)  # a run directory: its best policy
    output = Path(args.output) if args.output else checkpoint.parent / "evaluation.json"
    write_json_atomic(output, report)
    print(
        f"{report['env_id']}: {'greedy' if not args.epsilon else f'epsilon={args.epsilon}'} "
        f"return over {len(returns)} episodes: "
        f"{report['mean']:.1f} +/- {report['std']:.1f} (min {report['min']:.0f}, "
        f"max {report['max']:.0f}); written to {output}"
    )


if __name__ == "__main__":
    sys.exit(run_cli(main))

"""Evaluate a trained policy greedily over many episodes.

usage: trl-cartpole evaluate [checkpoint=]RUN_DIR [episodes=N] [seed=N] [epsilon=0.0]

RUN_DIR is the directory training printed (its best policy is evaluated; before its first
evaluation, its newest training state's) or one checkpoint
in it (runs/.../checkpoints/last). It plays as many episodes as the run's final evaluation
did (eval.final_episodes: 100 on CartPole, 30 whole games on Breakout) unless told. Prints
mean, std, min and max of the episode returns and writes them all as JSON beside the
checkpoint (checkpoints/evaluation-best.json for best).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from trl_cartpole.config.help import parse_args
from trl_cartpole.config.validation import check_envs_at_once, check_seed
from trl_cartpole.errors import ConfigError
from trl_cartpole.report.console import command
from trl_cartpole.store.files import check_checkpoint_exists


@dataclass
class EvaluateArgs:
    checkpoint: str = "???"  # a run directory (its checkpoints/best) or a checkpoint directory
    # greedy episodes, stepped together; null: the run's final evaluation's (eval.final_episodes)
    episodes: int | None = None
    seed: int | None = None  # null: the seeds of the run's own final evaluation
    output: str | None = None  # JSON file; null: evaluation-<checkpoint>.json beside it
    epsilon: float = 0.0  # probability of a random action instead of the greedy one


def main(argv: list[str]) -> None:
    args = parse_args(EvaluateArgs, argv, __doc__, command("evaluate"), positional="checkpoint")
    check_checkpoint_exists(args.checkpoint)  # every check before the heavy imports below
    if args.episodes is not None:
        if args.episodes < 1:
            raise ConfigError(f"episodes={args.episodes} must be >= 1")
        check_envs_at_once("episodes", args.episodes)  # the episodes are stepped together
    check_seed("seed", args.seed)
    if not 0.0 <= args.epsilon <= 1.0:
        raise ConfigError(f"epsilon={args.epsilon} must lie in [0, 1]")
    # imported after the arguments are checked: a refusal comes before torch is loaded
    from trl_cartpole.policy.load import evaluate_checkpoint, policy_checkpoint
    from trl_cartpole.report.progress_bar import clear_status, show_status
    from trl_cartpole.run.eval_protocol import cut_episodes_note
    from trl_cartpole.store.checkpoint import read_checkpoint_config
    from trl_cartpole.store.files import write_json_atomic

    checkpoint = policy_checkpoint(args.checkpoint)  # a run directory: its policy
    episodes = args.episodes or read_checkpoint_config(checkpoint).eval.final_episodes
    playing = f"playing {episodes} episodes of {checkpoint}"

    def show_played(played: int) -> None:  # pixel episodes are played 20 at a time
        if played < episodes:
            show_status(f"{playing} ({played} played)")

    show_status(playing)
    try:
        result, cfg = evaluate_checkpoint(
            checkpoint, episodes, args.seed, args.epsilon, on_turn=show_played
        )
    finally:
        clear_status()
    returns = result.returns
    report = {
        "checkpoint": str(checkpoint.resolve()),  # the one evaluated (runs/latest moves on)
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
    cut = cut_episodes_note(result, cfg["eval"]["max_steps"])
    if cut is not None:
        print(f"note: {cut}")
    output = Path(args.output or checkpoint.parent / f"evaluation-{checkpoint.name}.json")
    write_json_atomic(output, report)
    print(
        f"{report['env_id']}: {'greedy' if not args.epsilon else f'epsilon={args.epsilon}'} "
        f"return over {len(returns)} episodes: "
        f"{report['mean']:.1f} +/- {report['std']:.1f} (min {report['min']:.0f}, "
        f"max {report['max']:.0f}); written to {output}"
    )

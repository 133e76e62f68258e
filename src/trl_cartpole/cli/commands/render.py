"""Watch a trained agent: greedy episodes as a GIF/MP4, or live in a window.

usage: trl-cartpole render [checkpoint=]RUN_DIR [episodes=3] [output=agent.gif] [human=true]

RUN_DIR is the directory training printed (its best policy plays; before its first
evaluation, its newest training state's) or one checkpoint in it.
Every frame is captioned with the episode, step and return so far and written to ``output``
(default: checkpoints/video.gif in the run). ``human=true`` opens Gymnasium's window instead.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

from trl_cartpole.config.help import parse_args
from trl_cartpole.config.validation import check_seed
from trl_cartpole.errors import ConfigError
from trl_cartpole.policy.formats import check_video_arguments
from trl_cartpole.report.console import command
from trl_cartpole.store.files import check_checkpoint_exists


@dataclass
class RenderArgs:
    checkpoint: str = "???"  # a run directory (its checkpoints/best) or a checkpoint directory
    episodes: int = 3  # greedy episodes, one after the other
    output: str | None = None  # .gif or .mp4 (mp4 needs the video extra); null: video.gif beside it
    fps: int = 50  # frames per second of the file
    # frame size relative to the env's render, in (0, 4]; null: 0.5 (a classic-control env's
    # 600x400 picture), 3 for an Atari game's 160x210 screen
    scale: float | None = None
    seed: int | None = None  # null: the seeds of the run's own final evaluation
    human: bool = False  # open Gymnasium's window instead of writing a file (needs a display)


def main(argv: list[str]) -> None:
    args = parse_args(RenderArgs, argv, __doc__, command("render"), positional="checkpoint")
    check_checkpoint_exists(args.checkpoint)  # every check before the heavy imports below
    check_seed("seed", args.seed)
    if not args.human:
        check_video_arguments(args.episodes, args.fps, args.scale, args.output)
    # imported after the arguments are checked: a refusal comes before torch is loaded
    from trl_cartpole.policy.load import load_trained_policy
    from trl_cartpole.policy.video import record_agent

    if not args.human:
        print(
            record_agent(
                args.checkpoint, args.episodes, args.seed, args.output, args.fps, args.scale
            )
        )
        return
    if args.episodes < 1:
        raise ConfigError("episodes must be >= 1")
    if not os.environ.get("DISPLAY") and not os.environ.get("WAYLAND_DISPLAY"):
        raise ConfigError("human=true needs a display; write a file instead (output=x.gif)")
    trained = load_trained_policy(args.checkpoint, seed=args.seed, render_mode="human")
    for _ in range(args.episodes):
        trained.env.rollout(trained.cfg.eval.max_steps, trained.actor)
    trained.env.close()

"""Watch a trained agent: greedy episodes as a GIF/MP4, or live in a window.

usage: python scripts/render.py checkpoint=RUN_DIR [episodes=3] [output=agent.gif] [human=true]

RUN_DIR is the directory training printed (its best policy plays) or one checkpoint in it.
Every frame is captioned with the episode, step and return so far and written to ``output``
(default: checkpoints/video.gif in the run). ``human=true`` opens Gymnasium's window instead.
"""

from __future__ import annotations

import os
import sys
from dataclasses import dataclass
from pathlib import Path

from trl_cartpole.cli import run_cli
from trl_cartpole.cli_help import parse_args
from trl_cartpole.errors import ConfigError


@dataclass
class RenderArgs:
    checkpoint: str = "???"  # a run directory (its checkpoints/best) or a checkpoint directory
    episodes: int = 3  # greedy episodes, one after the other
    output: str | None = None  # .gif or .mp4 (mp4 needs the video extra); null: video.gif beside it
    fps: int = 50  # frames per second of the file
    scale: float = 0.5  # frame size relative to the env's render (0, 4]
    seed: int | None = None  # null: the seeds of the run's own final evaluation
    human: bool = False  # open Gymnasium's window instead of writing a file (needs a display)


def main(argv: list[str]) -> None:
    args = parse_args(RenderArgs, argv, __doc__)
    # imported after the arguments are read, so that --help answers at once
    from trl_cartpole.policy_io import load_trained_policy
    from trl_cartpole.video import render_episodes, write_video

    if args.episodes < 1 or args.fps < 1 or not 0 < args.scale <= 4:
        raise ConfigError("episodes and fps must be >= 1 and scale in (0, 4]")
    if args.human:
        if not os.environ.get("DISPLAY") and not os.environ.get("WAYLAND_DISPLAY"):
            raise ConfigError("human=true needs a display; write a file instead (output=x.gif)")
    else:
        os.environ.setdefault("SDL_VIDEODRIVER", "dummy")  # no window for rgb_array frames
    trained = load_trained_policy(
        args.checkpoint, seed=args.seed, render_mode="human" if args.human else "rgb_array"
    )
    actor, env, cfg = trained.actor, trained.env, trained.cfg
    if args.human:
        for _ in range(args.episodes):
            env.rollout(cfg.eval.max_steps, actor)
        env.close()
        return
    frames, returns = [], []
    for episode in render_episodes(actor, env, args.episodes, cfg.eval.max_steps, args.scale):
        frames.extend(episode.frames)
        returns.append(episode.episode_return)
    env.close()
    output = Path(args.output or trained.checkpoint.parent / "video.gif")
    write_video(frames, output, args.fps)
    print(
        f"{cfg.env.id}: {args.episodes} greedy episodes, returns {returns}, "
        f"{len(frames)} frames written to {output}"
    )


if __name__ == "__main__":
    sys.exit(run_cli(main))

"""Watch a trained agent: greedy episodes as a GIF/MP4, or live in a window.

    python scripts/render.py checkpoint=runs/.../checkpoints/best [episodes=3] \
        [output=FILE.gif|FILE.mp4] [fps=50] [scale=0.5] [seed=N] [human=false]

Rebuilds the policy from the checkpoint's config, plays ``episodes`` greedy episodes and writes
every frame, captioned with the episode, step and return so far, to ``output`` (default:
``video.gif`` beside the checkpoint directory), scaled by ``scale``. ``human=true`` opens
Gymnasium's window instead (needs a display).
"""

from __future__ import annotations

import os
import sys
from dataclasses import dataclass
from pathlib import Path

from omegaconf import OmegaConf

from trl_cartpole.cli import run_cli
from trl_cartpole.errors import ConfigError
from trl_cartpole.policy_io import load_trained_policy
from trl_cartpole.video import render_episodes, write_video


@dataclass
class RenderArgs:
    checkpoint: str = "???"
    episodes: int = 3
    output: str | None = None
    fps: int = 50
    scale: float = 0.5
    seed: int | None = None
    human: bool = False


def main(argv: list[str]) -> None:
    args = OmegaConf.to_object(
        OmegaConf.merge(OmegaConf.structured(RenderArgs), OmegaConf.from_dotlist(argv))
    )
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

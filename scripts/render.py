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

from trl_cartpole.checkpoint import load_policy, read_checkpoint_config, read_observation_norm
from trl_cartpole.cli import run_cli
from trl_cartpole.config import ConfigError
from trl_cartpole.envs import make_env_from_config
from trl_cartpole.models import make_q_actor_for_env
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
    cfg = read_checkpoint_config(args.checkpoint)
    seed = cfg.seed + 2 * cfg.eval.seed_offset if args.seed is None else args.seed
    observation_norm = read_observation_norm(args.checkpoint)
    if args.human:
        if not os.environ.get("DISPLAY") and not os.environ.get("WAYLAND_DISPLAY"):
            raise ConfigError("human=true needs a display; write a file instead (output=x.gif)")
        env = make_env_from_config(
            cfg.env, seed, num_envs=1, observation_norm=observation_norm, render_mode="human"
        )
    else:
        os.environ.setdefault("SDL_VIDEODRIVER", "dummy")  # no window for rgb_array frames
        env = make_env_from_config(
            cfg.env, seed, num_envs=1, observation_norm=observation_norm, render_mode="rgb_array"
        )
    actor = load_policy(args.checkpoint, make_q_actor_for_env(env, cfg.network))
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
    output = Path(args.output or Path(args.checkpoint).parent / "video.gif")
    write_video(frames, output, args.fps)
    print(
        f"{cfg.env.id}: {args.episodes} greedy episodes, returns {returns}, "
        f"{len(frames)} frames written to {output}"
    )


if __name__ == "__main__":
    sys.exit(run_cli(main))

"""Watch an agent: greedy episodes rendered to a GIF or MP4, or to a live window.

Frames come from Gymnasium's ``render_mode="rgb_array"`` through the same ``make_env`` the
training used; each frame carries the episode number, the step and the return so far. GIFs
are written with Pillow (a matplotlib dependency); MP4 needs ``imageio[ffmpeg]``
(``pip install -e '.[video]'``). In a notebook, :func:`show_agent` does it all in one call.
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from PIL import Image, ImageDraw
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModuleBase
from torchrl.envs import EnvBase, ExplorationType, set_exploration_type

from trl_cartpole.compat import gym_env
from trl_cartpole.envs.pixels import PIXELS_KEY
from trl_cartpole.errors import ConfigError
from trl_cartpole.policy.formats import check_video_arguments, check_video_output
from trl_cartpole.policy.load import load_trained_policy
from trl_cartpole.report.console import quiet_libraries, shown_path
from trl_cartpole.report.progress_bar import clear_status, show_status
from trl_cartpole.run.env_kind import EnvKind
from trl_cartpole.store.files import write_atomic

__all__ = [
    "EpisodeFrames",
    "Recording",
    "record_agent",
    "render_episodes",
    "show_agent",
    "write_video",
]


@dataclass
class EpisodeFrames:
    """One rendered episode: ``frames`` ``[T + 1]`` of ``[H, W, 3]`` uint8 and its return."""

    frames: list[np.ndarray]
    episode_return: float


def _captioned(frame: np.ndarray, text: str, scale: float) -> np.ndarray:
    """``frame`` ``[H, W, 3]`` resized by ``scale`` (enlarged by whole pixels, as a game's screen
    is drawn), with ``text`` drawn in its top-left corner."""
    image = Image.fromarray(frame)
    if scale != 1.0:
        size = (max(1, round(image.width * scale)), max(1, round(image.height * scale)))
        image = image.resize(size, Image.Resampling.NEAREST if scale > 1 else None)
    ImageDraw.Draw(image).text((6, 6), text, fill=(0, 0, 0))
    return np.asarray(image)


# the white band that names the agent's view under the scene, in pixels
VIEW_CAPTION_HEIGHT = 14


@torch.no_grad()
def _with_agent_view(scene: np.ndarray, pixels: torch.Tensor) -> np.ndarray:
    """``scene`` ``[H, W, 3]`` above a caption band and the agent's newest patch (``pixels``
    ``[frames, h, w]`` uint8), enlarged to the scene's width by whole pixels, in gray."""
    patch = pixels[-1].numpy()  # [h, w]
    factor = max(scene.shape[1] // patch.shape[1], 1)
    enlarged = (patch.shape[1] * factor, patch.shape[0] * factor)
    view = np.asarray(Image.fromarray(patch).resize(enlarged, Image.Resampling.NEAREST))
    width = max(scene.shape[1], view.shape[1])  # a game's small screen may be the narrower
    view = np.pad(view, ((0, 0), (0, width - view.shape[1])), constant_values=255)
    scene = np.pad(scene, ((0, 0), (0, width - scene.shape[1]), (0, 0)), constant_values=255)
    band = Image.new("RGB", (width, VIEW_CAPTION_HEIGHT), (255, 255, 255))
    caption = f"what the network sees: its last {patch.shape[0]}x{patch.shape[1]} patch, x{factor}"
    ImageDraw.Draw(band).text((6, 1), caption, fill=(0, 0, 0))
    return np.concatenate([scene, np.asarray(band), np.repeat(view[..., None], 3, axis=-1)], axis=0)


def render_episodes(
    actor: TensorDictModuleBase,
    env: EnvBase,
    episodes: int,
    max_steps: int = 10_000,
    scale: float = 1.0,
) -> Iterator[EpisodeFrames]:
    """Play ``episodes`` greedy episodes on ``env`` (made with ``render_mode="rgb_array"``).

    Yields each episode's frames: the reset state, then one frame after every step, each
    resized by ``scale`` and captioned with the episode, step and return so far. For a policy
    from pixels (``env`` writes ``"pixels"``), what the agent saw (its newest gray patch,
    enlarged) is drawn under the scene.
    """
    gymnasium_env = gym_env(env)  # the Gymnasium env behind TorchRL's GymWrapper

    def frame(td: TensorDictBase, caption: str) -> np.ndarray:
        scene = _captioned(gymnasium_env.render(), caption, scale)
        return scene if PIXELS_KEY not in td else _with_agent_view(scene, td[PIXELS_KEY])

    for episode in range(1, episodes + 1):
        td = env.reset()
        frames = [frame(td, f"episode {episode}  step 0  return 0")]
        episode_return = 0.0
        with set_exploration_type(ExplorationType.DETERMINISTIC):
            for step in range(1, max_steps + 1):
                td = env.step(actor(td))
                episode_return += td["next", "reward"].item()
                caption = f"episode {episode}  step {step}  return {episode_return:g}"
                frames.append(frame(td["next"], caption))
                if td["next", "done"].item():
                    break
                td = td["next"]
        yield EpisodeFrames(frames, episode_return)


def _gif_palette(frames: list[np.ndarray]) -> Image.Image:
    """One 256-colour palette for every frame of a GIF, from up to 8 frames across it (a game or
    a drawing has a few flat colours, which one palette keeps: on Breakout's frames at scale 3,
    4.3-4.5 ms a frame against 59-63 ms for Pillow's own per-frame palette search, measured
    beside a training run)."""
    picks = np.linspace(0, len(frames) - 1, num=min(8, len(frames))).round().astype(int)
    return Image.fromarray(np.concatenate([frames[i] for i in picks], axis=0)).quantize(256)


def write_video(frames: list[np.ndarray], path: str | Path, fps: int = 50) -> Path:
    """Write ``frames`` to ``path`` (``.gif`` or ``.mp4``) under a temporary name, then rename."""
    path = Path(path)
    check_video_output(str(path))
    if path.suffix == ".gif":
        palette = _gif_palette(frames)
        images = [
            Image.fromarray(frame).quantize(palette=palette, dither=Image.Dither.NONE)
            for frame in frames
        ]
        return write_atomic(
            path,
            lambda tmp: images[0].save(
                tmp, save_all=True, append_images=images[1:], duration=1000 / fps, loop=0
            ),
        )
    import imageio.v3 as iio  # an .mp4: check_video_output found imageio

    return write_atomic(
        path, lambda tmp: iio.imwrite(tmp, np.stack(frames), fps=fps, codec="libx264")
    )


@dataclass
class Recording:
    """What :func:`record_agent` wrote: the file, each episode's return and the frame count."""

    path: Path
    env_id: str
    returns: list[float]
    frames: int

    def __str__(self) -> str:
        episodes = len(self.returns)
        returns = ", ".join(f"{value:g}" for value in self.returns)
        return (
            f"{self.env_id}: {episodes} greedy episode{'s' * (episodes != 1)}, return "
            f"{returns}; {self.frames} frames in {shown_path(self.path)}"
        )


def record_agent(
    run_dir_or_checkpoint: str | Path,
    episodes: int = 1,
    seed: int | None = None,
    output: str | Path | None = None,
    fps: int = 50,
    scale: float | None = None,
) -> Recording:
    """Play ``episodes`` greedy episodes of a trained policy into a GIF (or MP4) file.

    ``run_dir_or_checkpoint`` is a run directory (its best policy plays) or a checkpoint;
    ``seed`` defaults to the run's final evaluation seeds and ``output`` to ``video.gif``
    beside the checkpoint; frames are scaled by ``scale`` (None: the kind of env's
    :attr:`~trl_cartpole.run.env_kind.EnvKind.video_scale`).
    """
    check_video_arguments(episodes, fps, scale, None if output is None else str(output))
    os.environ.setdefault("SDL_VIDEODRIVER", "dummy")  # frames only, no window
    frames, returns = [], []
    with quiet_libraries():  # no TorchRL INFO lines (spec checks), as in the scripts
        trained = load_trained_policy(run_dir_or_checkpoint, seed=seed, render_mode="rgb_array")
        if scale is None:
            scale = EnvKind(trained.cfg.env).video_scale
        try:
            show_status(f"rendering episode 1 of {episodes}")
            for episode in render_episodes(
                trained.actor, trained.env, episodes, trained.cfg.eval.max_steps, scale
            ):
                frames.extend(episode.frames)
                returns.append(episode.episode_return)
                if len(returns) < episodes:
                    show_status(f"rendering episode {len(returns) + 1} of {episodes}")
        finally:
            trained.env.close()
            clear_status()  # an error's line starts on a clean line
    target = Path(output or trained.checkpoint.parent / "video.gif")
    show_status(f"writing {len(frames)} frames to {shown_path(target)}")
    try:
        path = write_video(frames, target, fps)
    finally:
        clear_status()
    return Recording(Path(path), trained.cfg.env.id, returns, len(frames))


def show_agent(run_dir_or_checkpoint: str | Path, episodes: int = 1, **options: Any) -> Any:
    """:func:`record_agent` into a GIF, shown inline when it ends a notebook cell.

    ``options`` are :func:`record_agent`'s (``seed``, ``output``, ``fps``, ``scale``). Prints
    what was recorded; returns an ``IPython.display.Image`` of the GIF, or its path where
    IPython is not installed.
    """
    output = options.get("output")
    if output is not None and Path(output).suffix != ".gif":
        raise ConfigError(f"output={str(output)!r}: show_agent writes a .gif file")
    recording = record_agent(run_dir_or_checkpoint, episodes, **options)
    print(recording)
    try:
        from IPython.display import Image as IPythonImage
    except ImportError:
        return recording.path
    return IPythonImage(filename=str(recording.path))

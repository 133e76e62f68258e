"""Watch an agent: greedy episodes rendered to a GIF or MP4, or to a live window.

Frames come from Gymnasium's ``render_mode="rgb_array"`` through the same ``make_env`` the
training used; each frame carries the episode number, the step and the return so far. GIFs
are written with Pillow (a matplotlib dependency); MP4 needs ``imageio[ffmpeg]``
(``pip install -e '.[video]'``). In a notebook, :func:`show_agent` does it all in one call.
"""

from __future__ import annotations

import contextlib
import functools
import os
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from PIL import Image, ImageDraw, ImageFont
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


@dataclass
class _Shot:
    """What one frame of a video shows, before it is drawn: the env's picture ``scene``
    ``[H, W, 3]`` uint8, the agent's newest gray patch ``patch`` ``[h, w]`` uint8 (None for a
    policy from a state vector) and the ``caption``."""

    scene: np.ndarray
    patch: np.ndarray | None
    caption: str


# the white band that names the agent's view under the scene, in pixels
VIEW_CAPTION_HEIGHT = 14
_BLACK, _WHITE = (0, 0, 0), (255, 255, 255)


@functools.cache
def _font() -> ImageFont.FreeTypeFont | ImageFont.ImageFont:
    """Pillow's default font, loaded once (Pillow loads it anew for every ``ImageDraw``)."""
    return ImageFont.load_default()


def _in_palette(image: Image.Image, palette: Image.Image | None) -> Image.Image:
    """``image`` mapped to ``palette``'s colours (no dithering), or as it is without one."""
    if palette is None:
        return image
    return image.convert("RGB").quantize(palette=palette, dither=Image.Dither.NONE)


def _resized(image: Image.Image, scale: float, palette: Image.Image | None) -> Image.Image:
    """``image`` resized by ``scale`` (enlarged by whole pixels, as a game's screen is drawn;
    shrunk with Pillow's bicubic filter) and mapped to ``palette``: before enlarging, which
    gives the same picture for a fraction of the work, or after shrinking, which blends
    colours."""
    if scale >= 1:
        image = _in_palette(image, palette)
    if scale != 1:
        size = (max(1, round(image.width * scale)), max(1, round(image.height * scale)))
        shrink = Image.Resampling.BICUBIC
        image = image.resize(size, Image.Resampling.NEAREST if scale > 1 else shrink)
    return image if scale >= 1 else _in_palette(image, palette)


def _label(text: str, where: tuple[int, int], margin: int) -> tuple[Image.Image, tuple[int, int]]:
    """``text`` as drawn at ``where``: black, anti-aliased, on a white box ``margin`` pixels
    larger on each side; returns the box (RGB) and the corner to paste it at."""
    left, top, right, bottom = ImageDraw.Draw(Image.new("RGB", (1, 1))).textbbox(
        where, text, font=_font()
    )
    corner = (left - margin, top - margin)
    box = Image.new("RGB", (right - left + 2 * margin, bottom - top + 2 * margin), _WHITE)
    offset = (where[0] - corner[0], where[1] - corner[1])
    ImageDraw.Draw(box).text(offset, text, fill=_BLACK, font=_font())
    return box, corner


def _drawn(shot: _Shot, scale: float, palette: Image.Image | None = None) -> Image.Image:
    """``shot`` as one video frame: the scene resized by ``scale`` with its caption on a white
    label in the top-left corner (legible on a dark game screen) and, for a policy from pixels,
    a caption band and the agent's patch, enlarged to the scene's width by whole pixels, under
    it. In RGB, or in ``palette``'s colours (a GIF's): the RGB frame mapped to them, pixel for
    pixel, but each part mapped before it is enlarged: a Breakout frame at x3 maps 41 000
    pixels instead of the finished frame's 511 000."""
    scene = _resized(Image.fromarray(shot.scene), scale, palette)
    label, corner = _label(shot.caption, (6, 6), margin=2)
    scene.paste(_in_palette(label, palette), corner)
    if shot.patch is None:
        return scene
    height, width = shot.patch.shape
    factor = max(scene.width // width, 1)
    view = _resized(Image.fromarray(shot.patch).convert("RGB"), factor, palette)
    full_width = max(scene.width, view.width)  # a game's small screen may be the narrower
    band = Image.new("RGB", (full_width, VIEW_CAPTION_HEIGHT), _WHITE)
    caption = f"what the network sees: its last {height}x{width} patch, x{factor}"
    ImageDraw.Draw(band).text((6, 1), caption, fill=_BLACK, font=_font())
    size = (full_width, scene.height + VIEW_CAPTION_HEIGHT + view.height)
    frame = Image.new(scene.mode, size, _colour(_WHITE, palette))
    if palette is not None:
        frame.putpalette(scene.getpalette())
    frame.paste(scene, (0, 0))
    frame.paste(_in_palette(band, palette), (0, scene.height))
    frame.paste(view, (0, scene.height + VIEW_CAPTION_HEIGHT))
    return frame


def _colour(rgb: tuple[int, int, int], palette: Image.Image | None) -> tuple[int, ...] | int:
    """``rgb`` as an image drawn in ``palette`` takes it: the index it maps to, or ``rgb``."""
    if palette is None:
        return rgb
    return _in_palette(Image.new("RGB", (1, 1), rgb), palette).getpixel((0, 0))


@contextlib.contextmanager
def _one_torch_thread() -> Iterator[None]:
    """torch on one thread, without gradients, inside: one game's forward pass (batch 1) gains
    nothing from more threads, and beside another busy process two made a Breakout frame
    14x slower (54.9 against 4.0 ms a step, measured beside a training run)."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        with torch.no_grad():
            yield
    finally:
        torch.set_num_threads(threads)


def _play(
    actor: TensorDictModuleBase, env: EnvBase, episodes: int, max_steps: int
) -> Iterator[tuple[list[_Shot], float]]:
    """Play ``episodes`` greedy episodes on ``env`` (made with ``render_mode="rgb_array"``);
    yield each one's shots (the reset state, then one after every step) and its return."""
    gymnasium_env = gym_env(env)  # the Gymnasium env behind TorchRL's GymWrapper

    def shot(td: TensorDictBase, caption: str) -> _Shot:
        patch = td[PIXELS_KEY][-1].numpy().copy() if PIXELS_KEY in td else None  # [h, w]
        return _Shot(np.array(gymnasium_env.render()), patch, caption)  # its own copy

    for episode in range(1, episodes + 1):
        with _one_torch_thread(), set_exploration_type(ExplorationType.DETERMINISTIC):
            td = env.reset()
            shots = [shot(td, f"episode {episode}  step 0  return 0")]
            episode_return = 0.0
            for step in range(1, max_steps + 1):
                td = env.step(actor(td))
                episode_return += td["next", "reward"].item()
                caption = f"episode {episode}  step {step}  return {episode_return:g}"
                shots.append(shot(td["next"], caption))
                if td["next", "done"].item():
                    break
                td = td["next"]
        yield shots, episode_return


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
    for shots, episode_return in _play(actor, env, episodes, max_steps):
        yield EpisodeFrames([np.asarray(_drawn(shot, scale)) for shot in shots], episode_return)


def _evenly_spaced(count: int, most: int = 8) -> list[int]:
    """Up to ``most`` indices spread evenly over ``range(count)``, the first and last included."""
    return np.linspace(0, count - 1, num=min(most, count)).round().astype(int).tolist()


def _gif_palette(frames: list[np.ndarray]) -> Image.Image:
    """One 256-colour palette for every frame of a GIF, from a few ``frames`` across it (a game
    or a drawing has a few flat colours, which one palette keeps: on Breakout's frames at scale
    3, 4.3-4.5 ms a frame against 59-63 ms for Pillow's own per-frame palette search, measured
    beside a training run)."""
    return Image.fromarray(np.concatenate(frames, axis=0)).quantize(256)


def _write_gif(images: Iterator[Image.Image], path: Path, fps: int) -> Path:
    """Write the palette images ``images`` to the GIF ``path`` under a temporary name."""
    first = next(images)
    return write_atomic(
        path,
        lambda tmp: first.save(
            tmp, save_all=True, append_images=images, duration=1000 / fps, loop=0
        ),
    )


def write_video(frames: list[np.ndarray], path: str | Path, fps: int = 50) -> Path:
    """Write ``frames`` to ``path`` (``.gif`` or ``.mp4``) under a temporary name, then rename."""
    path = Path(path)
    check_video_output(str(path))
    if not frames:
        raise ConfigError(f"no frames to write to {shown_path(path)}: pass at least one")
    if path.suffix == ".gif":
        palette = _gif_palette([frames[i] for i in _evenly_spaced(len(frames))])
        return _write_gif((_in_palette(Image.fromarray(f), palette) for f in frames), path, fps)
    import imageio.v3 as iio  # an .mp4: check_video_output found imageio

    return write_atomic(
        path, lambda tmp: iio.imwrite(tmp, np.stack(frames), fps=fps, codec="libx264")
    )


def _write_shots(shots: list[_Shot], path: Path, fps: int, scale: float) -> Path:
    """:func:`write_video` of ``shots`` drawn at ``scale``; a GIF's frames are drawn in its
    palette (300 Breakout frames at x3 with the agent's view: 3.4-3.8 ms a frame to draw and
    write, against 8.0-14.9 ms drawn in RGB and mapped when finished, measured side by side
    beside a training run)."""
    if path.suffix != ".gif":
        return write_video([np.asarray(_drawn(shot, scale)) for shot in shots], path, fps)
    palette = _gif_palette(
        [np.asarray(_drawn(shots[i], scale)) for i in _evenly_spaced(len(shots))]
    )
    return _write_gif((_drawn(shot, scale, palette) for shot in shots), path, fps)


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
    shots, returns = [], []
    with quiet_libraries():  # no TorchRL INFO lines (spec checks), as in the scripts
        trained = load_trained_policy(run_dir_or_checkpoint, seed=seed, render_mode="rgb_array")
        if scale is None:
            scale = EnvKind(trained.cfg.env).video_scale
        try:
            show_status(f"rendering episode 1 of {episodes}")
            for episode, episode_return in _play(
                trained.actor, trained.env, episodes, trained.cfg.eval.max_steps
            ):
                shots.extend(episode)
                returns.append(episode_return)
                if len(returns) < episodes:
                    show_status(f"rendering episode {len(returns) + 1} of {episodes}")
        finally:
            trained.env.close()
            clear_status()  # an error's line starts on a clean line
    target = Path(output or trained.checkpoint.parent / "video.gif")
    show_status(f"writing {len(shots)} frames to {shown_path(target)}")
    try:
        path = _write_shots(shots, target, fps, scale)
    finally:
        clear_status()
    return Recording(Path(path), trained.cfg.env.id, returns, len(shots))


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

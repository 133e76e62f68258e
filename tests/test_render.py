"""Watching an agent headless: a GIF with one frame per step plus one per reset."""

from __future__ import annotations

import re

import numpy as np
import pytest
from PIL import Image

from trl_cartpole.errors import ConfigError
from trl_cartpole.policy.video import (
    VIEW_CAPTION_HEIGHT,
    _drawn,
    _gif_palette,
    _in_palette,
    _label,
    _Shot,
    _write_shots,
    write_video,
)

from .conftest import run_script


@pytest.mark.slow  # a run, then its video
def test_render_writes_a_gif_with_every_step_of_each_episode(smoke_checkpoint, tmp_path):
    out = tmp_path / "agent.gif"
    proc = run_script(
        "render.py",
        f"checkpoint={smoke_checkpoint}",
        "episodes=2",
        "scale=0.25",
        f"output={out}",
        timeout=300,
        env={"PATH": "/usr/bin:/bin", "HOME": str(tmp_path)},  # headless: no DISPLAY
    )
    assert proc.returncode == 0, proc.stderr[-2000:]
    # "...: 2 greedy episodes, return r1, r2; N frames in FILE": a frame per step (r = steps in
    # CartPole) plus the reset's.
    found = re.search(r"2 greedy episodes, return ([\d., ]+); (\d+) frames in (.+)", proc.stdout)
    returns = [float(r) for r in found.group(1).split(",")]
    expected_frames = int(sum(returns)) + len(returns)
    assert int(found.group(2)) == expected_frames and found.group(3).strip() == str(out)
    with Image.open(out) as gif:
        assert gif.n_frames == expected_frames
        assert gif.size == (150, 100)  # 600x400 scaled by 0.25
    # the long steps are said as they start (stderr redirected here: a line each)
    assert proc.stderr.splitlines() == [
        "rendering episode 1 of 2 ...",
        "rendering episode 2 of 2 ...",
        f"writing {expected_frames} frames to {out} ...",
    ], proc.stderr


@pytest.mark.slow  # a fresh interpreter
def test_human_mode_without_a_display_is_a_clear_error(smoke_checkpoint, tmp_path):
    proc = run_script(
        "render.py",
        f"checkpoint={smoke_checkpoint}",
        "human=true",
        env={"PATH": "/usr/bin:/bin", "HOME": str(tmp_path)},
    )
    assert proc.returncode == 2
    assert "error: human=true needs a display" in proc.stderr


def test_unknown_video_format_is_refused(tmp_path):
    with pytest.raises(ConfigError, match=r"choose a \.gif or \.mp4"):
        write_video([], tmp_path / "x.avi")
    with pytest.raises(ConfigError, match=r"no frames to write to .*x\.gif: pass at least one"):
        write_video([], tmp_path / "x.gif")
    assert not list(tmp_path.iterdir())


def test_a_gif_of_a_dark_game_has_a_frame_per_step(tmp_path):
    """On a black game screen the step's caption still tells the frames apart (drawn black on
    black, they looked alike and Pillow merged them into one)."""
    scene = np.zeros((210, 160, 3), np.uint8)  # [H, W, 3]: a dark screen
    patch = np.full((84, 84), 40, np.uint8)  # [h, w]: the agent's gray view
    shots = [_Shot(scene, patch, f"episode 1  step {step}  return 0") for step in range(5)]
    path = _write_shots(shots, tmp_path / "dark.gif", fps=50, scale=3.0)
    with Image.open(path) as gif:  # the view enlarged x5 (480 // 84) under the scene and band
        assert gif.n_frames == 5 and gif.size == (480, 630 + VIEW_CAPTION_HEIGHT + 84 * 5)


@pytest.mark.parametrize("scale", [0.5, 1.0, 3.0])
@pytest.mark.parametrize("with_patch", [True, False])
def test_a_frame_drawn_in_the_gifs_palette_is_the_rgb_frame_mapped_to_it(scale, with_patch):
    """Drawing a GIF's frame part by part in its palette (each part mapped before it is
    enlarged) gives exactly the RGB frame mapped whole, caption, label and view included."""
    scene = np.zeros((210, 160, 3), np.uint8)  # [H, W, 3]: a dark screen, one brick
    scene[100:104, 70:90] = (200, 72, 72)
    scene[:, 150:] = (142, 142, 142)  # a wall
    patch = np.linspace(0, 255, 84 * 84).astype(np.uint8).reshape(84, 84) if with_patch else None
    shot = _Shot(scene, patch, "episode 2  step 17  return 4")
    in_rgb = _drawn(shot, scale)
    palette = _gif_palette([np.asarray(in_rgb)])
    drawn = np.asarray(_drawn(shot, scale, palette))  # [H', W'] palette indices
    np.testing.assert_array_equal(drawn, np.asarray(_in_palette(in_rgb, palette)))
    box, (left, top) = _label(shot.caption, (6, 6), margin=2)
    white = _in_palette(Image.new("RGB", (1, 1), (255, 255, 255)), palette).getpixel((0, 0))
    margin = drawn[top, left : min(left + box.width, drawn.shape[1])]  # the label's top edge
    assert (margin == white).all() and 0 <= top <= 6 and left == 4
    assert len(np.unique(drawn[: round(210 * scale)])) > 3  # the scene, its label and text


def test_a_game_plays_on_one_torch_thread_and_gives_the_threads_back():
    import torch

    from trl_cartpole.policy.video import _one_torch_thread

    before = torch.get_num_threads()  # the tests' one thread (conftest): set two to see it
    torch.set_num_threads(2)
    try:
        with _one_torch_thread():
            assert torch.get_num_threads() == 1 and not torch.is_grad_enabled()
        assert torch.get_num_threads() == 2 and torch.is_grad_enabled()
    finally:
        torch.set_num_threads(before)

"""Watching an agent headless: a GIF with one frame per step plus one per reset."""

from __future__ import annotations

import re

import pytest
from PIL import Image

from trl_cartpole.errors import ConfigError
from trl_cartpole.policy.video import write_video

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
    assert not list(tmp_path.iterdir())

"""The formats a policy exports or records to, and what each needs; torch-free, so that the
export and render commands check their arguments before they load anything.
"""

from __future__ import annotations

import importlib.util

from trl_cartpole.errors import ConfigError, install_hint

__all__ = [
    "FORMATS",
    "MAX_EPISODES_IN_A_VIDEO",
    "ONNX_PACKAGES",
    "check_onnx_installed",
    "check_video_arguments",
    "check_video_output",
]

# output suffix -> (what it is, the function of trl_cartpole.policy.export that writes it)
FORMATS = {
    ".onnx": ("ONNX model", "export_onnx"),
    ".pt2": ("torch.export program", "export_program"),
}
ONNX_PACKAGES = ("onnx", "onnxscript")  # torch.onnx.export's (dynamo) exporter needs both


def check_onnx_installed() -> None:
    """Raise a one-line :class:`ConfigError` naming the export extra when ONNX's packages are
    missing."""
    missing = [name for name in ONNX_PACKAGES if importlib.util.find_spec(name) is None]
    if missing:
        raise ConfigError(
            f"ONNX export needs the {' and '.join(missing)} package(s), which are not "
            f"installed; {install_hint('export')}"
        )


def check_video_output(output: str) -> None:
    """Refuse a video file that cannot be written: a ``.gif``, or an ``.mp4`` with imageio
    installed."""
    if not output.endswith((".gif", ".mp4")):
        raise ConfigError(f"output={output!r}: choose a .gif or .mp4 file name")
    if output.endswith(".mp4") and importlib.util.find_spec("imageio") is None:
        raise ConfigError(
            f"writing .mp4 needs imageio[ffmpeg]: {install_hint('video')} (or use .gif)"
        )


# A video keeps its frames in memory until it is written: 20 CartPole episodes of up to 500
# frames of 300 x 200 x 3 bytes = 90 MB.
MAX_EPISODES_IN_A_VIDEO = 20


def check_video_arguments(
    episodes: int, fps: int, scale: float | None, output: str | None = None
) -> None:
    """Raise a one-line :class:`ConfigError` for a video that cannot be recorded (``output``:
    :func:`check_video_output`; None: the default GIF; ``scale`` None: the env's own)."""
    if output is not None:
        check_video_output(output)
    if episodes < 1 or fps < 1 or not (scale is None or 0 < scale <= 4):
        raise ConfigError("episodes and fps must be >= 1 and scale in (0, 4]")
    if episodes > MAX_EPISODES_IN_A_VIDEO:
        raise ConfigError(
            f"episodes={episodes}: a video holds at most {MAX_EPISODES_IN_A_VIDEO} episodes (their "
            "frames are kept in memory until the file is written); make several"
        )

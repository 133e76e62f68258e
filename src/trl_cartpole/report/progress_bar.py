"""The console's view of a run: a tqdm bar, or one line per evaluation when redirected.

The bar shows the frames, the last greedy evaluation and the best one, the last training
episode's return and epsilon. With the output going to a file, each evaluation is one line
instead; ``logger.progress_bar=false`` shows nothing.
"""

from __future__ import annotations

import sys

from tqdm.auto import tqdm

from trl_cartpole.report.plotting import live_plot_target

__all__ = ["BAR_FORMAT", "ProgressBar", "bar_mode"]

# 80 columns hold the bar with eval and best first: "CartPole-v1  29%|██▊   | 14.3k/50.0k 00:21,
# eval 500 best 500 | ret 134 eps .05"
BAR_FORMAT = "{desc} {percentage:3.0f}%|{bar}| {n_fmt}/{total_fmt} {elapsed}{postfix}"


def _short(value: float) -> str:
    """A return as the bar shows it: ``500``, ``-123``, ``10.5``."""
    return f"{value:.0f}" if abs(value) >= 100 else f"{value:.1f}"


def bar_mode(progress_bar: bool) -> str:
    """``bar`` on a terminal or in a notebook, ``lines`` (one per evaluation) when redirected."""
    if not progress_bar:
        return "off"
    return "bar" if sys.stderr.isatty() or live_plot_target() == "notebook" else "lines"


class ProgressBar:
    """A tqdm bar over the run's frames (``bar``), one line per evaluation (``lines``), or off."""

    def __init__(
        self, progress_bar: bool = True, description: str = "", total_frames: int | None = None
    ) -> None:
        self.mode = bar_mode(progress_bar)
        self.total_frames = total_frames
        self._options = {
            "disable": self.mode != "bar",
            "total": total_frames,
            "unit": "frame",
            "unit_scale": True,
            "dynamic_ncols": True,
            "desc": description,
            "bar_format": BAR_FORMAT,
        }
        self.bar: tqdm | None = None
        self.postfix: dict[str, str] = {}  # eval, best, ret, eps: shown in this order

    def open(self, frames: int) -> None:
        """Show the bar, starting at ``frames`` (a resumed run's count)."""
        self.bar = tqdm(initial=frames, **self._options)

    def advance(self, frames: int, last_return: float | None, epsilon: float | None) -> None:
        """Move the bar by ``frames``; show the last episode's return and epsilon."""
        if self.bar is not None:
            self.bar.update(frames)
        if last_return is not None:
            self.postfix.update(ret=f"{last_return:.0f}")
        if epsilon is not None:
            self.postfix.update(eps=f"{epsilon:.2f}".replace("0.", "."))
        self._show_postfix()

    def evaluation(self, mean: float, best: float, frames: int) -> None:
        """Show a greedy evaluation's mean return and the best so far."""
        self.postfix.update(eval=_short(mean), best=_short(best))
        self._show_postfix()
        if self.mode == "lines":  # output redirected: one line per evaluation, no redraws
            print(
                f"{frames} / {self.total_frames} frames: greedy return {mean:.1f} "
                f"(best {best:.1f})",
                file=sys.stderr,
                flush=True,
            )

    def _show_postfix(self) -> None:
        if self.bar is not None:
            shown = {key: f"{key} {value}" for key, value in self.postfix.items()}
            greedy = " ".join(shown[key] for key in ("eval", "best") if key in shown)
            training = " ".join(shown[key] for key in ("ret", "eps") if key in shown)
            self.bar.set_postfix_str(" | ".join(part for part in (greedy, training) if part))

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()

    def status(self, text: str) -> None:
        """Say which long step runs now (the final evaluation, the plots): on a terminal one
        line rewritten in place, cleared by :meth:`clear`; redirected, a line each."""
        show_status(text, "off" if self.mode == "off" else None)

    def clear(self) -> None:
        """Remove the status line from a terminal."""
        clear_status("off" if self.mode == "off" else None)


def show_status(text: str, mode: str | None = None) -> None:
    """``text`` on stderr: rewritten in place on a terminal (``bar``), a line when redirected
    (``lines``), nothing when ``off``; ``mode`` None picks as :func:`bar_mode` does."""
    mode = _status_mode() if mode is None else mode
    if mode == "bar":
        print(f"\r\033[K{text} ...", end="", file=sys.stderr, flush=True)
    elif mode == "lines":
        print(f"{text} ...", file=sys.stderr, flush=True)


def clear_status(mode: str | None = None) -> None:
    """Remove :func:`show_status`'s line from a terminal."""
    if (_status_mode() if mode is None else mode) == "bar":
        print("\r\033[K", end="", file=sys.stderr, flush=True)


def _status_mode() -> str:
    """``bar`` on a terminal, ``lines`` when redirected, ``off`` in a notebook (whose cell
    output shows no rewritten line)."""
    if sys.stderr.isatty():
        return "bar"
    return "off" if live_plot_target() == "notebook" else "lines"

"""notebooks/quickstart.ipynb runs top to bottom (executed with nbclient), so it cannot rot."""

from __future__ import annotations

import os
import shutil

import nbformat
import pytest
from nbclient import NotebookClient

from .conftest import ROOT

pytestmark = pytest.mark.slow  # executes the quick-start notebook: a training run in a kernel


def test_quickstart_notebook_trains_evaluates_and_renders(monkeypatch):
    notebook = nbformat.read(ROOT / "notebooks" / "quickstart.ipynb", as_version=4)
    client = NotebookClient(
        notebook, timeout=600, kernel_name="python3", resources={"metadata": {"path": ROOT}}
    )
    monkeypatch.setenv("MPLBACKEND", "agg")
    runs, latest = ROOT / "runs", ROOT / "runs" / "latest"  # the notebook trains into runs/
    before = set(runs.iterdir()) if runs.is_dir() else set()
    latest_before = os.readlink(latest) if latest.is_symlink() else None
    try:
        client.execute()
        outputs = [
            out for cell in notebook.cells if cell.cell_type == "code" for out in cell.outputs
        ]
        text = "".join(out.get("text", "") for out in outputs if out.output_type == "stream")
        # the ending: "run directory: runs/<run> (durations.png, ...)", relative to the kernel's cwd
        run_dir = ROOT / text.split("run directory: ", 1)[1].split(" (", 1)[0]
        assert run_dir.parent == runs, run_dir
        assert (run_dir / "summary.json").is_file()
        assert (run_dir / "checkpoints" / "video.gif").is_file()
    finally:  # leave runs/ as it was, whatever failed
        for new in set(runs.iterdir()) - before if runs.is_dir() else ():
            if new.is_dir() and not new.is_symlink():
                shutil.rmtree(new)
        if latest.is_symlink():
            latest.unlink()
        if latest_before is not None:
            latest.symlink_to(latest_before)
    assert "solved at" in text
    assert "30 greedy games: mean " in text and "1 greedy episode, return " in text
    images = [out for out in outputs if "image/png" in out.get("data", {})]
    gifs = [out for out in outputs if "image/gif" in out.get("data", {})]
    assert len(images) == 1, "the live duration plot was not displayed (once, the latest)"
    assert gifs, "the agent's GIF was not displayed inline"

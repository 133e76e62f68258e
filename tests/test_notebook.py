"""notebooks/quickstart.ipynb runs top to bottom (executed with nbclient), so it cannot rot."""

from __future__ import annotations

import shutil
from pathlib import Path

import nbformat
from nbclient import NotebookClient

from .conftest import ROOT


def test_quickstart_notebook_trains_evaluates_and_renders(tmp_path, monkeypatch):
    notebook = nbformat.read(ROOT / "notebooks" / "quickstart.ipynb", as_version=4)
    client = NotebookClient(
        notebook, timeout=600, kernel_name="python3", resources={"metadata": {"path": ROOT}}
    )
    monkeypatch.setenv("MPLBACKEND", "agg")
    client.execute()
    outputs = [out for cell in notebook.cells if cell.cell_type == "code" for out in cell.outputs]
    text = "".join(out.get("text", "") for out in outputs if out.output_type == "stream")
    run_dir = Path(text.split("run directory: ", 1)[1].splitlines()[0])
    assert (run_dir / "summary.json").is_file() and (run_dir / "agent.gif").is_file()
    shutil.rmtree(run_dir)  # under the repository's (ignored) runs/
    assert "solved: True" in text
    assert "mean " in text and "frames, return" in text
    images = [out for out in outputs if "image/png" in out.get("data", {})]
    gifs = [out for out in outputs if "image/gif" in out.get("data", {})]
    assert images, "the live duration plot was not displayed"
    assert gifs, "the agent's GIF was not displayed inline"

"""The documentation site builds with warnings as errors, its reference rendered from the code."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

import trl_cartpole

# the factories: every make_* the package exports but make_q_network (make_q_actor's helper)
FACTORIES = [n for n in trl_cartpole.__all__ if n.startswith("make_") and n != "make_q_network"]

pytest.importorskip("mkdocs")
pytest.importorskip("mkdocstrings")
ROOT = Path(__file__).resolve().parent.parent


def test_the_site_builds_strict_with_every_factory_and_its_defaults_beside_torchrls(tmp_path):
    proc = subprocess.run(
        [sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(tmp_path)],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    page = (tmp_path / "reference" / "factories" / "index.html").read_text()
    assert all(f"{name}(" in page for name in FACTORIES)  # each signature is rendered
    assert "<!-- factory-defaults -->" not in page  # the table replaced its marker
    # a row of the table: HardUpdate's own default beside ours, read off both signatures
    assert "value_network_update_interval" in page and "(<code>HardUpdate</code>)" in page
    assert ":func:" not in page and "&gt;&gt;&gt; " in page  # roles resolved; examples kept

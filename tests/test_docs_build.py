"""The documentation site builds with warnings as errors, its reference rendered from the code."""

from __future__ import annotations

import html
import shutil
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
    assert [n for n in FACTORIES if f"{n}(" not in page] == []  # each signature is rendered
    assert "<!-- factory-defaults -->" not in page  # the table replaced its marker
    # a row of the table: HardUpdate's own default beside ours, read off both signatures
    assert "value_network_update_interval" in page and "(<code>HardUpdate</code>)" in page
    assert ":func:" not in page and "&gt;&gt;&gt; " in page  # roles resolved; examples kept
    # every factory's arguments as a parameter list, not a paragraph
    assert page.count("Parameters:") >= len(FACTORIES) and ":param" not in page


def _build(config_dir: Path, site_dir: Path) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(site_dir)],
        cwd=config_dir,
        capture_output=True,
        text=True,
        timeout=300,
    )


def _copy_of_the_docs(tmp_path: Path) -> Path:
    """The site's sources in ``tmp_path/repo``: mkdocs.yml, docs/, the README; src linked."""
    repo = tmp_path / "repo"
    shutil.copytree(ROOT / "docs", repo / "docs", ignore=shutil.ignore_patterns("__pycache__"))
    for name in ("mkdocs.yml", "README.md"):
        shutil.copy(ROOT / name, repo / name)
    (repo / "src").symlink_to(ROOT / "src")
    return repo


@pytest.mark.parametrize(
    "link, said",
    [
        pytest.param("[a page](no-such-page.md)", "no-such-page.md", marks=pytest.mark.slow),
        ("[an anchor](guide.md#no-such-anchor)", "#no-such-anchor"),
    ],
)
def test_a_broken_link_fails_the_build(tmp_path, link, said):
    repo = _copy_of_the_docs(tmp_path)
    with (repo / "docs" / "tutorial.md").open("a", encoding="utf-8") as tutorial:
        tutorial.write(f"\n{link}\n")
    proc = _build(repo, tmp_path / "site")
    assert proc.returncode != 0
    assert "contains a link" in proc.stderr and said in proc.stderr


def test_the_index_shows_the_readme_quick_start_and_reuse_example(tmp_path):
    repo = _copy_of_the_docs(tmp_path)
    proc = _build(repo, tmp_path / "site")
    assert proc.returncode == 0, proc.stderr[-3000:]
    index = (tmp_path / "site" / "index.html").read_text()
    readme = (ROOT / "README.md").read_text()
    install = next(line for line in readme.splitlines() if line.startswith("python3 -m venv"))
    assert html.escape(install, quote=False) in index
    assert 'id="reuse-the-parts-in-your-own-torchrl-code"' in index
    assert 'href="reference/factories/"' in index  # the README's docs/ links, as site links
    assert "readme-section" not in index
    assert 'href="css/site.css"' in index  # the tables scroll inside the content column

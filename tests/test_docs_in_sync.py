"""The docs cannot drift: generated blocks match their sources, and the module table the code."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from benchmarks import docs

from .conftest import ROOT


def test_every_generated_block_matches_its_source():
    """Each ``<!-- generated:NAME -->`` block is what ``python -m benchmarks docs`` writes."""
    assert docs.stale_blocks(write=False) == []


def test_the_architecture_table_names_every_module_of_the_package_and_no_other():
    package = ROOT / "src" / "trl_cartpole"
    modules = {
        path.relative_to(package).as_posix()
        for path in package.rglob("*.py")
        if path.parent == package and path.name not in ("__init__.py", "__main__.py")
    }
    table = (ROOT / "docs" / "architecture.md").read_text().split("## What each module owns")[1]
    named = set(re.findall(r"`([\w/]+\.py)`", table.split("\n\n", 2)[1]))
    assert modules - named == set(), "modules missing from docs/architecture.md"
    assert named - modules == set(), "docs/architecture.md names modules that do not exist"


def test_the_readme_states_the_size_of_the_default_tier(request):
    """The README's count of default-tier tests is the count pytest selects."""
    readme = (ROOT / "README.md").read_text()
    stated = int(re.search(r"the default tier of (\d+) tests", readme)[1])
    config = request.config
    whole_tier = (
        config.getoption("markexpr") == "not slow"
        and not config.getoption("keyword")
        and [Path(arg).resolve() for arg in config.args] == [ROOT / "tests"]
    )
    if not whole_tier:
        pytest.skip("counts the default tier only when the whole tier runs")
    assert stated == len(request.session.items)

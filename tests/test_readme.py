"""The README's reuse example runs as written."""

from __future__ import annotations

import re

from .conftest import ROOT


def test_readme_reuse_example_runs(capsys):
    readme = (ROOT / "README.md").read_text()
    section = readme.split("## Reuse the components in another TorchRL project", 1)[1]
    code = re.search(r"```python\n(.*?)```", section, re.DOTALL).group(1)
    exec(compile(code, "README.md", "exec"), {})
    assert "last TD loss" in capsys.readouterr().out

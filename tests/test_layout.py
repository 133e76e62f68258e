"""The package's layout rules: TorchRL internals in one module, no benchmarks.

The layers of its imports are import-linter contracts in pyproject.toml (lint-imports, in CI).
"""

from __future__ import annotations

import ast
import re
import subprocess
import sys
from pathlib import Path

from .conftest import ROOT

PACKAGE = ROOT / "src" / "trl_cartpole"
PRIVATE_TORCHRL_NAMES = re.compile(
    r"\._carrier|\._memo\b|base_env\._env|\._transform\b|\._buffer\b|[.'\"]_weight_sync_schemes"
    r"|action_func_mapping|prioritized\.(Sum|Min)SegmentTree"
)


def test_private_torchrl_names_are_read_only_in_the_compatibility_module():
    found = [
        f"{path.name}:{number}"
        for path in sorted(PACKAGE.rglob("*.py"))
        if path.name != "compat.py"
        for number, line in enumerate(path.read_text().splitlines(), 1)
        if PRIVATE_TORCHRL_NAMES.search(line)
    ]
    assert found == []


def test_the_package_does_not_import_the_benchmarks_or_their_peers():
    pattern = re.compile(r"^\s*(from|import)\s+(benchmarks|stable_baselines3)\b", re.MULTILINE)
    offenders = [p.name for p in PACKAGE.rglob("*.py") if pattern.search(p.read_text())]
    assert offenders == []


def test_the_import_layers_of_pyproject_hold():
    """``lint-imports`` (import-linter) keeps every contract of ``[tool.importlinter]``."""
    lint_imports = Path(sys.executable).with_name("lint-imports")
    proc = subprocess.run(
        [str(lint_imports), "--no-cache"], cwd=ROOT, capture_output=True, text=True, timeout=120
    )
    assert proc.returncode == 0 and "0 broken" in proc.stdout, proc.stdout[-2000:]


LONGEST_FUNCTION = 80  # lines of code, its docstring left out


def _code_lines(function: ast.FunctionDef | ast.AsyncFunctionDef) -> int:
    lines = function.end_lineno - function.lineno + 1
    first = function.body[0]
    if isinstance(first, ast.Expr) and isinstance(first.value, ast.Constant):
        lines -= first.end_lineno - first.lineno + 1  # the docstring
    return lines


def test_no_function_of_the_package_is_longer_than_80_lines():
    too_long = [
        f"{path.relative_to(PACKAGE)}:{node.name} ({_code_lines(node)} lines)"
        for path in sorted(PACKAGE.rglob("*.py"))
        for node in ast.walk(ast.parse(path.read_text()))
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef))
        and _code_lines(node) > LONGEST_FUNCTION
    ]
    assert too_long == []


# What runs after the build gets its values from the builder, never from the config.
AFTER_THE_BUILD = ("summary", "kept_policy", "checkpointer", "learner", "evaluation", "history")


def test_nothing_after_the_build_reads_the_config():
    readers = [
        f"run/{name}.py:{number}"
        for name in AFTER_THE_BUILD
        for number, line in enumerate((PACKAGE / "run" / f"{name}.py").read_text().splitlines(), 1)
        if re.search(r"\bcfg\b|stored_config\.\w", line)
    ]
    assert readers == []

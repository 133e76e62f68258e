"""The package's layout rules: no import circle, TorchRL internals in one module, no benchmarks."""

from __future__ import annotations

import ast
import re

from .conftest import ROOT

PACKAGE = ROOT / "src" / "trl_cartpole"
PRIVATE_TORCHRL_NAMES = re.compile(
    r"\._carrier|\._memo\b|base_env\._env|\._transform\b|\._buffer\b|[.'\"]_weight_sync_schemes"
    r"|action_func_mapping|prioritized\.(Sum|Min)SegmentTree"
)


def _module_imports() -> dict[str, set[str]]:
    """``{module: the package modules it imports at module level}``."""
    graph = {}
    for path in PACKAGE.glob("*.py"):
        name = path.stem
        imported = set()
        for node in ast.parse(path.read_text()).body:  # module level only (not in functions)
            if isinstance(node, ast.ImportFrom) and (node.module or "").startswith("trl_cartpole"):
                parts = node.module.split(".")
                if len(parts) > 1:
                    imported.add(parts[1])
                else:  # from trl_cartpole import x
                    imported.update(alias.name for alias in node.names)
        graph[name] = imported - {name}
    return graph


def test_no_import_circle_inside_the_package():
    graph = _module_imports()
    state: dict[str, str] = {}

    def visit(module: str, path: list[str]) -> None:
        state[module] = "open"
        for dependency in sorted(graph.get(module, ())):
            assert state.get(dependency) != "open", f"import circle: {[*path, dependency]}"
            if dependency not in state:
                visit(dependency, [*path, dependency])
        state[module] = "done"

    for module in sorted(graph):
        if module not in state:
            visit(module, [module])


def test_the_schema_and_the_errors_import_nothing_of_the_package():
    graph = _module_imports()
    assert graph["config"] == set() and graph["errors"] == set()


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

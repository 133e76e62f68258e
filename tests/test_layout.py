"""The package's layout rules: other libraries' private names in one module, no benchmarks.

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
PUBLIC_DESPITE_THE_UNDERSCORE = {"_exit"}  # os._exit: documented API


def _is_private(name: str) -> bool:
    return name.startswith("_") and not name.endswith("__")


def _own_bases(node: ast.ClassDef, own_classes: set[str]) -> bool:
    """Whether every base of a class is the package's own (or ``object``)."""
    names = [ast.unparse(base).rsplit(".", 1)[-1] for base in node.bases]
    return all(name in own_classes or name in ("object", "Protocol", "Generic") for name in names)


def _own_private_names(trees: list[ast.Module]) -> set[str]:
    """The private names the package's own classes define (methods, ``self._x = ...``): those of
    classes that inherit from another library's are not the package's to read elsewhere."""
    classes = [n for tree in trees for n in ast.walk(tree) if isinstance(n, ast.ClassDef)]
    own_classes = {c.name for c in classes}
    for _ in range(3):  # a class on a class on a class of the package's own
        own_classes = {c.name for c in classes if _own_bases(c, own_classes)}
    names = {
        n.name for tree in trees for n in ast.walk(tree) if isinstance(n, ast.FunctionDef)
    } - {n.name for c in classes if not _own_bases(c, own_classes) for n in c.body if
         isinstance(n, ast.FunctionDef)}  # fmt: skip
    for c in classes:
        if _own_bases(c, own_classes):
            for n in ast.walk(c):
                if isinstance(n, ast.Attribute) and isinstance(n.ctx, ast.Store):
                    names.add(n.attr)
                if isinstance(n, ast.AnnAssign) and isinstance(n.target, ast.Name):
                    names.add(n.target.id)  # a dataclass's field
    return {name for name in names if _is_private(name)}


def _foreign_private_uses(tree: ast.Module, own: set[str]) -> list[tuple[int, str]]:
    """Where a module reads another library's private name: ``obj._x`` on anything but
    ``self``/``cls``/``super()`` or the module's own class (a subclass's override of a hook
    such as ``_default_checkpointer``), ``getattr(obj, "_x")``, ``from lib._private import x``."""
    classes = {n.name for n in ast.walk(tree) if isinstance(n, ast.ClassDef)}
    found = []
    for n in ast.walk(tree):
        if isinstance(n, ast.Attribute) and _is_private(n.attr) and n.attr not in own:
            owner = n.value
            if isinstance(owner, ast.Name) and owner.id in ("self", "cls", *classes):
                continue
            if isinstance(owner, ast.Call) and ast.unparse(owner.func) == "super":
                continue
            if n.attr not in PUBLIC_DESPITE_THE_UNDERSCORE:
                found.append((n.lineno, ast.unparse(n)))
        elif isinstance(n, ast.Call) and ast.unparse(n.func) in ("getattr", "hasattr", "setattr"):
            name = (
                n.args[1].value if len(n.args) > 1 and isinstance(n.args[1], ast.Constant) else ""
            )
            if isinstance(name, str) and _is_private(name) and name not in own:
                found.append((n.lineno, ast.unparse(n)))
        elif isinstance(n, ast.ImportFrom) and n.level == 0 and n.module:
            if n.module.split(".")[0] == "trl_cartpole":
                continue
            parts = [*n.module.split("."), *(alias.name for alias in n.names)]
            if any(_is_private(part) for part in parts):
                found.append((n.lineno, f"from {n.module} import ..."))
    return found


def test_private_names_of_other_libraries_are_read_only_in_the_compatibility_module():
    """Another library's private name (TorchRL's, Gymnasium's, Ray's, Python's) is read in
    ``compat.py`` alone, where tests/test_compat.py checks each still means what it did."""
    paths = sorted(PACKAGE.rglob("*.py"))
    trees = {path: ast.parse(path.read_text()) for path in paths}
    own = _own_private_names(list(trees.values()))
    found = [
        f"{path.relative_to(PACKAGE)}:{line} {text}"
        for path, tree in trees.items()
        if path.name != "compat.py"
        for line, text in _foreign_private_uses(tree, own)
    ]
    assert found == []


def test_the_private_name_rule_sees_each_form():
    code = """
import threading
from torchrl.envs.transforms.utils import _set_missing_tolerance
from ray._raylet import Config
class Mine:
    def __init__(self):
        self._mine = 1
    def _helper(self):
        return self._inherited
class Theirs(LazyTensorStorage):
    def _step(self):
        self._len = 0
Theirs._default_checkpointer = None
def f(storage, mine, parent):
    threading._shutdown()
    getattr(storage, "_last_cursor", 0)
    parent._step(None)
    storage._len = 3
    return mine._mine, mine._helper(), super()._x
"""
    tree = ast.parse(code)
    found = [text for _, text in _foreign_private_uses(tree, _own_private_names([tree]))]
    assert sorted(found) == sorted(
        [
            "from torchrl.envs.transforms.utils import ...",
            "from ray._raylet import ...",
            "threading._shutdown",
            "getattr(storage, '_last_cursor', 0)",
            "parent._step",
            "storage._len",
        ]
    )


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
AFTER_THE_BUILD = ("summary", "best_policy", "checkpointer", "learner", "evaluation", "history")


def test_nothing_after_the_build_reads_the_config():
    readers = [
        f"run/{name}.py:{number}"
        for name in AFTER_THE_BUILD
        for number, line in enumerate((PACKAGE / "run" / f"{name}.py").read_text().splitlines(), 1)
        if re.search(r"\bcfg\b|stored_config\.\w", line)
    ]
    assert readers == []

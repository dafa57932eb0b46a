"""Arrows point one way: the core package ``hbench`` imports no plugin.

The plugins (``plugins/hbench_*``) build on the core's public modules; a core module that imported
one would make the core depend on an installable extra and put the arrow both ways.
"""

from __future__ import annotations

import ast
import tomllib
from pathlib import Path

import hbench

CORE = Path(hbench.__file__).parent
PLUGINS = sorted(
    p.name for p in (CORE.parent / "plugins").iterdir() if (p / "__init__.py").is_file()
)


def _imported(path: Path) -> set[str]:
    """Top-level package names imported anywhere in ``path`` (also inside functions)."""
    names: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if isinstance(node, ast.Import):
            names.update(alias.name.split(".")[0] for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names.add(node.module.split(".")[0])
    return names


def test_the_plugins_are_found():
    assert {"hbench_wang", "hbench_baifu", "hbench_oracle"} <= set(PLUGINS)


def test_no_core_module_imports_a_plugin():
    found = {
        str(path.relative_to(CORE.parent)): sorted(_imported(path) & set(PLUGINS))
        for path in sorted(CORE.rglob("*.py"))
    }
    assert {k: v for k, v in found.items() if v} == {}


def test_test_tools_are_not_runtime_dependencies():
    """Only the benchmarks import pytest-benchmark: it sits in the dev extra, not beside numpy."""
    project = tomllib.loads((CORE.parent / "pyproject.toml").read_text())["project"]
    runtime = " ".join(project["dependencies"])
    assert "pytest" not in runtime
    assert any(d.startswith("pytest-benchmark") for d in project["optional-dependencies"]["dev"])
    for path in sorted(CORE.rglob("*.py")):
        assert not _imported(path) & {"pytest", "pytest_benchmark"}, path

"""hbench's layout: modules grouped by concern, top-level names as faces, no import cycle.

The modules live in subpackages by what they do (``hbench.model``, ``hbench.sim``, ...). Each
top-level module name imports too: the names plugins use (``hbench.identifiers``,
``hbench.polyphase``, ``hbench.conformance``, ``hbench.records``) are public faces without a
warning; every other top-level name is deprecated, and reading a name from it warns with the
package path. hbench's own modules, the plugins, the example plugin and the benchmarks import the
package paths only, and only names that exist.
The import graph among hbench's modules, imports inside functions included, has no cycle; the
layers are checked by import-linter (``lint-imports``, contracts in ``pyproject.toml``).
"""

from __future__ import annotations

import ast
import importlib
import re
import subprocess
import sys
import tomllib
import warnings
from pathlib import Path

import pytest

import hbench
from hbench.aliases import REMOVED_IN

CORE = Path(hbench.__file__).parent
REPO = CORE.parent

#: Top-level module name -> the module in its package.
MOVED = {
    "hbench.plants": "hbench.model.plants",
    "hbench.controllers": "hbench.model.controllers",
    "hbench.nonlinearities": "hbench.model.nonlinearities",
    "hbench.noise": "hbench.model.noise",
    "hbench.signals": "hbench.model.signals",
    "hbench.ordered": "hbench.numerics.ordered",
    "hbench.kernels": "hbench.numerics.kernels",
    "hbench.runtime": "hbench.system.runtime",
    "hbench.limits": "hbench.system.limits",
    "hbench.atomic": "hbench.system.atomic",
    "hbench.scenarios": "hbench.sim.scenarios",
    "hbench.simulate": "hbench.sim.simulate",
    "hbench.records": "hbench.sim.records",
    "hbench.seeding": "hbench.sim.seeding",
    "hbench.readers": "hbench.io.readers",
    "hbench.identifiers": "hbench.ident.identifiers",
    "hbench.polyphase": "hbench.ident.polyphase",
    "hbench.runner": "hbench.bench.runner",
    "hbench.tidy": "hbench.bench.tidy",
    "hbench.schema": "hbench.bench.schema",
    "hbench.metrics": "hbench.bench.metrics",
    "hbench.conformance": "hbench.bench.conformance",
    "hbench.results": "hbench.tables.results",
    "hbench.headline": "hbench.tables.headline",
    "hbench.summary": "hbench.tables.summary",
    "hbench.report": "hbench.report.build",
    "hbench.report_beyond": "hbench.report.beyond",
    "hbench.figures": "hbench.report.figures",
    "hbench.style": "hbench.report.style",
    "hbench.reproduce": "hbench.paper.reproduce",
    "hbench.sweep": "hbench.sweep.app",
    "hbench.config": "hbench.sweep.config",
    "hbench.callbacks": "hbench.sweep.callbacks",
    "hbench.hydra_adapter": "hbench.sweep.hydra_adapter",
}
#: The top-level names plugins import: faces without a warning.
PUBLIC = {"hbench.identifiers", "hbench.polyphase", "hbench.conformance", "hbench.records"}
#: Top-level names that are packages: only the app's or builder's names are deprecated there.
PACKAGES = {"hbench.report", "hbench.sweep"}


def _public_name(module_name: str) -> str:
    """A name defined in ``module_name`` itself (a function or class, else a constant)."""
    module = importlib.import_module(module_name)
    for name, value in sorted(vars(module).items()):
        if not name.startswith("_") and getattr(value, "__module__", None) == module_name:
            return name
    for name, value in sorted(vars(module).items()):  # a module of constants
        if not name.startswith("_") and type(value).__name__ != "module":
            return name
    raise AssertionError(f"{module_name} has no public name")


@pytest.mark.parametrize("old", sorted(set(MOVED) - PUBLIC))
def test_a_deprecated_name_warns_with_the_new_path(old):
    new = MOVED[old]
    face = importlib.import_module(old)
    name = _public_name(new)
    with pytest.warns(DeprecationWarning, match=re.escape(f"import {name} from {new}")) as seen:
        value = getattr(face, name)
    assert f"removed in hbench {REMOVED_IN}" in str(seen[0].message)
    assert value is getattr(importlib.import_module(new), name)


@pytest.mark.parametrize("old", sorted(PUBLIC))
def test_a_public_face_serves_its_module_without_a_warning(old):
    new = importlib.import_module(MOVED[old])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        face = importlib.import_module(old)
        for name in (_public_name(MOVED[old]), *(n for n in vars(new) if not n.startswith("_"))):
            assert getattr(face, name) is getattr(new, name)
    assert set(dir(face)) >= {n for n in vars(new) if not n.startswith("_")}


@pytest.mark.parametrize("name", ["find_rows", "NOT_OK", "CELL_COLUMNS"])
def test_a_name_moved_out_of_the_report_builder_warns_with_its_new_place(name):
    from hbench.report import build

    new = build.MOVED[name]
    with pytest.warns(DeprecationWarning, match=re.escape(f"import {name} from {new}")) as seen:
        value = getattr(build, name)
    assert seen[0].filename == __file__  # blamed on the reader: the default filters show it
    assert value is getattr(importlib.import_module(new), name)
    with pytest.raises(AttributeError, match="no attribute"):
        build.no_such_name  # noqa: B018


def test_a_package_imports_its_submodules_without_a_warning():
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        from hbench.report import (  # noqa: F401
            aggregate,
            beyond,
            build,
            elements,
            figures,
            inputs,
            style,
            table_files,
        )
        from hbench.sweep import app, callbacks, config, hydra_adapter, jobs  # noqa: F401


def _modules() -> dict[str, Path]:
    """hbench's module names -> files."""
    out = {}
    for path in sorted(CORE.rglob("*.py")):
        parts = path.relative_to(REPO).with_suffix("").parts
        out[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = path
    return out


MODULES = _modules()


def imports(path: Path, package: str) -> set[str]:
    """The hbench modules ``path`` imports, anywhere in it (inside functions too).

    ``package`` is the package a relative import starts from. ``from P import N`` counts as an
    import of the module ``P.N`` when that is a module, else of ``P``.
    """
    found: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                up = package.split(".")[: len(package.split(".")) - node.level + 1]
                base = ".".join([*up, *([base] if base else [])])
            for alias in node.names:
                found.add(f"{base}.{alias.name}" if f"{base}.{alias.name}" in MODULES else base)
    return {name for name in found if name in MODULES}


def graph() -> dict[str, set[str]]:
    """Module -> the hbench modules it imports (itself excluded)."""
    out = {}
    for name, path in MODULES.items():
        package = name if path.name == "__init__.py" else name.rpartition(".")[0]
        out[name] = imports(path, package) - {name}
    return out


def cycles(edges: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components with more than one module (Tarjan's algorithm)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in sorted(edges.get(v, ())):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                found.append(sorted(component))

    for v in sorted(edges):
        if v not in index:
            visit(v)
    return found


def test_the_cycle_finder_finds_a_cycle():
    assert cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    assert cycles({"a": {"b"}, "b": set()}) == []


def test_the_graph_counts_imports_inside_functions(tmp_path):
    source = tmp_path / "m.py"
    source.write_text("def f():\n    from hbench.sim import records\n    from . import errors\n")
    assert imports(source, "hbench") == {"hbench.sim.records", "hbench.errors"}


def test_no_import_cycle_among_hbench_modules():
    assert cycles(graph()) == []


def _sources() -> list[Path]:
    """hbench's modules (the faces themselves apart), the plugins, the example plugin and the
    benchmarks."""
    faces = {MODULES[old] for old in MOVED if old not in PACKAGES}
    plugins = sorted((REPO / "plugins").rglob("*.py"))
    return (
        [p for p in MODULES.values() if p not in faces]
        + plugins
        + sorted((REPO / "examples").rglob("*.py"))
        + sorted((REPO / "benchmarks").glob("*.py"))
    )


def test_hbench_plugins_and_benchmarks_import_the_new_paths_only():
    old = set(MOVED) - PACKAGES
    found = {}
    for path in _sources():
        tree = ast.parse(path.read_text(), filename=str(path))
        bad = {name for name in imports(path, "hbench") if name in old}
        for node in ast.walk(tree):  # a module's name read from its package
            if isinstance(node, ast.ImportFrom) and node.module in PACKAGES:
                bad |= {
                    f"{node.module}.{a.name}"
                    for a in node.names
                    if f"{node.module}.{a.name}" not in MODULES
                }
        if bad:
            found[str(path.relative_to(REPO))] = sorted(bad)
    assert found == {}


def unresolved(path: Path) -> set[str]:
    """The names ``from hbench... import NAME`` in ``path`` reads that are neither a module of
    hbench nor a name of the module it reads them from (read without a warning)."""
    out = set()
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if not (isinstance(node, ast.ImportFrom) and (node.module or "").startswith("hbench")):
            continue
        if node.level or node.module.split(".")[0] != "hbench":
            continue
        for alias in node.names:
            if f"{node.module}.{alias.name}" in MODULES:
                continue
            with warnings.catch_warnings():
                warnings.simplefilter("error", DeprecationWarning)
                try:
                    getattr(importlib.import_module(node.module), alias.name)
                except (ImportError, AttributeError, DeprecationWarning):
                    out.add(f"{node.module}.{alias.name}")
    return out


def test_unresolved_finds_a_name_that_does_not_exist(tmp_path):
    source = tmp_path / "m.py"
    source.write_text("from hbench import parallel, hookimpl\nfrom hbench.bench import runner\n")
    assert unresolved(source) == {"hbench.parallel"}


def test_every_hbench_name_imported_exists():
    """hbench's modules, the plugins, the example plugin and the benchmarks import only names
    that exist (a module of hbench, or a name its module holds)."""
    found = {str(p.relative_to(REPO)): sorted(unresolved(p)) for p in _sources()}
    assert {k: v for k, v in found.items() if v} == {}


def _lint_imports(*args: str) -> subprocess.CompletedProcess:
    """``lint-imports`` (import-linter, the dev extra) run on the repository."""
    pytest.importorskip("importlinter")
    command = Path(sys.executable).with_name("lint-imports")
    return subprocess.run(
        [str(command), "--no-cache", *args],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=300,
    )


def test_the_import_contracts_are_kept():
    """The layers, independence and no-plugin contracts of ``pyproject.toml``."""
    done = _lint_imports()
    assert done.returncode == 0, done.stdout + done.stderr
    assert "0 broken" in done.stdout


def test_a_broken_contract_fails(tmp_path):
    """The check can fail: the same layers upside down break."""
    project = tomllib.loads((REPO / "pyproject.toml").read_text())["tool"]["importlinter"]
    layers = next(c for c in project["contracts"] if c["type"] == "layers")["layers"]
    config = tmp_path / "upside-down.ini"
    config.write_text(
        "[importlinter]\nroot_package = hbench\n\n[importlinter:contract:upside-down]\n"
        "name = upside down\ntype = layers\ncontainers = hbench\nlayers =\n"
        + "".join(f"    {layer}\n" for layer in reversed(layers))
    )
    done = _lint_imports("--config", str(config))
    assert done.returncode == 1, done.stdout + done.stderr
    assert "upside down BROKEN" in done.stdout


def test_the_profilers_phases_name_functions_that_exist():
    """``benchmarks/profile_reproduce.py`` finds each phase by the file and name of a function;
    a phase whose function moved would read 0 s without an error. Every phase in hbench names a
    function defined anywhere in that file (module level, in a class, or nested, as
    ``draw_example`` and ``warm_up`` are in ``reproduce()``)."""
    from benchmarks.profile_reproduce import PHASES

    checked = 0
    for label, suffix, name in PHASES:
        if not suffix.startswith("hbench/"):
            continue  # a library's file (pandas, matplotlib): not this project's layout
        path = REPO / suffix
        assert path.is_file(), f"{label.strip()}: {suffix} does not exist"
        defined = {
            node.name
            for node in ast.walk(ast.parse(path.read_text()))
            if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef)
        }
        assert name in defined, f"{label.strip()}: {suffix} defines no function {name}"
        checked += 1
    assert checked >= 5

"""numpydoc sections on the public API plugin authors use (as python-control's docstring test).

Every public function of the modules behind :mod:`hbench.ident.identifiers` (``estimate``,
``selection``, ``blind``, ``invoke``), :mod:`hbench.ident.polyphase`,
:mod:`hbench.bench.conformance` and :mod:`hbench.sim.records` has a one-line summary and, when it
takes parameters, a ``Parameters`` section naming each of them."""

from __future__ import annotations

import importlib
import inspect
import re

import pytest

MODULES = (
    "hbench.ident.estimate",
    "hbench.ident.selection",
    "hbench.ident.blind",
    "hbench.ident.invoke",
    "hbench.ident.polyphase",
    "hbench.bench.conformance",
    "hbench.sim.records",
)


def _public_functions() -> list[tuple[str, str]]:
    out = []
    for module_name in MODULES:
        module = importlib.import_module(module_name)
        for name, obj in vars(module).items():
            if (
                not name.startswith("_")
                and inspect.isfunction(obj)
                and obj.__module__ == module_name
            ):
                out.append((module_name, name))
    return out


def _section(doc: str, title: str) -> list[str] | None:
    """The lines of numpydoc section ``title`` (``None`` when there is none)."""
    lines = doc.splitlines()
    for i in range(len(lines) - 1):
        if lines[i].strip() == title and re.fullmatch(r"\s*-{3,}\s*", lines[i + 1]):
            body = []
            for j in range(i + 2, len(lines)):
                if j + 1 < len(lines) and re.fullmatch(r"\s*-{3,}\s*", lines[j + 1]):
                    break  # the next section's title
                body.append(lines[j])
            return body
    return None


def _documented(body: list[str]) -> set[str]:
    """Parameter names of a section: its unindented ``name : type`` (or ``a, b : type``) lines."""
    names: set[str] = set()
    for line in body:
        if line and not line[0].isspace():
            for part in line.split(" : ")[0].split(","):
                names.add(part.strip().lstrip("*"))
    return names


FUNCTIONS = _public_functions()


def test_the_public_functions_are_found():
    modules = {m for m, _ in FUNCTIONS}  # hbench.sim.records: classes only, no function
    assert modules == {
        "hbench.ident.estimate",
        "hbench.ident.selection",
        "hbench.ident.blind",
        "hbench.ident.invoke",
        "hbench.ident.polyphase",
        "hbench.bench.conformance",
    }
    assert ("hbench.ident.blind", "blind_fit") in FUNCTIONS
    assert ("hbench.ident.polyphase", "bias_compensated") in FUNCTIONS


@pytest.mark.parametrize(("module_name", "name"), FUNCTIONS, ids=[f"{m}.{n}" for m, n in FUNCTIONS])
def test_public_function_has_numpydoc_sections(module_name, name):
    func = getattr(importlib.import_module(module_name), name)
    doc = inspect.getdoc(func) or ""
    assert doc.strip(), "no docstring"
    assert doc.splitlines()[0].strip(), "no one-line summary first"
    params = [
        p.name for p in inspect.signature(func).parameters.values() if p.name not in ("self", "cls")
    ]
    if not params:
        return
    body = _section(doc, "Parameters")
    assert body is not None, "no Parameters section"
    missing = [p for p in params if p not in _documented(body)]
    assert not missing, f"parameters not documented: {missing}"

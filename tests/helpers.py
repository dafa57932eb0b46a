"""Shared builders for tests (scenarios, estimates) so test files do not repeat them."""

from __future__ import annotations

import contextlib
import copy
import shutil
import subprocess
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from hbench.hookspecs import hookimpl
from hbench.ident.identifiers import Estimate, Identifier, IdentifyOptions, identify
from hbench.plugins import register_module, registry, unregister_module
from hbench.sim import scenarios
from hbench.sim.records import Record, Truth
from hbench.sim.simulate import simulate

TRUE_STRUCTURE = IdentifyOptions(na=2, tau=3, nb=2)

#: The contract's columns (shared/docs/contract.md), written out here rather than imported from
#: hbench so that a change in hbench's constants cannot silently change what the tests demand.
FITNESS_COLUMNS = [
    "method",
    "nonlinearity",
    "p",
    "delay",
    "sigma2",
    "snr_mean",
    "n",
    "fitness_mean",
    "fitness_std",
]
BIAS_COLUMNS = [
    "method",
    "nonlinearity",
    "p",
    "delay",
    "sigma2",
    "parameter",
    "true",
    "mean",
    "bias",
    "std",
    "n",
]


def paper_spec(**overrides: Any) -> dict[str, Any]:
    """The paper's example spec with dotted overrides (``noise__sigma2=0`` style keys)."""
    spec = copy.deepcopy(scenarios.PAPER_SECTION6)
    # a new plugin name resets its group, so names go first whatever the argument order
    ordered = sorted(overrides.items(), key=lambda kv: not kv[0].endswith("__name"))
    for key, value in ordered:
        path = key.split("__")
        if path[0] == "noise" and path[-1] in ("sigma2", "snr"):
            spec["noise"].pop("sigma2", None)
            spec["noise"].pop("snr", None)
        if path[-1] == "name" and len(path) == 2:
            spec[path[0]] = {}
        scenarios.set_dotted(spec, ".".join(path), value)
    return spec


def sim(runs: int = 2, seed: int = 0, **overrides: Any) -> tuple[Record, Truth]:
    return simulate(scenarios.build(paper_spec(**overrides)), runs, np.random.default_rng(seed))


def run_method(
    name: str,
    record: Record,
    truth: Truth | None = None,
    options: IdentifyOptions | None = None,
    **method_options: Any,
) -> Estimate:
    cls = registry().get("identifiers", name)
    return identify(cls(**method_options), record, options or IdentifyOptions(), truth)


@contextlib.contextmanager
def registered_methods(plugin_name: str, *classes: type[Identifier]) -> Iterator[None]:
    """Register throwaway methods (under their ``name``) as a plugin while inside."""

    class Plugin:
        @hookimpl
        def register_identifiers(self, register: Any) -> None:
            for cls in classes:
                register(cls.name, cls)

    plugin = Plugin()
    register_module(plugin, name=plugin_name)
    try:
        yield
    finally:
        unregister_module(plugin)


#: Why the LaTeX tests skip where pdflatex is missing (CI installs it from Debian).
NO_PDFLATEX = "needs pdflatex with booktabs (Debian: texlive-latex-base, texlive-latex-extra)"
HAS_PDFLATEX = shutil.which("pdflatex") is not None


def compile_tex(folder: Path, files: list[Path]) -> subprocess.CompletedProcess[str]:
    """Compile ``files`` (LaTeX tables under ``folder``), each input into one article with
    booktabs, by pdflatex in ``folder``; the finished process (``returncode`` 0: compiled)."""
    doc = folder / "doc.tex"
    doc.write_text(
        "\\documentclass{article}\n\\usepackage{booktabs}\n\\begin{document}\n"
        + "".join(f"\\input{{{f.relative_to(folder).as_posix()}}}\n" for f in files)
        + "\\end{document}\n"
    )
    return subprocess.run(
        ["pdflatex", "-interaction=nonstopmode", "-halt-on-error", doc.name],
        cwd=folder,
        capture_output=True,
        text=True,
        timeout=120,
    )

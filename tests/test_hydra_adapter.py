"""hbench.sweep.hydra_adapter: the one private hook into Hydra, for the versions it supports."""

from __future__ import annotations

import inspect

import hydra
import pytest

from hbench.sweep import hydra_adapter


def test_the_installed_hydra_is_a_supported_version():
    """Supported: Hydra 1.3.x (``hydra-core==1.3.*`` in pyproject.toml). A new series needs
    :func:`hbench.sweep.hydra_adapter.report_errors` checked against its internals first."""
    assert hydra_adapter.SUPPORTED == ("1.3",)
    assert hydra.__version__.rsplit(".", 1)[0] in hydra_adapter.SUPPORTED, hydra.__version__


def test_hydra_still_reports_a_runs_errors_through_the_wrapped_function():
    """The hook holds only while Hydra's runner looks ``run_and_report`` up at call time."""
    from hydra._internal import utils

    assert "run_and_report(" in inspect.getsource(utils._run_hydra)
    original = utils.run_and_report
    seen = []

    def handle(func):
        seen.append(func)
        raise SystemExit(2)

    with hydra_adapter.report_errors(handle):
        assert utils.run_and_report is not original
        with pytest.raises(SystemExit) as exc:
            utils.run_and_report(lambda: 1)
    assert exc.value.code == 2 and len(seen) == 1
    assert utils.run_and_report is original


def test_no_other_module_reaches_into_hydras_internals():
    import ast
    from pathlib import Path

    import hbench

    core = Path(hbench.__file__).parent
    found = []
    for path in sorted(core.rglob("*.py")):
        if path.name == "hydra_adapter.py":
            continue
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom) and node.module and "._" in node.module:
                found.append(f"{path.name}: {node.module}")
    assert found == []


@pytest.mark.parametrize("private", ["._processes", "._actions", "_run_hydra", "hydra._internal"])
def test_private_attributes_of_libraries_are_not_used(private):
    """Hydra's internals only in ``hbench/sweep/hydra_adapter.py``; the executor's workers and the
    parser's actions through their public interfaces."""
    from pathlib import Path

    import hbench

    core = Path(hbench.__file__).parent
    found = [
        str(path.relative_to(core))
        for path in sorted(core.rglob("*.py"))
        if path.name != "hydra_adapter.py" and private in path.read_text()
    ]
    assert found == []

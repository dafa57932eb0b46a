"""Benchmarks of hbench (pytest-benchmark), run with ``pytest benchmarks --benchmark-only``.

pytest collects only ``test_*.py`` by default; this folder names its modules ``bench_*.py`` so
that they stay out of the test suite, and the hook below collects them when the folder is given.
The project's ``addopts`` holds ``--benchmark-skip``; ``--benchmark-only`` overrides it.
"""

from __future__ import annotations

import copy
from pathlib import Path
from typing import Any

import pytest

from hbench.sim import scenarios
from hbench.sim.simulate import Scenario
from hbench.system import runtime


def pytest_collect_file(file_path: Path, parent: pytest.Collector) -> pytest.Module | None:
    if (
        file_path.suffix == ".py"
        and file_path.name.startswith("bench_")
        and not parent.session.isinitpath(file_path)  # pytest collects given paths itself
    ):
        return pytest.Module.from_parent(parent, path=file_path)
    return None


@pytest.fixture(scope="session", autouse=True)
def _tuned_allocator() -> None:
    """The benchmarks measure the library as the ``hbench`` command runs it: with glibc's
    allocator tuned (:func:`hbench.system.runtime.tune_allocator`, opt-in)."""
    runtime.tune_allocator()


@pytest.fixture(scope="session")
def paper_scenario() -> Scenario:
    """The paper's Section 6 example: 500 s, T = 0.6 s, p = 5, sigma^2 = 1e-3."""
    spec: dict[str, Any] = copy.deepcopy(scenarios.PAPER_SECTION6)
    assert spec["duration"] == 500.0 and spec["p"] == 5 and spec["noise"]["sigma2"] == 1e-3
    sc = scenarios.build(spec)
    sc.discrete_plant  # noqa: B018 - discretise once, outside the timed calls
    return sc

"""Worker processes (:mod:`hbench.bench.parallel`) against one process, in the same run.

* ``test_cell[case]``: one 1000-run cell of the paper's example (4 methods, chunks of 200).
* ``test_scope[case]``: a sweep's jobs: 6 cells of 500 runs one after another.

Cases: ``one`` (``jobs=1``); ``per-cell`` (``jobs=2``, a process pool started per cell by
:func:`hbench.bench.parallel.map_chunks`); ``kept`` (``jobs=2`` inside
:func:`hbench.bench.parallel.kept_workers`, as ``hbench sweep`` runs its cells; the warm-up round
starts the pool). The rows of every case are asserted identical to those of ``one``. The
figures, and the comparison that chose this executor, are in ``docs/performance.md`` (section
"Worker processes").
"""

from __future__ import annotations

import contextlib

import pandas as pd
import pytest
from pytest_benchmark.fixture import BenchmarkFixture

from hbench.bench import parallel
from hbench.bench.runner import methods_from_names, run_cell
from hbench.sim.simulate import Scenario

METHODS = ["wang-lsm", "wang-iv", "bai-fu", "oracle"]
SEED = 2026
CASES = ["one", "per-cell", "kept"]
_rows: dict[str, pd.DataFrame] = {}
_mean: dict[str, float] = {}


def _cells(scenario: Scenario, count: int, runs: int, jobs: int) -> pd.DataFrame:
    methods = methods_from_names(METHODS)
    out = [
        run_cell(scenario, methods, runs, SEED + i, cell=str(i), jobs=jobs).rows
        for i in range(count)
    ]
    rows = pd.concat(out, ignore_index=True)
    rows = rows[rows["quantity"] != "seconds"]  # timings differ
    return rows.sort_values(["cell", "method", "quantity", "run"]).reset_index(drop=True)


def _bench(
    benchmark: BenchmarkFixture, scenario: Scenario, case: str, what: str, count: int, runs: int
) -> None:
    jobs = 1 if case == "one" else 2
    with parallel.kept_workers() if case == "kept" else contextlib.nullcontext():
        rows = benchmark.pedantic(
            _cells, (scenario, count, runs, jobs), rounds=5, iterations=1, warmup_rounds=1
        )
    key = f"{what}-{case}"
    _mean[key] = benchmark.stats.stats.mean
    benchmark.extra_info.update(cells=count, runs=runs, methods=METHODS, jobs=jobs)
    if case == "one":
        _rows[what] = rows
        return
    pd.testing.assert_frame_equal(rows, _rows[what], check_exact=True)
    ratio = _mean[f"{what}-one"] / _mean[key]
    benchmark.extra_info["speedup_vs_one"] = ratio
    print(f"\n{what}, {case}: {ratio:.2f}x one process")
    if case == "kept":
        over = _mean[f"{what}-per-cell"] / _mean[key]
        benchmark.extra_info["kept_over_per_cell"] = over
        print(f"{what}: kept over per-cell {over:.2f}x")


@pytest.mark.parametrize("case", CASES)
def test_cell(benchmark: BenchmarkFixture, paper_scenario: Scenario, case: str) -> None:
    _bench(benchmark, paper_scenario, case, "cell", 1, 1000)


@pytest.mark.parametrize("case", CASES)
def test_scope(benchmark: BenchmarkFixture, paper_scenario: Scenario, case: str) -> None:
    _bench(benchmark, paper_scenario, case, "scope", 6, 500)

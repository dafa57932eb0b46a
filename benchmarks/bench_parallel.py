"""hbench's bespoke worker pool (``hbench.workers``) against the standard executor
(``hbench.parallel``) and one process, in the same run.

* ``test_cell[case]``: one 1000-run cell of the paper's example (4 methods, chunks of 200).
* ``test_scope[case]``: a sweep's jobs: 6 cells of 500 runs one after another in one scope.

Cases, all but ``one`` with ``jobs=2``: ``one`` (``jobs=1``); ``standard`` (a
``ProcessPoolExecutor`` started per cell by :func:`hbench.parallel.map_chunks`); ``standard-kept``
(the same inside :func:`hbench.parallel.kept_workers`); ``loky`` (joblib's loky reusable
executor); ``fork`` (``hbench.workers`` forking per cell); ``kept`` (inside
``hbench.workers.kept_workers``). The rows of every case are asserted identical to those of
``one``.
"""

from __future__ import annotations

import contextlib

import pandas as pd
import pytest
from pytest_benchmark.fixture import BenchmarkFixture

from hbench import kernels, parallel, workers
from hbench.runner import methods_from_names, run_cell
from hbench.simulate import Scenario

METHODS = ["wang-lsm", "wang-iv", "bai-fu", "oracle"]
SEED = 2026
CASES = ["one", "standard", "standard-kept", "loky", "fork", "kept"]
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


def _loky_map_chunks(fn, work, pieces, jobs):
    """:func:`hbench.parallel.map_chunks` on joblib's loky reusable executor."""
    from joblib.externals.loky import get_reusable_executor

    if jobs <= 1 or len(pieces) < 2:
        yield from (fn(work, *p) for p in pieces)
        return
    mine = max(len(pieces) // jobs, 1)
    ex = get_reusable_executor(
        jobs - 1, timeout=300, initializer=parallel._start_worker, initargs=(None, ())
    )
    futures = [ex.submit(parallel._chunk_of, fn, work, kernels._asked(), p) for p in pieces[mine:]]
    for p in pieces[:mine]:
        yield fn(work, *p)
    for f in futures:
        yield parallel._reissue(f.result())


def _bench(benchmark, monkeypatch, scenario, case, what, count, runs):
    if case in ("fork", "kept"):
        monkeypatch.setattr(parallel, "map_chunks", workers.map_chunks)
    if case == "loky":
        monkeypatch.setattr(parallel, "map_chunks", _loky_map_chunks)
    jobs = 1 if case == "one" else 2
    scope = {"kept": workers.kept_workers, "standard-kept": parallel.kept_workers}
    with scope.get(case, contextlib.nullcontext)():
        rows = benchmark.pedantic(
            _cells, (scenario, count, runs, jobs), rounds=5, iterations=1, warmup_rounds=1
        )
    key = f"{what}-{case}"
    _mean[key] = benchmark.stats.stats.mean
    if case == "one":
        _rows[what] = rows
    else:
        pd.testing.assert_frame_equal(rows, _rows[what])
        ratio = _mean[f"{what}-one"] / _mean[key]
        benchmark.extra_info["speedup_vs_one"] = ratio
        if case == "kept":
            for other in ("standard", "standard-kept", "loky"):
                over = _mean[f"{what}-{other}"] / _mean[key]
                benchmark.extra_info[f"kept_over_{other}"] = over
                print(f"\n{what}: hbench.workers kept over {other} {over:.2f}x")
        print(f"\n{what}, {case}: {ratio:.2f}x one process")


@pytest.mark.parametrize("case", CASES)
def test_cell(benchmark: BenchmarkFixture, monkeypatch, paper_scenario: Scenario, case: str):
    _bench(benchmark, monkeypatch, paper_scenario, case, "cell", 1, 1000)


@pytest.mark.parametrize("case", CASES)
def test_scope(benchmark: BenchmarkFixture, monkeypatch, paper_scenario: Scenario, case: str):
    _bench(benchmark, monkeypatch, paper_scenario, case, "scope", 6, 500)

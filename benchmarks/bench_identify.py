"""Identification throughput on the paper's example, and the O(K) inner-signal solve of eq. (27).

* ``test_identify_1000_runs[method]``: one batch of 1000 runs per method (structure selected).
* ``test_inner_signal_tridiagonal`` vs ``test_inner_signal_dense``: the same eq. (27) problem for
  20 runs, solved through the tridiagonal normal equations vs a dense least-squares solve; the
  ratio of their means is the speed-up, and both must agree to 1e-10 (checked here).
"""

from __future__ import annotations

import numpy as np
import pytest
from pytest_benchmark.fixture import BenchmarkFixture

from hbench.ident import polyphase as pp
from hbench.ident.identifiers import IdentifyOptions, identify
from hbench.plugins import registry
from hbench.sim.simulate import Scenario, simulate

METHODS = ["wang-lsm", "wang-iv", "bai-fu", "sun-liu-sano", "oracle", "oracle-inv"]


@pytest.fixture(scope="module")
def batch(paper_scenario: Scenario):
    return simulate(paper_scenario, 1000, 0)


@pytest.mark.parametrize("method", METHODS)
def test_identify_1000_runs(benchmark: BenchmarkFixture, batch, method: str) -> None:
    record, truth = batch
    m = registry().get("identifiers", method)()
    est = benchmark.pedantic(
        identify,
        args=(m, record, IdentifyOptions(), truth),
        rounds=3,
        iterations=1,
        warmup_rounds=1,
    )
    assert est.U.shape == truth.U.shape
    benchmark.extra_info["runs_per_second"] = record.runs / benchmark.stats.stats.mean


@pytest.fixture(scope="module")
def simo(batch):
    record, truth = batch
    R = 20
    y = record.y[:R]
    a = np.broadcast_to(truth.plant.a, (R, truth.plant.a.size)).copy()
    b = np.broadcast_to(truth.plant.b_normalised, (R, truth.plant.nb)).copy()
    w = pp.filtered_output(y, a)
    sys = pp.simo_system(w, record.p, truth.plant.tau(record.p), truth.plant.na)
    h0, h1 = pp.simo_channels(b, record.p)
    return sys, h0, h1


def test_inner_signal_tridiagonal(benchmark: BenchmarkFixture, simo) -> None:
    sys, h0, h1 = simo
    U = benchmark(pp.inner_signal_ls, sys, h0, h1)
    dense = pp.inner_signal_dense(sys, h0, h1)
    # both solve the same full-rank least-squares problem: equal up to rounding
    np.testing.assert_allclose(U, dense, rtol=0, atol=1e-10)
    benchmark.extra_info["runs"] = h0.shape[0]


def test_inner_signal_dense(benchmark: BenchmarkFixture, simo) -> None:
    sys, h0, h1 = simo
    benchmark.pedantic(pp.inner_signal_dense, args=(sys, h0, h1), rounds=3, iterations=1)
    benchmark.extra_info["runs"] = h0.shape[0]

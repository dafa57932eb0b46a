"""Throughput of :func:`hbench.sim.simulate.simulate` on the paper's example (500 s, p = 5)."""

from __future__ import annotations

import numpy as np
from pytest_benchmark.fixture import BenchmarkFixture

from hbench.sim.simulate import Scenario, simulate


def _run(benchmark: BenchmarkFixture, scenario: Scenario, runs: int) -> None:
    record, _truth = benchmark.pedantic(
        simulate, args=(scenario, runs, 0), rounds=3, iterations=1, warmup_rounds=1
    )
    assert record.y.shape == (runs, scenario.K * scenario.p)
    assert np.all(np.isfinite(record.y))
    mean = benchmark.stats.stats.mean
    benchmark.extra_info["runs"] = runs
    benchmark.extra_info["runs_per_second"] = runs / mean
    benchmark.extra_info["seconds_per_run"] = mean / runs


def test_simulate_1000_runs_paper(benchmark: BenchmarkFixture, paper_scenario: Scenario) -> None:
    _run(benchmark, paper_scenario, 1000)


def test_simulate_1_run_paper(benchmark: BenchmarkFixture, paper_scenario: Scenario) -> None:
    """One run: the per-call overhead (seed spawning, lifting, the loop over 833 slow steps)."""
    _run(benchmark, paper_scenario, 1)

"""``hbench reproduce`` timed from the shell as a user runs it: the defaults (100 runs) and
``--runs 1000``, start-up included (6 noise levels x 8 methods, every table, Figures 4 and 5 and
the report).

Targets on the idle 2-core machine: 3 s wall for the defaults, 4 s for ``--runs 1000``.
``test_cli_startup`` times ``hbench --help`` in the same run: the share of the budget that is
the interpreter and imports rather than work. ``test_reproduce_without[pdf-N]`` and
``[figures-N]`` run the same command with its PDFs, or the drawing of every figure, left out
(:mod:`benchmarks.without_figures`): what the figures cost of the budget, as ratios to
``test_reproduce[this-N]`` of the same run.

``test_cross_relation_gram[moments]`` against ``[rows]``: ``sun-liu-sano``'s cross-relation Gram
for 1000 runs of the paper's example, from the channels' moments (as the method computes it)
against the equations' rows written out (``tests/test_sls.py``'s reference), same run.

Before/after in one run: set ``HBENCH_BENCH_BASELINE`` to the source tree of another revision
(``git archive REV | tar -x -C DIR`` and its compiled ``hbench/numerics/_kernels*.so`` copied in);
``test_reproduce[baseline-*]`` then runs that tree with this environment's interpreter in the same
run as ``test_reproduce[this-*]``, and the later of each pair records ``ratio_to_baseline`` (wall,
this / baseline) and ``cpu_ratio_to_baseline`` (CPU seconds of all the run's processes, user +
system: the figure that moves least with the machine's load). Each case records the load average
(``load_average``: the higher of before and after). Without the variable the baseline cases are
skipped."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hbench_sls import cross_relation_gram
from pytest_benchmark.fixture import BenchmarkFixture

from benchmarks.shell import hbench, tree_of
from hbench.ident import polyphase as pp
from hbench.sim.simulate import Scenario, simulate
from tests.test_sls import rows_gram

_seconds: dict[str, float] = {}
TARGETS = {100: 3.0, 1000: 4.0}


def test_cli_startup(benchmark: BenchmarkFixture) -> None:
    benchmark.pedantic(hbench, args=("--help",), rounds=3, iterations=1)
    _seconds["startup"] = benchmark.stats.stats.mean


def _timed(
    benchmark: BenchmarkFixture, tmp_path: Path, runs: int, lead: tuple[str, ...], **kw: Any
) -> tuple[float, float]:
    """``hbench reproduce --runs runs`` timed in three rounds (``lead``: arguments before the
    command's, ``kw``: :func:`benchmarks.shell.hbench`'s); records its wall and CPU seconds, its
    target and the load average in ``extra_info`` and returns the mean wall and CPU seconds."""
    counter = iter(range(100))
    cpu: list[float] = []

    def setup():
        out = str(tmp_path / f"r{next(counter)}")
        return (*lead, "reproduce", "--runs", str(runs), "--out", out), {**kw, "cpu": cpu}

    load = os.getloadavg()[0]
    proc = benchmark.pedantic(hbench, setup=setup, rounds=3, iterations=1)
    assert "scored cells" in proc.stdout
    wall, cpu_mean = benchmark.stats.stats.mean, sum(cpu) / len(cpu)
    benchmark.extra_info.update(
        wall_seconds=wall,
        cpu_seconds=cpu_mean,
        target_seconds=TARGETS[runs],
        load_average=max(load, os.getloadavg()[0]),
    )
    return wall, cpu_mean


@pytest.mark.parametrize("runs", sorted(TARGETS))
@pytest.mark.parametrize("which", ["this", "baseline"])
def test_reproduce(benchmark: BenchmarkFixture, tmp_path: Path, which: str, runs: int) -> None:
    key = f"{which}-{runs}"
    _seconds[key], _seconds[f"cpu-{key}"] = _timed(
        benchmark, tmp_path, runs, (), tree=tree_of(which)
    )
    wall = _seconds[key]
    other_key = f"{'this' if which == 'baseline' else 'baseline'}-{runs}"
    if other_key in _seconds:
        this_key = f"this-{runs}"
        base_key = f"baseline-{runs}"
        benchmark.extra_info["ratio_to_baseline"] = _seconds[this_key] / _seconds[base_key]
        benchmark.extra_info["cpu_ratio_to_baseline"] = (
            _seconds[f"cpu-{this_key}"] / _seconds[f"cpu-{base_key}"]
        )
    line = (
        f"\nhbench reproduce --runs {runs} ({which}): {wall:.2f} s wall, "
        f"{_seconds[f'cpu-{key}']:.2f} s CPU, "
        f"load average {benchmark.extra_info['load_average']:.1f}"
    )
    if which == "this":
        line += f" (target {TARGETS[runs]:g} s wall on the idle machine)"
    if "startup" in _seconds:
        line += f"; start-up {_seconds['startup']:.2f} s"
    if "ratio_to_baseline" in benchmark.extra_info:
        line += (
            f"; this/baseline: wall {benchmark.extra_info['ratio_to_baseline']:.2f}, "
            f"CPU {benchmark.extra_info['cpu_ratio_to_baseline']:.2f}"
        )
    print(line)


@pytest.mark.parametrize("runs", sorted(TARGETS))
@pytest.mark.parametrize("without", ["pdf", "figures"])
def test_reproduce_without(
    benchmark: BenchmarkFixture, tmp_path: Path, without: str, runs: int
) -> None:
    """``hbench reproduce --runs N`` with its PDFs, or every figure's drawing, left out
    (:mod:`benchmarks.without_figures`): what the command's figures cost of its time, beside
    ``test_reproduce[this-N]`` of the same run (``ratio_to_this``, wall and CPU)."""
    wall, cpu_mean = _timed(
        benchmark, tmp_path, runs, (without,), module="benchmarks.without_figures"
    )
    line = (
        f"\nhbench reproduce --runs {runs} without its {without}: {wall:.2f} s wall, "
        f"{cpu_mean:.2f} s CPU, load average {benchmark.extra_info['load_average']:.1f}"
    )
    if f"this-{runs}" in _seconds:
        benchmark.extra_info["ratio_to_this"] = wall / _seconds[f"this-{runs}"]
        benchmark.extra_info["cpu_ratio_to_this"] = cpu_mean / _seconds[f"cpu-this-{runs}"]
        line += (
            f"; over the whole command: wall {benchmark.extra_info['ratio_to_this']:.2f}, "
            f"CPU {benchmark.extra_info['cpu_ratio_to_this']:.2f}"
        )
    print(line)


@pytest.fixture(scope="module")
def channels(paper_scenario: Scenario) -> np.ndarray:
    """The SIMO channels ``W`` of 1000 runs' ``w = A(q) y`` (true A), full periods."""
    record, truth = simulate(paper_scenario, 1000, 0)
    a = np.broadcast_to(truth.plant.a, (record.runs, truth.plant.a.size))
    w = pp.filtered_output(record.y, np.ascontiguousarray(a))
    sys_ = pp.simo_system(w, record.p, 3, pp.first_valid(w))
    return sys_.W[:, np.all(sys_.valid, axis=1)]


@pytest.mark.parametrize("how", ["moments", "rows"])
def test_cross_relation_gram(benchmark: BenchmarkFixture, channels: np.ndarray, how: str) -> None:
    fn = cross_relation_gram if how == "moments" else rows_gram
    G = benchmark.pedantic(fn, args=(channels,), rounds=3, iterations=1, warmup_rounds=1)
    _seconds[f"gram-{how}"] = benchmark.stats.stats.mean
    if how == "rows":  # the same matrices
        ref = cross_relation_gram(channels)
        np.testing.assert_allclose(G, ref, rtol=0, atol=1e-12 * np.abs(ref).max())
        if "gram-moments" in _seconds:
            benchmark.extra_info["rows_over_moments"] = (
                _seconds["gram-rows"] / _seconds["gram-moments"]
            )

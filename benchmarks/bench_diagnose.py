"""Where ``hbench diagnose`` spends: the actuator maps of the class fits, compiled against the
numpy path, and a whole diagnosis on both, in the same run.

* ``test_actuator_maps[c|numpy]``: :func:`hbench.diagnose.core.stiction_batch` and
  :func:`hbench.diagnose.core.backlash_batch` of 200 candidates over 833 inputs (the paper
  loop's record length at the slow rate), on the compiled kernels and on the numpy path.
* ``test_diagnose_record[c|numpy]``: the diagnosis of one benchmark loop record (paper plant,
  stiction, no effect; every extension fitted) on both paths. The rows are the same on both
  (``tests/test_kernels.py``); the ratio of the means is what all the compiled kernels buy
  (the nominal's blind identification runs on them too).
* ``test_diagnose_cli[this|baseline]``: ``hbench diagnose`` of that record, written to a CSV,
  from the shell: this tree, and with ``HBENCH_BENCH_BASELINE`` set (another revision's source
  tree with its compiled kernels, as for ``bench_reproduce.py``) that tree in the same run; the
  later of the pair records ``ratio_to_baseline`` (wall) and ``cpu_ratio_to_baseline``.

The ratios are printed and kept in ``extra_info``.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from pytest_benchmark.fixture import BenchmarkFixture

from benchmarks.shell import hbench, tree_of
from hbench.diagnose import benchmark_cases as bc
from hbench.diagnose import core
from hbench.diagnose.validate import diagnose
from hbench.numerics import kernels

PATHS = ["c", "numpy"]
STICTION_CASE = (13060, "none", "stiction", "paper")
_seconds: dict[tuple[str, str], float] = {}


def _paired(benchmark: BenchmarkFixture, what: str, path: str) -> None:
    """Keep this path's mean; once both paths ran, print and keep their ratio."""
    _seconds[(what, path)] = benchmark.stats.stats.mean
    if all((what, p) in _seconds for p in PATHS):
        ratio = _seconds[(what, "numpy")] / _seconds[(what, "c")]
        benchmark.extra_info["speedup_of_kernels"] = ratio
        print(
            f"\n{what}: compiled {_seconds[(what, 'c')]:.3g} s, numpy "
            f"{_seconds[(what, 'numpy')]:.3g} s ({ratio:.2f}x)"
        )


def _backend(path: str) -> Any:
    if path == "c" and kernels.backend() != "c":
        pytest.skip(f"kernels not in use: {kernels.status()}")
    return kernels.use("auto" if path == "c" else "numpy")


@pytest.mark.parametrize("path", PATHS)
def test_actuator_maps(benchmark: BenchmarkFixture, path: str) -> None:
    rng = np.random.default_rng(0)
    x = np.cumsum(rng.standard_normal(833)) * 0.05
    S = rng.uniform(0.01, 0.5, 200)
    J = S * rng.uniform(0, 1, 200)

    def run() -> tuple[np.ndarray, np.ndarray]:
        return core.stiction_batch(x, S, J), core.backlash_batch(x, S)

    with _backend(path):
        out = benchmark.pedantic(run, rounds=5, iterations=1, warmup_rounds=1)
    assert out[0].shape == out[1].shape == (200, 833)
    _paired(benchmark, "actuator maps", path)


@pytest.fixture(scope="module")
def stiction_record() -> Any:
    return bc.simulate_bench_case(bc.draw_bench_case(*STICTION_CASE))


@pytest.mark.parametrize("path", PATHS)
def test_diagnose_record(benchmark: BenchmarkFixture, stiction_record: Any, path: str) -> None:
    with _backend(path):
        d = benchmark.pedantic(
            diagnose,
            args=(stiction_record,),
            kwargs={"extend_all": True},
            rounds=2,
            iterations=1,
        )
    assert d.nonlinearity["class"] in core.CLASSES
    _paired(benchmark, "diagnosis of one record", path)


@pytest.fixture(scope="module")
def stiction_csv(tmp_path_factory: pytest.TempPathFactory) -> Path:
    folder = tmp_path_factory.mktemp("diagnose")
    return bc.write_bench_case(bc.draw_bench_case(*STICTION_CASE), folder)


@pytest.mark.parametrize("which", ["this", "baseline"])
def test_diagnose_cli(
    benchmark: BenchmarkFixture, stiction_csv: Path, tmp_path: Path, which: str
) -> None:
    tree = tree_of(which)
    cpu: list[float] = []
    args = ("diagnose", str(stiction_csv), "--json", str(tmp_path / "d.json"))
    load = os.getloadavg()[0]
    benchmark.pedantic(hbench, args=args, kwargs={"tree": tree, "cpu": cpu}, rounds=2)
    assert (tmp_path / "d.json").exists()
    _seconds[("cli", which)] = benchmark.stats.stats.mean
    _seconds[("cli-cpu", which)] = sum(cpu) / len(cpu)
    benchmark.extra_info.update(load_average=max(load, os.getloadavg()[0]))
    if all(("cli", w) in _seconds for w in ("this", "baseline")):
        wall = _seconds[("cli", "this")] / _seconds[("cli", "baseline")]
        cpu_ratio = _seconds[("cli-cpu", "this")] / _seconds[("cli-cpu", "baseline")]
        benchmark.extra_info.update(ratio_to_baseline=wall, cpu_ratio_to_baseline=cpu_ratio)
        print(
            f"\nhbench diagnose: this {_seconds[('cli', 'this')]:.2f} s wall, baseline "
            f"{_seconds[('cli', 'baseline')]:.2f} s (ratio {wall:.2f}; CPU ratio {cpu_ratio:.2f}); "
            f"load average {benchmark.extra_info['load_average']:.1f}"
        )

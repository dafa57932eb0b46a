"""``hbench sweep``: the same 16-job sweep under the basic and the joblib launcher (n_jobs=2).

Run with ``.venv/bin/pytest benchmarks --benchmark-only -k bench_sweep``. The joblib case records
``speedup`` = basic time / joblib time (the fastest of :data:`ROUNDS` rounds each) in
``extra_info``. Each job is heavy enough (the paper's 500 s record, 4 methods, 3000 runs: about
6 s of work) that the per-job Hydra overhead (~0.4 s, paid by both launchers) and the start-up
of the worker processes (~3 s, joblib only) do not dominate. The whole ``hbench sweep`` command
is timed in a fresh process, as a user runs it.

Both runs use one BLAS thread per process (``OPENBLAS_NUM_THREADS=1``), which is what joblib's
loky workers get on their own (it caps them at cores / n_jobs): the ratio then measures the
launcher, not BLAS. With the default threads the basic launcher already spreads the batched
matrix products of the simulation over both cores (about 20 % faster per job), which caps the
joblib speed-up near 1.6x on 2 cores.

What the launcher controls and what the machine does are told apart. The speed-up is the product of
two factors, both recorded in ``extra_info``: ``cores_busy``, the CPU seconds of the joblib sweep
(its process and its workers) per wall second, which is how well the launcher keeps two workers fed
(start-up, the Hydra overhead in the parent and the last job's tail cost it), and ``cpu_ratio``, the
basic sweep's CPU seconds over the joblib sweep's for the same work, which is how much slower each
process computes while another runs beside it (shared caches, memory bandwidth, and on this shared
virtual machine the host's other tenants, which no counter inside it shows). The checks are on
the launcher: joblib keeps at least 1.5 cores busy (a launcher that ran the jobs one after
another keeps ~1) and is faster than basic at all; the speed-up itself is reported, not
asserted, since the machine's factor moves by a quarter between runs. Current figures:
``docs/performance.md`` (section "Sweep launchers").
"""

from __future__ import annotations

import importlib.util
import itertools
import os
import subprocess
import sys
import time
from pathlib import Path

import pandas as pd
import pytest
from pytest_benchmark.fixture import BenchmarkFixture

#: 2 x 2 x 2 x 2 = 16 jobs.
SWEEP = (
    "noise.snr=5,20",
    "scenario.p=4,5",
    "plant.delay=2,7",
    "nonlinearity=backlash,stiction",
    "methods=[wang-lsm,wang-iv,bai-fu,sun-liu-sano]",
    "runs=3000",
)
LAUNCHERS = {
    "basic": (),
    "joblib": ("hydra/launcher=joblib", "hydra.launcher.n_jobs=2"),
}
#: Rounds per launcher; the speed-up compares the fastest of each (this shared machine's speed
#: varies by ~20 % from minute to minute, which a single round each turned into 1.15-1.56x).
ROUNDS = 2
_counter = itertools.count()


ONE_THREAD = {k: "1" for k in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")}
_runs: dict[str, dict[str, float]] = {}


def _busy_seconds() -> float:
    """CPU seconds spent by the whole machine (all processes) so far, from /proc/stat."""
    try:
        fields = Path("/proc/stat").read_text().split("\n", 1)[0].split()[1:]
    except OSError:
        return float("nan")
    user, nice, system, _idle, _iowait, irq, softirq = (int(v) for v in fields[:7])
    return (user + nice + system + irq + softirq) / os.sysconf("SC_CLK_TCK")


def _sweep(out: Path, launcher: str) -> int:
    argv = [
        sys.executable,
        "-m",
        "hbench.cli",
        "sweep",
        "-m",
        *SWEEP,
        *LAUNCHERS[launcher],
        f"out={out}",
    ]
    busy0, own0 = _busy_seconds(), _children_seconds()
    t0 = time.perf_counter()
    proc = subprocess.run(argv, capture_output=True, text=True, env={**os.environ, **ONE_THREAD})
    wall = time.perf_counter() - t0
    assert proc.returncode == 0, proc.stderr[-2000:]
    own = _children_seconds() - own0
    # cores' worth of CPU used by other processes meanwhile: a busy machine hides the speed-up
    foreign = max(0.0, (_busy_seconds() - busy0 - own) / wall)
    prev = _runs.get(launcher)
    if prev is None or wall < prev["wall"]:  # the fastest round, and the busiest machine seen
        _runs[launcher] = {"wall": wall, "cpu": own, "foreign_cores": foreign}
    _runs[launcher]["foreign_cores"] = max(foreign, _runs[launcher]["foreign_cores"])
    return proc.returncode


def _children_seconds() -> float:
    import resource

    ru = resource.getrusage(resource.RUSAGE_CHILDREN)
    return ru.ru_utime + ru.ru_stime


@pytest.mark.parametrize("launcher", list(LAUNCHERS))
def test_sweep_16_jobs(benchmark: BenchmarkFixture, tmp_path: Path, launcher: str) -> None:
    if (
        launcher == "joblib"
        and importlib.util.find_spec("hydra_plugins.hydra_joblib_launcher") is None
    ):
        pytest.skip("needs the joblib extra")

    def setup() -> tuple[tuple[Path, str], dict[str, object]]:
        return (tmp_path / f"round{next(_counter)}", launcher), {}  # a fresh folder: no resume

    status = benchmark.pedantic(_sweep, setup=setup, rounds=ROUNDS, iterations=1)
    assert status == 0
    out = max(tmp_path.iterdir(), key=lambda p: p.stat().st_mtime)
    assert len(pd.read_csv(out / "fitness.csv")) == 16 * 4
    benchmark.extra_info.update(
        launcher=launcher, jobs=16, cores=os.cpu_count(), blas_threads=1, **_runs[launcher]
    )
    if launcher == "joblib" and "basic" in _runs:
        basic, joblib = _runs["basic"], _runs["joblib"]
        speedup = basic["wall"] / joblib["wall"]  # the fastest round of each
        cores_busy = joblib["cpu"] / joblib["wall"]  # the launcher's factor
        cpu_ratio = basic["cpu"] / joblib["cpu"]  # the machine's: speedup = cores_busy x this
        foreign = max(basic["foreign_cores"], joblib["foreign_cores"])
        benchmark.extra_info.update(
            speedup=speedup,
            basic_seconds=basic["wall"],
            cores_busy=cores_busy,
            cpu_ratio=cpu_ratio,
            max_foreign_cores=foreign,
        )
        print(
            f"\nsweep speed-up joblib(n_jobs=2) vs basic: {speedup:.2f}x = {cores_busy:.2f} "
            f"cores kept busy x {cpu_ratio:.2f} (one process's CPU per job over two's) "
            f"(other processes used up to {foreign:.2f} cores meanwhile)"
        )
        if (os.cpu_count() or 1) >= 2 and foreign < 0.2:  # only on an otherwise idle machine
            assert speedup > 1.0, f"joblib is slower than the basic launcher: {speedup:.2f}x"
            assert cores_busy > 1.5, f"joblib keeps only {cores_busy:.2f} of 2 cores busy"

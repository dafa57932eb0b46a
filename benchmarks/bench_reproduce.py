"""``hbench reproduce`` with its defaults, timed from the shell as a user runs it (issue 7).

Target: under 10 s wall, start-up included (100 runs x 6 noise levels x 7 methods, every table,
Figures 4 and 5 and the report). ``test_cli_startup`` times ``hbench --help`` in the same session:
the share of the budget that is the interpreter and imports rather than work.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

from pytest_benchmark.fixture import BenchmarkFixture

_seconds: dict[str, float] = {}


def _hbench(*args: str) -> subprocess.CompletedProcess[str]:
    proc = subprocess.run(
        [sys.executable, "-m", "hbench.cli", *args],
        capture_output=True,
        text=True,
        env=dict(os.environ),
    )
    assert proc.returncode == 0, proc.stderr[-2000:]
    return proc


def test_cli_startup(benchmark: BenchmarkFixture) -> None:
    benchmark.pedantic(_hbench, args=("--help",), rounds=3, iterations=1)
    _seconds["startup"] = benchmark.stats.stats.mean


def test_reproduce_defaults(benchmark: BenchmarkFixture, tmp_path: Path) -> None:
    counter = iter(range(100))

    def setup():
        return (("reproduce", "--out", str(tmp_path / f"r{next(counter)}")),), {}

    def run(args):
        return _hbench(*args)

    proc = benchmark.pedantic(run, setup=setup, rounds=2, iterations=1)
    assert "scored cells" in proc.stdout
    wall = benchmark.stats.stats.mean
    benchmark.extra_info.update(wall_seconds=wall, target_seconds=10.0)
    if "startup" in _seconds:
        share = _seconds["startup"] / wall
        benchmark.extra_info["startup_share"] = share
        print(
            f"\nhbench reproduce: {wall:.1f} s wall (target 10 s); start-up "
            f"{_seconds['startup']:.2f} s = {100 * share:.0f} %"
        )

"""The command line of the experiment scripts that run over a benchmark grid:
``START PER_CELL PLANTS [--jobs N]``, as ``python -m hbench.diagnose.calibrate bench``'s
``--start``, ``--per-cell`` and ``--plants`` (``hbench.diagnose.benchmark_cases.bench_grid``)."""

from __future__ import annotations

import argparse

from hbench.diagnose import benchmark_cases as bc


def parse(description: str) -> tuple[list[bc.BenchCase], int]:
    """``(the grid's cases, --jobs)`` from ``sys.argv``; ``description`` heads ``--help``."""
    ap = argparse.ArgumentParser(description=description)
    ap.add_argument("start", type=int)
    ap.add_argument("per_cell", type=int)
    ap.add_argument("plants")
    ap.add_argument("--jobs", type=int, default=2)
    args = ap.parse_args()
    return list(bc.bench_grid(args.start, args.per_cell, tuple(args.plants.split(",")))), args.jobs

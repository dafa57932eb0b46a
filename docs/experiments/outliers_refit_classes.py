"""The outliers extension's class sets (``extension-classes.md``, section 2): every
``outliers`` record of the calibration seeds named there, diagnosed with every extension fitted
under each value of ``Outliers.REFIT_CLASSES`` given on the command line (default: ``nominal
all both``). Prints the counts per setting and the records whose class or cause differs.

    MPLBACKEND=Agg python docs/experiments/outliers_refit_classes.py nominal all both
"""

from __future__ import annotations

import sys
import warnings

from hbench.diagnose import benchmark_cases as bc
from hbench.diagnose import calibrate, effects

OTHERS = ("first-order", "third-order", "nmp")


def cases() -> list[bc.BenchCase]:
    """The 55 records: the grids' ``outliers`` records and 30 more (calibration seeds)."""
    out = [c for c in bc.bench_grid(13000, 2, ("paper",)) if c.effect == "outliers"]
    out += [c for c in bc.bench_grid(11000, 1, OTHERS) if c.effect == "outliers"]
    out += bc.bench_grid(14000, 3, ("paper",), effects=("outliers",))
    return out + bc.bench_grid(14100, 1, OTHERS, effects=("outliers",))


def main(settings: list[str]) -> None:
    warnings.simplefilter("ignore")
    calibrate.OPTIONS["extend_all"] = True
    todo = cases()
    rows = {}
    for v in settings:  # the workers fork after the switch is set
        effects.Outliers.REFIT_CLASSES = v
        rows[v] = calibrate.run(todo, jobs=2)
        r = rows[v]
        print(
            f"{v}: class {sum(x['found_cls'] == x['cls'] for x in r)}, "
            f"cause {sum(x['cause'] == 'outliers' for x in r)}, "
            f"gain > 0 {sum((x.get('gain') or 0) > 0 for x in r)} of {len(r)}, "
            f"seconds {sum(x.get('seconds', 0) for x in r):.0f}",
            flush=True,
        )
    for rs in zip(*(rows[v] for v in settings), strict=True):
        if len({(x["found_cls"], x["cause"]) for x in rs}) > 1:
            said = " | ".join(
                f"{v} {x['found_cls']} {x['cause']} {x.get('gain') or 0:.1f}"
                for v, x in zip(settings, rs, strict=True)
            )
            print(rs[0]["seed"], rs[0]["plant"], rs[0]["cls"], ":", said)


if __name__ == "__main__":
    main(sys.argv[1:] or ["nominal", "all", "both"])

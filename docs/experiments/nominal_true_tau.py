"""``nominal-order-by-simulation.md``, section 4: the diagnosis with the blind route's fractional
delay ``tau`` given as the plant's, on the records of a benchmark grid whose structure selection
reads another (an upper bound on what a better reading of ``tau`` could gain).

    python docs/experiments/nominal_true_tau.py START PER_CELL PLANTS [--jobs 2]

(the grid as ``python -m hbench.diagnose.calibrate bench``'s options). For every record it
prints the selection's ``tau`` on the fit part (as the nominal's blind method reads it) and the
plant's (its discrete delay modulo ``p``); where they differ, the diagnosis as it is and with
``tau`` given in every blind identification of the diagnosis (the nominal's and the
extensions'), and per plant the causes and classes right both ways. The script replaces
``hbench.diagnose.nominal.IdentifyOptions`` in its own process (and the workers forked from it)
to give ``tau``; nothing in the package changes.
"""

from __future__ import annotations

from typing import Any

import grid_args
import numpy as np

from hbench.diagnose import benchmark_cases as bc
from hbench.diagnose import calibrate
from hbench.diagnose import nominal as nm
from hbench.ident.identifiers import IdentifyOptions
from hbench.ident.selection import bias_compensated_fit, select_structure

#: The tau given to every blind identification of the current record (None: selected).
GIVEN: dict[str, int | None] = {"tau": None}


def options_with_tau(*args: Any, **kwargs: Any) -> IdentifyOptions:
    """``IdentifyOptions(*args, **kwargs)`` with ``tau`` given as :data:`GIVEN`'s (when set and
    the caller gives none)."""
    if GIVEN["tau"] is not None and kwargs.get("tau") is None:
        kwargs["tau"] = GIVEN["tau"]
    return IdentifyOptions(*args, **kwargs)


def taus(case: bc.BenchCase) -> tuple[int, int]:
    """(the selection's tau on the fit part, the plant's tau)."""
    dp = bc._scenario(case, bc.case_plant(case), {"name": "linear"}).discrete_plant
    ctx = nm.make_context(bc.simulate_bench_case(case))
    part = ctx.part(0, ctx.k_fit)
    opts = IdentifyOptions(nb_max=int(min(3, ctx.p - 1)), na_range=nm.NA_NOMINAL)
    st = select_structure(part.y, part.p, opts, bias_compensated_fit)
    return int(st.tau[0]), int(dp.delay) % case.p


def both(item: tuple[bc.BenchCase, int]) -> tuple[dict[str, Any], dict[str, Any]]:
    case, tau = item
    GIVEN["tau"] = None
    before = calibrate.run_case(case)
    GIVEN["tau"] = tau
    after = calibrate.run_case(case)
    GIVEN["tau"] = None
    return before, after


def main() -> None:
    cases, jobs = grid_args.parse(__doc__.split("\n\n")[0])
    nm.IdentifyOptions = options_with_tau  # this process and its forked workers only
    read = calibrate.parallel_map(taus, cases, jobs)
    wrong = [(c, t) for c, (s, t) in zip(cases, read, strict=True) if s != t]
    for c, (s, t) in zip(cases, read, strict=True):
        print(f"{c.seed} {c.plant} p={c.p} {c.cls}/{c.effect}: selected tau {s}, plant's {t}")
    rows = calibrate.parallel_map(both, wrong, jobs)
    total: dict[str, np.ndarray] = {}
    for (case, _), (b, a) in zip(wrong, rows, strict=True):
        print(
            f"{case.seed} {case.plant} {case.cls}/{case.effect}: cause {b['cause']} -> "
            f"{a['cause']}, class {b['found_cls']} -> {a['found_cls']}"
        )
        t = total.setdefault(case.plant, np.zeros(5, int))
        t += [
            1,
            b["cause"] == case.effect,
            a["cause"] == case.effect,
            b["found_cls"] == case.cls,
            a["found_cls"] == case.cls,
        ]
    for plant, (n, cb, ca, kb, ka) in total.items():
        print(
            f"{plant}: {n} records with tau read wrong; cause right {cb} -> {ca}, "
            f"class {kb} -> {ka}"
        )


if __name__ == "__main__":
    main()

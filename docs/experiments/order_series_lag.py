"""The series-lag test of ``order-effect.md`` section 4 (measured, not adopted).

For each benchmark loop record of a calibration grid: the nominal model's dynamics times one
(or two equal) first-order lags ``(1 - c) / (1 - c q^-1)`` (DC gain kept), ``c`` by a grid and a
bounded search on the fit part's simulation RSS, the output scale, offset and start-up transient
refitted by least squares (:func:`hbench.diagnose.core.fit_output`). Prints per record the best
``c``, the validation-fit gain over the nominal (simulation criterion) and the fit-part
``dBIC = n log(RSS_lag / RSS_nominal) + k log n`` (k lags).

    python docs/experiments/order_series_lag.py 11000 1 first-order,third-order,nmp
    python docs/experiments/order_series_lag.py 13000 2 paper
"""

from __future__ import annotations

import sys

import numpy as np
from scipy.optimize import minimize_scalar

from hbench.diagnose import benchmark_cases as bc
from hbench.diagnose import core
from hbench.diagnose import nominal as nm
from hbench.diagnose.validate import val_fit


def lagged(model: core.Model, cs: list[float]) -> core.Model:
    a, b = model.lin.a, model.lin.b
    for c in cs:
        a, b = np.convolve(a, [1.0, -c]), b * (1.0 - c)
    return model.with_(lin=core.Linear(a=a, b=b, delay=model.lin.delay))


def run(case: bc.BenchCase) -> str:
    ctx = nm.make_context(bc.simulate_bench_case(case))
    nom = nm.fit_nominal(ctx, "wang-lsm", 0)
    base, idx, n = val_fit(ctx, nom.model), ctx.fit_idx, ctx.fit_idx.size

    def rss(cs: list[float]) -> tuple[float, core.Model]:
        m = core.fit_output(lagged(nom.model, cs), ctx.x, ctx.y, idx)
        return float(np.sum((ctx.y - m.simulate(ctx.x))[idx] ** 2)), m

    r0 = rss([])[0]
    out = []
    for k in (1, 2):
        grid = np.linspace(0.0, 0.99, 34)
        c0 = grid[int(np.argmin([rss([c] * k)[0] for c in grid]))]
        c = minimize_scalar(
            lambda c, k=k: rss([c] * k)[0],
            bounds=(max(0.0, c0 - 0.03), min(0.995, c0 + 0.03)),
            method="bounded",
        ).x
        r, m = rss([c] * k)
        dbic = n * np.log(r / r0) + k * np.log(n)
        out.append(f"lag{k} c {c:.3f} gain {val_fit(ctx, m) - base:6.1f} dBIC {dbic:8.1f}")
    return f"{case.seed} {case.plant} p={case.p} {case.effect} {case.cls} | " + " | ".join(out)


if __name__ == "__main__":
    start, per, plants = int(sys.argv[1]), int(sys.argv[2]), tuple(sys.argv[3].split(","))
    for case in bc.bench_grid(start, per, plants):
        print(run(case), flush=True)

"""``order-effect.md``, section 6: what the ``order`` records of a benchmark grid show of their
missing pole when the valve's output is known (the oracle), beside the records without an
effect.

    python docs/experiments/order_oracle.py START PER_CELL PLANTS [--jobs 2]

(the grid as ``python -m hbench.diagnose.calibrate bench``'s options). For every ``order`` record
and every record without an effect, with the true inner signal ``U`` (the Truth's valve on the
record's ``x``, held over each slow period) and the measured ``y``, validation simulation fit
(%) of:

* the true plant (the extra lag included) simulated from ``U`` from rest, the output gain and
  offset by least squares on the fit part;
* the best output-error model (``core.oe_fit``, the variable-projection refinement) with two
  poles and with three, fitted on the fit part from ``U``: ``nb`` of ``na`` or ``na + 1``, every
  delay ``0 .. 4 p``, two poles from the least-squares start, three poles from it and from the
  two-pole model's poles with a pole at 0.9 or 0.7 added; the fit with the smallest fit-part
  residual is kept.

The three-pole fit's gain over the two-pole fit is what one pole more is worth on the
diagnosis's criterion when nothing but the plant's order is wrong; per plant and effect the
script prints its median and the records where it reaches 2 points, and the same of the true
plant's fit over the two-pole fit.
"""

from __future__ import annotations

from typing import Any

import grid_args
import numpy as np
from scipy import signal

from hbench.diagnose import benchmark_cases as bc
from hbench.diagnose import calibrate, core
from hbench.diagnose import nominal as nm
from hbench.diagnose.class_ceiling import true_inner


def true_plant_fit(case: bc.BenchCase, ctx: nm.Context, u: np.ndarray) -> float:
    """The true plant (the extra lag included) simulated from ``u`` from rest, as the record's
    loop starts, the output gain and offset by least squares on the fit part."""
    dp = bc._scenario(case, bc.case_plant(case), {"name": "linear"}).discrete_plant
    z = signal.lfilter(dp.num, dp.den, u)
    X = np.column_stack([z, np.ones_like(z)])
    coef = np.linalg.lstsq(X[ctx.fit_idx], ctx.y[ctx.fit_idx], rcond=None)[0]
    return core.fit_percent(ctx.y[ctx.val_idx], (X @ coef)[ctx.val_idx])


def best_oe(ctx: nm.Context, u: np.ndarray, na: int, starts: list[np.ndarray | None]) -> core.OEFit:
    """The output-error model with ``na`` poles of smallest fit-part residual over ``nb`` in
    ``na .. na + 1``, every delay ``0 .. 4 p`` and the denominators ``starts`` (None: the
    least-squares start), each refined by variable projection."""
    best: core.OEFit | None = None
    for d in range(0, 4 * ctx.p + 1):
        for nb in (na, na + 1):
            for a0 in starts:
                f = core.oe_fit(u, ctx.y, na, nb, d, ctx.fit_idx, a_init=a0, refine=True)
                if np.isfinite(f.rss) and (best is None or f.rss < best.rss):
                    best = f
    assert best is not None
    return best


def one(case: bc.BenchCase) -> dict[str, Any]:
    ctx = nm.make_context(bc.simulate_bench_case(case))
    u = np.repeat(true_inner(case, ctx.x), ctx.p)
    two = best_oe(ctx, u, 2, [None])
    a2 = np.asarray(two.lin.a, float)
    three = best_oe(ctx, u, 3, [None, np.convolve(a2, [1.0, -0.9]), np.convolve(a2, [1.0, -0.7])])
    val = ctx.val_idx
    return {
        "case": case,
        "true": true_plant_fit(case, ctx, u),
        "two": core.fit_percent(ctx.y[val], two.yhat[val]),
        "three": core.fit_percent(ctx.y[val], three.yhat[val]),
        "delay": int(two.lin.delay),
    }


def main() -> None:
    grid, jobs = grid_args.parse(__doc__.split("\n\n")[0])
    cases = [c for c in grid if c.effect in ("order", "none")]
    rows = calibrate.parallel_map(one, cases, jobs)
    gains: dict[tuple[str, str], list[tuple[float, float]]] = {}
    for r in rows:
        c = r["case"]
        gain = r["three"] - r["two"]
        gains.setdefault((c.plant, c.effect), []).append((gain, r["true"] - r["two"]))
        print(
            f"{c.seed} {c.plant} {c.cls}/{c.effect} p={c.p}: true plant {r['true']:.1f}, "
            f"two poles {r['two']:.1f} (delay {r['delay']}), three poles {r['three']:.1f}: "
            f"third pole worth {gain:+.1f}"
        )
    for (plant, effect), pairs in sorted(gains.items()):
        g, t = (np.array(v) for v in zip(*pairs, strict=True))
        print(
            f"{plant} {effect}: {len(g)} records; third pole worth >= 2 points on "
            f"{int(np.sum(g >= 2.0))}, median {np.median(g):+.1f}, range {g.min():+.1f} to "
            f"{g.max():+.1f}; the true plant over two poles >= 2 points on "
            f"{int(np.sum(t >= 2.0))}, median {np.median(t):+.1f}"
        )


if __name__ == "__main__":
    main()

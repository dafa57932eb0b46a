"""Where the valve class is lost on the benchmark's loops: the class chooser with more known.

For each record of :mod:`hbench.diagnose.benchmark_cases` the class is chosen four ways, each
by the rules of :func:`hbench.diagnose.nominal.choose_graph` on half BIC differences:

* ``true-graph``: on the graph of the true inner signal ``(x, U)`` (the Truth's valve output),
  :func:`hbench.diagnose.classes.fit_graph`;
* ``true-dynamics``: by equation error with the record's true linear part ``B / A`` and delay
  (only the valve's parameters, a gain and an offset fitted):
  ``A(q) y(t) = c B(q) f(x; theta)(t - d) + m + w(t)`` (:func:`known_dynamics_classes`);
* ``blind-graph``: on the graph of the blind estimate of ``U`` (the nominal's starting point);
* ``blind``: the nominal model's class as :func:`hbench.diagnose.nominal.fit_nominal` chooses.

``python -m hbench.diagnose.class_ceiling --start 10000 --per-cell 1`` prints the class right per
chooser, per true class, per noise level and per parameter size (calibration seeds only).
"""

from __future__ import annotations

import argparse
import collections
import json
import sys
from collections.abc import Sequence
from typing import Any

import numpy as np
from scipy import signal

from hbench.diagnose import benchmark_cases as bc
from hbench.diagnose import classes, core
from hbench.diagnose import nominal as nm

CHOOSERS: tuple[str, ...] = ("true-graph", "true-dynamics", "blind-graph", "blind")


def true_inner(case: bc.BenchCase, x: np.ndarray) -> np.ndarray:
    """The valve output ``U`` of ``case`` for the controller output ``x`` (the Truth's)."""
    sc = bc._scenario(case, bc.case_plant(case), bc._nl_spec(case))
    nl = sc.nonlinearity
    state = nl.initial_state(1)
    U = np.empty(x.size)
    for k in range(x.size):
        u, state = nl.step(np.array([x[k]]), state)
        U[k] = float(np.asarray(u).ravel()[0])
    return U


def known_dynamics_classes(
    x: np.ndarray, y: np.ndarray, p: int, idx: np.ndarray, a: np.ndarray, b: np.ndarray, delay: int
) -> dict[str, classes.ClassFit]:
    """Every class fitted by equation error with the linear part known.

    ``w = A(q) y - c z - m`` with ``z = q^-delay B(q) f(x; theta)`` (fast rate, ``f`` held over
    the ``p`` fast samples of each slow one); ``c, m`` by least squares for every candidate,
    ``theta`` on the coarse grid then three fine passes. Scores ``(BIC_linear - BIC) / 2`` with
    ``k = 2 + N_SHAPE``.
    """
    ya = signal.lfilter(a, [1.0], y)[idx]
    bb = np.concatenate([np.zeros(delay + 1), b])

    def rss_of(params: dict[str, np.ndarray], cls: str) -> np.ndarray:
        F = core.nl_batch(cls, x, params)
        F = np.repeat(F, p, axis=1) if p > 1 else F
        Z = signal.lfilter(bb, [1.0], F, axis=1)[:, idx]
        Zm = Z - Z.mean(axis=1, keepdims=True)
        ym = ya - ya.mean()
        szz = np.einsum("cn,cn->c", Zm, Zm)
        return np.maximum(ym @ ym - (Zm @ ym) ** 2 / np.maximum(szz, 1e-300), 0.0)

    out: dict[str, classes.ClassFit] = {}
    n = idx.size
    for cls in core.CLASSES:
        if cls == "linear":
            theta: dict[str, float] = {}
            rss = float(rss_of({}, cls)[0])
        else:
            params = classes.coarse_grid(cls, x)
            r = rss_of(params, cls)
            theta, rss = classes._take(params, int(np.argmin(r))), float(r.min())
            for spread in (1.0, 1.0, 0.2):
                fp = classes.fine_grid(cls, x, theta, spread)
                r = rss_of(fp, cls)
                if r.min() < rss:
                    theta, rss = classes._take(fp, int(np.argmin(r))), float(r.min())
        out[cls] = classes.ClassFit(
            cls,
            theta,
            rss,
            n,
            2 + core.N_SHAPE[cls],
            info=classes.shape_info(cls, theta, x),
        )
    return classes.score_against_linear(out)


def size_of(case: bc.BenchCase, x: np.ndarray) -> float:
    """The valve's parameter in units of the paper loop's x range (the issue's scale)."""
    lo, hi = np.percentile(x, [1, 99])
    scale = float(hi - lo) / bc.R_X_PAPER
    q = case.nl_params
    if case.cls == "backlash":
        return q["d"] / scale
    if case.cls == "deadband":
        return (q["d1"] + q["d2"]) / scale
    if case.cls == "stiction":
        return q["S"] / scale
    if case.cls == "saturation":
        return float(np.mean((x < q["u_min"]) | (x > q["u_max"])))
    return 0.0


#: ``run_one`` fits only the blind chooser when this is set (``--blind-only``).
OPTIONS: dict[str, bool] = {"blind_only": False}


def run_one(case: bc.BenchCase) -> dict[str, Any]:
    """The four choosers' classes on ``case``'s record (the blind one only with
    ``OPTIONS["blind_only"]``; the others then read ``n/a``)."""
    rec = bc.simulate_bench_case(case)
    ctx = nm.make_context(rec)
    U = true_inner(case, ctx.x)
    row: dict[str, Any] = {
        "seed": case.seed,
        "plant": case.plant,
        "cls": case.cls,
        "effect": case.effect,
        "p": case.p,
        "sigma2": case.sigma2,
        "size": size_of(case, ctx.x),
    }
    for ch in CHOOSERS:
        row[ch] = "n/a"
    if not OPTIONS["blind_only"]:
        _known(case, ctx, U, row)
    try:
        nom = nm.fit_nominal(ctx)
        row["blind"] = nom.chosen
        row["blind-graph"] = nm.choose_graph(nom.model.info["graph_fits"])
        row["scores"] = nom.scores
        row["fits"] = {
            c: {"score": f.score, "strength": f.info.get("strength"), "theta": f.theta}
            for c, f in nom.class_fits.items()
        }
    except Exception as exc:  # a record the blind route refuses counts as wrong
        row["blind"] = row["blind-graph"] = "error"
        row["error"] = str(exc)
    return row


def _known(case: bc.BenchCase, ctx: nm.Context, U: np.ndarray, row: dict[str, Any]) -> None:
    kf = ctx.k_fit
    row["true-graph"] = nm.choose_graph(classes.fit_graph(ctx.x[:kf], U[:kf]))
    dp = bc._scenario(case, bc.case_plant(case), {"name": "linear"}).discrete_plant
    fits = known_dynamics_classes(
        ctx.x[:kf],
        ctx.y[: kf * ctx.p],
        ctx.p,
        np.arange(len(dp.a) + 40, kf * ctx.p),
        np.asarray(dp.a),
        np.asarray(dp.b),
        int(dp.delay),
    )
    row["true-dynamics"] = nm.choose_graph(fits)


def summary(rows: list[dict[str, Any]]) -> str:
    """Class right per chooser, per true class, per noise decade and per parameter size."""
    out = ["chooser        all   " + "  ".join(f"{c[:9]:>9s}" for c in core.CLASSES)]
    for ch in CHOOSERS:
        per = [sum(r[ch] == r["cls"] for r in rows if r["cls"] == c) for c in core.CLASSES]
        tot = [sum(r["cls"] == c for r in rows) for c in core.CLASSES]
        out.append(
            f"{ch:13s} {sum(per):3d}/{len(rows):3d} "
            + "  ".join(f"{a:4d}/{b:<4d}" for a, b in zip(per, tot, strict=True))
        )
    out.append("\nwithout an effect only:")
    sub = [r for r in rows if r["effect"] == "none"]
    for ch in CHOOSERS:
        out.append(f"  {ch:13s} {sum(r[ch] == r['cls'] for r in sub):3d}/{len(sub)}")
    out.append("\nper noise decade (sigma^2 <1e-3, >=1e-3): right / records")
    for ch in CHOOSERS:
        lo = [r for r in rows if r["sigma2"] < 1e-3]
        hi = [r for r in rows if r["sigma2"] >= 1e-3]
        out.append(
            f"  {ch:13s} {sum(r[ch] == r['cls'] for r in lo):3d}/{len(lo):3d}"
            f"  {sum(r[ch] == r['cls'] for r in hi):3d}/{len(hi):3d}"
        )
    out.append("\nper class and parameter size (lower / upper half of its range): right / records")
    for c in core.CLASSES[1:]:
        sub = [r for r in rows if r["cls"] == c]
        if not sub:
            continue
        med = float(np.median([r["size"] for r in sub]))
        for ch in CHOOSERS:
            lo = [r for r in sub if r["size"] < med]
            hi = [r for r in sub if r["size"] >= med]
            out.append(
                f"  {c:10s} {ch:13s} size<{med:.3f}: {sum(r[ch] == c for r in lo):3d}/{len(lo):3d}"
                f"  >=: {sum(r[ch] == c for r in hi):3d}/{len(hi):3d}"
            )
    out.append("\nconfusions (true -> found), per chooser")
    for ch in CHOOSERS:
        cnt = collections.Counter((r["cls"], r[ch]) for r in rows if r[ch] != r["cls"])
        out.append(f"  {ch}: " + ", ".join(f"{a}->{b} {n}" for (a, b), n in cnt.most_common()))
    return "\n".join(out)


def main(argv: Sequence[str] | None = None) -> int:
    """Run the four choosers on a grid of calibration cases and print :func:`summary`."""
    from hbench.diagnose.calibrate import parallel_map

    ap = argparse.ArgumentParser(prog="python -m hbench.diagnose.class_ceiling")
    ap.add_argument("--start", type=int, default=bc.CALIBRATION_SEEDS.start)
    ap.add_argument("--per-cell", type=int, default=1)
    ap.add_argument("--plants", default=",".join(bc.BENCH_PLANTS))
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--json", default=None)
    ap.add_argument("--blind-only", action="store_true", help="the blind chooser only")
    args = ap.parse_args(argv)
    OPTIONS["blind_only"] = bool(args.blind_only)
    cases = bc.bench_grid(args.start, args.per_cell, tuple(args.plants.split(",")))
    rows = parallel_map(run_one, cases, args.jobs)
    print(summary(rows))
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(rows, fh, default=float)
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())

"""The experiment of ``coloured-noise-class.md``: the valve class on the paper loop's
coloured-noise records, under variants of the record and of the chooser.

Calibration seeds 17000-17005, each with every valve class (30 records of the paper loop's
``colored-noise`` cell of :func:`hbench.diagnose.benchmark_cases.draw_bench_case`; the same
seeds' ``none`` records where a variant's cost is measured). Prints one Markdown row per
variant: the class right, and how many records were called ``backlash``; then the number of
poles the blind model and the class comparison's structure take on the records as generated.

    python docs/experiments/coloured_noise_class.py [--jobs 2]

Takes about 12 minutes on two cores (13-14 CPU minutes).
"""

from __future__ import annotations

import argparse
from collections import Counter
from concurrent.futures import ProcessPoolExecutor
from dataclasses import replace
from typing import Any

import numpy as np
from scipy import signal

from hbench.diagnose import benchmark_cases as bc
from hbench.diagnose import classes
from hbench.diagnose import generator as gen
from hbench.diagnose import nominal as nm
from hbench.diagnose.validate import diagnose
from hbench.sim.records import Record

SEEDS = range(17000, 17006)

#: name -> (effect of the records, what changes, in words)
VARIANTS: dict[str, tuple[str, str]] = {
    "as generated": ("colored-noise", "the benchmark's records"),
    "outside the loop": ("colored-noise", "the same noise added to y after the loop"),
    "d1 = 0": ("colored-noise", "the noise's pole at 0: white noise through 1 + c1 q^-1"),
    "d1 = 0.5": ("colored-noise", "the noise's pole at 0.5"),
    "prewhitening AR(30)": ("colored-noise", "the class fits' prewhitener of order 30"),
    "prewhitening AR(150)": ("colored-noise", "the class fits' prewhitener of order 150"),
    "at least two poles": ("colored-noise", "the class comparison's structure with na >= 2"),
    "output error": ("colored-noise", "classes by output error in the nominal's structure"),
    "Box-Jenkins, AR(8) noise": (
        "colored-noise",
        "classes by prediction error, noise 1 / D with D an AR(8) of the nominal's residual",
    ),
    "none: as generated": ("none", "the same seeds without an effect"),
    "none: nominal noise x 10": ("none", "the nominal noise (e / A) ten times larger"),
    "none: at least two poles": ("none", "the class comparison's na >= 2, no effect"),
    "none: output error": ("none", "classes by output error, no effect"),
    "none: Box-Jenkins, AR(8) noise": ("none", "classes by prediction error, no effect"),
}


def record(case: bc.BenchCase, d1: float | None = None, outside: bool = False) -> Record:
    """The record of ``case``, with the coloured noise's pole set to ``d1`` (the benchmark's
    own simulation with that pole: the same noise stream) or the noise added after the loop
    (the controller does not see it; the noise drawn as
    :func:`hbench.diagnose.benchmark_cases.simulate_bench_case` draws it)."""
    if d1 is not None:
        case = replace(case, effect_params={**case.effect_params, "d1": d1})
    if case.effect != "colored-noise" or not outside:
        return bc.simulate_bench_case(case)
    rng = np.random.default_rng(np.random.SeedSequence([20261128, case.seed]))
    ep = case.effect_params
    sc = bc._scenario(case, bc.case_plant(case), bc._nl_spec(case))
    c, d = bc.noise_filter(bc.nominal_plant(case), sc.discrete_plant)
    col = signal.lfilter((1.0, ep["c1"]), (1.0, -ep["d1"]), rng.standard_normal(case.K * case.p))
    add = col * (ep["s"] / ep["snr"]) / max(float(np.std(col)), 1e-300)
    sc.noise = gen.InjectedNoise(case.noise_sigma, c, d, None)
    sc.sigma2 = 1.0
    rec = gen.simulate_effect(sc, "none", ep, case.K, rng)
    return replace(rec, y=rec.y + add[None, :])


def chosen_class(variant: str, seed: int, cls: str) -> tuple[str, int, int]:
    """The class chosen under ``variant``, and the poles of the blind model and of the
    structure the classes are compared in."""
    effect = VARIANTS[variant][0]
    case = bc.draw_bench_case(seed, effect, cls, "paper")
    if variant == "none: nominal noise x 10":
        case = replace(case, noise_sigma=10 * case.noise_sigma)
    d1 = {"d1 = 0": 0.0, "d1 = 0.5": 0.5}.get(variant)
    rec = record(case, d1=d1, outside=variant == "outside the loop")
    order = {"prewhitening AR(30)": 30, "prewhitening AR(150)": 150}.get(variant)
    if order is not None:  # the prewhitener's order (bound as its default at definition)
        plain = classes.prewhitener
        classes.prewhitener = lambda w, kept, order=order: plain(w, kept, order)
    two = variant.endswith("at least two poles")
    if two:
        na_select = classes.NA_SELECT
        classes.NA_SELECT = tuple(n for n in na_select if n >= 2)
    try:
        d = diagnose(rec, source=case.name)
    finally:
        if order is not None:
            classes.prewhitener = plain
        if two:
            classes.NA_SELECT = na_select
    poles = (d.nominal.model.lin.na, d.nominal.class_fits["linear"].info["structure"]["na"])
    if not variant.endswith(("output error", "AR(8) noise")):
        return str(d.nonlinearity["class"]), *poles
    ctx, nom = d.ctx, d.nominal
    idx = ctx.fit_idx
    prefilter = None
    if "Box-Jenkins" in variant:
        res = np.asarray(nom.resid)[idx]
        prefilter = classes.prewhitener(res, np.ones(res.size, bool), 8)
    _, _, chosen = nm.hammerstein_pem(ctx, nom.model, idx, prefilter=prefilter)
    return str(chosen), *poles


def _one(task: tuple[str, int, str]) -> tuple[str, int, str, str, int, int]:
    variant, seed, cls = task
    return variant, seed, cls, *chosen_class(variant, seed, cls)


def main(argv: Any = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--jobs", type=int, default=2)
    args = ap.parse_args(argv)
    tasks = [(v, s, c) for v in VARIANTS for s in SEEDS for c in bc.CLASSES]
    with ProcessPoolExecutor(args.jobs) as ex:
        rows = list(ex.map(_one, tasks, chunksize=2))
    print("| variant | records | class right | called backlash |")
    print("|---|---|---|---|")
    for v, (_effect, words) in VARIANTS.items():
        mine = [r for r in rows if r[0] == v]
        right = sum(r[2] == r[3] for r in mine)
        backlash = sum(r[3] == "backlash" for r in mine)
        print(f"| {v} ({words}) | {len(mine)} | {right} | {backlash} |")
    print("\nPoles (na) of the blind model and of the class comparison's structure, as generated:")
    for v in ("as generated", "none: as generated"):
        mine = [r for r in rows if r[0] == v]
        blind = dict(sorted(Counter(r[4] for r in mine).items()))
        compared = dict(sorted(Counter(r[5] for r in mine).items()))
        print(f"{v}: blind {blind}, compared {compared}")


if __name__ == "__main__":
    main()

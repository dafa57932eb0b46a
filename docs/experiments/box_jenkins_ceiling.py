"""The experiment of ``box-jenkins-classes.md``, section 1: how often the valve class can be
told on the paper loop's coloured-noise records when the plant and the noise are known, and
how often the Box-Jenkins comparison (:mod:`hbench.diagnose.box_jenkins`) tells it.

Calibration seeds 17000-17005, each with every valve class, for the ``colored-noise`` and the
``none`` cells of :func:`hbench.diagnose.benchmark_cases.draw_bench_case` (paper loop). The
record is simulated as :func:`~hbench.diagnose.benchmark_cases.simulate_bench_case` does, with
its truth kept (the noise-free output and the output noise). Per record, the class is chosen
by :func:`hbench.diagnose.nominal.choose_graph` from fits on the fit part (the first two thirds,
from fast sample 100) of:

* ``true plant, true noise``: the true plant ``G``, the noise whitened by an AR(30) fitted to the
  true output noise (the prediction error of the true model), each class's parameters on its
  coarse grid with gain and offset by least squares;
* ``true plant, no noise model``: the same with no whitening (output error);
* ``true A, equation error``: ``A y = B u + m`` with the true ``A`` and ``B``;
* ``Box-Jenkins, true delay``: :func:`hbench.diagnose.box_jenkins.compare_classes` with the true
  delay and ``nb`` (``na`` by BIC), nothing else known.

    python docs/experiments/box_jenkins_ceiling.py [--jobs 2]

Takes about 2 minutes on two cores.
"""

from __future__ import annotations

import argparse
from collections import Counter
from concurrent.futures import ProcessPoolExecutor
from typing import Any

import numpy as np
from scipy import signal

from hbench.diagnose import benchmark_cases as bc
from hbench.diagnose import box_jenkins, classes, core
from hbench.diagnose import nominal as nm
from hbench.diagnose.generator import InjectedNoise, additive_effect
from hbench.sim.simulate import simulate

SEEDS = range(17000, 17006)
EFFECTS = ("colored-noise", "none")
VARIANTS = (
    "true plant, true noise",
    "true plant, no noise model",
    "true A, equation error",
    "Box-Jenkins, true delay",
)
BURN = 100


def record_and_truth(case: bc.BenchCase) -> tuple[Any, Any, Any]:
    """``(record, truth, fast plant)`` of ``case``: the steps of
    :func:`hbench.diagnose.benchmark_cases.simulate_bench_case` with the truth kept."""
    rng = np.random.default_rng(np.random.SeedSequence([20261128, case.seed]))
    ep = case.effect_params
    N = case.K * case.p
    sc = bc._scenario(case, bc.case_plant(case), bc._nl_spec(case))
    c, d = bc.noise_filter(bc.nominal_plant(case), sc.discrete_plant)
    if case.effect == "colored-noise":
        col = signal.lfilter((1.0, ep["c1"]), (1.0, -ep["d1"]), rng.standard_normal(N))
        add = col * (ep["s"] / ep["snr"]) / max(float(np.std(col)), 1e-300)
    else:
        add = additive_effect(case.effect, ep, N, rng)
    sc.noise = InjectedNoise(case.noise_sigma, c, d, add)
    sc.sigma2 = 1.0
    rec, truth = simulate(sc, 1, rng)
    return rec, truth, sc.discrete_plant


def known_model_classes(
    x: np.ndarray,
    y: np.ndarray,
    p: int,
    plant: Any,
    whiten: np.ndarray,
    rows: np.ndarray,
    equation_error: bool,
) -> dict[str, classes.ClassFit]:
    """Every class on its coarse grid with the plant known; gain and offset by least squares
    on the prediction error ``whiten (y - G u)`` (or the equation error ``A y - B u``)."""
    xf = x[: rows[-1] // p + 1]
    out: dict[str, classes.ClassFit] = {}
    bq = np.concatenate([np.zeros(1 + plant.delay), plant.b])
    for cls in core.CLASSES:
        grid = classes.coarse_grid(cls, xf)
        F = core.nl_batch(cls, x, grid) if grid else x[None, :]
        u = np.repeat(F, p, axis=1)
        if equation_error:
            g = signal.lfilter(bq, [1.0], u, axis=-1)
            ty = signal.lfilter(plant.a, [1.0], y)
            one = np.ones(y.size)
        else:
            g = signal.lfilter(whiten, [1.0], signal.lfilter(bq, plant.a, u, axis=-1), axis=-1)
            ty = signal.lfilter(whiten, [1.0], y)
            one = signal.lfilter(whiten, [1.0], signal.lfilter(bq, plant.a, np.ones(y.size)))
        g, ty, one = g[:, rows], ty[rows], one[rows]
        rss = np.empty(g.shape[0])
        for j in range(g.shape[0]):
            A = np.stack([g[j], one], axis=1)
            coef, *_ = np.linalg.lstsq(A, ty, rcond=None)
            e = ty - A @ coef
            rss[j] = e @ e
        j = int(np.argmin(rss))
        theta = {k: float(v[j]) for k, v in grid.items()}
        out[cls] = classes.ClassFit(
            cls,
            theta,
            float(rss[j]),
            rows.size,
            2 + core.N_SHAPE[cls],
            info=classes.shape_info(cls, theta, xf),
        )
    return classes.score_against_linear(out)


def ar_fit(v: np.ndarray, order: int) -> np.ndarray:
    X = np.stack([v[order - k : v.size - k] for k in range(1, order + 1)], axis=1)
    coef, *_ = np.linalg.lstsq(X, v[order:], rcond=None)
    return np.concatenate([[1.0], -coef])


def chosen(task: tuple[int, str, str]) -> tuple[int, str, str, dict[str, str]]:
    seed, effect, cls = task
    rec, truth, plant = record_and_truth(bc.draw_bench_case(seed, effect, cls, "paper"))
    x, y, p = rec.x[0], rec.y[0], rec.p
    rows = np.arange(BURN, round(2 / 3 * x.size) * p)
    whiten = ar_fit(truth.v[0], 30)
    fits = {
        "true plant, true noise": known_model_classes(x, y, p, plant, whiten, rows, False),
        "true plant, no noise model": known_model_classes(x, y, p, plant, np.ones(1), rows, False),
        "true A, equation error": known_model_classes(x, y, p, plant, np.ones(1), rows, True),
        "Box-Jenkins, true delay": box_jenkins.compare_classes(
            x, y, p, rows, plant.b.size, plant.delay, x_scale=x[: rows[-1] // p + 1]
        ),
    }
    return seed, effect, cls, {v: nm.choose_graph(f, nm.MIN_STRENGTH_EQ) for v, f in fits.items()}


def main(argv: Any = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--jobs", type=int, default=2)
    args = ap.parse_args(argv)
    tasks = [(s, e, c) for e in EFFECTS for s in SEEDS for c in bc.CLASSES]
    with ProcessPoolExecutor(args.jobs) as ex:
        rows = list(ex.map(chosen, tasks, chunksize=2))
    print("| records | " + " | ".join(VARIANTS) + " |")
    print("|---" * (len(VARIANTS) + 1) + "|")
    for e in EFFECTS:
        mine = [r for r in rows if r[1] == e]
        cells = []
        for v in VARIANTS:
            right = sum(r[2] == r[3][v] for r in mine)
            lin = sum(r[3][v] == "linear" for r in mine)
            cells.append(f"{right} ({lin} linear)")
        print(f"| {e} ({len(mine)}) | " + " | ".join(cells) + " |")
    wrong = Counter(r[3]["Box-Jenkins, true delay"] for r in rows if r[1] == "none")
    print("\nBox-Jenkins, true delay, records without an effect, classes found:", dict(wrong))


if __name__ == "__main__":
    main()

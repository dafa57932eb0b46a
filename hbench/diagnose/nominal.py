"""Step 1 of the workflow: the nominal model of a record.

``p >= 2`` (output fast-sampling): ``G`` and the inner signal ``U`` are identified blindly on the
fit part (default ``wang-lsm``, orders ``na <= 2`` (:data:`NA_NOMINAL`), the delay's multiple of
``p`` as given, assumption A3). Every actuator class is fitted to the graph ``(x(n), U(n))``
(:func:`hbench.diagnose.classes.fit_graph`), then from there by equation error through the
dynamics (:func:`equation_error_classes`: the likelihood of the nominal noise model, in a
structure richer than the blind model's so that an effect's misfit is not taken for a valve),
and the class is chosen by BIC with the rules of :func:`choose_graph` (:func:`blind_model`).
The chosen class's parameters are then fitted by equation error in the blind model's own
structure, started at their prediction-error estimate with a noise model of its own
(:data:`THETA_START`: :mod:`hbench.diagnose.box_jenkins`, consistent under output noise of other
dynamics, where the graph's and equation error's estimates are biased). The simulated output
is ``y_hat = k G(q) f(x) + m`` with ``k, m`` and the start-up transient by least squares on
the fit part. The noise model is the paper's: equation error ``e / A(q)``, so the model's
innovations are ``A(q) (y - y_hat)``.

``p = 1`` (a plant log: no fast sampling, so no blind route): an output-error model from ``x`` to
``y`` with orders ``na = nb`` in 1..3 and delay 0..8 by BIC on the fit part; every class fitted
through the dynamics with the linear part re-fitted for each candidate
(:func:`hbench.diagnose.classes.fit_dynamic`); a class beats ``linear`` only when its fit
improves by :data:`DYNAMIC_MARGIN` points (see :func:`choose_dynamic`). The class is decided on
the whole record (the sticking episodes that reveal a valve may lie anywhere in a plant log);
the parameters of the nominal model are then fitted on the fit part only, like every model
whose validation fit is reported. The noise model is white output noise, so the innovations are
the residuals. Oscillating plant loops (Thornhill's regularity ``r > 1``) also get He et al.'s
curve-fitting test, which can name stiction, with Horch's cross-correlation phase reported as
evidence only (:func:`shape_test`, :func:`oscillation_verdict`).

What was measured on the way to these choices, and the alternatives that were not adopted (the
class decided on the fit part alone; the literature's OP-PV pattern tests; a differenced route
for integrating loops; where the misses on synthetic plant loops come from), is written up in
``docs/experiments/`` (``literature-stiction-tests.md``, ``integrating-route.md``,
``valve-position-ceiling.md``, ``diagnose-benchmark-loops.md``, ``diagnose-class-ceiling.md``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from hbench.diagnose import box_jenkins, classes, core
from hbench.errors import InputError, MethodError, describe
from hbench.ident.identifiers import Estimate, IdentifyOptions, identify, run_status
from hbench.sim.records import Record

#: Denominator orders of the nominal blind model (the ``order`` effect goes beyond).
NA_NOMINAL: tuple[int, int] = (1, 2)
#: Share of a record's slow samples in the fit part (the rest validates), by default.
FIT_FRACTION = 2 / 3
#: Fewest slow samples in the fit part and in the validation part.
MIN_FIT, MIN_VAL = 80, 40
#: Output-error orders and delays searched for ``p = 1``.
NA_DYNAMIC: tuple[int, ...] = (1, 2, 3)
DELAYS_DYNAMIC: range = range(0, 9)

#: p >= 2: a class other than linear needs a score (half a BIC difference) of at least this ...
GRAPH_MARGIN = 3.0
#: ... and a fitted map that departs from a straight line by this share of its variance
#: (:func:`hbench.diagnose.classes.strength`).
MIN_STRENGTH = 0.01
#: ... on the graph; through equation error (:func:`blind_model`) the BIC difference is the
#: likelihood-ratio test itself, and the strength only keeps out maps that are linear over the
#: data: this share. A clipping of 5-10 % of the samples leaves 0.2-1 % of the map's variance
#: off a straight line while its score is in the hundreds (``diagnose-class-ceiling.md``).
MIN_STRENGTH_EQ = 0.001
#: p >= 2: stiction (which holds backlash as J = 0) must beat backlash's score by this much ...
GRAPH_NEST_MARGIN = 2.0
#: ... and show a slip jump of at least this share of S (J = 0 is backlash): the smallest
#: J / S the benchmark calls stiction (:mod:`hbench.diagnose.benchmark_cases` draws 0.1-1).
MIN_JUMP_SHARE = 0.1
#: p >= 2: the class fits through the dynamics are refitted on data prewhitened by an AR
#: model of the best fit's equation error (:func:`equation_error_classes`).
PREWHITEN = True
#: p >= 2: the criterion the classes are compared by: ``"equation-error"``
#: (:func:`equation_error_classes`) or ``"box-jenkins"``
#: (:func:`hbench.diagnose.box_jenkins.compare_classes`: an output-error plant and an AR noise
#: model of its own; fewer classes right on the calibration grids:
#: ``docs/experiments/box-jenkins-classes.md``).
CLASS_CRITERION = "equation-error"
#: ... the first fast samples the Box-Jenkins criterion leaves out (the simulation's start-up).
BJ_BURN = 100
#: p >= 2: where the chosen class's parameters are started when fitted in the nominal's
#: structure (:func:`model_structure_fit`): ``"graph"`` (the (x, U) graph's fit) or
#: ``"box-jenkins"`` (the class fitted by :func:`hbench.diagnose.box_jenkins.compare_classes`;
#: chosen on the calibration grids: ``docs/experiments/box-jenkins-classes.md``).
THETA_START = "box-jenkins"
#: p = 1: a class beats linear when its simulation fit improves by at least this (points of %).
#: Tuned on the development loops of ``../shared/data/stictiongpt``: there the memory classes
#: gained at most 1.6 points on records without stiction.
DYNAMIC_MARGIN = 3.0
#: p = 1: a static class (dead zone, saturation) is preferred to the best memory class
#: (stiction, backlash) only when its fit exceeds it by this many points.
DYNAMIC_STATIC_MARGIN = 3.0
#: p = 1, shape test for oscillating loops: an oscillation is regular when Thornhill's
#: regularity exceeds this (the literature's value) ...
REGULARITY = 1.0
#: ... and a regular oscillation whose controller output is this triangular (He et al.'s
#: stiction index; they use 0.6) is a sticking valve. 0.7 is set on the development loops:
#: 0.73-0.86 for the oscillating loop with stiction, at most 0.63 for those without.
SHAPE_INDEX = 0.7
#: p = 1, Horch's cross-correlation test on a regular oscillation (his limits): a phase
#: ``|dphi|`` above 2 pi / 3 (an odd correlation) is a sticking valve ...
HORCH_ODD = 2 * np.pi / 3
#: ... and below pi / 3 (an even correlation) an oscillation the valve does not cause.
HORCH_EVEN = np.pi / 3


@dataclass
class Context:
    """A record split into its fit and validation parts (one run)."""

    record: Record
    x: np.ndarray
    y: np.ndarray
    r: np.ndarray | None
    p: int
    h: float
    k_fit: int
    options: Any = None

    @property
    def K(self) -> int:
        return self.x.size

    @property
    def N(self) -> int:
        return self.y.size

    @property
    def n_fit(self) -> int:
        """Fast samples in the fit part."""
        return self.k_fit * self.p

    @property
    def fit_idx(self) -> np.ndarray:
        return np.arange(self.n_fit)

    @property
    def val_idx(self) -> np.ndarray:
        return np.arange(self.n_fit, self.N)

    @property
    def all_idx(self) -> np.ndarray:
        return np.arange(self.N)

    def fit_segment(self, k0: int) -> Context:
        """The fit part's slow samples ``k0 .. k_fit - 1`` as a context of its own whose fit
        part is all of it (it has no validation part): a class compared on one regime of a
        record. Raises ``ValueError`` unless ``0 <= k0 < k_fit``."""
        if not 0 <= k0 < self.k_fit:
            raise ValueError(f"the segment must start in the fit part [0, {self.k_fit}), got {k0}")
        return Context(
            record=self.part(k0, self.k_fit),
            x=self.x[k0 : self.k_fit],
            y=self.y[k0 * self.p : self.n_fit],
            r=None if self.r is None else self.r[k0 : self.k_fit],
            p=self.p,
            h=self.h,
            k_fit=self.k_fit - k0,
            options=self.options,
        )

    def part(self, k0: int, k1: int) -> Record:
        """The sub-record of slow samples ``k0 .. k1 - 1``."""
        p = self.p
        return Record(
            y=self.y[None, k0 * p : k1 * p],
            x=self.x[None, k0:k1],
            r=None if self.r is None else self.r[None, k0:k1],
            p=p,
            h=self.h,
            source=self.record.source,
        )


def make_context(
    record: Record, fit_fraction: float = FIT_FRACTION, options: Any = None
) -> Context:
    """Check that ``record`` can be diagnosed and split it."""
    if record.runs != 1:
        raise InputError(f"diagnose takes one run, the record has {record.runs}")
    if record.x is None:
        raise InputError("diagnose needs x (the controller output)")
    if not 0.2 <= fit_fraction <= 0.9:
        raise InputError(f"the fit fraction must lie in [0.2, 0.9], got {fit_fraction:g}")
    x = np.asarray(record.x[0], float)
    y = np.asarray(record.y[0], float)
    K = x.size
    k_fit = int(np.floor(fit_fraction * K))
    if k_fit < MIN_FIT or K - k_fit < MIN_VAL:
        need = int(np.ceil(max(MIN_FIT / fit_fraction, MIN_VAL / (1 - fit_fraction))))
        raise InputError(
            f"the record is too short for the validation split: {K} slow samples (p = "
            f"{record.p}); fitting on {fit_fraction:.3g} of it and validating on the rest needs "
            f"at least {need} slow samples ({need * record.p} rows), {MIN_FIT} to fit and "
            f"{MIN_VAL} to validate"
        )
    for name, v in (("y", y), ("x", x)):
        if np.ptp(v) == 0:
            raise InputError(
                f"{name} is constant over the record ({v[0]:.6g}): nothing to identify"
            )
    if np.ptp(y[: k_fit * record.p]) == 0 or np.ptp(x[:k_fit]) == 0:
        raise InputError("x or y is constant over the fit part: nothing to identify")
    r = None if record.r is None else np.asarray(record.r[0], float)
    return Context(record, x, y, r, int(record.p), float(record.h), k_fit, options)


@dataclass
class Nominal:
    """The nominal model and what it leaves."""

    model: core.Model
    class_fits: dict[str, classes.ClassFit]
    chosen: str
    yhat: np.ndarray
    resid: np.ndarray
    innov: np.ndarray
    U: np.ndarray | None = None
    estimate: Estimate | None = None
    structure: dict[str, int] = field(default_factory=dict)
    lin_structure: classes.LinearStructure | None = None
    info: dict[str, Any] = field(default_factory=dict)
    #: Arrays derived from this nominal that several detectors use, computed once (e.g. the
    #: noise-model draws of :func:`hbench.diagnose.effects.null_draws`).
    cache: dict[str, Any] = field(default_factory=dict, repr=False, compare=False)

    @property
    def scores(self) -> dict[str, float]:
        return {c: float(f.score) for c, f in self.class_fits.items()}


def noise_denominator(model: core.Model) -> np.ndarray | None:
    """The nominal noise model ``e / D(q)``'s ``D``: ``A(q)`` for p >= 2 (the paper's equation
    error), ``None`` for p = 1 (output error: white residuals)."""
    if model.p == 1 or model.info.get("noise") == "output-error":
        return None
    return np.asarray(model.lin.a, float)


def innovations(model: core.Model, resid: np.ndarray) -> np.ndarray:
    """The nominal noise model's innovations: ``A(q) resid`` for p >= 2 (equation error),
    ``resid`` for p = 1 (output error)."""
    d = noise_denominator(model)
    if d is None:
        return resid.copy()
    from scipy import signal

    return signal.lfilter(d, [1.0], resid)


def finish(
    model: core.Model,
    ctx: Context,
    idx: np.ndarray | None = None,
    *,
    trend: int = 0,
    weights: np.ndarray | None = None,
    refit_output: bool = True,
) -> tuple[core.Model, np.ndarray, np.ndarray, np.ndarray]:
    """Fit the output scale (and trend) on ``idx`` (default: the fit part), simulate, and
    return ``(model, yhat, resid, innov)``."""
    idx = ctx.fit_idx if idx is None else idx
    if refit_output:
        model = core.fit_output(model, ctx.x, ctx.y, idx, trend=trend, weights=weights)
    yhat = model.simulate(ctx.x)
    resid = ctx.y - yhat
    return model, yhat, resid, innovations(model, resid)


# --------------------------------------------------------------------------- p >= 2: blind


def identify_blind(
    ctx: Context,
    method: str = "wang-lsm",
    *,
    record: Record | None = None,
    na_range: tuple[int, int] = NA_NOMINAL,
    na: int | None = None,
    delay_multiple: int = 0,
) -> Estimate:
    """The blind method on ``record`` (default: the fit part)."""
    from hbench.plugins import registry

    rec = record if record is not None else ctx.part(0, ctx.k_fit)
    cls = registry().get("identifiers", method)
    nb_max = int(min(3, ctx.p - 1))
    opts = IdentifyOptions(
        nb_max=nb_max, na_range=na_range, na=na, delay_multiple=int(delay_multiple)
    )
    try:
        est = identify(cls(), rec, opts)
    except (InputError, MethodError):
        raise
    except Exception as exc:  # the method's own failure: one line naming it, not a traceback
        raise MethodError(f"method {method!r} failed: {describe(exc)}") from exc
    status, reason = run_status(est)
    if status[0] == "failed":  # identifiable, yet neither an estimate nor a reason: the method's
        raise MethodError(f"method {method!r} failed: {reason[0]}")
    if status[0] != "ok" or np.all(np.isnan(est.U[0])):
        why = reason[0] or "no inner-signal estimate"
        raise InputError(f"the blind method {method!r} cannot identify this record: {why}")
    return est


def linear_from_estimate(est: Estimate, p: int, delay_multiple: int = 0) -> core.Linear:
    na, nb, tau = int(est.na[0]), int(est.nb[0]), int(est.tau[0])
    a = np.concatenate([[1.0], est.a[0, :na]])
    return core.Linear(a=core.stabilise(a), b=est.b[0, :nb].copy(), delay=tau + delay_multiple * p)


def choose_graph(fits: dict[str, classes.ClassFit], min_strength: float = MIN_STRENGTH) -> str:
    """The class on the (x, U) graph: the best score if it reaches :data:`GRAPH_MARGIN` and
    its map's strength ``min_strength``; stiction over backlash only by
    :data:`GRAPH_NEST_MARGIN` more and with a slip jump ``J >= MIN_JUMP_SHARE S``; a
    one-sided dead zone (:func:`hbench.diagnose.classes.one_sided`) over the saturation only
    by :data:`GRAPH_NEST_MARGIN` more (it nests the one-sided saturation but for the few
    samples beyond its far edge)."""
    cands = {
        c: f.score
        for c, f in fits.items()
        if c != "linear" and f.score >= GRAPH_MARGIN and f.info.get("strength", 1.0) >= min_strength
    }
    if not cands:
        return "linear"

    def nested(richer: str, simpler: str, force: bool = False) -> None:
        """The richer class stays only if it beats the simpler one it holds by the margin
        (and ``force`` is false); otherwise the simpler one is the candidate in its place."""
        if simpler not in fits:
            return
        alt = fits[simpler]
        if force or cands[richer] < alt.score + GRAPH_NEST_MARGIN:
            cands.pop(richer)
            if alt.score >= GRAPH_MARGIN and alt.info.get("strength", 1.0) >= min_strength:
                cands[simpler] = alt.score

    if "stiction" in cands:
        th = fits["stiction"].theta
        nested("stiction", "backlash", force=th["J"] < MIN_JUMP_SHARE * th["S"])
    if "deadband" in cands and fits["deadband"].info.get("one_sided"):
        nested("deadband", "saturation")
    if not cands:
        return "linear"
    return max(cands, key=lambda c: cands[c])


def model_from_blind(
    ctx: Context,
    est: Estimate,
    *,
    shift: int = 0,
    delay_multiple: int = 0,
    cls: str | None = None,
    label: str = "nominal",
    k_end: int | None = None,
) -> tuple[core.Model, dict[str, classes.ClassFit], str, np.ndarray]:
    """Class fits on the (x, U) graph of ``est`` (slow samples ``< k_end``, default the fit
    part) and the model they give."""
    k_end = ctx.k_fit if k_end is None else k_end
    U = np.full(ctx.K, np.nan)
    Uf = est.U[0][:k_end]
    U[: Uf.size] = Uf
    fits = classes.fit_graph(ctx.x[:k_end], U[:k_end], shift=shift)
    chosen = cls if cls is not None else choose_graph(fits)
    lin = linear_from_estimate(est, ctx.p, delay_multiple)
    theta = fits[chosen].theta
    model = core.Model(
        cls=chosen,
        theta=theta,
        lin=lin,
        p=ctx.p,
        shift=shift,
        label=label,
        info={
            "noise": "equation-error",
            "na": int(est.na[0]),
            "nb": int(est.nb[0]),
            "tau": int(est.tau[0]),
            "method": est.method,
            "delay_multiple": int(delay_multiple),
            "class_fits": fits,
        },
    )
    return model, fits, chosen, U


def equation_error_classes(
    model: core.Model,
    ctx: Context,
    graph: dict[str, classes.ClassFit],
    which: tuple[str, ...] = core.CLASSES,
) -> dict[str, classes.ClassFit]:
    """Every class fitted by equation error through the dynamics (started at the graph fit's
    parameters), scored as on the graph: ``score = (BIC_linear - BIC) / 2``.

    Equation error is the likelihood of the nominal noise model (``e / A``, the paper's eq. 2),
    computed from ``x`` and ``y``; the graph of the blind inner signal carries the noise of
    the blind estimate as well, which hides a small slip jump or dead zone. The classes are
    compared in one richer structure (:func:`hbench.diagnose.classes.selection_structure`: order,
    delay and a trend by BIC, so that no class is chosen for absorbing a misfit of the linear
    part), on the rows left once outliers of the best fit are dropped
    (:func:`hbench.diagnose.classes.trim_outliers`). With :data:`PREWHITEN` every class is then
    refitted (from its white fit, on the finer grids) with ``y``, the inputs and the trend
    filtered by ``D(q)``, an AR model of the best fit's equation error
    (:func:`hbench.diagnose.classes.prewhitener`: generalised least squares), on the rows whose
    filter window holds no outlier row; the scores are those fits'. The equation error is white
    only under the nominal noise model; noise of other dynamics, a change of the plant or a
    missing pole colour it, and the white criterion then counts correlated rows as
    independent evidence. ``info["eq"]`` holds ``[a, b, m]`` of the
    class's parameters with the blind model's orders and delay (the nominal's linear part). The
    fits are on the fit part; ``which`` limits the classes (``linear`` is always fitted: the
    scores are relative to it).
    """
    idx = ctx.fit_idx
    p = ctx.p
    xs = shifted(ctx.x, model.shift)
    x_fit = xs[: ctx.k_fit]  # the fit part of the x the candidates are scaled to
    todo = [c for c in core.CLASSES if c in which or c == "linear"]
    inputs = [xs] + [
        core.nl_one(c, xs, graph[c].theta) for c in todo if c in graph and graph[c].theta
    ]
    st = classes.selection_structure(
        np.repeat(np.array(inputs), p, axis=1), ctx.y, p, idx, model.lin.delay
    )

    def fit_all(
        st: classes.EqStructure,
        start: dict[str, dict[str, float] | None],
        coarse: bool,
        prefilter: np.ndarray | None = None,
    ) -> dict[str, tuple[dict[str, float], float, np.ndarray]]:
        out: dict[str, tuple[dict[str, float], float, np.ndarray]] = {}
        for cls in todo:
            args = (cls, xs, ctx.y, p, st.idx, st.na, st.nb, st.delay)
            kw = {"extra": st.extra, "prefilter": prefilter}
            theta, rss, th = classes.fit_equation_error(
                *args, theta0=start.get(cls), coarse=coarse, **kw
            )
            # stiction from the backlash it holds, saturation from a one-sided dead zone
            fitted = {c: v[0] for c, v in out.items()}
            for seed in classes.nested_starts(cls, fitted, x_fit):
                t1, r1, h1 = classes.fit_equation_error(*args, theta0=seed, **kw)
                if r1 < rss:
                    theta, rss, th = t1, r1, h1
            out[cls] = (theta, rss, th)
        return out

    start = {c: (graph[c].theta or None) if c in graph else None for c in todo}
    found = fit_all(st, start, True)
    whole = st

    def best_residual() -> tuple[np.ndarray, np.ndarray]:
        """``(rows, w)``: the equation error of the best fit so far on every row."""
        best = min(found, key=lambda c: found[c][1])
        theta = found[best][0]
        u = np.repeat(core.nl_one(best, xs, theta) if theta else xs, p)
        return classes.eq_residual(u, ctx.y, whole, found[best][2])

    kept = None
    for _ in range(2):  # a first fit that spikes bias flags more rows than the spikes' own
        rows, w = best_residual()
        trimmed = classes.trim_outliers(rows, w, st.na)
        if trimmed is None or (kept is not None and np.array_equal(trimmed, kept)):
            break
        kept = trimmed
        st = classes.EqStructure(st.na, st.nb, st.delay, st.extra, kept)
        found = fit_all(st, {c: found[c][0] or None for c in todo}, True)
    if PREWHITEN:  # generalised least squares: the same AR filter D(q) for every class
        rows, w = best_residual()
        kept_mask = np.isin(rows, st.idx)
        d = classes.prewhitener(w, kept_mask)
        rows_d = classes.prewhitened_rows(rows, kept_mask, d.size - 1)
        st = classes.EqStructure(st.na, st.nb, st.delay, st.extra, rows_d)
        found = fit_all(st, {c: found[c][0] or None for c in todo}, False, d)
    na, nb, delay = model.lin.na, max(model.lin.nb, 2), model.lin.delay
    out: dict[str, classes.ClassFit] = {}
    for cls, (theta, rss, _) in found.items():
        u = np.repeat(core.nl_one(cls, xs, theta) if theta else xs, p)
        _, eq = core.batch_arx(u[None, :], ctx.y, na, nb, delay, idx)
        out[cls] = classes.ClassFit(
            cls,
            theta,
            rss,
            st.n,
            st.k_linear + core.N_SHAPE[cls],
            info={
                **classes.shape_info(cls, theta, x_fit),
                "eq": eq[0],
                "structure": {"na": st.na, "nb": st.nb, "delay": st.delay},
                "outliers_dropped": 0 if kept is None else int(idx.size - kept.size),
            },
        )
    return classes.score_against_linear(out)


def box_jenkins_classes(
    model: core.Model, ctx: Context, which: tuple[str, ...]
) -> dict[str, classes.ClassFit]:
    """The classes ``which`` fitted by :func:`hbench.diagnose.box_jenkins.compare_classes` on the
    fit part from :data:`BJ_BURN`, with ``model``'s delay and ``nb`` (at least 2)."""
    xs = shifted(ctx.x, model.shift)
    rows = ctx.fit_idx[ctx.fit_idx >= BJ_BURN]
    nb = max(model.lin.nb, 2)
    return box_jenkins.compare_classes(
        xs, ctx.y, ctx.p, rows, nb, model.lin.delay, which, x_scale=xs[: ctx.k_fit]
    )


def model_structure_fit(
    cls: str,
    model: core.Model,
    ctx: Context,
    graph: dict[str, classes.ClassFit],
    nested: bool = True,
) -> tuple[dict[str, float], np.ndarray]:
    """The chosen class's parameters and ``[a, b, m]`` by equation error in the blind model's
    orders and delay (the nominal's own structure; the richer structure of
    :func:`equation_error_classes` only chooses the class), started at the graph fit's
    parameters and, for stiction with ``nested``, also at the backlash it nests (``J = 0``)."""
    idx = ctx.fit_idx
    na, nb, delay = model.lin.na, max(model.lin.nb, 2), model.lin.delay
    xs = shifted(ctx.x, model.shift)
    args = (xs, ctx.y, ctx.p, idx, na, nb, delay)

    def start(c: str) -> dict[str, float] | None:
        g = graph.get(c)
        return (g.theta or None) if g is not None else None

    theta, rss, th = classes.fit_equation_error(cls, *args, theta0=start(cls))
    if cls == "stiction" and nested and start("backlash"):
        b, _, _ = classes.fit_equation_error("backlash", *args, theta0=start("backlash"))
        (seed,) = classes.nested_starts(cls, {"backlash": b}, xs)
        t1, r1, _ = classes.fit_equation_error(cls, *args, theta0=seed)
        if r1 < rss:
            theta, rss, th = classes.fit_equation_error(cls, *args, theta0=t1)
    return theta, th


def blind_model(
    ctx: Context,
    est: Estimate,
    *,
    shift: int = 0,
    delay_multiple: int = 0,
    label: str = "nominal",
    candidates: tuple[str, ...] | None = None,
) -> tuple[core.Model, dict[str, classes.ClassFit], str, np.ndarray]:
    """The blind route's model: the (x, U) graph of ``est`` gives every class a starting
    point (:func:`model_from_blind`), equation error through the dynamics chooses the class
    and fits its parameters with the linear part (:func:`equation_error_classes`,
    :func:`choose_graph`), and the output scale, offset and start-up transient are fitted on
    the fit part. ``candidates`` limits the equation-error fits to those classes, ``linear``
    and the graph's best class (the extensions pass the nominal's class: the equation-error
    fits are most of a diagnosis's time). Returns ``(model, class fits, chosen, U)``."""
    model, graph, _, U = model_from_blind(
        ctx, est, shift=shift, delay_multiple=delay_multiple, label=label
    )
    which = core.CLASSES
    if candidates is not None:
        top = max((c for c in graph if c != "linear"), key=lambda c: graph[c].score)
        which = tuple(dict.fromkeys(("linear", *candidates, top)))
    if CLASS_CRITERION == "box-jenkins":
        fits = box_jenkins_classes(model, ctx, which)
        starts = {**graph, **{c: f for c, f in fits.items() if f.theta}}
    else:
        fits = equation_error_classes(model, ctx, graph, which=which)
        starts = graph
    chosen = choose_graph(fits, MIN_STRENGTH_EQ)
    if CLASS_CRITERION != "box-jenkins" and THETA_START == "box-jenkins" and chosen != "linear":
        # stiction with the backlash it nests (the nested start of ``model_structure_fit``)
        bj = box_jenkins_classes(
            model, ctx, ("backlash", chosen) if chosen == "stiction" else (chosen,)
        )
        starts = {**graph, **{c: f for c, f in bj.items() if f.theta}}
    theta, th = model_structure_fit(chosen, model, ctx, starts, nested="backlash" in fits)
    na, nb = model.lin.na, max(model.lin.nb, 2)
    lin = core.Linear(
        a=core.stabilise(np.concatenate([[1.0], th[:na]])),
        b=np.asarray(th[na : na + nb]),
        delay=model.lin.delay,
    )
    model = model.with_(
        cls=chosen,
        theta=theta,
        lin=lin,
        gain=1.0,
        offset=0.0,
        info={**model.info, "refit": "equation-error", "class_fits": fits, "graph_fits": graph},
    )
    return core.fit_output(model, ctx.x, ctx.y, ctx.fit_idx), fits, chosen, U


def nominal_blind(
    ctx: Context,
    method: str = "wang-lsm",
    delay_multiple: int = 0,
    candidates: tuple[str, ...] | None = None,
) -> Nominal:
    est = identify_blind(ctx, method, delay_multiple=delay_multiple)
    model, fits, chosen, U = blind_model(
        ctx, est, delay_multiple=delay_multiple, candidates=candidates
    )
    model, yhat, resid, innov = finish(model, ctx, refit_output=False)
    structure = {
        "na": int(est.na[0]),
        "nb": int(est.nb[0]),
        "tau": int(est.tau[0]),
        "delay": int(model.lin.delay),
    }
    return Nominal(
        model=model,
        class_fits=fits,
        chosen=chosen,
        yhat=yhat,
        resid=resid,
        innov=innov,
        U=U,
        estimate=est,
        structure=structure,
        info={"route": "blind", "method": method},
    )


def shifted(x: np.ndarray, shift: int) -> np.ndarray:
    """``x(n - shift)`` (the first value repeated before the start)."""
    x = np.asarray(x, float)
    return x if shift <= 0 else np.concatenate([np.full(shift, x[0]), x[:-shift]])


def arx_refine(
    model: core.Model,
    ctx: Context,
    idx: np.ndarray | None = None,
    *,
    na: int | None = None,
    nb: int | None = None,
) -> core.Model:
    """The blind model's actuator parameters and linear part re-fitted together by equation
    error on ``idx`` (class, delay and shift kept; ``nb`` at least 2), output scale and
    initial transient by least squares on the simulation.

    Equation error is the nominal noise model's own criterion (``e / A``, the paper's eq. 2),
    so the refit is consistent exactly where the blind LSM is, and biased where it is
    (coloured equation noise: the ``colored-noise`` extension). The blind inner signal is
    noisy; its graph gives the class and a starting point, the refit the parameters.
    """
    idx = ctx.fit_idx if idx is None else idx
    na = model.lin.na if na is None else na
    nb = max(model.lin.nb, 2) if nb is None else nb
    xs = shifted(ctx.x, model.shift)
    theta, _, th = classes.fit_equation_error(
        model.cls, xs, ctx.y, ctx.p, idx, na, nb, model.lin.delay, theta0=model.theta or None
    )
    a = core.stabilise(np.concatenate([[1.0], th[:na]]))
    lin = core.Linear(a=a, b=np.asarray(th[na : na + nb]), delay=model.lin.delay)
    m = model.with_(
        theta=theta, lin=lin, gain=1.0, offset=0.0, info={**model.info, "refit": "equation-error"}
    )
    return core.fit_output(m, ctx.x, ctx.y, idx)


def nominal_family_fit(
    model: core.Model, ctx: Context, idx: np.ndarray | None = None, **kw: Any
) -> core.Model:
    """Fit ``model`` on ``idx`` the way the nominal model is fitted (equation error for the
    blind route, output error for ``p = 1``)."""
    idx = ctx.fit_idx if idx is None else idx
    if ctx.p >= 2:
        return arx_refine(model, ctx, idx, **kw)
    m = refit_linear(model, ctx, idx, **kw)
    return core.fit_output(m, ctx.x, ctx.y, idx)


# --------------------------------------------------------------------------- p = 1: dynamic


def choose_dynamic(fits: dict[str, classes.ClassFit]) -> str:
    """The class through the dynamics (``score``: fit gain over linear, points of %).

    A class needs :data:`DYNAMIC_MARGIN`. Between the memory classes, stiction wins ties (it
    holds backlash as ``J = 0``: in a plant log a valve's dead band is stiction's); a static
    class wins over the best memory class only by :data:`DYNAMIC_STATIC_MARGIN`.
    """
    ok = {c: f.score for c, f in fits.items() if c != "linear" and f.score >= DYNAMIC_MARGIN}
    if not ok:
        return "linear"
    memory = {c: ok[c] for c in ("stiction", "backlash") if c in ok}
    static = {c: ok[c] for c in ("deadband", "saturation") if c in ok}
    best_mem = None
    if memory:
        best_mem = (
            "stiction"
            if "stiction" in memory and memory["stiction"] >= max(memory.values()) - 1.0
            else max(memory, key=lambda c: memory[c])
        )
    if static:
        best_static = max(static, key=lambda c: static[c])
        if best_mem is None or static[best_static] >= memory[best_mem] + DYNAMIC_STATIC_MARGIN:
            return best_static
    assert best_mem is not None
    return best_mem


def fit_dynamic_classes(
    ctx: Context,
    idx: np.ndarray,
    lin: classes.LinearStructure,
    which: tuple[str, ...] = core.CLASSES,
) -> dict[str, tuple[classes.ClassFit, core.OEFit]]:
    out: dict[str, tuple[classes.ClassFit, core.OEFit]] = {}
    for cls in which:
        theta0 = None
        if cls == "stiction" and "backlash" in out:  # stiction holds backlash as J = 0
            (theta0,) = classes.nested_starts(cls, {"backlash": out["backlash"][0].theta}, ctx.x)
        out[cls] = classes.fit_dynamic(cls, ctx.x, ctx.y, ctx.p, idx, lin, theta0=theta0)
    return out


def nominal_dynamic(ctx: Context) -> Nominal:
    """The ``p = 1`` route (also usable for ``p >= 2`` as a non-blind check)."""
    u_lin = np.repeat(ctx.x, ctx.p) if ctx.p > 1 else ctx.x
    delays = DELAYS_DYNAMIC if ctx.p == 1 else range(0, 3 * ctx.p)
    # the class is decided on the whole record (module notes); parameters on the fit part
    lin_all = classes.select_linear(u_lin, ctx.y, ctx.all_idx, na_values=NA_DYNAMIC, delays=delays)
    whole = fit_dynamic_classes(ctx, ctx.all_idx, lin_all)
    fl = core.fit_percent(ctx.y, whole["linear"][1].yhat)
    fits: dict[str, classes.ClassFit] = {}
    for cls, (cf, oe) in whole.items():
        cf.score = 0.0 if cls == "linear" else core.fit_percent(ctx.y, oe.yhat) - fl
        cf.info["fit_whole"] = core.fit_percent(ctx.y, oe.yhat)
        fits[cls] = cf
    chosen = choose_dynamic(fits)
    shape = shape_test(ctx.x, ctx.y)
    if ctx.p == 1:
        chosen = oscillation_verdict(chosen, fits, shape)
    lin_fit = classes.select_linear(u_lin, ctx.y, ctx.fit_idx, na_values=NA_DYNAMIC, delays=delays)
    cf, oe = classes.fit_dynamic(chosen, ctx.x, ctx.y, ctx.p, ctx.fit_idx, lin_fit)
    model = core.Model(
        cls=chosen,
        theta=cf.theta,
        lin=oe.lin,
        p=ctx.p,
        gain=1.0,
        offset=oe.offset,
        init=oe.init,
        label="nominal",
        info={"noise": "output-error", "na": oe.lin.na, "nb": oe.lin.nb, "delay": oe.lin.delay},
    )
    model, yhat, resid, innov = finish(model, ctx)
    structure = {"na": oe.lin.na, "nb": oe.lin.nb, "delay": oe.lin.delay}
    return Nominal(
        model=model,
        class_fits=fits,
        chosen=chosen,
        yhat=yhat,
        resid=resid,
        innov=innov,
        structure=structure,
        lin_structure=lin_fit,
        info={
            "route": "output-error",
            "shape_test": shape,
            "class_fits_whole": {c: whole[c][0].theta for c in whole},
        },
    )


def shape_test(x: np.ndarray, y: np.ndarray | None = None) -> dict[str, Any]:
    """The literature's stiction tests for oscillating loops: oscillation regularity
    (Thornhill), the triangularity of the controller output (He et al.'s curve fitting) and,
    with ``y``, the symmetry of the cross-correlation of ``x`` and ``y`` (Horch).

    Returns ``regularity``, ``period``, ``shape_index`` and ``horch_phase`` (nan unless the
    oscillation is regular), and the verdicts ``stiction`` (triangular), ``horch_odd`` and
    ``horch_even`` (all False unless regular).
    """
    from hbench.diagnose import stats

    r, period = stats.regularity(x)
    regular = bool(r > REGULARITY)
    si = stats.stiction_index(x) if regular else float("nan")
    hp = stats.horch_phase(x, y) if regular and y is not None else float("nan")
    return {
        "regularity": float(r),
        "period": float(period),
        "shape_index": float(si),
        "horch_phase": float(hp),
        "stiction": bool(regular and np.isfinite(si) and si > SHAPE_INDEX),
        "horch_odd": bool(regular and np.isfinite(hp) and hp > HORCH_ODD),
        "horch_even": bool(regular and np.isfinite(hp) and hp < HORCH_EVEN),
        "decided": False,
    }


def oscillation_verdict(
    chosen: str, fits: dict[str, classes.ClassFit], shape: dict[str, Any]
) -> str:
    """The class of a plant loop once the oscillation tests of :func:`shape_test` are heard.

    A triangular controller output (He et al.) names stiction when the stiction fit through the
    dynamics is no worse than linear and the fit chose another class. Horch's phase is
    reported as evidence but decides nothing: on the synthetic plant loops
    (:func:`hbench.diagnose.generator.loop_cases`) the phase it measures is that of the PI
    controller at the oscillation frequency, ``2 atan(1 / (w Ti))``, whatever the valve (an
    outside oscillation on a fast flow loop reads "odd"; a sticking level valve can read
    "even"), and letting it decide changed no development verdict. ``shape["decided"]``
    records whether the shape test changed the class.
    """
    new = chosen
    if chosen != "stiction" and shape["stiction"] and fits["stiction"].score >= 0.0:
        new = "stiction"
    shape["decided"] = new != chosen
    return new


def fit_nominal(
    ctx: Context,
    method: str = "wang-lsm",
    delay_multiple: int = 0,
    candidates: tuple[str, ...] | None = None,
) -> Nominal:
    """The nominal model: blind for ``p >= 2`` (``candidates``: see :func:`blind_model`),
    output error for ``p = 1``."""
    if ctx.p >= 2:
        return nominal_blind(ctx, method, delay_multiple, candidates)
    return nominal_dynamic(ctx)


def hammerstein_pem(
    ctx: Context,
    model: core.Model,
    idx: np.ndarray,
    *,
    prefilter: np.ndarray | None = None,
    which: tuple[str, ...] = core.CLASSES,
    label: str = "pem",
) -> tuple[core.Model, dict[str, classes.ClassFit], str]:
    """Every class fitted through the dynamics on ``idx`` (non-blind: from ``x`` to ``y``), with
    ``model``'s orders and delay, by output error (``prefilter`` None: the FIR ``D = 1``) or,
    with ``prefilter`` ``D``, by prediction error with the noise model ``1 / D``; the linear
    part is re-fitted for every class (``linear`` too), and a memory actuator's start state
    re-chosen on the simulation (:func:`reanchor`); the class chosen by BIC as on the graph
    (:func:`choose_graph`). Returns the chosen model (output scale fitted, unfiltered)."""
    if prefilter is None:
        prefilter = np.ones(1)
    lin_m = model.lin
    nb = max(lin_m.nb, 1)
    oe0 = core.OEFit(lin=lin_m, offset=0.0, yhat=np.zeros(ctx.N), rss=np.inf, n=idx.size)
    ls = classes.LinearStructure(lin_m.na, nb, lin_m.delay, oe0)
    a_set = [lin_m.a]
    fits: dict[str, classes.ClassFit] = {}
    lins: dict[str, core.OEFit] = {}
    for cls in which:
        cf, oe = classes.fit_dynamic(
            cls,
            shifted(ctx.x, model.shift),
            ctx.y,
            ctx.p,
            idx,
            ls,
            prefilter=prefilter,
            delays=[lin_m.delay],
            a_set=a_set,
            top=2,
            theta0=model.theta if cls == model.cls and model.theta else None,
        )
        cf.k = 2 * lin_m.na + 1 + core.N_SHAPE[cls]
        cf.info.update(classes.shape_info(cls, cf.theta, ctx.x[: idx.size // ctx.p]))
        fits[cls], lins[cls] = cf, oe
    base = fits["linear"].bic if "linear" in fits else min(f.bic for f in fits.values())
    for f in fits.values():
        f.score = float((base - f.bic) / 2)
    chosen = choose_graph(fits) if "linear" in fits else which[0]
    m = core.Model(
        cls=chosen,
        theta=fits[chosen].theta,
        lin=lins[chosen].lin,
        p=ctx.p,
        shift=model.shift,
        label=label,
        info={**model.info, "noise": "output-error", "class_fits": fits},
    )
    m = reanchor(m, ctx, idx)
    return core.fit_output(m, ctx.x, ctx.y, idx), fits, chosen


def simulation_rss(model: core.Model, ctx: Context, idx: np.ndarray | None = None) -> float:
    """The RSS of ``model``'s simulation of ``ctx.y`` from ``ctx.x`` over ``idx`` (default:
    the fit part)."""
    idx = ctx.fit_idx if idx is None else idx
    return float(np.sum((ctx.y - model.simulate(ctx.x))[idx] ** 2))


def reanchor(model: core.Model, ctx: Context, idx: np.ndarray) -> core.Model:
    """The state a memory actuator starts in, re-chosen by the simulation error on ``idx``.

    A prediction-error criterion with a low-pass noise model weighs the low frequencies
    little, so the start state it picks (which sets the valve's offset until it first
    moves) can be poor for simulation."""
    if model.cls not in ("backlash", "stiction"):
        return model
    best: tuple[float, core.Model] | None = None
    d0s = (1.0, -1.0) if model.cls == "stiction" else (None,)
    for d0 in d0s:
        for g0 in np.linspace(0.0, 1.0, 9):
            th = {**model.theta, "g0": float(g0)}
            if d0 is not None:
                th["d0"] = d0
            cand = core.fit_output(model.with_(theta=th), ctx.x, ctx.y, idx)
            rss = simulation_rss(cand, ctx, idx)
            if best is None or rss < best[0]:
                best = (rss, cand)
    assert best is not None
    return best[1]


def refit_linear(
    model: core.Model,
    ctx: Context,
    idx: np.ndarray,
    *,
    na: int | None = None,
    nb: int | None = None,
    delay: int | None = None,
    weights: np.ndarray | None = None,
) -> core.Model:
    """The model with its linear part re-fitted by output error on ``idx`` (class, parameters
    and shift kept): the non-blind refit the extensions use."""
    u = np.repeat(model.inner(ctx.x), ctx.p)
    na = model.lin.na if na is None else na
    nb = max(model.lin.nb, 1) if nb is None else nb
    delay = model.lin.delay if delay is None else delay
    same = model.lin.na == na
    best = core.oe_fit(u, ctx.y, na, nb, delay, idx, weights=weights, refine=True)
    if same:
        for kw in ({"a_init": model.lin.a, "refine": True}, {"a_fixed": model.lin.a}):
            g = core.oe_fit(u, ctx.y, na, nb, delay, idx, weights=weights, **kw)
            if g.rss < best.rss:
                best = g
    return model.with_(
        lin=best.lin,
        gain=1.0,
        offset=best.offset,
        init=best.init,
        info={**model.info, "noise": "output-error"},
    )

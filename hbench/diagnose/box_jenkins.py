"""The valve classes compared by prediction error with a noise model of its own (Box-Jenkins).

The diagnosis starts the chosen class's parameters here
(:data:`hbench.diagnose.nominal.THETA_START`);
comparing the classes by it is an option (:data:`hbench.diagnose.nominal.CLASS_CRITERION`) that
the calibration grids did not choose (``docs/experiments/box-jenkins-classes.md``).

Model of one record at the fast rate ``t`` (slow sample ``n = floor(t / p)``, the inner signal
held over each slow period):

    y(t) = q^-delay B(q) / A(q) [u(t) - u(0)] + m + v(t),   u(t) = c f(x(n); theta),
    v(t) = e(t) / D(q),   D(q) = 1 + d1 q^-1 + ... + d_nd q^-nd,   e white,

an output-error plant (``A`` and ``B`` not shared with the noise) and an autoregressive noise
model of order :data:`NOISE_ORDER` (Box-Jenkins with ``C = 1``; a high-order AR approximates
any stable, minimum-phase noise spectrum: the nominal noise ``C / A e`` of the benchmark's
plants and an output noise with dynamics of its own alike). ``f`` is the class's shape
(:func:`hbench.diagnose.core.nl_batch`), ``c`` its gain (the plant's ``B`` takes it when the
plant is fitted), ``u(0)`` the inner signal at the first sample (the simulation starts at rest
in that state, as :func:`hbench.diagnose.core.oe_fit` does).

The one-step predictor's error is ``eps(t) = D(q) [y(t) - G(q) (u(t) - u(0)) - m]`` and the
class's criterion ``V = sum over the fit rows of eps(t)^2`` (the Gaussian likelihood's; the
direct prediction-error method, consistent in closed loop when plant and noise lie in the
model set: Ljung, *System Identification*, 1999, section 13.4). The equation-error criterion
the classes are otherwise compared by (:func:`hbench.diagnose.nominal.equation_error_classes`)
is this one with ``A`` shared between plant and noise; under output noise of other dynamics it
is biased (``docs/experiments/coloured-noise-class.md``).

``V`` is minimised by block coordinate descent, each block exactly, so ``V`` never grows:
1. ``D`` given the plant: least squares of the AR on ``w = y - G (u - u(0)) - m`` (the rows'
   lags reach before the first fit row; ``w`` is 0 before the record, as the filter starts);
2. the class's parameters given ``G`` and ``D``: every candidate of the class's grids (on the
   first pass :func:`hbench.diagnose.classes.coarse_grid`, on later ones the parameters so far;
   the nested class's best as a start: :func:`~hbench.diagnose.classes.nested_starts`; then
   :func:`~hbench.diagnose.classes.fine_grid` at spreads 1, 1/2, 1/4 around the best), with
   ``c`` and ``m`` by least squares (regressors ``D G (f - f(0))`` and ``D 1``);
3. ``A``, ``B`` and ``m`` given ``D`` and the class's shape: Levenberg-Marquardt on ``eps``
   (``scipy.optimize.least_squares``), accepted only if ``V`` falls with ``A`` stable.
:data:`ITERATIONS` passes; the best state is kept. Every class starts from the ``linear``
class's fit (which ``saturation`` with both limits open holds exactly), the linear class from
Steiglitz-McBride (:func:`hbench.diagnose.core.oe_fit`).

Orders: ``nb`` and ``delay`` as given (the nominal's), ``na`` by BIC of the linear class over
:data:`NA_CHOICES`. Scores as every class comparison's: ``(BIC_linear - BIC) / 2`` with
``na + nb + 1`` parameters for the linear part and the class's shape parameters
(:data:`hbench.diagnose.core.N_SHAPE`); the noise model's are common to all classes.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import optimize, signal

from hbench.diagnose import classes, core

#: Order of the autoregressive noise model ``D``.
NOISE_ORDER = 30
#: Denominator orders of the plant, the one by BIC of the linear class.
NA_CHOICES: tuple[int, ...] = (1, 2, 3)
#: Passes of the block coordinate descent per class.
ITERATIONS = 3
#: Fine-grid spreads searched around the best candidate of the coarse grid.
SPREADS: tuple[float, ...] = (1.0, 0.5, 0.25)


@dataclass
class State:
    """One class's fit: the plant ``a, b`` (delay fixed; ``B`` holds the class's gain), offset
    ``m``, noise ``d``, the class's parameters and the criterion ``V``."""

    a: np.ndarray
    b: np.ndarray
    m: float
    d: np.ndarray
    theta: dict[str, float]
    rss: float


def _plant(a: np.ndarray, b: np.ndarray, delay: int, u: np.ndarray) -> np.ndarray:
    """``q^-delay B(q)/A(q) u`` from rest along the last axis (``b`` starts at ``q^-1``)."""
    return signal.lfilter(np.concatenate([np.zeros(1 + delay), b]), a, u, axis=-1)


def ar_noise(w: np.ndarray, rows: np.ndarray, order: int) -> np.ndarray:
    """``[1, d1, .., d_order]`` minimising ``sum over rows of (D(q) w)(t)^2``, ``w`` zero
    before its first sample (as :func:`scipy.signal.lfilter` starts)."""
    wp = np.concatenate([np.zeros(order), w])
    X = np.stack([wp[rows + order - k] for k in range(1, order + 1)], axis=1)
    coef, *_ = np.linalg.lstsq(X, -wp[rows + order], rcond=None)
    return np.concatenate([[1.0], coef])


def _fast(F: np.ndarray, p: int) -> np.ndarray:
    """Slow-rate shapes ``(C, K)`` held over each period, from the first sample's value."""
    F = np.atleast_2d(F)
    return np.repeat(F - F[:, :1], p, axis=-1)


def _candidates(
    st: State,
    cls: str,
    params: dict[str, np.ndarray],
    x: np.ndarray,
    y: np.ndarray,
    p: int,
    delay: int,
    rows: np.ndarray,
) -> tuple[dict[str, float], float, float, float]:
    """The best of the candidates ``params`` of ``cls`` given the plant and noise of ``st``:
    ``(theta, gain, m, V)``, gain and offset by least squares."""
    F = core.nl_batch(cls, x, params)
    g = signal.lfilter(st.d, [1.0], _plant(st.a, st.b, delay, _fast(F, p)), axis=-1)[:, rows]
    ty = signal.lfilter(st.d, [1.0], y)[rows]
    one = signal.lfilter(st.d, [1.0], np.ones(y.size))[rows]
    s_gg = np.einsum("ij,ij->i", g, g)
    s_go, s_gy = g @ one, g @ ty
    s_oo, s_oy, s_yy = one @ one, one @ ty, ty @ ty
    det = s_gg * s_oo - s_go**2
    flat = det <= 1e-9 * s_gg * s_oo  # a shape constant over the record: the offset alone
    det = np.where(flat, 1.0, det)
    c = np.where(flat, 0.0, (s_gy * s_oo - s_go * s_oy) / det)
    m = np.where(flat, s_oy / s_oo, (s_gg * s_oy - s_go * s_gy) / det)
    rss = np.where(flat, s_yy - s_oy**2 / s_oo, s_yy - c * s_gy - m * s_oy)
    j = int(np.argmin(rss))
    e = ty - c[j] * g[j] - m[j] * one  # the sums' difference cancels near a perfect fit
    return {k: float(v[j]) for k, v in params.items()}, float(c[j]), float(m[j]), float(e @ e)


def _rss(st: State, u: np.ndarray, y: np.ndarray, delay: int, rows: np.ndarray) -> float:
    e = signal.lfilter(st.d, [1.0], y - _plant(st.a, st.b, delay, u) - st.m)[rows]
    return float(e @ e)


def _fit_plant(st: State, u: np.ndarray, y: np.ndarray, delay: int, rows: np.ndarray) -> State:
    """Step 3: ``A``, ``B``, ``m`` by Levenberg-Marquardt with ``D`` and ``u`` fixed; kept
    only if ``V`` falls with ``A`` stable."""
    na = st.a.size - 1
    nb = st.b.size
    yd = signal.lfilter(st.d, [1.0], y)
    dsum = signal.lfilter(st.d, [1.0], np.ones(y.size))

    def resid(th: np.ndarray) -> np.ndarray:
        yh = _plant(np.concatenate([[1.0], th[:na]]), th[na : na + nb], delay, u)
        return (yd - signal.lfilter(st.d, [1.0], yh) - th[-1] * dsum)[rows]

    th0 = np.concatenate([st.a[1:], st.b, [st.m]])
    with np.errstate(all="ignore"):
        sol = optimize.least_squares(resid, th0, method="lm", max_nfev=40 * th0.size)
    a = np.concatenate([[1.0], sol.x[:na]])
    if not np.all(np.isfinite(sol.x)) or np.any(np.abs(np.roots(a)) >= core.STABLE_RADIUS):
        return st
    new = State(a, sol.x[na : na + nb], float(sol.x[-1]), st.d, st.theta, 0.0)
    new.rss = _rss(new, u, y, delay, rows)
    return new if new.rss < st.rss else st


def fit_class(
    cls: str,
    x: np.ndarray,
    y: np.ndarray,
    p: int,
    delay: int,
    rows: np.ndarray,
    start: State,
    nested: dict[str, dict[str, float]] | None = None,
    x_scale: np.ndarray | None = None,
) -> State:
    """``cls`` fitted by the block coordinate descent from ``start`` (a linear fit); ``nested``
    the fitted classes' parameters for :func:`hbench.diagnose.classes.nested_starts`;
    ``x_scale`` the samples of ``x`` the grids are scaled to (the fit part's)."""
    xs = x if x_scale is None else x_scale
    st = start
    shape = x if cls == "linear" else None
    for _ in range(ITERATIONS):
        u = _fast(x if shape is None else shape, p)[0]
        w = y - _plant(st.a, st.b, delay, u) - st.m
        st = State(st.a, st.b, st.m, ar_noise(w, rows, NOISE_ORDER), st.theta, 0.0)
        st.rss = _rss(st, u, y, delay, rows)
        if cls != "linear":
            grids = [] if st.theta else [classes.coarse_grid(cls, xs)]
            grids += [
                {k: np.array([v]) for k, v in s.items()}
                for s in classes.nested_starts(cls, nested or {}, xs)
            ]
            if st.theta:
                grids.append({k: np.array([v]) for k, v in st.theta.items()})
            best = min(
                (_candidates(st, cls, g, x, y, p, delay, rows) for g in grids),
                key=lambda r: r[3],
            )
            for spread in SPREADS:
                fine = classes.fine_grid(cls, xs, best[0], spread)
                if not fine:
                    break
                cand = _candidates(st, cls, fine, x, y, p, delay, rows)
                if cand[3] < best[3]:
                    best = cand
            theta, c, m, v = best
            if v < st.rss:  # the gain moves into B (the plant's step refits it)
                shape = core.nl_one(cls, x, theta)
                st = State(st.a, st.b * c, m, st.d, theta, v)
            elif shape is None:
                shape = core.nl_one(cls, x, st.theta) if st.theta else x
        u = _fast(x if shape is None else shape, p)[0]
        st = _fit_plant(st, u, y, delay, rows)
    return st


def linear_start(
    x: np.ndarray, y: np.ndarray, p: int, na: int, nb: int, delay: int, rows: np.ndarray
) -> State:
    """The linear class fitted from Steiglitz-McBride's output-error estimate."""
    u = _fast(x, p)[0]
    oe = core.oe_fit(np.repeat(x, p), y, na, nb, delay, rows)
    st = State(oe.lin.a, np.asarray(oe.lin.b, float), float(oe.offset), np.ones(1), {}, 0.0)
    st.rss = _rss(st, u, y, delay, rows)
    return fit_class("linear", x, y, p, delay, rows, st)


def compare_classes(
    x: np.ndarray,
    y: np.ndarray,
    p: int,
    rows: np.ndarray,
    nb: int,
    delay: int,
    which: tuple[str, ...] = core.CLASSES,
    x_scale: np.ndarray | None = None,
) -> dict[str, classes.ClassFit]:
    """Every class of ``which`` (and ``linear``) fitted and scored as the module docstring
    says, on the fast samples ``rows`` (``rows[0] >= NOISE_ORDER`` keeps the noise filter's
    start-up out). ``info`` holds the structure, the noise model and the fitted plant."""
    rows = np.asarray(rows)
    n = rows.size
    lin_by_na = {na: linear_start(x, y, p, na, nb, delay, rows) for na in NA_CHOICES}
    bic = {
        na: n * np.log(max(s.rss, 1e-300) / n) + (na + nb + 1) * np.log(n)
        for na, s in lin_by_na.items()
    }
    na = min(bic, key=lambda k: bic[k])
    lin = lin_by_na[na]
    xs = x if x_scale is None else x_scale
    states = {"linear": lin}
    for cls in core.CLASSES:
        if cls == "linear" or cls not in which:
            continue
        fitted = {c: s.theta for c, s in states.items() if s.theta}
        states[cls] = fit_class(cls, x, y, p, delay, rows, lin, fitted, xs)
    out: dict[str, classes.ClassFit] = {}
    for cls, st in states.items():
        out[cls] = classes.ClassFit(
            cls,
            dict(st.theta),
            st.rss,
            n,
            na + nb + 1 + core.N_SHAPE[cls],
            info={
                **classes.shape_info(cls, st.theta, xs),
                "structure": {"na": na, "nb": nb, "delay": delay, "noise_order": NOISE_ORDER},
                "criterion": "box-jenkins",
                "plant": {"a": st.a.tolist(), "b": st.b.tolist()},
            },
        )
    return classes.score_against_linear(out)

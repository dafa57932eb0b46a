"""Numerical core of ``hbench diagnose``: actuator maps batched over parameter candidates,
output-error fits, the simulation of a Hammerstein model from the measured ``x``, and the fit in %.

Conventions: one run at a time (``record.select([0])``); slow signals have shape ``(K,)``, fast
ones ``(N,)`` with ``N = K p``; candidate batches put the candidate first, ``(C, K)``.

The actuator maps here are the rules of :mod:`hbench.model.nonlinearities` written for a batch of
*parameter* candidates (that module batches over runs with one parameter set), so a grid of
candidates is one pass over time. ``tests/test_diagnose.py`` checks them against the
library classes sample by sample.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from scipy import signal

from hbench.diagnose.stats import lagged
from hbench.numerics import kernels

#: The nonlinearity classes of the contract, in order of complexity.
CLASSES: tuple[str, ...] = ("linear", "backlash", "deadband", "saturation", "stiction")

#: Number of shape parameters of each class (the gain and offset come on top).
N_SHAPE: dict[str, int] = {
    "linear": 0,
    "backlash": 1,
    "deadband": 2,
    "saturation": 2,
    "stiction": 2,
}


def fit_percent(y: np.ndarray, yhat: np.ndarray) -> float:
    """``100 (1 - ||y - yhat|| / ||y - mean y||)``; ``-inf`` for a constant ``y`` and for a
    ``yhat`` so far off that the norm of the error overflows (a diverging simulation)."""
    y = np.asarray(y, float)
    den = float(np.linalg.norm(y - y.mean()))
    if not den > 0:
        return float("-inf")
    with np.errstate(over="ignore"):
        num = np.linalg.norm(y - np.asarray(yhat, float))
    return float(100.0 * (1.0 - num / den))


# --------------------------------------------------------------------------- actuator maps


def _col(v: Any, C: int) -> np.ndarray:
    return np.broadcast_to(np.asarray(v, float), (C,)).astype(float)


def backlash_batch(x: np.ndarray, width: Any, g0: Any = 0.5) -> np.ndarray:
    """Play operator of total width ``width[c]`` for each candidate.

    ``u(k) = max(x(k) - w/2, min(x(k) + w/2, u(k-1)))`` with ``u(-1) = x(0) + (g0 - 1/2) w``
    (``g0 = 1/2``: centred on the first input, :class:`hbench.model.nonlinearities.Backlash` with
    ``u0=None``; ``g0`` in [0, 1] spans the positions the valve may have started at). Runs
    compiled where the kernels are built (:func:`hbench.numerics.kernels.backlash_rows`, the
    same numbers as the loop below).
    """
    x = np.asarray(x, float)
    step = BacklashStep(float(x[0]), width, g0)
    out = kernels.backlash_rows(x, step.half, step.u)
    if out is not None:
        return out
    out = np.empty((step.half.size, x.size))
    for k in range(x.size):
        out[:, k] = step(x[k])
    return out


class BacklashStep:
    """The play operator of :func:`backlash_batch` one input at a time (for a loop that
    computes ``x(k)`` from earlier outputs): started at the first input ``x0``, each call
    ``step(x_k)`` returns ``u(k)`` for every candidate."""

    def __init__(self, x0: float, width: Any, g0: Any = 0.5) -> None:
        w = np.atleast_1d(np.asarray(width, float))
        self.half = w / 2
        self.u = x0 + (_col(g0, w.size) - 0.5) * w

    def __call__(self, xk: float) -> np.ndarray:
        self.u = np.maximum(xk - self.half, np.minimum(xk + self.half, self.u))
        return self.u


def stiction_batch(x: np.ndarray, S: Any, J: Any, d0: Any = 1.0, g0: Any = 0.5) -> np.ndarray:
    """Choudhury stiction (the rules of :class:`hbench.model.nonlinearities.Stiction`) for each
    candidate ``(S[c], J[c])``, starting stuck.

    Initial state: the valve last moved in direction ``d0`` (+1 or -1) and stuck at the input
    ``x_ss = x(0) + d0 (g0 (S + J) - J)``, at position ``x_ss - d0 (S - J)/2``: the first input
    then lies in the stuck band ``[x_ss - S, x_ss + J]`` (for ``d0 = +1``) at the fraction
    ``g0`` from its upper end. ``d0 = 1, g0 = 1/2`` is the library's ``u0=None`` (at rest at
    ``x(0)``); the record does not say where the valve started, so a fit grids ``d0, g0``.
    Runs compiled where the kernels are built (:func:`hbench.numerics.kernels.stiction_rows`,
    the same numbers as the loop below).
    """
    x = np.asarray(x, float)
    step = StictionStep(float(x[0]), S, J, d0, g0)
    out = kernels.stiction_rows(x, step.x_prev, step.S, step.J, step.h, step.d, step.x_ss, step.u)
    if out is not None:
        return out
    out = np.empty((step.S.size, x.size))
    for k in range(x.size):
        out[:, k] = step(x[k])
    return out


class StictionStep:
    """The stiction rules of :func:`stiction_batch` one input at a time (for a loop that
    computes ``x(k)`` from earlier outputs): started at the first input ``x0``, each call
    ``step(x_k)`` returns ``u(k)`` for every candidate."""

    def __init__(self, x0: float, S: Any, J: Any, d0: Any = 1.0, g0: Any = 0.5) -> None:
        self.S = np.atleast_1d(np.asarray(S, float))
        C = self.S.size
        self.J = _col(J, C)
        self.d = _col(d0, C).copy()
        self.h = (self.S - self.J) / 2
        self.x_ss = x0 + self.d * (_col(g0, C) * (self.S + self.J) - self.J)
        self.u = self.x_ss - self.d * self.h
        self.x_prev = x0
        self.stuck = np.ones(C, bool)

    def __call__(self, xk: float) -> np.ndarray:
        sticks = ~self.stuck & (np.sign(xk - self.x_prev) != self.d)
        self.x_ss = np.where(sticks, self.x_prev, self.x_ss)
        stuck = self.stuck | sticks
        ahead = self.d * (xk - self.x_ss)
        reverse = stuck & (-ahead > self.S)
        go_on = stuck & (ahead > self.J)
        self.d = np.where(reverse, -self.d, self.d)
        self.stuck = stuck & ~(reverse | go_on)
        self.u = np.where(self.stuck, self.u, xk - self.d * self.h)
        self.x_prev = xk
        return self.u


def nl_batch(cls: str, x: np.ndarray, params: dict[str, np.ndarray]) -> np.ndarray:
    """The shape ``f(x; theta_c)`` for every candidate ``c``: shape ``(C, K)``.

    ``params`` per class: ``{}`` (linear), ``width`` (backlash), ``lower, upper`` (dead zone:
    zero output for ``lower <= x <= upper``, slope 1 outside), ``u_min, u_max`` (saturation),
    ``S, J`` (stiction). Gain and offset are fitted afterwards.
    """
    x = np.asarray(x, float)
    if cls == "linear":
        return x[None, :].copy()
    if cls == "backlash":
        return backlash_batch(x, params["width"], params.get("g0", 0.5))
    if cls == "deadband":
        lo = np.atleast_1d(np.asarray(params["lower"], float))[:, None]
        hi = np.atleast_1d(np.asarray(params["upper"], float))[:, None]
        return x[None, :] - np.clip(x[None, :], lo, hi)
    if cls == "saturation":
        lo = np.atleast_1d(np.asarray(params["u_min"], float))[:, None]
        hi = np.atleast_1d(np.asarray(params["u_max"], float))[:, None]
        return np.clip(x[None, :], lo, hi)
    if cls == "stiction":
        return stiction_batch(
            x, params["S"], params["J"], params.get("d0", 1.0), params.get("g0", 0.5)
        )
    raise ValueError(f"unknown nonlinearity class {cls!r}")


def nl_one(cls: str, x: np.ndarray, theta: dict[str, float]) -> np.ndarray:
    """``f(x; theta)`` for one parameter set, shape ``(K,)``."""
    return nl_batch(cls, x, {k: np.array([v]) for k, v in theta.items()})[0]


def nl_stepper(cls: str, theta: dict[str, float], x0: float) -> Callable[[float], float]:
    """``f(.; theta)`` one input at a time, started at the first input ``x0``: a call with
    ``x(k)`` returns ``u(k)`` (the memory of backlash and stiction kept between calls), the
    same numbers as :func:`nl_one` on the whole sequence."""
    if cls == "backlash":
        bl = BacklashStep(x0, theta["width"], theta.get("g0", 0.5))
        return lambda xk: float(bl(xk)[0])
    if cls == "stiction":
        st = StictionStep(x0, theta["S"], theta["J"], theta.get("d0", 1.0), theta.get("g0", 0.5))
        return lambda xk: float(st(xk)[0])
    return lambda xk: float(nl_one(cls, np.array([xk]), theta)[0])


def scale_of(x: np.ndarray) -> float:
    """A robust range of ``x`` (1st to 99th percentile), never zero."""
    x = np.asarray(x, float)
    lo, hi = np.percentile(x, [1, 99])
    s = float(hi - lo)
    return s if s > 0 else max(float(np.ptp(x)), 1e-12)


# --------------------------------------------------------------------------- linear dynamics


#: The largest root radius :func:`stabilise` leaves: a root beyond it is moved onto it.
STABLE_RADIUS = 0.999


def stabilise(a: np.ndarray) -> np.ndarray:
    """``[1, a1, ...]`` with roots outside the unit circle reflected inside (radius <=
    :data:`STABLE_RADIUS`)."""
    a = np.asarray(a, float)
    if a.size <= 1:
        return a
    r = np.roots(a)
    mag = np.abs(r)
    if np.all(mag < STABLE_RADIUS):
        return a
    r = np.where(mag > 1, 1 / np.conj(r), r)
    mag = np.abs(r)
    r = np.where(mag > STABLE_RADIUS, r * STABLE_RADIUS / np.maximum(mag, 1e-300), r)
    return np.real(np.poly(r))


def lfilter_rest(b: np.ndarray, a: np.ndarray, u: np.ndarray) -> np.ndarray:
    """``B(q)/A(q) u`` from rest along the last axis."""
    return signal.lfilter(b, a, u, axis=-1)


@dataclass
class Linear:
    """``y = q^-delay B(q)/A(q) u`` at the fast rate, ``B = b1 q^-1 + ...``, ``A = 1 + a1 q^-1 ..``.

    ``num`` is the full numerator in powers of ``q^-1`` (leading zeros for the delay,
    ``num[0] = 0``).
    """

    a: np.ndarray
    b: np.ndarray
    delay: int

    @property
    def num(self) -> np.ndarray:
        return np.concatenate([np.zeros(self.delay + 1), self.b])

    @property
    def na(self) -> int:
        return self.a.size - 1

    @property
    def nb(self) -> int:
        return self.b.size

    def response(self, u: np.ndarray) -> np.ndarray:
        """``G(q)(u - u[0])`` from rest (the plant starts at the steady state of ``u[0]``)."""
        u = np.asarray(u, float)
        return lfilter_rest(self.num, self.a, u - u[..., :1])


#: Whether fits carry a start-up transient term (set per record by the diagnosis through
#: :func:`transient`: a simulated record starts from rest, a plant log in steady operation).
TRANSIENT = {"on": True}


@contextmanager
def transient(on: bool) -> Iterator[None]:
    """Fits inside the block carry the start-up transient term when ``on``."""
    old = TRANSIENT["on"]
    TRANSIENT["on"] = bool(on)
    try:
        yield
    finally:
        TRANSIENT["on"] = old


def step_basis(a: np.ndarray, delay: int, nb: int, N: int) -> np.ndarray:
    """``(N, nb)``: ``q^-(delay + j) / A(q)`` applied to a unit step at ``t = 0``, ``j = 1..nb``.

    The simulation assumes the input held at ``u(0)`` before the record; a record that starts
    from rest (a simulation) or after a different input shows the difference as ``G`` times a
    step: a combination of these columns. Only a step at the start, so a transient cannot
    mimic a level change later in the record (free initial-state responses of slow poles
    could).
    """
    if not TRANSIENT["on"] or nb <= 0:
        return np.zeros((N, 0))
    return signal.lfilter(
        [1.0], np.asarray(a, float), lagged(np.ones(N), range(delay + 1, delay + 1 + nb)), axis=0
    )


def _wls(A: np.ndarray, y: np.ndarray, w: np.ndarray | None) -> np.ndarray:
    if w is not None:
        sw = np.sqrt(w)
        A, y = A * sw[:, None], y * sw
    return np.linalg.lstsq(A, y, rcond=None)[0]


@dataclass
class OEFit:
    """An output-error fit: the linear part, output offset and the fit's residual on ``idx``."""

    lin: Linear
    offset: float
    yhat: np.ndarray
    rss: float
    n: int
    info: dict[str, Any] = field(default_factory=dict)
    init: np.ndarray = field(default_factory=lambda: np.zeros(0))


def oe_fit(
    u: np.ndarray,
    y: np.ndarray,
    na: int,
    nb: int,
    delay: int,
    idx: np.ndarray,
    *,
    weights: np.ndarray | None = None,
    iters: int = 6,
    extra: np.ndarray | None = None,
    a_fixed: np.ndarray | None = None,
    a_init: np.ndarray | None = None,
    refine: bool = False,
) -> OEFit:
    """Output-error model ``y = q^-delay B/A (u - u0) + m (+ extra @ c)`` by Steiglitz-McBride.

    ARX start, then ``iters`` Steiglitz-McBride passes that filter ``y`` and ``u`` by ``1/A``
    of the previous pass (denominator kept stable); of the ARX and the last pass's ``A``, the
    one that simulates better is kept (under equation-error noise the passes drift away from
    the ARX estimate, which is then the consistent one), and a last least-squares pass on the
    simulation error gives ``B``, the offset and ``extra`` with ``A`` fixed. Only the samples
    ``idx`` enter
    the criterion (the whole signal is simulated). ``weights`` (per sample) give an IRLS hook.
    ``a_fixed`` skips the iterations and keeps that denominator (a guard against a poor local
    solution of the iterations); ``a_init`` starts the iterations there instead of at ARX.
    ``refine`` then minimises the simulation error over ``A`` itself (variable projection:
    ``B``, the offset and the transient solved by least squares inside, Gauss-Newton outside),
    the exact output-error estimate the iterations approximate.
    """
    u = np.asarray(u, float) - float(u[0])
    y = np.asarray(y, float)
    N = y.size
    idx = np.asarray(idx)
    w = None if weights is None else np.asarray(weights, float)[idx]
    blags = range(delay + 1, delay + 1 + nb)
    ones = np.ones(N)
    ex = np.zeros((N, 0)) if extra is None else np.asarray(extra, float).reshape(N, -1)
    a = np.ones(1)
    start = max(na, delay + nb)
    sel = idx[idx >= start] if idx.size else idx
    wsel = None if weights is None else np.asarray(weights, float)[sel]
    first = 0
    tried: list[np.ndarray] = []
    if a_init is not None and np.asarray(a_init).size == na + 1:
        a, first = stabilise(np.asarray(a_init, float)), 1
        tried.append(a)
    for it in range(first, iters + 1 if a_fixed is None else 0):
        if it == 0:
            yf, uf, cf, exf = y, u, ones, ex
        else:
            # A y_f = B u_f + (A / A_prev) d with d = m + extra c: d enters unfiltered
            yf = signal.lfilter([1.0], a, y)
            uf = signal.lfilter([1.0], a, u)
            cf, exf = ones, ex
        if na:
            Phi = np.hstack([-lagged(yf, range(1, na + 1)), lagged(uf, blags), cf[:, None], exf])
        else:
            Phi = np.hstack([lagged(uf, blags), cf[:, None], exf])
        theta = _wls(Phi[sel], yf[sel], wsel)
        a_new = stabilise(np.concatenate([[1.0], theta[:na]])) if na else np.ones(1)
        if it == 0:
            tried.append(a_new)  # the equation-error (ARX) estimate
        if np.allclose(a_new, a, rtol=0, atol=1e-9) and it > 1:
            a = a_new
            break
        a = a_new
    tried.append(a)  # the Steiglitz-McBride estimate (biased under coloured noise)
    # final pass: simulation-error least squares for B, offset, extra and the start-up
    # transient with A fixed
    ul = lagged(u, blags)
    yi = y[idx]
    sw = None if w is None else np.sqrt(w)

    def design(a_: np.ndarray) -> np.ndarray:
        return np.hstack(
            [signal.lfilter([1.0], a_, ul, axis=0), ones[:, None], ex, step_basis(a_, delay, nb, N)]
        )

    def sim_rss(a_: np.ndarray) -> float:
        X_ = design(a_)[idx]
        r_ = yi - X_ @ _wls(X_, yi, w)
        return float(np.sum(r_**2) if w is None else np.sum(w * r_**2))

    if a_fixed is None and len(tried) > 1:
        a = min(tried, key=sim_rss)
    if refine and a_fixed is None and a.size > 1:
        from scipy.optimize import least_squares

        def resid(th: np.ndarray) -> np.ndarray:
            a_ = stabilise(np.concatenate([[1.0], th]))
            X_ = design(a_)[idx]
            c_ = _wls(X_, yi, w)
            r_ = yi - X_ @ c_
            return r_ if sw is None else r_ * sw

        sol = least_squares(resid, a[1:], method="lm", max_nfev=40 * a.size, xtol=1e-10)
        a_ref = stabilise(np.concatenate([[1.0], sol.x]))
        if sim_rss(a_ref) <= sim_rss(a):
            a = a_ref
    X = design(a)
    coef = _wls(X[idx], y[idx], w)
    b = coef[:nb]
    yhat = X @ coef
    r = (y - yhat)[idx]
    rss = float(np.sum(r**2) if w is None else np.sum(w * r**2))
    lin = Linear(a=a, b=b, delay=int(delay))
    ne = ex.shape[1]
    return OEFit(
        lin=lin,
        offset=float(coef[nb]),
        yhat=yhat,
        rss=rss,
        n=int(idx.size),
        info={"extra": coef[nb + 1 : nb + 1 + ne].tolist()},
        init=np.asarray(coef[nb + 1 + ne :]),
    )


# --------------------------------------------------------------------------- the model


@dataclass
class Model:
    """A Hammerstein model of the record: ``y_hat = gain G(q) u + offset + trend``.

    ``u`` is the actuator output ``f(x(n - shift); theta)`` held over each slow period (``shift``
    slow samples of extra delay: the delay effect), ``G`` the fast-rate linear part (its
    numerator carries the fractional delay and the assumed multiple of p).
    """

    cls: str
    theta: dict[str, float]
    lin: Linear
    p: int
    shift: int = 0
    gain: float = 1.0
    offset: float = 0.0
    trend: np.ndarray = field(default_factory=lambda: np.zeros(0))
    init: np.ndarray = field(default_factory=lambda: np.zeros(0))
    label: str = "nominal"
    info: dict[str, Any] = field(default_factory=dict)

    def inner(self, x: np.ndarray) -> np.ndarray:
        """The actuator output at the slow rate, aligned with ``x`` (after ``shift``)."""
        u = nl_one(self.cls, x, self.theta)
        if self.shift > 0:
            u = np.concatenate([np.full(self.shift, u[0]), u[: -self.shift]])
        return u

    def response(self, x: np.ndarray) -> np.ndarray:
        """``G(q) u`` at the fast rate before gain and offset."""
        return self.lin.response(np.repeat(self.inner(x), self.p))

    def simulate(self, x: np.ndarray) -> np.ndarray:
        """``y_hat`` at the fast rate over the whole record, from ``x`` alone."""
        z = self.response(x)
        out = self.gain * z + self.offset
        if self.trend.size:
            out = out + trend_basis(z.size, self.trend.size) @ self.trend
        if self.init.size:
            out = out + self.init[0] * step_response(self.lin, z.size)
        return out

    def with_(self, **changes: Any) -> Model:
        return replace(self, **changes)


def step_response(lin: Linear, N: int) -> np.ndarray:
    """``G(q)`` applied to a unit step at ``t = 0``, ``(N,)``: the shape of the start-up
    transient of a record that starts from rest (the fitted ``Model.init`` scales it)."""
    return signal.lfilter(lin.num, lin.a, np.ones(N))


def start_transient(lin: Linear, N: int) -> np.ndarray:
    """The start-up transient column of the output fits, ``(N, 1)``, or ``(N, 0)`` when fits
    carry none (a plant log; see :func:`transient`)."""
    return step_response(lin, N)[:, None] if TRANSIENT["on"] else np.zeros((N, 0))


def trend_basis(N: int, order: int) -> np.ndarray:
    """Columns ``t, t^2, ...`` (``t`` in records: 0 at the start, 1 at ``N``); (N, order)."""
    t = np.arange(N) / max(N, 1)
    return np.stack([t ** (k + 1) for k in range(order)], axis=1) if order else np.zeros((N, 0))


def output_columns(model: Model, x: np.ndarray, trend: int = 0) -> np.ndarray:
    """``(N, k)``: the columns :func:`fit_output` fits, the simulation ``G f(x)``, the offset,
    ``trend`` polynomial terms and the start-up transient (when fits carry it)."""
    z = model.response(x)
    N = z.size
    return np.hstack(
        [z[:, None], np.ones((N, 1)), trend_basis(N, trend), start_transient(model.lin, N)]
    )


def fit_output(
    model: Model,
    x: np.ndarray,
    y: np.ndarray,
    idx: np.ndarray,
    *,
    trend: int = 0,
    weights: np.ndarray | None = None,
) -> Model:
    """Gain, offset (and ``trend`` polynomial terms, and the initial transient) of ``model`` by
    least squares on ``idx``."""
    X = output_columns(model, x, trend)
    coef = _wls(X[idx], np.asarray(y, float)[idx], None if weights is None else weights[idx])
    return model.with_(
        gain=float(coef[0]),
        offset=float(coef[1]),
        trend=np.asarray(coef[2 : 2 + trend]),
        init=np.asarray(coef[2 + trend :]),
    )


def _partitioned_ls(
    Z: list[np.ndarray], Sh: np.ndarray, y: np.ndarray, C: int
) -> tuple[np.ndarray, np.ndarray]:
    """Least squares for C candidates at once: regressors ``[Z_1 .. Z_nb | Sh]``.

    ``Z[i]`` (C, n) differ by candidate, ``Sh`` (n, ns) is shared, ``y`` (n,) is the target.
    Normal equations assembled blockwise (shared block once), lightly regularised (1e-12 of the
    trace), solved per candidate. Returns ``(theta (C, nb + ns), rss (C,))`` with
    ``rss = y'y - 2 theta'g + theta'G theta`` clipped at 0.
    """
    nb = len(Z)
    m = nb + Sh.shape[1]
    G = np.empty((C, m, m))
    g = np.empty((C, m))
    for i1 in range(nb):
        g[:, i1] = Z[i1] @ y
        G[:, i1, nb:] = Z[i1] @ Sh
        G[:, nb:, i1] = G[:, i1, nb:]
        for i2 in range(i1, nb):
            G[:, i1, i2] = G[:, i2, i1] = np.einsum("cn,cn->c", Z[i1], Z[i2])
    G[:, nb:, nb:] = Sh.T @ Sh
    g[:, nb:] = Sh.T @ y
    G = G + 1e-12 * (np.trace(G, axis1=1, axis2=2) + 1e-300)[:, None, None] * np.eye(m)
    th = np.linalg.solve(G, g[..., None])[..., 0]
    rss = np.maximum(
        y @ y - 2 * np.einsum("ci,ci->c", th, g) + np.einsum("ci,cij,cj->c", th, G, th), 0.0
    )
    return th, rss


def batch_fixed_a(
    u: np.ndarray,
    y: np.ndarray,
    a: np.ndarray,
    delays: Any,
    nb: int,
    idx: np.ndarray,
    weights: np.ndarray | None = None,
    prefilter: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Separable least squares over a batch of inputs with the denominator ``a`` fixed.

    For every candidate input ``u[c]`` (shape ``(C, N)``, fast rate) and every delay in
    ``delays``: ``y ~ sum_j b_j q^-(delay+j) / A(q) (u - u0) + m`` by least squares on ``idx``.
    Returns ``rss`` of shape ``(C, n_delays)``, the coefficients ``(C, n_delays, nb + 1)`` (``b``
    then ``m``) and the delays as an array. ``prefilter`` (an FIR ``D(q)``, the inverse of a
    noise model) filters both sides: the prediction-error criterion of ``y = G u + e / D``.
    """
    u = np.atleast_2d(np.asarray(u, float))
    C, N = u.shape
    y = np.asarray(y, float)
    delays = np.atleast_1d(np.asarray(delays, int))
    if prefilter is None:
        z = signal.lfilter([1.0], a, u - u[:, :1], axis=-1)  # (C, N)
    else:
        z = signal.lfilter(prefilter, a, u - u[:, :1], axis=-1)
        y = signal.lfilter(prefilter, [1.0], y)
    idx = np.asarray(idx)
    w = np.ones(idx.size) if weights is None else np.asarray(weights, float)[idx]
    yi = y[idx]
    rss = np.empty((C, delays.size))
    coef = np.empty((C, delays.size, nb + 1))
    sw = np.sqrt(w)
    yw = yi * sw
    for j, d in enumerate(delays):
        # shared columns: the offset and the start-up transient
        fb = step_basis(a, int(d), nb, N)
        if prefilter is not None and fb.shape[1]:
            fb = signal.lfilter(prefilter, [1.0], fb, axis=0)
        Sh = np.hstack([np.ones((N, 1)), fb])[idx] * sw[:, None]  # (n, ns)
        Z = []
        for lag in range(d + 1, d + 1 + nb):
            src = idx - lag
            col = np.where(src[None, :] >= 0, z[:, np.clip(src, 0, None)], 0.0)
            Z.append(col * sw[None, :])
        th, rss[:, j] = _partitioned_ls(Z, Sh, yw, C)
        coef[:, j] = th[:, : nb + 1]
    return rss, coef, delays


def arx_residual(
    u: np.ndarray, y: np.ndarray, na: int, nb: int, delay: int, idx: np.ndarray
) -> np.ndarray:
    """The residual of the equation-error regression of :func:`arx_rss` on ``idx``."""
    u = np.asarray(u, float)
    y = np.asarray(y, float)
    sel = np.asarray(idx)
    sel = sel[sel >= max(na, delay + nb)]
    cols = [lagged(u, range(delay + 1, delay + 1 + nb))]
    if na:
        cols.insert(0, -lagged(y, range(1, na + 1)))
    Phi = np.hstack([*cols, np.ones((y.size, 1))])[sel]
    theta = np.linalg.lstsq(Phi, y[sel], rcond=None)[0]
    return y[sel] - Phi @ theta


def arx_rss(
    u: np.ndarray, y: np.ndarray, na: int, nb: int, delay: int, idx: np.ndarray
) -> tuple[float, int]:
    """RSS and number of parameters of the equation-error regression
    ``y(t) = -a y(t-1..na) + b u(t-delay-1..) + m`` on the samples ``idx``."""
    u = np.asarray(u, float)
    y = np.asarray(y, float)
    start = max(na, delay + nb)
    sel = np.asarray(idx)
    sel = sel[sel >= start]
    cols = [lagged(u, range(delay + 1, delay + 1 + nb))]
    if na:
        cols.insert(0, -lagged(y, range(1, na + 1)))
    Phi = np.hstack([*cols, np.ones((y.size, 1))])[sel]
    theta = np.linalg.lstsq(Phi, y[sel], rcond=None)[0]
    r = y[sel] - Phi @ theta
    return float(r @ r), int(Phi.shape[1])


def batch_arx(
    u: np.ndarray,
    y: np.ndarray,
    na: int,
    nb: int,
    delay: int,
    idx: np.ndarray,
    extra: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Equation-error least squares over a batch of inputs.

    For every candidate input ``u[c]`` (shape ``(C, N)``):
    ``y(t) = -a1 y(t-1) .. - a_na y(t-na) + b1 u(t-delay-1) + .. + m`` on the samples ``idx``
    (the maximum-likelihood criterion under the paper's equation-error noise ``e / A``).
    ``extra`` (shape ``(N, k)``): more regressors shared by every candidate (e.g. a trend),
    their coefficients after ``m``. Returns ``rss`` ``(C,)`` and ``theta``
    ``(C, na + nb + 1 + k)`` ordered ``a, b, m`` (then ``extra``'s).
    """
    u = np.atleast_2d(np.asarray(u, float))
    C, N = u.shape
    y = np.asarray(y, float)
    idx = np.asarray(idx)
    idx = idx[idx >= max(na, delay + nb)]
    yi = y[idx]
    shared = [-lagged(y, range(1, na + 1)), np.ones((N, 1))]
    if extra is not None:
        shared.append(np.asarray(extra, float).reshape(N, -1))
    Sh = np.hstack(shared)[idx]  # (n, na + 1 + k)
    # idx >= delay + nb, so every lagged row is a sample of u: views of u where the rows are
    # consecutive (the usual case), a gather otherwise; row-major either way, which the
    # products below run fastest on
    window = idx.size > 0 and bool(np.all(np.diff(idx) == 1))
    Z = [
        u[:, idx[0] - lag : idx[0] - lag + idx.size] if window else np.take(u, idx - lag, axis=1)
        for lag in range(delay + 1, delay + 1 + nb)
    ]
    th, rss = _partitioned_ls(Z, Sh, yi, C)
    # reorder to a, b, m
    theta = np.concatenate([th[:, nb : nb + na], th[:, :nb], th[:, nb + na :]], axis=1)
    return rss, theta

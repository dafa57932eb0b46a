"""Polyphase numerics shared by every blind method (Wang et al., Sections 3 and 4).

Indexing convention, used everywhere in hbench: fast sample ``t`` of the record; the inner signal
changes only at ``t = k p`` (property (1)). A candidate shift ``s`` in ``[0, p)`` is the fractional
delay tau; the paper shifts the output, ``y~(t) = y(t + s)``, and speaks of phase ``l = 1 .. p`` of
period ``k``: here that is the record's sample ``t = k p + l + s``. With the right shift, phase
l of ``Delta w = Delta A(q) y`` carries ``b_l Delta U(k)`` for ``l = 1 .. nb`` ("active", eq. 11)
and only noise for ``l = nb + 1 .. p`` ("quiet", eqs. 10, 12).

All functions are batched over runs (arrays ``(runs, ...)``, time last) for runs that share one
structure (na, nb, tau); callers group runs by structure.
"""

from __future__ import annotations

import functools
from collections.abc import Sequence
from typing import Any

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view
from scipy import signal
from scipy.linalg import lapack

from hbench.docparams import parameters
from hbench.numerics import kernels
from hbench.numerics.ordered import cholesky_inverse, ordered_products

_RCOND = 1e-12


#: numpydoc descriptions of the parameters shared here (:func:`hbench.docparams.parameters`)
_PARAMS: dict[str, tuple[str, str]] = {
    "N": ("int", "Fast samples of the record."),
    "p": ("int", "Fast-sampling ratio."),
    "shift": ("int", "Shift of the phases (the delay tau within a period)."),
    "na": ("int", "Denominator order."),
    "reg": ("QuietRegression", "The quiet-phase equations (13)."),
    "r": ("ndarray", "Reference at the slow rate, ``(runs, K)``."),
    "m": ("int", "Number of instruments."),
    "lag0": ("int, optional", "Lag of the first instrument (the paper's 1)."),
    "a": ("ndarray", "``(runs, na + 1)`` with the leading 1."),
    "y": ("ndarray", "Fast-rate outputs, ``(runs, N)``."),
    "dw": ("ndarray", "``Delta w`` with ``w = A(q) y``, ``(runs, N)``."),
    "t_min": ("int", "First fast sample that is defined."),
    "nb": ("int", "Numerator order."),
    "b": ("ndarray", "Numerators ``(runs, nb)``."),
    "sys": ("SimoSystem", "The SIMO blocks of (23) (:func:`simo_system`)."),
    "h0": ("ndarray", "``h_i(0)``, ``(runs, p)`` (:func:`simo_channels`)."),
    "h1": ("ndarray", "``h_i(1)``, ``(runs, p)``."),
}


# --- indexing ----------------------------------------------------------------------------------


@parameters(
    _PARAMS,
    l=("int", "Phase, 1 .. p."),
    t_min=("int", "First admissible fast sample."),
    k_min=("int, optional", "First admissible slow index."),
)
def phase_times(N: int, p: int, l: int, shift: int, t_min: int, k_min: int = 0) -> np.ndarray:
    """Slow indices ``k`` whose sample ``t = k p + l + shift`` satisfies ``t_min <= t < N``."""
    k0 = max(k_min, -(-(t_min - l - shift) // p))
    k1 = (N - 1 - l - shift) // p
    return np.arange(k0, k1 + 1) if k1 >= k0 else np.zeros(0, dtype=int)


@parameters(_PARAMS, z=("ndarray", "Signals, time on the last axis."))
def delta(z: np.ndarray) -> np.ndarray:
    """``Delta z(t) = z(t) - z(t-1)`` with ``Delta z(0) = nan`` (same length, time last)."""
    out = np.empty_like(z, dtype=float)
    out[..., 0] = np.nan
    np.subtract(z[..., 1:], z[..., :-1], out=out[..., 1:])
    return out


@parameters(
    _PARAMS,
    z=("ndarray", "Signals ``(runs, N)``."),
    block=("int, optional", "Samples scanned at a time."),
)
def first_valid(z: np.ndarray, block: int = 64) -> int:
    """Index of the first sample that is defined (not nan) in every run of ``z``.

    Scans ``block`` samples at a time from the start (a record's undefined samples are its
    first few), so a long record is not read to the end.
    """
    N = z.shape[-1]
    for t0 in range(0, N, block):
        bad = np.isnan(z[..., t0 : t0 + block]).reshape(-1, min(block, N - t0)).any(axis=0)
        if not bad.all():
            return t0 + int(np.argmin(bad))
    return N


# --- denominator: quiet-phase regressions (eqs. 13-15, 19, 20) ---------------------------------


class LagMoments:
    """Every second moment the quiet-phase regressions need, from one batched Gram matrix.

    With ``L`` the largest regression order, the window of period ``k``,
    ``z_k = [Delta y(k p - L) .. Delta y(k p + p - 1)]``, holds every sample and lag a regression
    at any phase and shift can use; ``G = (1/n) sum_k z_k z_k^T`` over the periods
    ``k0 .. k1`` whose window lies in the record (``k p - L >= 1``: ``Delta y(0)`` is undefined)
    then gives, for the residue class ``c = t mod p`` and lags ``i, j <= L``,
    ``(1/n) sum_t Delta y(t - i) Delta y(t - j)`` as ``G[L + c - i, L + c - j]``. One Gram per
    batch (``O(K (p + L)^2)`` per run) serves the selection tables of every order, shift and
    phase and the final fits; :class:`QuietRegression` rows use exactly the same periods.
    """

    def __init__(self, dy: np.ndarray, p: int, L: int, G: np.ndarray | None = None) -> None:
        self.p, self.L = int(p), int(L)
        K = dy.shape[1] // p
        self.k0, self.k1 = -(-(self.L + 1) // self.p), K - 1
        self.n = max(self.k1 - self.k0 + 1, 0)
        if self.n < 1:
            raise ValueError(f"record too short for regressions of order {L} at p = {p}")
        if G is None:
            win = sliding_window_view(dy, self.p + self.L, axis=1)[
                :, self.k0 * self.p - self.L :: self.p
            ]
            win = win[:, : self.n]
            G = np.einsum("rni,rnj->rij", win, win, optimize=True) / self.n
        self.G = G

    def take(self, idx: np.ndarray) -> LagMoments:
        """The same moments for the runs ``idx``."""
        sub = object.__new__(LagMoments)
        sub.p, sub.L, sub.k0, sub.k1, sub.n = self.p, self.L, self.k0, self.k1, self.n
        sub.G = self.G[idx]
        return sub

    def block(self, c: int, na: int) -> np.ndarray:
        """``(1/n) sum_t v(t) v(t)^T``, ``v = [Delta y(t) .. Delta y(t - na)]``, ``t = c mod p``."""
        a = self.L + c - np.arange(na + 1)
        return self.G[:, a[:, None], a[None, :]]


class QuietRegression:
    """The quiet-phase equations (13), stacked over the requested phases.

    ``target[r, j] = Delta y(t_j)``, ``phi[r, j, :] = -[Delta y(t_j - 1) .. Delta y(t_j - na)]``;
    ``k[j]`` is the slow index of row ``j`` (for instruments). Rows are the periods of a
    :class:`LagMoments` (the same for every order up to its ``L``), so the moments come from its
    Gram matrix without forming the rows; ``target`` and ``phi`` are formed only when a method
    asks for them. ``fast=True`` evaluates residual mean squares from the moments
    (``yy - 2 theta.f + theta' R theta``): exact algebra, but with rounding of order eps times
    ``yy`` (use it for selection tables, not final fits).
    """

    def __init__(
        self,
        dy: np.ndarray,
        lm: LagMoments,
        na: int,
        phases: tuple[int, ...] | list[int],
        shift: int,
        fast: bool = False,
    ) -> None:
        if na > lm.L:
            raise ValueError(f"order {na} exceeds the moments' largest lag {lm.L}")
        p = lm.p
        self.dy, self.lm, self.fast = dy, lm, fast
        self.phases, self.shift = tuple(int(l) for l in phases), int(shift)
        self._na = int(na)
        #: per phase: the residue class ``c = t mod p`` of its samples and the periods ``carry``
        #: between the slow index ``k`` of the paper's numbering and the period of ``t``
        self.classes = [((l + self.shift) % p, (l + self.shift) // p) for l in self.phases]
        periods = np.arange(lm.k0, lm.k1 + 1)
        self.t = np.concatenate([periods * p + c for c, _ in self.classes])
        self.k = np.concatenate([periods - carry for _, carry in self.classes])
        self._cache: dict[str, Any] = {}  # arrays, and the truncations to lower orders

    @property
    def n(self) -> int:
        return self.t.size

    @property
    def na(self) -> int:
        return self._na

    @property
    def target(self) -> np.ndarray:
        """``Delta y(t_j)`` per run, ``(runs, n)``."""
        if "target" not in self._cache:
            self._cache["target"] = take_periods(self.dy, self.t)
        return self._cache["target"]

    @property
    def phi(self) -> np.ndarray:
        """``-[Delta y(t_j - 1) .. Delta y(t_j - na)]`` per run, ``(runs, n, na)``."""
        if "phi" not in self._cache:
            lags = np.arange(1, self._na + 1)
            self._cache["phi"] = -take_periods(self.dy, self.t[:, None] - lags[None, :])
        return self._cache["phi"]

    def all_moments(self) -> np.ndarray:
        """``(1/n) sum z z^T`` with ``z = [Delta y(t), phi(t)]``: the mean of the phases' blocks."""
        if "M" not in self._cache:
            M = sum(self.lm.block(c, self._na) for c, _ in self.classes)
            M = M / len(self.phases)
            sign = np.ones(self._na + 1)
            sign[1:] = -1.0
            # C order whatever the number of runs (the fancy-indexed blocks are laid out
            # differently for one run than for many, and matmul's rounding follows the layout)
            self._cache["M"] = np.ascontiguousarray(M * sign[:, None] * sign[None, :])
        return self._cache["M"]

    def moments(self) -> tuple[np.ndarray, np.ndarray]:
        """``(Rm, f)``: ``(1/n) sum phi phi^T`` and ``(1/n) sum phi Delta y``."""
        M = self.all_moments()
        return M[:, 1:, 1:], M[:, 1:, 0]

    def inverse(self) -> np.ndarray:
        """``Rm^+``, the pseudo-inverse of ``(1/n) sum phi phi^T``, computed once per regression
        (the LSM's and the OLS's selection tables share it on one record)."""
        if "Rinv" not in self._cache:
            group = [
                reg for reg in self._cache.pop("inverted-with", [self]) if "Rinv" not in reg._cache
            ]
            Rinv = _pinv_sym(np.stack([reg.moments()[0] for reg in group]))
            Rinv.flags.writeable = False  # shared by the methods run on one record
            for reg, inv in zip(group, Rinv, strict=True):
                reg._cache.pop("inverted-with", None)
                reg._cache["Rinv"] = inv
        return self._cache["Rinv"]

    @staticmethod
    def invert_together(regs: Sequence[QuietRegression]) -> None:
        """Let regressions of one order (the shifts of a selection table) compute their
        :meth:`inverse` together: the first asked inverts every one of them in one batched call.
        LAPACK inverts the matrices one by one whatever the batch, so the numbers are the same;
        the call's overhead is paid once."""
        group = [reg for reg in regs if "Rinv" not in reg._cache]
        if len(group) > 1 and len({reg.na for reg in group}) == 1:
            for reg in group:
                reg._cache["inverted-with"] = group

    def least_squares(self) -> tuple[np.ndarray, np.ndarray]:
        """``(theta, residual mean square)`` of the ordinary LS of (13), ``theta = Rm^+ f``,
        computed once per regression (the OLS and the bias-compensated LSM both start from it,
        so their selection tables on one record share it). Read-only arrays."""
        if "ls" not in self._cache:
            theta = np.einsum("rik,rk->ri", self.inverse(), self.moments()[1])
            ms = self.residual_ms(theta)
            theta.flags.writeable = False
            ms.flags.writeable = False
            self._cache["ls"] = (theta, ms)
        return self._cache["ls"]

    def residual_ms(self, theta: np.ndarray) -> np.ndarray:
        """``(1/n) sum (Delta y - phi^T theta)^2`` per run.

        From the moments, ``v' M v`` with ``v = [1, -theta]``. Its rounding is of order eps
        times ``M[0, 0]``; unless ``fast``, runs whose residual is below ``1e-6 M[0, 0]`` (where
        that rounding would exceed ~1e-10 of the value, e.g. noise-free data) are recomputed
        from the rows.
        """
        M = self.all_moments()
        v = np.ones((theta.shape[0], self._na + 1))
        v[:, 1:] = -theta
        ms = np.sum(v * np.matmul(M, v[..., None])[..., 0], axis=1)
        if self.fast:
            return ms
        exact = ms < 1e-6 * M[:, 0, 0]
        if exact.any():
            rows = np.flatnonzero(exact)
            res = self.dy[np.ix_(rows, self.t)]
            for i in range(1, self._na + 1):
                res += theta[rows, i - 1 : i] * self.dy[np.ix_(rows, self.t - i)]
            ms = ms.copy()
            ms[rows] = np.mean(res**2, axis=1)
        return ms

    def truncate(self, na: int) -> QuietRegression:
        """The same rows with the first ``na`` regressors (moments from the same Gram); one
        object per order, kept, so that what it computes is computed once."""
        key = f"truncate/{int(na)}"
        if key not in self._cache:
            self._cache[key] = QuietRegression(
                self.dy, self.lm, na, self.phases, self.shift, self.fast
            )
        return self._cache[key]


@parameters(
    _PARAMS,
    dy=("ndarray", "``delta(y)``, ``(runs, N)``."),
    phases=("sequence of int", "The phases ``l`` (1-based) whose equations are stacked."),
    moments=("LagMoments, optional", "Moments of the same ``dy`` (rows and Gram shared)."),
    fast=(
        "bool, optional",
        "Residual mean squares from the moments (see :class:`QuietRegression`).",
    ),
)
def quiet_regression(
    dy: np.ndarray,
    p: int,
    na: int,
    phases: tuple[int, ...] | list[int],
    shift: int,
    moments: LagMoments | None = None,
    fast: bool = False,
) -> QuietRegression:
    """Rows of eq. (13) at the given phases (1-based ``l``) under ``shift``.

    ``dy`` is ``delta(y)``. ``moments`` (computed from the same ``dy``) fixes the rows to its
    periods and shares its Gram; without it one is computed with ``L = na``.
    """
    lm = LagMoments(dy, p, na) if moments is None else moments
    return QuietRegression(dy, lm, na, phases, shift, fast)


#: :func:`_pinv_sym` inverts through the Cholesky factor below this bound on the condition number
#: (far below ``1 / _RCOND``, so the pseudo-inverse would cut nothing there)
_CHOLESKY_COND = 1e9


def _pinv_sym(Rm: np.ndarray) -> np.ndarray:
    """``Rm^+`` of symmetric positive semi-definite matrices ``(..., n, n)``: the inverse through
    the Cholesky factor (:func:`hbench.numerics.ordered.cholesky_inverse`) where
    ``tr(Rm) tr(Rm^-1)`` (a bound on the condition number) is below :data:`_CHOLESKY_COND`, and
    ``np.linalg.pinv`` (``eigh``, eigenvalues below ``_RCOND`` times the largest cut) for the
    others, e.g. an order above the true one on noise-free data. Both are the pseudo-inverse to
    rounding; the first is ~10x faster on the regressions' 1x1 .. 5x5 matrices. C-ordered."""
    X, ok = cholesky_inverse(Rm, _CHOLESKY_COND)
    if not ok.all():
        bad = ~ok
        X[bad] = np.linalg.pinv(Rm[bad], rcond=_RCOND, hermitian=True)
    return X


@parameters(_PARAMS)
def ols(reg: QuietRegression) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Ordinary LS of (13): ``(theta, residual mean square, g11)``; biased under noise."""
    theta, ms = reg.least_squares()
    return theta.copy(), ms.copy(), reg.inverse()[:, 0, 0].copy()


#: How :func:`noise_variance` reads eq. (15) where it has no real root (``g11 s2 > 1``).
NO_ROOT = ("clip", "real", "modulus", "zero")


@parameters(
    _PARAMS,
    s2=("ndarray", "OLS residual mean square per run."),
    g11=("ndarray", "``(R^-1)_{11}`` per run."),
    no_root=("str, optional", "``clip``, ``real``, ``modulus`` or ``zero`` (above)."),
)
def noise_variance(s2: np.ndarray, g11: np.ndarray, no_root: str = "clip") -> np.ndarray:
    """Eq. (15), corrected: sigma^2 from the OLS residual mean square ``s2`` and ``g11``.

    The OLS residual mean square tends to ``2 sigma^2 - g11 sigma^4`` (not ``sigma^2 - ...`` as the
    extraction prints), so sigma^2 is the root of ``g11 x^2 - 2 x + s2 = 0`` that tends to ``s2/2``
    as ``g11 -> 0``: ``x = (1 - sqrt(1 - g11 s2)) / g11``, written stably as
    ``s2 / (1 + sqrt(1 - g11 s2))``.

    Where the discriminant ``1 - g11 s2`` is negative (a noise realisation far from the
    asymptote, or a regression on an active phase) there is no real root; ``no_root`` says what
    is taken: ``clip`` (default) the discriminant clipped to zero in the stable form above,
    ``x = s2``; ``real`` the complex roots' real part ``1/g11`` (the discriminant clipped in the
    form ``(1 - sqrt(.)) / g11``); ``modulus`` their modulus ``sqrt(s2 / g11)``, which gives the
    compensated residual ``s2 + g11 |x|^2 = 2 s2`` (as complex arithmetic with ``|e|^2`` would);
    ``zero`` no compensation, ``x = 0``.
    """
    disc = 1.0 - g11 * s2
    x = s2 / (1.0 + np.sqrt(np.clip(disc, 0.0, None)))
    if no_root == "clip":
        return x
    if no_root not in NO_ROOT:
        raise ValueError(f"no_root must be one of {', '.join(NO_ROOT)}, got {no_root!r}")
    none = disc < 0.0
    if not none.any():
        return x
    with np.errstate(invalid="ignore", divide="ignore"):
        other = {
            "real": lambda: 1.0 / g11,
            "modulus": lambda: np.sqrt(s2 / g11),
            "zero": lambda: np.zeros_like(x),
        }[no_root]()
    return np.where(none, other, x)


@parameters(
    _PARAMS, no_root=("str, optional", "Eq. (15) without a real root (:func:`noise_variance`).")
)
def bias_compensated(reg: QuietRegression, no_root: str = "clip") -> tuple[np.ndarray, np.ndarray]:
    """Eqs. (14)-(15): ``theta = R^-1 (f - [sigma^2, 0, ..., 0])`` and ``sigma^2``.

    ``E{phi(k) Delta e(kp+l)} = [+sigma^2, 0, ..., 0]`` because ``phi_1 = -Delta y(t-1)`` holds
    ``-e(t-1)`` and ``Delta e(t) = e(t) - e(t-1)``; the compensation therefore subtracts it.
    ``no_root``: eq. (15) without a real root (:func:`noise_variance`).
    """
    Rinv = reg.inverse()
    theta_ols, ms = reg.least_squares()
    sigma2 = noise_variance(ms, Rinv[:, 0, 0], no_root)
    theta = theta_ols - Rinv[:, :, 0] * sigma2[:, None]
    return theta, sigma2


@parameters(_PARAMS, k=("ndarray of int", "Slow indices of the equations."))
def instruments(
    r: np.ndarray, k: np.ndarray, m: int, lag0: int = 1
) -> tuple[np.ndarray, np.ndarray]:
    """``zeta(k) = [r(k - lag0), .., r(k - lag0 - m + 1)]`` (eq. 20: lag0 = 1) and a row mask."""
    lags = lag0 + np.arange(m)
    idx = k[:, None] - lags[None, :]
    ok = np.all((idx >= 0) & (idx < r.shape[1]), axis=1)
    return r[:, np.clip(idx, 0, r.shape[1] - 1)], ok


#: Runs whose instruments are laid out and multiplied together (they stay in a core's cache).
IV_BLOCK = 16


@parameters(_PARAMS)
def iv_moments(reg: QuietRegression, r: np.ndarray, m: int, lag0: int = 1) -> np.ndarray:
    """``(1/n) sum zeta [Delta y, phi^T]`` over the rows with every instrument defined.

    Phase by phase (the rows of a phase are consecutive periods): the instruments and the lags
    of ``Delta y`` are strided windows, multiplied as ``Z^T [Delta y, -phi]`` by one batched
    product per phase. Returns ``(runs, m, na + 1)``.
    """
    p, na, K = reg.lm.p, reg.na, r.shape[1]
    R = r.shape[0]
    out = np.zeros((R, m, na + 1))
    if K < m:  # no row has all its instruments
        return out
    periods = np.arange(reg.lm.k0, reg.lm.k1 + 1)
    phases = []  # (first instrument sample, first row's t, rows) per phase with rows
    for c, carry in reg.classes:
        k = periods - carry
        ok = (k - lag0 - m + 1 >= 0) & (k - lag0 < K)
        if ok.any():
            kk = periods[ok]
            phases.append((int(kk[0] - carry - lag0), int(kk[0] * p + c), kk.size))
    # a few runs at a time, so that their instruments and lags stay in cache between being laid
    # out and multiplied; phases with the same instrument rows share them (a run's products,
    # and their order of accumulation over the phases, are those of the whole batch at once)
    for b0 in range(0, R, IV_BLOCK):
        rb, db, ob = r[b0 : b0 + IV_BLOCK], reg.dy[b0 : b0 + IV_BLOCK], out[b0 : b0 + IV_BLOCK]
        laid: dict[tuple[int, int], np.ndarray] = {}
        for start, t0, size in phases:
            ZT = laid.get((start, size))
            if ZT is None:  # zeta(k)^T of the rows, (runs, m, n_c)
                ZT = laid[start, size] = _lagged_rows(rb, start, m, size)
            # the lags of Delta y of the rows, laid out like zeta^T: (runs, na + 1, n_c)
            lagged = _lagged_rows(db, t0, na + 1, size, p)
            ob += _instrument_products(ZT, lagged.transpose(0, 2, 1))
    n = sum(size for _, _, size in phases)
    out[:, :, 1:] *= -1.0
    return out / max(n, 1)


def _lagged_rows(r: np.ndarray, start: int, m: int, n: int, step: int = 1) -> np.ndarray:
    """``out[:, i, j] = r[:, start - i + j step]``, ``(R, m, n)`` in C order: ``m`` lags of ``n``
    rows ``step`` samples apart, transposed, copied lag by lag (slices, no gather)."""
    out = np.empty((r.shape[0], m, n))
    for i in range(m):
        out[:, i, :] = r[:, start - i : start - i + (n - 1) * step + 1 : step]
    return out


def _instrument_products(ZT: np.ndarray, Y: np.ndarray) -> np.ndarray:
    """``sum_j ZT[:, :, j] Y[:, j]^T`` per run: ``(R, m, q)`` from ``(R, m, n)`` and ``(R, n, q)``.

    One batched product; ``Y`` is the transpose of a C-ordered ``(R, q, n)`` array (numpy hands
    it to BLAS as such, without a copy). Every run's operands have the same layout whatever the
    batch, so each run's product is the same BLAS call and its numbers do not depend on the
    runs batched with it."""
    return np.matmul(np.ascontiguousarray(ZT), Y)


@parameters(_PARAMS)
def iv(reg: QuietRegression, r: np.ndarray, m: int, lag0: int = 1) -> np.ndarray:
    """Eq. (20): extended IV ``theta = [(1/n) sum zeta phi^T]^+ (1/n) sum zeta Delta y``."""
    G = iv_moments(reg, r, m, lag0)
    return np.einsum("rim,rm->ri", np.linalg.pinv(G[:, :, 1:], rcond=_RCOND), G[:, :, 0])


@parameters(
    _PARAMS, ms=("ndarray", "Residual mean square per run."), K=("int", "Rows of the regression.")
)
def aic(ms: np.ndarray, na: int, K: int) -> np.ndarray:
    """Eq. (19): ``V(na) = (1 + 2 na / K) (1/K) sum (Delta y - phi^T theta)^2`` from the residual
    mean square ``ms`` over ``K`` rows.
    """
    return (1.0 + 2.0 * na / K) * ms


# --- numerator (eqs. 17, 18, 21) ---------------------------------------------------------------


@parameters(
    _PARAMS, a=("ndarray", "``(runs, N)``."), t=("ndarray of int", "Sample indices, any shape.")
)
def take_periods(a: np.ndarray, t: np.ndarray) -> np.ndarray:
    """``a[:, t]`` for an index array ``t`` of any shape, in C order.

    ``a[:, t]`` lays the result out with the run axis innermost when ``t`` is 2-D, but not for
    one run; reductions and products then sum in another order, and a run's numbers would
    depend on the runs batched with it. ``np.take`` gives the same layout for any batch.
    """
    return np.take(a, t, axis=1)


@parameters(_PARAMS)
def filtered_output(y: np.ndarray, a: np.ndarray) -> np.ndarray:
    """``w(t) = A(q) y(t)`` per run (``a`` of shape ``(runs, na + 1)``); ``nan`` for ``t < na``.

    Compiled when :mod:`hbench.numerics.kernels` is built (the same bits as the numpy lines below).
    """
    compiled = kernels.filtered_output(y, a)
    if compiled is not None:
        return compiled
    na = a.shape[1] - 1
    N = y.shape[1]
    w = np.empty(y.shape)
    w[:, :na] = np.nan
    np.multiply(a[:, :1], y[:, na:], out=w[:, na:])
    for i in range(1, na + 1):
        w[:, na:] += a[:, i : i + 1] * y[:, na - i : N - i]
    return w


@parameters(_PARAMS)
def filtered_output_and_delta(y: np.ndarray, a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(w, delta(w))`` with ``w =`` :func:`filtered_output` ``(y, a)``: compiled in one pass
    per run when :mod:`hbench.numerics.kernels` is built (the same bits as the two calls).
    """
    compiled = kernels.filtered_output_and_delta(y, a)
    if compiled is not None:
        return compiled
    w = filtered_output(y, a)
    return w, delta(w)


@parameters(_PARAMS)
def common_periods(dw: np.ndarray, p: int, shift: int, t_min: int, nb: int) -> np.ndarray:
    """Slow indices k whose phases 1 .. nb all have a defined sample (the numerator's rows)."""
    k = phase_times(dw.shape[1], p, 1, shift, t_min)
    k_last = phase_times(dw.shape[1], p, nb, shift, t_min)
    return np.intersect1d(k, k_last)


@parameters(
    _PARAMS,
    a=("ndarray", "``(runs, N)``."),
    k=("ndarray of int", "Slow indices."),
    width=("int", "Phases taken per period."),
)
def period_block(a: np.ndarray, p: int, k: np.ndarray, shift: int, width: int) -> np.ndarray:
    """``a[:, k p + shift + l]`` for ``l = 1 .. width``, shape ``(runs, len(k), width)``.

    A strided view when ``k`` is consecutive (as :func:`common_periods` gives) and ``a`` is laid
    out row by row, else a C-order gather (:func:`take_periods`). Elementwise results computed
    from either are the same C-order arrays, so reductions over them sum in the same order.
    """
    row_major = (
        a.ndim == 2
        and a.strides[1] == a.itemsize
        and (a.shape[0] == 1 or abs(a.strides[0]) >= a.shape[1] * a.itemsize)
    )  # a view of another layout would lay out (and sum) elementwise results otherwise
    if row_major and k.size and int(k[-1] - k[0]) == k.size - 1:
        start = int(k[0]) * p + shift + 1
        stop = int(k[-1]) * p + shift + width + 1
        return sliding_window_view(a[:, start:stop], width, axis=1)[:, ::p]
    t = k[:, None] * p + np.arange(1, width + 1)[None, :] + shift
    return take_periods(a, t)


@parameters(_PARAMS)
def phase_variances(dw: np.ndarray, p: int, shift: int, t_min: int) -> np.ndarray:
    """``Var{Delta w^(l)}``, l = 1..p (the paper's Table 2): mean square over common periods."""
    k = common_periods(dw, p, shift, t_min, p)
    block = period_block(dw, p, k, shift, p)
    compiled = kernels.period_mean_squares(block)  # the same sums, term after term
    return compiled if compiled is not None else np.mean(np.square(block), axis=1)


@parameters(_PARAMS)
def filtered_phase_variances(
    y: np.ndarray, a: np.ndarray, p: int, shift: int, t_min: int
) -> np.ndarray:
    """:func:`phase_variances` of ``delta(filtered_output(y, a))``; compiled, the kernel forms
    neither ``w`` nor ``Delta w`` (the same numbers: the same operations in the same order).
    """
    k = common_periods(y, p, shift, t_min, p)
    if k.size and int(k[-1] - k[0]) == k.size - 1:
        compiled = kernels.filtered_phase_variances(y, a, p, int(k[0]) * p + shift + 1, k.size)
        if compiled is not None:
            return compiled
    return phase_variances(delta(filtered_output(y, a)), p, shift, t_min)


@parameters(_PARAMS, sigma2=("ndarray", "Noise variance per run (eq. 15)."))
def b_lsm(
    dw: np.ndarray, p: int, shift: int, nb: int, sigma2: np.ndarray, t_min: int
) -> np.ndarray:
    """Eq. (18) with corrected signs.

    ``b_l = (mean dw1 dwl + sigma^2 delta(l-2)) / (mean dw1^2 - 2 sigma^2)``.

    ``E{Delta e(kp+1) Delta e(kp+2)} = -sigma^2`` and ``E{Delta e^2} = 2 sigma^2`` give those signs.
    Returns ``(runs, nb)`` with ``b1 = 1``.
    """
    k = common_periods(dw, p, shift, t_min, nb)
    D = period_block(dw, p, k, shift, nb)  # (R, n, nb)
    d1 = D[:, :, 0]
    den = np.mean(d1**2, axis=1) - 2.0 * sigma2
    b = np.ones((dw.shape[0], nb))
    for l in range(2, nb + 1):
        num = np.mean(d1 * D[:, :, l - 1], axis=1) + (sigma2 if l == 2 else 0.0)
        b[:, l - 1] = num / den
    return b


@parameters(_PARAMS)
def b_ols(dw: np.ndarray, p: int, shift: int, nb: int, t_min: int) -> np.ndarray:
    """LS ratio of active phases, ``b_l = sum dw1 dwl / sum dw1^2`` (the noise-free design)."""
    return b_lsm(dw, p, shift, nb, np.zeros(dw.shape[0]), t_min)


@parameters(_PARAMS)
def b_iv(
    dw: np.ndarray, r: np.ndarray, p: int, shift: int, nb: int, m: int, t_min: int, lag0: int = 1
) -> np.ndarray:
    """Eq. (21): ``b_l = [(1/K) sum zeta dw1]^+ (1/K) sum zeta dwl``, ``zeta(k) = r(k-1..k-m)``."""
    k = common_periods(dw, p, shift, t_min, nb)
    if k.size and int(k[-1] - k[0]) == k.size - 1:  # consecutive (as common_periods gives)
        k = k[(k - lag0 - m + 1 >= 0) & (k - lag0 < r.shape[1])]  # every instrument defined
        start, D = int(k[0]) - lag0 if k.size else 0, period_block(dw, p, k, shift, nb)
        S = np.empty((dw.shape[0], m, nb))
        for b0 in range(0, dw.shape[0], IV_BLOCK):  # a few runs at a time, as in iv_moments
            ZT = _lagged_rows(r[b0 : b0 + IV_BLOCK], start, m, k.size)
            S[b0 : b0 + IV_BLOCK] = _instrument_products(ZT, D[b0 : b0 + IV_BLOCK])
    else:
        Z, ok = instruments(r, k, m, lag0)
        k, ZT = k[ok], Z[:, ok].transpose(0, 2, 1)
        S = _instrument_products(ZT, period_block(dw, p, k, shift, nb))
    C = S / len(k)  # every (1/K) sum zeta dwl at once, (R, m, nb)
    g = C[:, :, 0]
    b = np.ones((dw.shape[0], nb))
    gg = np.einsum("rm,rm->r", g, g)
    for l in range(2, nb + 1):
        b[:, l - 1] = np.einsum("rm,rm->r", g, C[:, :, l - 1]) / gg
    return b


@parameters(_PARAMS, b=("ndarray", "Numerators ``(runs, nb)`` with ``b1 = 1``."))
def v_eiv(dw: np.ndarray, p: int, shift: int, b: np.ndarray, t_min: int) -> np.ndarray:
    """The generalised prediction error of the static EIV systems (17), Section 6 step (iv):
    ``V_EIV(l) = (1/K) sum (Delta w(kp + l) - b_l Delta w(kp + 1))^2 / (b_l^2 + 1)`` for
    ``l = 2 .. nb`` (Sima & Van Huffel 2004, Definition 3), over the numerator's rows
    (:func:`common_periods`). ``b`` is ``(runs, nb)``; returns ``(runs, nb)`` with column 0
    (``b_1 = 1``, no equation) ``nan``.
    """
    nb = b.shape[1]
    out = np.full(b.shape, np.nan)
    if nb < 2:
        return out
    k = common_periods(dw, p, shift, t_min, nb)
    D = period_block(dw, p, k, shift, nb)  # (R, n, nb)
    d1 = D[:, :, 0]
    for l in range(2, nb + 1):
        bl = b[:, l - 1 : l]
        out[:, l - 1] = np.mean(np.square(D[:, :, l - 1] - bl * d1), axis=1) / (bl[:, 0] ** 2 + 1.0)
    return out


# --- inner signal (eqs. 23-27) -----------------------------------------------------------------


@parameters(_PARAMS)
def simo_channels(b: np.ndarray, p: int) -> tuple[np.ndarray, np.ndarray]:
    """Eq. (25): ``h_i(0) = b_1 + .. + b_i`` and ``h_i(1) = b_{i+1} + .. + b_nb``, i = 1..p."""
    R, nb = b.shape
    bp = np.zeros((R, p))
    bp[:, : min(nb, p)] = b[:, :p]
    h0 = np.cumsum(bp, axis=1)
    h1 = b.sum(axis=1, keepdims=True) - h0
    return h0, h1


@parameters(
    _PARAMS,
    lower=("ndarray", "Sub-diagonal, ``(R, M-1)``."),
    diag=("ndarray", "Diagonal, ``(R, M)``."),
    upper=("ndarray", "Super-diagonal, ``(R, M-1)``."),
    rhs=("ndarray", "Right-hand sides, ``(R, M)``."),
)
def solve_tridiagonal(
    lower: np.ndarray, diag: np.ndarray, upper: np.ndarray, rhs: np.ndarray
) -> np.ndarray:
    """Batched Thomas algorithm: ``diag`` and ``rhs`` ``(R, M)``, ``lower``/``upper`` ``(R, M-1)``.

    O(M) per run, vectorised over runs. Stable for the symmetric positive definite normal
    equations of (27). A symmetric system (``lower is upper``) goes to LAPACK's ``dptsv`` as one
    block-diagonal system of all runs (about 3x faster; the zero coupling makes each run's block
    the very arithmetic of its own solve); runs with a non-finite entry, runs LAPACK finds not
    positive definite (each then solved alone) and unsymmetric systems take this loop. A run's
    numbers never depend on the other runs of the batch.
    """
    R, M = diag.shape
    if lower is upper and M > 1:
        # one system for all runs would let a nan in one run reach every other: finite runs
        # only, the others by the loop (which keeps their nan to themselves)
        fin = np.isfinite(diag).all(axis=1) & np.isfinite(rhs).all(axis=1)
        fin &= np.isfinite(lower).all(axis=1)
        if fin.any():
            every = bool(fin.all())
            sel = slice(None) if every else fin  # a view, not a copy, in the usual case
            e = np.zeros((R if every else int(fin.sum()), M))
            e[:, :-1] = lower[sel]  # zero coupling between consecutive runs
            _d, _e, xf, info = lapack.dptsv(diag[sel].ravel(), e.ravel()[:-1], rhs[sel].ravel())
            if info == 0 and every and np.isfinite(xf).all():
                return xf.reshape(R, M)
            x = np.empty((R, M))
            alone = np.flatnonzero(fin)
            if info == 0:
                x[fin] = xf.reshape(-1, M)
                # an overflowing run (inf) makes its predecessor nan through the zero coupling
                # (x * 0): runs whose solution is not finite are solved again on their own
                alone = alone[~np.isfinite(x[alone]).all(axis=1)]
            # (otherwise a run is not positive definite: each run alone, LAPACK or the loop)
            for r in alone:
                _d, _e, x[r], info_r = lapack.dptsv(diag[r], lower[r], rhs[r])
                if info_r != 0:
                    x[r] = _thomas(
                        lower[r : r + 1], diag[r : r + 1], lower[r : r + 1], rhs[r : r + 1]
                    )[0]
            x[~fin] = _thomas(lower[~fin], diag[~fin], lower[~fin], rhs[~fin])
            return x
    return _thomas(lower, diag, upper, rhs)


def _thomas(lower: np.ndarray, diag: np.ndarray, upper: np.ndarray, rhs: np.ndarray) -> np.ndarray:
    """Batched Thomas algorithm, the pure-numpy path of :func:`solve_tridiagonal`."""
    R, M = diag.shape
    c = np.empty((R, M))
    d = np.empty((R, M))
    c[:, 0] = (upper[:, 0] / diag[:, 0]) if M > 1 else 0.0
    d[:, 0] = rhs[:, 0] / diag[:, 0]
    for i in range(1, M):
        den = diag[:, i] - lower[:, i - 1] * c[:, i - 1]
        if i < M - 1:
            c[:, i] = upper[:, i] / den
        d[:, i] = (rhs[:, i] - lower[:, i - 1] * d[:, i - 1]) / den
    x = np.empty((R, M))
    x[:, -1] = d[:, -1]
    for i in range(M - 2, -1, -1):
        x[:, i] = d[:, i] - c[:, i] * x[:, i + 1]
    return x


class SimoSystem:
    """The stacked SIMO equations (26) for the periods ``n = n0 .. n0 + M - 1``.

    ``W[r, j, i] = w(p (n0 + j) + i + shift)`` (i = 1..p) where ``valid[j, i]`` (the sample
    exists), 0 where it does not (such entries are never read); unknowns
    ``U~(n0 - 1) .. U~(n0 + M - 1)`` (``M + 1`` of them).

    Give the blocks ``W`` ``(runs, M, p)``, or the rows ``source`` ``(runs, N)`` of ``w`` with
    ``start``, the sample of ``W[:, 0, 0]``: then ``W`` is laid out on first use (the compiled
    eq. (27) reads ``source`` in place and never forms it). ``source`` is not copied: leave it
    unchanged while the system is in use.
    """

    def __init__(
        self,
        W: np.ndarray | None = None,
        valid: np.ndarray | None = None,
        n0: int = 1,
        *,
        source: np.ndarray | None = None,
        start: int = 0,
    ) -> None:
        if (W is None) == (source is None) or valid is None:
            raise ValueError("a SIMO system needs valid and either W or source")
        self._W, self.valid, self.n0 = W, valid, int(n0)
        self.source, self.start = source, int(start)

    @property
    def laid_out(self) -> bool:
        """Whether :attr:`W` exists (given, or formed from ``source`` on first use)."""
        return self._W is not None

    @property
    def W(self) -> np.ndarray:
        """The blocks ``(runs, M, p)``, zero where the sample does not exist."""
        if self._W is None:
            assert self.source is not None
            R, N = self.source.shape
            M, p = self.valid.shape
            avail = min(M * p, N - self.start)
            # the samples of consecutive periods are consecutive: one slice, reshaped, no gather
            W = np.zeros((R, M * p))
            W[:, :avail] = self.source[:, self.start : self.start + avail]
            W = W.reshape(R, M, p)
            W[:, ~self.valid] = 0.0
            self._W = W
        return self._W


@parameters(_PARAMS)
def simo_periods(N: int, p: int, shift: int, t_min: int) -> tuple[int, int]:
    """``(n0, M)``: the first period and the number of periods of :func:`simo_system` for a
    record of ``N`` fast samples (without arranging the blocks).
    """
    n0 = max(1, -(-(t_min - 1 - shift) // p))
    n1 = (N - 1 - 1 - shift) // p  # last period with at least its first sample
    return int(n0), max(n1 - n0 + 1, 0)


@parameters(_PARAMS, w=("ndarray", "``A(q) y``, ``(runs, N)``."))
def simo_system(w: np.ndarray, p: int, shift: int, t_min: int) -> SimoSystem:
    """The SIMO blocks of (23) from ``w``; periods with no valid sample are dropped. The blocks
    are laid out when first used (:attr:`SimoSystem.W`).
    """
    N = w.shape[1]
    n0, M = simo_periods(N, p, shift, t_min)
    n = np.arange(n0, n0 + M)
    t = n[:, None] * p + np.arange(1, p + 1)[None, :] + shift
    valid = (t >= t_min) & (t < N)
    if n.size == 0:
        return SimoSystem(W=np.zeros((w.shape[0], 0, p)), valid=valid, n0=int(n0))
    return SimoSystem(valid=valid, n0=int(n0), source=w, start=int(t[0, 0]))


def _validity_patterns(valid: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(V, which)``: the distinct rows of ``valid`` (M, p) as the columns of ``V`` (p, n) in
    0/1, and the pattern of each row. Rows are keyed as integers (``np.unique(valid, axis=0)``
    sorts them as byte strings, 10x slower)."""
    M, p = valid.shape
    if M == 0:
        return np.zeros((p, 0)), np.zeros(0, np.intp)
    if p > 62:  # the integer keys would overflow
        patterns, which = np.unique(valid, axis=0, return_inverse=True)
        return patterns.astype(float).T, which.ravel()
    bits = np.arange(p - 1, -1, -1, dtype=np.int64)  # the first column most significant
    key = valid.astype(np.int64) @ (np.int64(1) << bits)
    codes, which = np.unique(key, return_inverse=True)
    # the same patterns, in the same order, as ``np.unique(valid, axis=0)[0].astype(float).T``
    patterns = ((codes[:, None] >> bits[None, :]) & 1).astype(float)
    return patterns.T, which.ravel()


@parameters(_PARAMS)
def inner_signal_ls(sys: SimoSystem, h0: np.ndarray, h1: np.ndarray) -> np.ndarray:
    """Eq. (27): ``U = (H^T H)^-1 H^T W`` through its tridiagonal normal equations, O(K).

    Row ``(n, i)`` reads ``w_i(n) = h_i(0) U(n) + h_i(1) U(n-1)``. Returns ``U~(n0 - 1 ..)``,
    shape ``(runs, M + 1)``.

    Every sum over the ``p`` channels runs term after term from the first
    (:func:`hbench.numerics.ordered.ordered_products`), and the solve is LAPACK's ``dptsv`` (the
    reference ``dpttrf``/``dpttrs`` arithmetic) or, for a run it cannot take, the Thomas loop: the
    compiled kernel (:func:`hbench.numerics.kernels.inner_signal_ls`) does the same operations, so
    both paths give the same numbers on any machine."""
    R = h0.shape[0]
    M = sys.valid.shape[0]
    if kernels.active_library() is None or not lapack_is_reference():
        compiled = None  # the numpy path, or a LAPACK that computes otherwise than the kernel
    elif sys.source is not None and not sys.laid_out:  # w read in place, no blocks formed
        compiled = kernels.inner_signal_ls(sys.source, sys.valid, h0, h1, start=sys.start)
    else:
        compiled = kernels.inner_signal_ls(sys.W, sys.valid, h0, h1)
    if compiled is not None:
        return compiled
    # sums over the valid channels of each period. Periods share a handful of validity
    # patterns (all channels but at the record's ends): formed per pattern, spread to periods
    Vp, which = _validity_patterns(sys.valid)

    def per_period(h2: np.ndarray) -> np.ndarray:
        return take_periods(ordered_products(h2, np.ascontiguousarray(Vp.T)), which)

    W = sys.W if sys.valid.all() else np.where(sys.valid, sys.W, 0.0)  # as the kernel reads
    # equation block j couples unknowns j (= U(n-1)) and j+1 (= U(n))
    a11 = per_period(h1**2)  # coefficient of U(n-1)^2
    a22 = per_period(h0**2)
    a12 = per_period(h0 * h1)
    b1 = _ordered_channels(W, h1)  # (R, M)
    b2 = _ordered_channels(W, h0)
    diag = np.zeros((R, M + 1))
    diag[:, :-1] += a11
    diag[:, 1:] += a22
    off = a12
    rhs = np.zeros((R, M + 1))
    rhs[:, :-1] += b1
    rhs[:, 1:] += b2
    # an unknown in no equation (e.g. U(n0 - 1) when nb = 1, all h_i(1) = 0) is undetermined:
    # pin it (unit diagonal, decoupled) and report nan
    free = diag <= 0.0
    if free.any():
        diag = np.where(free, 1.0, diag)
        off = off.copy()
        off[free[:, :-1]] = 0.0
        off[free[:, 1:]] = 0.0
        rhs = np.where(free, 0.0, rhs)
    with np.errstate(divide="ignore", invalid="ignore"):  # a singular run: inf/nan, quietly
        U = solve_tridiagonal(off, diag, off, rhs)  # as the kernel does
    return np.where(free, np.nan, U)


def _ordered_channels(W: np.ndarray, h: np.ndarray) -> np.ndarray:
    """``sum_i W[:, :, i] h[:, i]`` over the channels term after term from the first, (R, M)."""
    out = W[:, :, 0] * h[:, 0:1]
    for i in range(1, W.shape[2]):
        out = out + W[:, :, i] * h[:, i : i + 1]
    return out


@parameters(_PARAMS)
def inner_signal_dense(sys: SimoSystem, h0: np.ndarray, h1: np.ndarray) -> np.ndarray:
    """Eq. (27) by a dense least-squares solve of ``H U = W`` (reference and benchmark baseline)."""
    R = h0.shape[0]
    M, _p = sys.valid.shape
    out = np.empty((R, M + 1))
    rows = np.argwhere(sys.valid)  # (eq, 2): period j, channel i
    for r in range(R):
        H = np.zeros((rows.shape[0], M + 1))
        H[np.arange(rows.shape[0]), rows[:, 0]] = h1[r, rows[:, 1]]
        H[np.arange(rows.shape[0]), rows[:, 0] + 1] = h0[r, rows[:, 1]]
        out[r] = np.linalg.lstsq(H, sys.W[r, rows[:, 0], rows[:, 1]], rcond=None)[0]
    return out


@parameters(_PARAMS)
def bezout_combiner(h0: np.ndarray, h1: np.ndarray) -> np.ndarray:
    """Minimum-norm degree-0 multichannel inverse: ``g`` with ``sum g_i h_i(0) = 1``,
    ``sum g_i h_i(1) = 0`` (Bezout identity over the polyphase channels; exists under A4).

    Then ``sum_i g_i w_i(n) = U(n)`` for noise-free data, whatever the phase of B.
    """
    Hm = np.stack([h0, h1], axis=1)  # (R, 2, p)
    rhs = np.array([1.0, 0.0])
    gram = np.einsum("rai,rbi->rab", Hm, Hm)
    lam = np.linalg.solve(gram, np.broadcast_to(rhs, (h0.shape[0], 2))[..., None])[..., 0]
    return np.einsum("rai,ra->ri", Hm, lam)


@parameters(_PARAMS)
def inner_signal_bezout(sys: SimoSystem, h0: np.ndarray, h1: np.ndarray) -> np.ndarray:
    """``U~(n) = sum_i g_i w_i(n)`` for periods whose p samples all exist; nan elsewhere.

    Returns the same layout as :func:`inner_signal_ls` (``U~(n0 - 1 ..)``); ``U~(n0-1)`` is nan.
    """
    g = bezout_combiner(h0, h1)
    full = np.all(sys.valid, axis=1)
    U = np.einsum("rji,ri->rj", sys.W, g)
    U[:, ~full] = np.nan
    return np.concatenate([np.full((U.shape[0], 1), np.nan), U], axis=1)


@parameters(
    _PARAMS, n_first=("int", "First slow index returned."), M=("int", "Slow samples returned.")
)
def inner_signal_direct(
    y: np.ndarray, a: np.ndarray, b: np.ndarray, p: int, shift: int, n_first: int, M: int
) -> np.ndarray:
    """Direct inverse (Bai & Fu): ``u~(t) = A(q)/B(q) y~(t)`` down-sampled, ``U~(n) = u~(p n)``.

    With ``B(q) = q^-1 (b1 + b2 q^-1 + ...)``: ``u~(t - 1) = A(q)/(b1 + b2 q^-1 + ..) y~(t)``, so
    ``U~(n)`` is the filter's output at ``y~(p n + 1)``. Filtered from rest over the record.
    Returns ``U~(n_first .. n_first + M - 1)``; unstable (growing) if B is not minimum phase.
    """
    R, _N = y.shape
    out = np.full((R, M), np.nan)
    z = batched_lfilter(a, b, y[:, shift:])
    t = (np.arange(n_first, n_first + M)) * p + 1
    # filtered from rest on a record that need not start at rest: drop the samples until the
    # 1/B transient has decayed below 1e-3 (nan there)
    rho = max_root_modulus(b)
    with np.errstate(divide="ignore"):
        skip = np.where(
            (rho > 0.0) & (rho < 1.0), np.ceil(np.log(1e-3) / np.log(np.clip(rho, 1e-300, None))), 0
        )
    ok = (t[None, :] < z.shape[1]) & (t[None, :] >= skip[:, None])
    vals = z[:, np.clip(t, 0, z.shape[1] - 1)]
    return np.where(ok, vals, out)


@parameters(_PARAMS, c=("ndarray", "Polynomial coefficients per row, highest power first."))
def max_root_modulus(c: np.ndarray) -> np.ndarray:
    """Largest ``|root|`` of each row's polynomial ``c[r, 0] z^n + .. + c[r, n]`` (0 if n = 0).

    Eigenvalues of the batched companion matrices: one LAPACK call for all runs.
    """
    R, n1 = c.shape
    if n1 < 2:
        return np.zeros(R)
    n = n1 - 1
    comp = np.zeros((R, n, n))
    comp[:, 0, :] = -c[:, 1:] / c[:, :1]
    if n > 1:
        comp[:, np.arange(1, n), np.arange(n - 1)] = 1.0
    return np.max(np.abs(np.linalg.eigvals(comp)), axis=1)


@parameters(
    _PARAMS,
    num=("ndarray", "Numerators per run, ``(runs, nn)``."),
    den=("ndarray", "Denominators per run, ``(runs, nd)``."),
    x=("ndarray", "Inputs per run, ``(runs, N)``."),
)
def batched_lfilter(num: np.ndarray, den: np.ndarray, x: np.ndarray) -> np.ndarray:
    """``scipy.signal.lfilter(num[r], den[r], x[r])`` for every run r, from rest.

    lfilter takes one coefficient set per call; a loop over runs in its compiled kernel
    (~40 us per run of 4000 samples) measured faster than a recursion over time vectorised
    over runs (~100 us per time step for 1000 runs). Compiled when :mod:`hbench.numerics.kernels` is
    built (scipy's arithmetic, the same bits, without a Python call per run).
    """
    compiled = kernels.lfilter_rows(num, den, x)
    if compiled is not None:
        return compiled
    out = np.empty(x.shape)
    for r in range(x.shape[0]):
        out[r] = signal.lfilter(num[r], den[r], x[r])
    return out


@parameters(
    _PARAMS,
    U_tilde=("ndarray", "``U~(n_first ..)``, ``(runs, M)``."),
    n_first=("int", "Slow index of ``U_tilde[:, 0]``."),
    delay_multiple=("int", "m of the delay ``tau + m p`` (assumption A3)."),
    K=("int", "Slow samples of the record."),
)
def align(U_tilde: np.ndarray, n_first: int, delay_multiple: int, K: int) -> np.ndarray:
    """Place ``U~(n_first ..)`` on the record's slow grid: ``U(n) = U~(n + m)``; nan elsewhere.

    ``U~(n) = u(p n - m p)`` when the delay is ``tau + m p`` (assumption A3 gives m).
    """
    R, M = U_tilde.shape
    out = np.full((R, K), np.nan)
    n = np.arange(n_first, n_first + M) - delay_multiple
    ok = (n >= 0) & (n < K)
    out[:, n[ok]] = U_tilde[:, ok]
    return out


@functools.cache
def lapack_is_reference() -> bool:
    """Whether scipy's LAPACK ``dptsv`` gives the reference ``dpttrf``/``dptts2`` arithmetic that
    :func:`hbench.numerics.kernels.inner_signal_ls` performs (no fused multiply-adds), checked once
    per process on a fixed eq.-(27) system; where it does not (an FMA build of LAPACK), eq. (27)
    runs the numpy path on both backends, so they still agree. A property of the build and the
    libraries, not of the backend switch (:func:`hbench.numerics.kernels.use`), which it neither
    reads nor depends on."""
    if not kernels.built():
        return False

    rng = np.random.default_rng(27)
    valid = np.ones((60, 5), bool)
    valid[-1, 2:] = False
    W = np.where(
        valid, rng.standard_normal((4, 60, 5)) * np.exp(rng.uniform(-5, 5, (4, 1, 1))), 0.0
    )
    b = np.concatenate([np.ones((4, 1)), rng.standard_normal((4, 2))], axis=1)
    h0, h1 = simo_channels(b, 5)
    got = kernels.inner_signal_ls_built(W, valid, h0, h1)
    with kernels.use("numpy"):
        want = inner_signal_ls(SimoSystem(W=W, valid=valid, n0=1), h0, h1)
    return got is not None and bool(np.array_equal(got, want))

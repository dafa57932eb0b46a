"""Methods beyond the paper (GitHub issue 8), each derived in its class docstring.

* ``wang-lsm-cn``: the bias-compensated LSM generalised to coloured equation noise, with the
  noise correlation estimated from the quiet phases.
* ``joint-refine``: (A, B, U) refined jointly over the SIMO model of eq. (26) by variable
  projection, started from ``wang-lsm-cn``.
* ``wang-delay``: assumption A3 relaxed, the delay's multiple of p estimated from the alignment
  of the measured x with the estimated inner signal.
"""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np
from scipy import signal

from hbench import polyphase as pp
from hbench.errors import InputError
from hbench.hookspecs import Register, hookimpl
from hbench.identifiers import Estimate, Identifier, IdentifyOptions, SelectionRule, blind_fit
from hbench.records import Record, Truth


def quiet_autocovariance(
    dy: np.ndarray, theta: np.ndarray, p: int, phases: tuple[int, ...], shift: int, lags: int
) -> np.ndarray:
    """``gamma_j = E{eps(t) eps(t - j)}``, j = 0..lags, of the quiet-phase equation noise.

    ``eps(t) = Delta y(t) - phi(t)^T theta`` is observable at every quiet phase; ``gamma_j`` is the
    mean of products of phases ``l`` and ``l - j`` of the same period, both quiet.
    Returns ``(runs, lags + 1)``.
    """
    na = theta.shape[1]
    N = dy.shape[1]
    k = None
    for l in phases:
        kl = pp.phase_times(N, p, l, shift, t_min=na + 1)
        k = kl if k is None else np.intersect1d(k, kl)
    t = k[:, None] * p + np.asarray(phases)[None, :] + shift  # (n, |Q|)
    lag = np.arange(na + 1)
    block = dy[:, t[..., None] - lag]  # (R, n, |Q|, na + 1)
    eps = block[..., 0] + np.einsum("rnqi,ri->rnq", block[..., 1:], theta)
    ph = np.asarray(phases)
    gam = np.zeros((dy.shape[0], lags + 1))
    for j in range(lags + 1):
        pairs = [(a, b) for a in range(len(ph)) for b in range(len(ph)) if ph[a] - ph[b] == j]
        if pairs:
            gam[:, j] = np.mean(
                [np.mean(eps[:, :, a] * eps[:, :, b], axis=1) for a, b in pairs], axis=0
            )
    return gam


def noise_bias(theta: np.ndarray, gamma: np.ndarray) -> np.ndarray:
    """``c_i = E{phi_i eps(t)} = -sum_m h_m gamma_{i+m}``, i = 1..na, h the impulse response of 1/A.

    ``phi_i = -Delta y(t - i)`` holds the noise part ``eps / A(q)`` delayed by i; ``gamma_k = 0``
    beyond the estimated lags (an MA noise model). For white ARX noise (``gamma_0 = 2 sigma^2``,
    ``gamma_1 = -sigma^2``) this is the paper's ``[sigma^2, 0, ..]`` of eq. (14).
    """
    R, na = theta.shape
    J = gamma.shape[1] - 1
    c = np.zeros((R, na))
    if J < 1:
        return c
    imp = np.zeros(J)
    imp[0] = 1.0
    for r in range(R):
        h = signal.lfilter([1.0], np.concatenate([[1.0], theta[r]]), imp)
        for i in range(1, min(na, J) + 1):
            c[r, i - 1] = -np.dot(h[: J - i + 1], gamma[r, i : J + 1])
    return c


class ColoredNoiseLSM(Identifier):
    """Bias-compensated LSM for coloured equation noise (hbench's extension of eqs. 13-15, 18).

    Derivation. At a quiet phase, ``Delta y(t) = phi(t)^T theta + eps(t)`` with
    ``eps = Delta C(q) e`` when the output noise is ``C(q)/A(q) e`` (the paper assumes C = 1, so
    ``eps = Delta e`` is MA(1)). With ``h`` the impulse response of 1/A and
    ``gamma_k = E{eps(t) eps(t-k)}``, the regressor's noise part gives
    ``E{phi_i eps(t)} = -sum_m h_m gamma_{i+m} =: c_i(theta, gamma)`` (u is uncorrelated with
    eps(t) when the loop's delay exceeds the noise's MA order, as in the paper's example). The
    quiet phases observe ``eps`` directly (``eps = A(q) Delta y`` there), so ``gamma_0 ..
    gamma_J`` (J = p - nb - 1, the lags two quiet phases of one period span) are estimated from
    the residuals, and ``theta = R^-1 (f - c(theta, gamma))`` is iterated to a fixed point from
    the paper's LSM (eq. 14). The numerator generalises eq. (18):
    ``b_l = (E{Dw1 Dwl} - gamma_{l-1}) / (E{Dw1^2} - gamma_0)``. With white ARX noise
    (gamma_0 = 2 sigma^2, gamma_1 = -sigma^2) both reduce to the paper's equations.

    Parameters
    ----------
    lags : int or None
        Noise MA lags J to estimate (default: all that the quiet block spans, p - nb - 1).
    iterations : int
        Fixed-point iterations (stops earlier at relative change < 1e-10).
    """

    name: ClassVar[str] = "wang-lsm-cn"
    summary: ClassVar[str] = "LSM compensated for coloured noise estimated from quiet phases"

    def __init__(self, lags: int | None = None, iterations: int = 50) -> None:
        if lags is not None and int(lags) < 1:
            raise InputError(f"wang-lsm-cn lags must be >= 1, got {lags}")
        self.lags = None if lags is None else int(lags)
        self.iterations = int(iterations)

    def options(self) -> dict[str, Any]:
        return {"lags": self.lags, "iterations": self.iterations}

    def identify(
        self, record: Record, options: IdentifyOptions, truth: Truth | None = None
    ) -> Estimate:
        p = record.p
        dy_all = pp.delta(record.y)
        gammas: dict[int, np.ndarray] = {}

        def denominator(reg: pp.QuietRegression, idx: np.ndarray):
            return pp.bias_compensated(reg)

        def refined(reg: pp.QuietRegression, idx: np.ndarray, tau: int, nb: int):
            theta, _ = pp.bias_compensated(reg)
            Rm, f = reg.moments()
            Rinv = np.linalg.pinv(Rm, rcond=1e-12, hermitian=True)
            phases = tuple(range(nb + 1, p + 1))
            J = len(phases) - 1 if self.lags is None else min(self.lags, len(phases) - 1)
            gamma = np.zeros((idx.size, J + 1))
            for _ in range(self.iterations):
                gamma = quiet_autocovariance(dy_all[idx], theta, p, phases, tau, J)
                new = np.einsum("rik,rk->ri", Rinv, f - noise_bias(theta, gamma))
                change = np.max(np.abs(new - theta)) / max(np.max(np.abs(theta)), 1e-300)
                theta = new
                if change < 1e-10:
                    break
            for j, i in enumerate(idx):
                gammas[int(i)] = gamma[j]
            return theta, gamma[:, 0] / 2.0

        def numerator(dw, tau, nb, sigma2, idx):
            t_min = pp.first_valid(dw)
            g = np.stack([gammas[int(i)] for i in idx])
            k = pp.phase_times(dw.shape[1], p, 1, tau, t_min)
            k = np.intersect1d(k, pp.phase_times(dw.shape[1], p, nb, tau, t_min))
            t = k[:, None] * p + np.arange(1, nb + 1)[None, :] + tau
            D = dw[:, t]
            d1 = D[:, :, 0]
            b = np.ones((dw.shape[0], nb))
            den = np.mean(d1**2, axis=1) - g[:, 0]
            for l in range(2, nb + 1):
                gl = g[:, l - 1] if l - 1 < g.shape[1] else 0.0
                b[:, l - 1] = (np.mean(d1 * D[:, :, l - 1], axis=1) - gl) / den
            return b

        return blind_fit(
            self.name,
            record,
            options,
            denominator=denominator,
            numerator=numerator,
            pooled=True,
            rule=SelectionRule(),
            info=self.options(),
            refine=refined,
        )


@hookimpl
def register_identifiers(register: Register) -> None:
    register(ColoredNoiseLSM.name, ColoredNoiseLSM)
    register(JointRefinement.name, JointRefinement)
    register(DelayEstimating.name, DelayEstimating)


def _simo_residual(
    y: np.ndarray, theta: np.ndarray, na: int, nb: int, p: int, tau: int, t_min: int
) -> tuple[np.ndarray, np.ndarray, pp.SimoSystem]:
    """Residual of eq. (26) with U eliminated by eq. (27): ``W(a) - H(b) U*(a, b)``.

    ``theta = [a1 .. a_na, b2 .. b_nb]`` per run. Returns ``(residual (R, M, p), U*, system)``;
    residual entries of absent samples are 0.
    """
    R = y.shape[0]
    a = np.concatenate([np.ones((R, 1)), theta[:, :na]], axis=1)
    b = np.concatenate([np.ones((R, 1)), theta[:, na:]], axis=1)
    w = pp.filtered_output(y, a)
    sys = pp.simo_system(w, p, tau, t_min)
    h0, h1 = pp.simo_channels(b, p)
    U = pp.inner_signal_ls(sys, h0, h1)
    Uc = np.nan_to_num(U)
    pred = h1[:, None, :] * Uc[:, :-1, None] + h0[:, None, :] * Uc[:, 1:, None]
    res = np.where(sys.valid[None], sys.W - pred, 0.0)
    return res, U, sys


def joint_refine(
    y: np.ndarray,
    theta0: np.ndarray,
    na: int,
    nb: int,
    p: int,
    tau: int,
    t_min: int,
    iterations: int = 20,
    tol: float = 1e-9,
) -> np.ndarray:
    """Batched Gauss-Newton (Levenberg-damped) on the concentrated SIMO criterion.

    Minimises ``||W(a) - H(b) U*(a, b)||^2`` over ``(a, b)`` (variable projection: U eliminated
    by eq. 27 at every step), from ``theta0``; forward-difference Jacobian, one step size per run.
    """
    theta = theta0.copy()
    R, n = theta.shape
    lam = np.full(R, 1e-3)
    res, _, _ = _simo_residual(y, theta, na, nb, p, tau, t_min)
    cost = np.sum(res**2, axis=(1, 2))
    for _ in range(iterations):
        J = np.empty((R, res[0].size, n))
        for i in range(n):
            step = 1e-7 * np.maximum(np.abs(theta[:, i]), 1.0)
            th = theta.copy()
            th[:, i] += step
            r_i, _, _ = _simo_residual(y, th, na, nb, p, tau, t_min)
            J[:, :, i] = ((r_i - res) / step[:, None, None]).reshape(R, -1)
        g = np.einsum("rki,rk->ri", J, res.reshape(R, -1))
        Hm = np.matmul(J.transpose(0, 2, 1), J)
        damp = lam[:, None, None] * np.diag(np.diag(Hm.mean(axis=0)) + 1e-300)[None]
        delta = -np.linalg.solve(Hm + damp * np.eye(n)[None], g[..., None])[..., 0]
        trial = theta + delta
        r_new, _, _ = _simo_residual(y, trial, na, nb, p, tau, t_min)
        c_new = np.sum(r_new**2, axis=(1, 2))
        better = c_new < cost
        theta = np.where(better[:, None], trial, theta)
        res = np.where(better[:, None, None], r_new, res)
        rel = np.where(better, (cost - c_new) / np.maximum(cost, 1e-300), 0.0)
        cost = np.where(better, c_new, cost)
        lam = np.where(better, lam / 3.0, lam * 5.0)
        if np.all((rel < tol) & (better | (lam > 1e6))):
            break
    return theta


class JointRefinement(Identifier):
    """Joint (A, B, U) refinement over the SIMO model of eq. (26), started from a blind estimate.

    Derivation. Eq. (26) is ``W(a) = H(b) U + E`` with ``W(a)`` the stacked ``A(q) y`` and
    ``H(b)`` bidiagonal in ``h_i(0), h_i(1)`` (eq. 25). For white Gaussian equation noise the ML
    estimate minimises ``||W(a) - H(b) U||^2`` over (a, b, U). For fixed (a, b) the minimiser in U
    is eq. (27); substituting it (variable projection, Golub & Pereyra 1973) leaves a criterion in
    (a, b) alone, minimised by damped Gauss-Newton from the start estimate (``start``). Unlike
    the quiet-phase estimators it uses every sample of every phase, so the parameter errors that
    propagate into U (Table 5's F vs F0 gap) shrink.

    Caveat, measured: the parameters come out biased (a1 by about +0.03 at sigma^2 = 1e-2 on the
    paper's example, even under white ARX noise): U is a nuisance parameter whose dimension grows
    with K, and the concentrated criterion is then not a consistent ML estimate (the
    incidental-parameter problem, Neyman & Scott 1948). Use it for the inner signal; for the
    parameters prefer ``wang-lsm-cn``.

    Parameters
    ----------
    start : str
        The method giving the structure and the start (``wang-lsm-cn`` or ``wang-lsm``).
    iterations : int
        Gauss-Newton iterations at most.
    """

    name: ClassVar[str] = "joint-refine"
    summary: ClassVar[str] = "Joint (A, B, U) refinement of eq. (26) by variable projection"

    def __init__(self, start: str = "wang-lsm-cn", iterations: int = 20) -> None:
        if start not in ("wang-lsm-cn", "wang-lsm"):
            raise InputError(f"joint-refine start must be wang-lsm-cn or wang-lsm, got {start!r}")
        self.start, self.iterations = start, int(iterations)

    def options(self) -> dict[str, Any]:
        return {"start": self.start, "iterations": self.iterations}

    def identify(
        self, record: Record, options: IdentifyOptions, truth: Truth | None = None
    ) -> Estimate:
        from hbench_wang import WangLSM

        from hbench.identifiers import groups

        first = (ColoredNoiseLSM() if self.start == "wang-lsm-cn" else WangLSM()).identify(
            record, options
        )
        est = first
        p, K = record.p, record.n_slow
        U = est.U.copy()
        a, b = est.a.copy(), est.b.copy()
        ok = est.identifiable
        for (na, tau, nb), idx in groups(est.na, est.tau, est.nb):
            idx = idx[ok[idx]]
            if idx.size == 0:
                continue
            theta0 = np.concatenate([est.a[idx, :na], est.b[idx, 1:nb]], axis=1)
            theta = joint_refine(record.y[idx], theta0, na, nb, p, tau, na, self.iterations)
            _, Ut, sys = _simo_residual(record.y[idx], theta, na, nb, p, tau, na)
            a[idx, :na] = theta[:, :na]
            b[idx, 1:nb] = theta[:, na:]
            U[idx] = pp.align(Ut, sys.n0 - 1, options.delay_multiple, K)
        return Estimate(
            method=self.name,
            a=a,
            b=b,
            na=est.na,
            nb=est.nb,
            tau=est.tau,
            sigma2=est.sigma2,
            U=U,
            identifiable=est.identifiable,
            reason=est.reason,
            criteria=est.criteria,
            info={**est.info, **self.options()},
        )


def delay_multiple_from_alignment(
    x: np.ndarray, U_tilde: np.ndarray, max_multiple: int
) -> tuple[np.ndarray, np.ndarray]:
    """The delay's multiple of p from the alignment of x(n) with the estimated inner signal.

    ``U~(n) = U(n - m)`` when the delay is ``tau + m p``; the actuator passes the changes of x
    into U (exactly for static maps, outside the dead band for backlash and stiction), so
    ``m = argmax_j |corr(Delta x(n), Delta U~(n + j))|`` (absolute: the blind gain has either
    sign). Returns ``(m, corr)`` with ``corr`` of shape ``(runs, max_multiple + 1)``.
    """
    R, K = x.shape
    dx = np.diff(x, axis=1)
    dU = np.diff(U_tilde, axis=1)
    corr = np.full((R, max_multiple + 1), np.nan)
    for j in range(max_multiple + 1):
        a = dx[:, : K - 1 - j]
        b = dU[:, j:]
        m = np.isfinite(a) & np.isfinite(b)
        n = m.sum(axis=1)
        nn = np.maximum(n, 1)[:, None]
        a0 = np.where(m, a - np.where(m, a, 0.0).sum(axis=1, keepdims=True) / nn, 0.0)
        b0 = np.where(m, b - np.where(m, b, 0.0).sum(axis=1, keepdims=True) / nn, 0.0)
        den = np.sqrt(np.sum(a0**2, axis=1) * np.sum(b0**2, axis=1))
        c = np.sum(a0 * b0, axis=1) / np.where(den > 0, den, 1.0)
        corr[:, j] = np.where((n > 10) & (den > 0), c, np.nan)
    best = np.argmax(np.nan_to_num(np.abs(corr), nan=-1.0), axis=1)
    return best, corr


class DelayEstimating(Identifier):
    """Relaxes assumption A3: the delay's multiple of p estimated from x (issue 8, part 1).

    Derivation. Output fast-sampling identifies the fractional delay tau in [0, p) (Section 3.4)
    but not its multiple m of p: y alone cannot tell ``tau`` from ``tau + m p``. The controller
    output x is measured, though, and ``U(n)`` is a (possibly memoryful) function of ``x(n)``;
    the blind estimate computed with m = 0 is ``U~(n) = U(n - m)`` up to scale, so m is the lag
    that best aligns ``Delta U~`` with ``Delta x`` (:func:`delay_multiple_from_alignment`). The
    estimate of the base method (``base``) is then re-aligned by the estimated m.

    Parameters
    ----------
    base : str
        The blind method run first (``wang-lsm-cn`` or ``wang-lsm``).
    max_multiple : int
        Largest multiple of p considered.
    """

    name: ClassVar[str] = "wang-delay"
    needs: ClassVar[frozenset[str]] = frozenset({"x"})
    summary: ClassVar[str] = "Delay beyond A3: multiple of p from the x-U alignment"

    def __init__(self, base: str = "wang-lsm-cn", max_multiple: int = 3) -> None:
        if base not in ("wang-lsm-cn", "wang-lsm"):
            raise InputError(f"wang-delay base must be wang-lsm-cn or wang-lsm, got {base!r}")
        if int(max_multiple) < 0:
            raise InputError(f"wang-delay max_multiple must be >= 0, got {max_multiple}")
        self.base, self.max_multiple = base, int(max_multiple)

    def options(self) -> dict[str, Any]:
        return {"base": self.base, "max_multiple": self.max_multiple}

    def identify(
        self, record: Record, options: IdentifyOptions, truth: Truth | None = None
    ) -> Estimate:
        from dataclasses import replace

        from hbench_wang import WangLSM

        method = ColoredNoiseLSM() if self.base == "wang-lsm-cn" else WangLSM()
        est = method.identify(record, replace(options, delay_multiple=0))
        m, corr = delay_multiple_from_alignment(record.x, est.U, self.max_multiple)
        K = record.n_slow
        U = np.full_like(est.U, np.nan)
        for j in np.unique(m):
            rows = m == j
            U[rows, : K - j] = est.U[rows, j:]
        est.U = U
        est.method = self.name
        est.delay_multiple = m
        est.criteria = {**est.criteria, "delay_corr": corr}
        est.info = {**est.info, **self.options()}
        return est

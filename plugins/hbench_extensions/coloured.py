"""``wang-lsm-cn``: the bias-compensated LSM generalised to coloured equation noise."""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np
from scipy import signal

from hbench.errors import InputError
from hbench.ident import polyphase as pp
from hbench.ident.identifiers import (
    Estimate,
    Identifier,
    IdentifyOptions,
    SelectionRule,
    bias_compensated_fit,
    blind_fit,
)
from hbench.sim.records import Record, Truth


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
    block = pp.take_periods(dy, t[..., None] - lag)  # (R, n, |Q|, na + 1)
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


def b_compensated(dw: np.ndarray, gamma: np.ndarray, p: int, shift: int, nb: int) -> np.ndarray:
    """Eq. (18) generalised to coloured noise: ``b_l = (E{Dw1 Dwl} - gamma_{l-1}) /
    (E{Dw1^2} - gamma_0)``, with ``gamma`` the quiet-phase noise autocovariance
    (:func:`quiet_autocovariance`); white ARX noise gives the paper's ``-2 sigma^2`` and
    ``+sigma^2``."""
    k = pp.common_periods(dw, p, shift, pp.first_valid(dw), nb)
    t = k[:, None] * p + np.arange(1, nb + 1)[None, :] + shift
    D = pp.take_periods(dw, t)
    d1 = D[:, :, 0]
    b = np.ones((dw.shape[0], nb))
    den = np.mean(d1**2, axis=1) - gamma[:, 0]
    for l in range(2, nb + 1):
        gl = gamma[:, l - 1] if l - 1 < gamma.shape[1] else 0.0
        b[:, l - 1] = (np.mean(d1 * D[:, :, l - 1], axis=1) - gl) / den
    return b


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
        Fixed-point iterations (stops earlier at relative change < 1e-10). A run whose iterates
        leave the floating-point range within them has diverged: its parameters are ``inf``
        and ``U`` ``nan`` (the run fails: ``hbench.ident.invoke.run_status``), without numpy's
        overflow warnings; ``info["diverged_runs"]`` counts such runs. A run still moving when
        the iterations run out keeps its last iterate; ``info["unconverged_runs"]`` counts
        those (the diverged ones are not among them).
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
        gammas: dict[int, np.ndarray] = {}
        diverged: set[int] = set()
        unconverged = 0  # runs still moving when the iterations run out

        def refined(reg: pp.QuietRegression, idx: np.ndarray, tau: int, nb: int):
            nonlocal unconverged
            theta, _ = pp.bias_compensated(reg)
            Rm, f = reg.moments()
            Rinv = np.linalg.pinv(Rm, rcond=1e-12, hermitian=True)
            phases = tuple(range(nb + 1, p + 1))
            J = len(phases) - 1 if self.lags is None else min(self.lags, len(phases) - 1)
            gamma = np.zeros((idx.size, J + 1))
            done = np.zeros(idx.size, bool)  # each run stops at its own fixed point, so its
            # estimate does not depend on its batch; a run whose iterates leave the
            # floating-point range has diverged (checked below)
            with np.errstate(over="ignore", invalid="ignore"):
                for _ in range(self.iterations):
                    g = quiet_autocovariance(reg.dy, theta, p, phases, tau, J)
                    new = np.einsum("rik,rk->ri", Rinv, f - noise_bias(theta, g))
                    change = np.max(np.abs(new - theta), axis=1) / np.maximum(
                        np.max(np.abs(theta), axis=1), 1e-300
                    )
                    lost = ~done & ~np.all(np.isfinite(new), axis=1)
                    gamma = np.where(done[:, None], gamma, g)
                    theta = np.where(done[:, None], theta, new)
                    done |= lost | (change < 1e-10)
                    theta[lost] = np.nan
                    diverged.update(int(i) for i in idx[lost])
                    if done.all():
                        break
            unconverged += int(np.sum(~done))
            for j, i in enumerate(idx):
                gammas[int(i)] = gamma[j]
            s2 = gamma[:, 0] / 2.0
            s2[[int(i) in diverged for i in idx]] = np.nan
            return theta, s2

        def numerator(dw, tau, nb, sigma2, idx):
            b = np.full((idx.size, nb), np.nan)  # a diverged run has none (b1 = 1 always)
            b[:, 0] = 1.0
            keep = np.array([int(i) not in diverged for i in idx], bool)
            if keep.any():
                gam = np.stack([gammas[int(i)] for i in idx[keep]])
                b[keep] = b_compensated(dw[keep], gam, p, tau, nb)
            return b

        est = blind_fit(
            self.name,
            record,
            options,
            denominator=bias_compensated_fit,
            numerator=numerator,
            pooled=True,
            rule=SelectionRule(),
            info=self.options(),
            refine=refined,
        )
        # a diverged run's parameters overflowed: infinite, which marks the run failed
        # (hbench.ident.invoke.run_status); the counts are in the estimate's info
        for i in sorted(diverged):
            est.a[i, : est.na[i]], est.b[i, : est.nb[i]], est.U[i] = np.inf, np.inf, np.nan
            est.sigma2[i] = np.nan
        est.info["diverged_runs"] = len(diverged)
        est.info["unconverged_runs"] = unconverged
        return est

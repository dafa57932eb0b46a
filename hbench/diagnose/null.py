"""Record-specific nulls: what the nominal noise model alone leaves, for the detectors' thresholds.

The drift detector's low-frequency threshold and the time-varying threshold
(:mod:`hbench.diagnose.effects`) are calibrated on the generator's records, whose noise
``e / A(q)`` has a correlation time of a few dozen fast samples: short next to the record, as
those statistics assume. A slow plant's equation-error
noise (the paper's Section 6 example: poles near 0.98 at the fast rate, a correlation time of
~100 samples, starting from rest) wanders over the whole record, and the same statistics reach
those thresholds on its noise alone. So for the blind route (p >= 2, noise model ``e / A``)
each of the two detectors also asks its statistic to exceed the :data:`QUANTILE` percentile of
the same statistic over :data:`N_DRAWS` draws of the nominal noise model: ``v* = e* / A(q)``
from rest at the record's start, ``e*`` white with the innovations' variance, with the nominal
output fit's columns (simulation, offset, start-up transient) projected out over the fit part,
as the nominal fit does to the record. The threshold is the larger of the calibrated one and
that percentile; for the generator's records the percentile almost always stays below the
calibrated value (the decision is the calibrated one), for a slow plant it rises above it.

The null treats the noise as independent of the simulation; in closed loop the controller
feeds it back into ``x``. The draws come from a Generator seeded with :data:`SEED` (a
diagnosis is reproducible); p = 1 (output error, white residuals) has no null: the calibrated
thresholds stand.
"""

from __future__ import annotations

import numpy as np
from scipy import signal

from hbench.diagnose import core
from hbench.diagnose import nominal as nm
from hbench.system import runtime

#: Draws of the noise model per record.
N_DRAWS = 200
#: The percentile of a statistic over the draws that a detector must also exceed.
QUANTILE = 99.0
#: Seed of the draws' Generator (a diagnosis of the same record gives the same answer).
SEED = 20261123


def generator() -> np.random.Generator:
    """The draws' Generator (seeded with :data:`SEED`)."""
    return np.random.default_rng(SEED)


def residual_draws(
    ctx: nm.Context,
    nom: nm.Nominal,
    rng: np.random.Generator,
    *,
    settle: int,
    n_draws: int = N_DRAWS,
) -> np.ndarray | None:
    """Draws of the nominal noise model's simulation residual over the fit part.

    Parameters
    ----------
    ctx, nom
        The record's context and its nominal model.
    rng
        Source of the white draws (:func:`generator` in the detectors).
    settle
        Fast samples at the start of the fit part left out of the innovations' variance (the
        detectors' start-up, :data:`hbench.diagnose.effects.SETTLE`).
    n_draws
        Number of draws.

    Returns
    -------
    numpy.ndarray or None
        ``(n_draws, n_fit)``: ``e* / A(q)`` from rest, ``e*`` white Gaussian with the variance
        (about their mean) of the nominal innovations over the fit part after ``settle``,
        with the nominal output fit's columns projected out over the fit part; ``None`` when
        the noise model is output error (p = 1).
    """
    d = nm.noise_denominator(nom.model)
    if d is None:
        return None
    n = ctx.n_fit
    innov = np.asarray(nom.innov, float)[settle:n]
    sigma = float(np.std(innov)) if innov.size > 1 else 0.0
    if not np.isfinite(sigma) or sigma <= 0:
        return None
    e = sigma * rng.standard_normal((n_draws, n))
    v = signal.lfilter([1.0], d, e, axis=-1)
    Q = orthonormal_basis(core.output_columns(nom.model, ctx.x)[:n])
    with runtime.one_blas_thread():
        return v - (v @ Q) @ Q.T


def orthonormal_basis(X: np.ndarray, rtol: float = 1e-10) -> np.ndarray:
    """``(n, r)``: an orthonormal basis of the column space of ``X`` (``(n, k)``), the
    directions whose singular value is below ``rtol`` times the largest left out (a start-up
    transient that has settled within the record is nearly the offset column)."""
    with runtime.one_blas_thread():  # the same rounding whatever the machine's core count
        U, s, _ = np.linalg.svd(X, full_matrices=False)
    return U[:, s > rtol * s[0]] if s.size and s[0] > 0 else U[:, :0]


def projection_rss(Y: np.ndarray, X: np.ndarray) -> np.ndarray:
    """Residual sum of squares of each column of ``Y`` (``(n, m)``) after least squares on
    the columns of ``X`` (``(n, k)``); ``(m,)``."""
    Q = orthonormal_basis(X)
    with runtime.one_blas_thread():
        R = Y - Q @ (Q.T @ Y)
    return np.einsum("nm,nm->m", R, R)


def percentile(values: np.ndarray, q: float = QUANTILE) -> float:
    """The ``q`` percentile of the finite ``values`` (``0`` when there is none)."""
    values = np.asarray(values, float)
    values = values[np.isfinite(values)]
    return float(np.percentile(values, q)) if values.size else 0.0

"""What a benchmark record can show of its coloured noise: the oracle test with the true plant.

The README's convention puts noise ``C(q) / A(q) e`` (ARMAX, the plant's own poles) in the
nominal model and calls ``colored-noise`` only noise with dynamics of its own, ``C / D e`` with
``D != A``. Whether a record carries that difference at all is a property of the record's draw,
not of a diagnosis; this module measures it with everything a diagnosis does not know.

Derivation. A ``colored-noise`` case of :mod:`hbench.diagnose.benchmark_cases` has the output
noise ``v = C_n / A e_1 + C_c / D e_2``: the nominal plant's process noise (``C_n / A``,
:func:`hbench.diagnose.benchmark_cases.noise_filter`, driven by white noise of standard
deviation ``noise_sigma``) plus the coloured part (``C_c = 1 + c1 q^-1``, ``D = 1 - d1 q^-1``,
scaled to the standard deviation ``s / snr``). With the true ``A`` the innovations are

    w = A v = C_n e_1 + (A C_c / D) e_2.

The null hypothesis is that ``w`` is a moving average of order ``n_c`` (any coefficients): its
autocorrelations ``rho_k`` vanish beyond lag ``n_c``. Which ``n_c`` is the README's convention
("``C(q) / A(q) e`` belongs to the nominal model") is a choice, made explicit here as ``null``:

* ``"armax"`` (default): ``C`` of the plant's order, ``n_c = na`` (ARMAX with ``deg C = deg A``,
  the usual family). ``A C_c / D = Q + R / D`` with ``deg Q = na``, so beyond lag ``na`` only
  the tail ``R / D`` is left (``R`` proportional to ``A(d1)``, small where ``D``'s pole is close
  to ``A``'s slow poles).
* ``"process"``: ``C`` of the generator's own process noise, whose ZOH numerator
  ``c_1 q^-1 + .. + c_na q^-na`` makes ``w`` a moving average of order ``na - 1``: lag ``na``
  joins the test, and there ``Q`` shows. Any noise with an instantaneous part (white measurement
  noise on ``y`` among it) moves that lag too; the benchmark's records without an effect carry
  none.

Beyond lag ``n_c`` the sample autocorrelations ``r = (rho_(n_c + 1) .. rho_L)`` of ``n`` samples
are asymptotically normal with mean ``r`` and covariance ``G / n``, Bartlett's formula beyond a
moving average's order: ``G[k, k'] = sum_(|i| <= n_c) rho_i rho_(i + k' - k)`` (``rho_i = 0``
for ``|i| > n_c``). The test of ``r = 0`` by ``T = n r_hat' G_hat^-1 r_hat`` (``G_hat`` from the
sample autocorrelations up to lag ``n_c``, :func:`shape_statistic`) is then chi-square with
``L - n_c`` degrees of freedom under the null, and noncentral with

    lambda = n r' G^-1 r

under the coloured noise (``rho`` computed exactly from the two filters' impulse responses).
The oracle's power at a level is the noncentral chi-square's probability beyond the central
one's quantile: the chance that this test, given the true dynamics, tells the record from one
whose noise is of the null's family (``lambda = 0``: the power is the level itself)
(``docs/experiments/colored-noise.md``, sections 8 and 10).
"""

from __future__ import annotations

import numpy as np
from scipy import stats

from hbench.diagnose import benchmark_cases as bc
from hbench.diagnose import stats as dstats
from hbench.diagnose.effects import ColoredNoise
from hbench.diagnose.generator import filter_norm, impulse_response
from hbench.diagnose.nominal import FIT_FRACTION

#: Last lag of the test (that of the diagnosis's whiteness route).
LAGS = ColoredNoise.NLAGS
#: Length of the impulse responses the autocovariances are summed over.
IMPULSE = 6000


def autocovariance(c: np.ndarray, d: np.ndarray, lags: int = LAGS) -> np.ndarray:
    """Autocovariances at lags ``0 .. lags`` of ``c(q) / d(q) e`` for unit white ``e`` (the
    impulse response's first :data:`IMPULSE` terms)."""
    h = impulse_response(c, d, IMPULSE)
    return np.array([h[: IMPULSE - k] @ h[k:] for k in range(lags + 1)])


#: The nulls of the module's derivation.
NULLS = ("armax", "process")


def innovations_acf(
    case: bc.BenchCase,
    c: np.ndarray,
    d: np.ndarray,
    snr: float,
    lags: int = LAGS,
    null: str = "armax",
) -> tuple[np.ndarray, int, int]:
    """``(rho, n_c, n)``: the autocorrelations at lags ``0 .. lags`` of the true innovations
    ``w = A v`` of ``case``'s plant, ``p`` and nominal noise with a coloured part ``c / d`` at
    ``snr`` (its standard deviation ``s / snr``); the null's moving-average order (``null``, one
    of :data:`NULLS`, :func:`null_order`); the fit part's fast samples."""
    A, cn, dn = _nominal(case)
    n_c = _order(A, cn, null)
    scale = case.effect_params["s"] / snr / filter_norm(c, d, 8000)
    g = autocovariance(np.convolve(cn, A), dn, lags) * case.noise_sigma**2
    g = g + autocovariance(np.convolve(c, A), d, lags) * scale**2
    return g / g[0], n_c, fit_samples(case)


def _nominal(case: bc.BenchCase) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(A, C_n, D_n)``: the nominal plant's denominator and its process noise's filter at the
    fast period of ``case``."""
    plant = bc.nominal_plant(case)
    dp = plant.discretize(case.T / case.p)
    cn, dn = bc.noise_filter(plant, dp)
    return np.asarray(dp.a, float), np.asarray(cn, float), np.asarray(dn, float)


def _order(A: np.ndarray, cn: np.ndarray, null: str) -> int:
    if null not in NULLS:
        raise ValueError(f"null must be one of {NULLS}, got {null!r}")
    if null == "armax":
        return A.size - 1
    taps = np.flatnonzero(np.abs(cn) > 0)
    return int(taps[-1] - taps[0])


def null_order(case: bc.BenchCase, null: str = "armax") -> int:
    """The moving-average order ``n_c`` of the innovations under ``null`` (one of
    :data:`NULLS`) for ``case``'s plant and ``p``: the plant's order (``"armax"``), or the span
    of its process noise's nonzero numerator taps (``"process"``: ``na - 1``)."""
    A, cn, _ = _nominal(case)
    return _order(A, cn, null)


def fit_samples(case: bc.BenchCase) -> int:
    """The fast samples of ``case``'s fit part (the diagnosis's default split)."""
    return int(case.K * FIT_FRACTION) * case.p


def coloured_filter(case: bc.BenchCase) -> tuple[np.ndarray, np.ndarray, float]:
    """``(C_c, D, snr)`` of a ``colored-noise`` case: ``1 + c1 q^-1``, ``1 - d1 q^-1`` and its
    SNR."""
    ep = case.effect_params
    return np.array([1.0, ep["c1"]]), np.array([1.0, -ep["d1"]]), float(ep["snr"])


def bartlett(rho: np.ndarray, n_c: int, lags: int) -> np.ndarray:
    """``G`` (lags ``n_c + 1 .. lags`` square): ``n`` times the covariance of the sample
    autocorrelations beyond a moving average of order ``n_c`` whose autocorrelations at lags
    ``0 .. n_c`` are ``rho[: n_c + 1]`` (Bartlett's formula)."""
    two_sided = np.concatenate([rho[n_c:0:-1], rho[: n_c + 1]])  # lags -n_c .. n_c
    g = np.correlate(two_sided, two_sided, "full")[2 * n_c :]  # g(m), m = 0 .. 2 n_c
    m = np.abs(np.subtract.outer(np.arange(lags - n_c), np.arange(lags - n_c)))
    return np.where(m <= 2 * n_c, g[np.minimum(m, 2 * n_c)], 0.0)


def noncentrality(rho: np.ndarray, n_c: int, n: int) -> tuple[float, int]:
    """``(lambda, L - n_c)`` of the module's derivation from the autocorrelations ``rho`` at
    lags ``0 .. L`` of ``n`` samples' innovations (:func:`innovations_acf`) and the null's
    moving-average order ``n_c``: the noncentrality and the degrees of freedom."""
    lags = rho.size - 1
    r = rho[n_c + 1 :]
    lam = float(n * r @ np.linalg.solve(bartlett(rho, n_c, lags), r))
    return max(lam, 0.0), lags - n_c


def power(lam: float, dof: int, level: float = 0.05) -> float:
    """Power at ``level`` of a chi-square test with ``dof`` degrees of freedom whose statistic
    has the noncentrality ``lam`` (``level`` itself at ``lam = 0``)."""
    crit = stats.chi2.ppf(1.0 - level, dof)
    return float(stats.ncx2.sf(crit, dof, lam)) if lam > 0 else float(level)


def noise_shape_power(case: bc.BenchCase, level: float = 0.05, null: str = "armax") -> float | None:
    """The oracle's power at ``level`` under ``null`` on ``case``'s own coloured noise (its
    ``d1``, ``c1`` and ``snr``); None for a case whose effect is not ``colored-noise``."""
    if case.effect != "colored-noise":
        return None
    lam, dof = noncentrality(*innovations_acf(case, *coloured_filter(case), null=null))
    return power(lam, dof, level)


def shape_statistic(w: np.ndarray, n_c: int, lags: int = LAGS) -> tuple[float, float]:
    """The test of the derivation on a series ``w`` of innovations: ``T`` and its chi-square
    p-value with ``lags - n_c`` degrees of freedom."""
    t, dof = noncentrality(dstats.acf(w, lags), n_c, w.size)
    return t, float(stats.chi2.sf(t, dof))

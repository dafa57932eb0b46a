"""What a benchmark record can show of its coloured noise: the oracle test with the true plant.

The README's convention puts noise ``C(q) / A(q) e`` (ARMAX, the plant's own poles) in the
nominal model and calls ``colored-noise`` only noise with dynamics of its own, ``C / D e`` with
``D != A``. Whether a record carries that difference at all is a property of the record's draw,
not of a diagnosis; this module measures it with everything a diagnosis does not know.

Derivation. A ``colored-noise`` case of :mod:`hbench.diagnose.benchmark_cases` has the output
noise ``v = C_n / A e_1 + C_c / D e_2``: the nominal plant's process noise (``C_n / A``, ZOH of
``1 / den(s)`` at the fast period, standard deviation ``noise_sigma`` for unit ``e_1``) plus the
coloured part (``C_c = 1 + c1 q^-1``, ``D = 1 - d1 q^-1``, standard deviation ``s / snr``). With
the true ``A`` the innovations are

    w = A v = C_n e_1 + (A C_c / D) e_2.

Without the coloured part ``w = C_n e_1`` is a moving average of order ``n_c = deg C_n``: its
autocorrelations ``r_k`` vanish for ``k > n_c``. The Ljung-Box statistic of ``n`` samples of
``w`` over the lags ``n_c + 1 .. L`` is then approximately chi-square with ``L - n_c`` degrees
of freedom (each ``r_k`` with variance ``1 / n``, Bartlett's correction for the moving average
left out), and with the coloured part approximately noncentral chi-square with the
noncentrality

    lambda = n sum_{k = n_c + 1}^{L} r_k^2,

``r_k`` the autocorrelations of ``w`` computed exactly from the two filters' impulse responses.
The oracle's power at a level is the noncentral chi-square's probability beyond the central
one's quantile: the chance that a test of the noise's shape, given the true dynamics, tells the
record from one whose noise is the nominal model's (``lambda = 0``: the power is the level
itself). Where ``D``'s pole lies among ``A``'s, ``A C_c / D`` is nearly a moving average and the
power is the level (``docs/experiments/colored-noise.md``, sections 8 and 10).
"""

from __future__ import annotations

import numpy as np
from scipy import signal, stats

from hbench.diagnose import benchmark_cases as bc

#: Last lag of the Ljung-Box sum (the diagnosis's whiteness route sums over 20 lags too).
LAGS = 20
#: Length of the impulse responses the autocovariances are summed over.
IMPULSE = 6000


def autocovariance(b: np.ndarray, a: np.ndarray, lags: int = LAGS) -> np.ndarray:
    """Autocovariances at lags ``0 .. lags`` of ``b(q) / a(q) e`` for unit white ``e`` (the
    impulse response's first :data:`IMPULSE` terms)."""
    imp = np.zeros(IMPULSE)
    imp[0] = 1.0
    h = signal.lfilter(b, a, imp)
    return np.array([h[: IMPULSE - k] @ h[k:] for k in range(lags + 1)])


def noncentrality(
    case: bc.BenchCase, d: np.ndarray, c: np.ndarray, snr: float, lags: int = LAGS
) -> tuple[float, int]:
    """``(lambda, L - n_c)`` of the module's derivation for ``case``'s plant, ``p`` and nominal
    noise, with a coloured part ``c / d`` at ``snr`` (its standard deviation ``s / snr``), over
    the fit part's fast samples (two thirds of the record, as the diagnosis's)."""
    plant = bc.nominal_plant(case)
    dp = plant.discretize(case.T / case.p)
    A = np.asarray(dp.a, float)
    cn, dn = bc._noise_filter(plant, dp)
    scale = case.effect_params["s"] / snr / bc.filter_norm(c, d, 8000)
    g = autocovariance(np.convolve(cn, A), dn, lags) * case.noise_sigma**2
    g = g + autocovariance(np.convolve(c, A), d, lags) * scale**2
    r = g / g[0]
    n_c = len(cn) - 1
    n = int(case.K * case.p * 2 / 3)
    return float(n * np.sum(r[n_c + 1 :] ** 2)), lags - n_c


def power(lam: float, dof: int, level: float = 0.05) -> float:
    """Power at ``level`` of a chi-square test with ``dof`` degrees of freedom whose statistic
    has the noncentrality ``lam`` (``level`` itself at ``lam = 0``)."""
    crit = stats.chi2.ppf(1.0 - level, dof)
    return float(stats.ncx2.sf(crit, dof, lam)) if lam > 0 else float(level)


def noise_shape_power(case: bc.BenchCase, level: float = 0.05) -> float | None:
    """The oracle's power at ``level`` on ``case``'s own coloured noise (its ``d1``, ``c1`` and
    ``snr``); None for a case whose effect is not ``colored-noise``."""
    if case.effect != "colored-noise":
        return None
    ep = case.effect_params
    lam, dof = noncentrality(
        case, np.array([1.0, -ep["d1"]]), np.array([1.0, ep["c1"]]), float(ep["snr"])
    )
    return power(lam, dof, level)

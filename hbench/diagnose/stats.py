"""Residual statistics for the detectors (pure functions of arrays)."""

from __future__ import annotations

from itertools import pairwise
from typing import Any

import numpy as np
from scipy import signal, stats


def acf(e: np.ndarray, nlags: int) -> np.ndarray:
    """Sample autocorrelation at lags ``0 .. nlags``."""
    e = np.asarray(e, float) - np.mean(e)
    n = e.size
    c0 = float(e @ e) / n
    if c0 <= 0:
        return np.zeros(nlags + 1)
    return np.array([1.0] + [float(e[k:] @ e[:-k]) / n / c0 for k in range(1, nlags + 1)])


def ljung_box(e: np.ndarray, nlags: int = 20) -> tuple[float, float]:
    """Ljung-Box ``Q`` over lags ``1 .. nlags`` and its chi-square p-value."""
    n = len(e)
    r = acf(e, nlags)[1:]
    q = float(n * (n + 2) * np.sum(r**2 / (n - np.arange(1, nlags + 1))))
    return q, float(stats.chi2.sf(q, nlags))


def lagged(z: np.ndarray, lags: range, fill: float = 0.0) -> np.ndarray:
    """Columns ``z(t - l)`` for ``l`` in ``lags`` (``fill`` before the start)."""
    N = z.size
    out = np.full((N, len(lags)), fill)
    for j, lag in enumerate(lags):
        if lag == 0:
            out[:, j] = z
        elif lag < N:
            out[lag:, j] = z[:-lag]
    return out


def granger(r: np.ndarray, u: np.ndarray, k: int, m: int, start: int) -> dict[str, float]:
    """Granger-style regressions of a residual ``r(t)`` on its own past and on an input's past.

    Three least-squares fits on the samples ``start ..`` (``start >= max(k, m)``, so no
    regressor reaches before the series' start), each with a constant (so neither series need
    be centred): ``full`` on ``r(t - 1 .. t - k)`` and ``u(t - 1 .. t - m)``, ``own`` on the
    residual's past alone, ``input`` on the input's past alone. Returned:

    * ``input_share``: the share (%) of what the residual's own past leaves that the input's
      past explains, ``100 (RSS_own - RSS_full) / RSS_own`` (a partial R^2), with its F
      statistic ``((RSS_own - RSS_full) / m) / (RSS_full / dof)``, ``dof = n - 1 - k - m``,
      and p-value from ``F(m, dof)`` (``input_f``, ``input_p``);
    * ``own_share``, ``own_f``, ``own_p``: the same for the residual's own past given the
      input's (``F(k, dof)``).

    With Gaussian white regression errors the two F statistics have those F distributions
    exactly when the regressors are fixed, and asymptotically for lagged regressors. In a
    closed loop the input's past is a function of the past noise (through the controller), so
    the plain cross-correlation of ``r`` and ``u`` is no test of the dynamics; conditioning on
    the residual's own past (which whitens a residual that is noise with a stable, invertible
    model of order up to ``k``) leaves the input terms without explanatory power exactly when
    the residual is such noise.
    """
    if k < 1 or m < 1 or start < max(k, m):
        raise ValueError(f"granger needs k, m >= 1 and start >= max(k, m); got {k}, {m}, {start}")
    r = np.asarray(r, float)
    u = np.asarray(u, float)
    n = r.size
    R = lagged(r, range(1, k + 1))
    U = lagged(u, range(1, m + 1))
    one = np.ones((n, 1))
    y = r[start:]

    def rss(X: np.ndarray) -> float:
        X = X[start:]
        th = np.linalg.lstsq(X, y, rcond=None)[0]
        e = y - X @ th
        return float(e @ e)

    full = rss(np.hstack([one, R, U]))
    own = rss(np.hstack([one, R]))
    inp = rss(np.hstack([one, U]))
    dof = max(y.size - 1 - k - m, 1)
    scale = max(full, 1e-300) / dof
    f_in = ((own - full) / m) / scale
    f_own = ((inp - full) / k) / scale
    return {
        "input_share": 100.0 * (own - full) / own if own > 0 else 0.0,
        "input_f": float(f_in),
        "input_p": f_pvalue(f_in, m, dof),
        "own_share": 100.0 * (inp - full) / inp if inp > 0 else 0.0,
        "own_f": float(f_own),
        "own_p": f_pvalue(f_own, k, dof),
    }


def periodogram(e: np.ndarray) -> np.ndarray:
    """``|DFT|^2 / n`` of the mean-removed series at bins ``0 .. n//2`` (along the last axis)."""
    e = np.asarray(e, float)
    e = e - np.mean(e, axis=-1, keepdims=True)
    return np.abs(np.fft.rfft(e, axis=-1)) ** 2 / e.shape[-1]


def _low_ref(n: int, low: int, ref: int) -> tuple[int, int]:
    """The bins :func:`low_frequency_ratio` compares on a series of ``n`` samples."""
    ref = min(ref, n // 2)
    return min(low, ref - 1), ref


def low_frequency_ratios(e: np.ndarray, low: int = 3, ref: int = 20) -> np.ndarray:
    """:func:`low_frequency_ratio`'s ratio of every series along the last axis of ``e``."""
    P = periodogram(e)
    low, ref = _low_ref(np.shape(e)[-1], low, ref)
    num = np.mean(P[..., 1 : low + 1], axis=-1)
    den = np.mean(P[..., low + 1 : ref + 1], axis=-1)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(den > 0, num / np.where(den > 0, den, 1.0), np.inf)


def low_frequency_ratio(e: np.ndarray, low: int = 3, ref: int = 20) -> tuple[float, float]:
    """Mean periodogram over bins ``1 .. low`` against bins ``low+1 .. ref``.

    A stationary disturbance whose correlation time is short next to the record has a flat
    spectrum over these few lowest bins, so the ratio is ``F(2 low, 2 (ref - low))``; a drift
    puts its power in the first bins. Returns ``(ratio, p_value)``.
    """
    ratio = float(low_frequency_ratios(e, low, ref))
    low, ref = _low_ref(np.size(e), low, ref)
    return ratio, float(stats.f.sf(ratio, 2 * low, 2 * (ref - low)))


def noise_model_trend(
    resid: np.ndarray,
    a: np.ndarray,
    *,
    scale: float = 1.0,
    span: float | None = None,
) -> tuple[Any, Any, Any]:
    """A ramp in a residual, tested under the noise model ``e / A(q)`` (prewhitened least squares).

    Model of the residual ``r(n)``, ``n = 0 .. N-1``, under the nominal noise model (the paper's
    eq. 2: equation error ``e / A``) with an offset and a ramp::

        r(n) = c0 + c1 n + v(n),    A(q) v(n) = e(n),    e white, N(0, s^2)        (1)

    with ``A(q) = 1 + a_1 q^-1 + ... + a_na q^-na``. Applying ``A(q)`` to (1) on the rows
    ``n >= na``, where the filter needs no sample before the record (so no initial state)::

        w(n) = (A r)(n) = c0 A(1) + c1 (A n)(n) + e(n),    n = na .. N-1          (2)

    a linear regression with white errors and regressors fixed by ``A``. Ordinary least squares
    on (2) is the generalised least squares estimate of ``(c0, c1)`` under (1) (the
    prewhitening of Cochrane and Orcutt, 1949, J. Am. Stat. Assoc. 44: 32-61, with ``A``
    known), and with ``m = N - na`` rows and the residual variance ``s2 = RSS / (m - 2)``::

        t = c1_hat / sqrt(s2 [(X'X)^-1]_11)  ~  t(m - 2)   under c1 = 0           (3)

    exactly for Gaussian ``e`` and a known ``A``; with a fitted ``A`` and a residual from
    which a model fit has been projected, (3) is the usual large-sample approximation.

    Parameters
    ----------
    resid
        ``(N,)`` or ``(m, N)``: the residual, or one residual per row (tested row by row).
    a
        ``[1, a_1, ..., a_na]``: the noise model's denominator ``A(q)`` (``[1]``: white noise,
        an ordinary t-test of the slope).
    scale
        The ramp's size is reported relative to this (e.g. the output's range).
    span
        Samples over which the ramp's size is reported: ``c1_hat * span`` (default ``N``, the
        residual's length; a longer span extrapolates the slope).

    Returns
    -------
    ramp, t, p
        ``|c1_hat| span / scale``, the t statistic of (3) and its two-sided p-value; floats
        for a 1-D ``resid``, ``(m,)`` arrays for a 2-D one. A residual too short for (2)
        (``N - na < 3``) gives ``nan`` statistics and ``p = 1``.
    """
    r = np.asarray(resid, float)
    one = r.ndim == 1
    R = np.atleast_2d(r)
    a = np.atleast_1d(np.asarray(a, float))
    N = R.shape[-1]
    na = a.size - 1
    m = N - na
    span = float(N if span is None else span)
    if m < 3 or not np.isfinite(scale) or scale <= 0:
        nan = np.full(R.shape[0], np.nan)
        out = (nan, nan, np.ones(R.shape[0]))
        return tuple(float(v[0]) for v in out) if one else out  # type: ignore[return-value]
    n = np.arange(N, dtype=float)
    # (2): the filter on the rows n >= na is the exact convolution (no initial state)
    X = np.stack([np.convolve(np.ones(N), a, "valid"), np.convolve(n, a, "valid")], axis=1)
    W = signal.lfilter(a, [1.0], R, axis=-1)[:, na:]
    Q, Rx = np.linalg.qr(X)
    beta = np.linalg.solve(Rx, Q.T @ W.T)  # (2, m_rows)
    E = W.T - X @ beta
    s2 = np.einsum("ij,ij->j", E, E) / (m - 2)
    Rinv = np.linalg.inv(Rx)
    v11 = float(Rinv[1] @ Rinv[1])  # [(X'X)^-1]_11 = row 1 of R^-1, squared
    with np.errstate(divide="ignore", invalid="ignore"):
        t = beta[1] / np.sqrt(s2 * v11)
    p = np.where(np.isnan(t), 1.0, 2 * stats.t.sf(np.abs(t), m - 2))
    ramp = np.abs(beta[1]) * span / scale
    if one:
        return float(ramp[0]), float(t[0]), float(p[0])
    return ramp, t, p


def robust_sigma(d: np.ndarray) -> float:
    """``1.4826 MAD``: the standard deviation of the Gaussian bulk of ``d``."""
    d = np.asarray(d, float)
    return float(1.4826 * np.median(np.abs(d - np.median(d))))


def spikes(
    e: np.ndarray, width: int = 7, k: float = 6.0, sigma: float | None = None
) -> tuple[np.ndarray, float]:
    """Isolated spikes of ``e``: samples farther than ``k`` sigmas from a running median of
    ``width`` samples (a Hampel filter). ``sigma`` is the noise scale (default the robust
    sigma of the deviations; give the innovations' when ``e`` is smooth, whose running median
    follows it so closely that the deviations' MAD is no scale). Returns ``(mask, sigma)``."""
    e = np.asarray(e, float)
    med = signal.medfilt(e, width)
    d = e - med
    s = robust_sigma(d) if sigma is None else float(sigma)
    if s <= 0:
        return np.zeros(e.size, bool), 0.0
    return np.abs(d) > k * s, s


def isolated_spikes(e: np.ndarray, k: float = 6.0) -> tuple[np.ndarray, np.ndarray, float]:
    """Isolated one-sample spikes: ``d(t) = e(t) - (e(t-1) + e(t+1)) / 2`` beyond ``k`` robust
    sigmas of ``d``, larger than its neighbours' and with both neighbours of the opposite sign
    and at least a quarter of its size (a spike of size ``S`` gives ``d = S`` at itself and
    ``-S/2`` on both sides; a step gives ``-S/2, S/2, 0``, so steps are not spikes). A smooth
    series leaves ``d`` small but not degenerate, unlike its deviations from a running median.
    Returns ``(mask, d, sigma)``."""
    e = np.asarray(e, float)
    d = np.zeros(e.size)
    if e.size >= 3:
        d[1:-1] = e[1:-1] - 0.5 * (e[:-2] + e[2:])
    s = robust_sigma(d[1:-1]) if e.size >= 3 else 0.0
    if s <= 0:
        return np.zeros(e.size, bool), d, 0.0
    a = np.abs(d)
    peak = np.zeros(e.size, bool)
    c, lft, rgt = d[1:-1], d[:-2], d[2:]
    peak[1:-1] = (
        (a[1:-1] >= a[:-2])
        & (a[1:-1] >= a[2:])
        & (lft * c < 0)
        & (rgt * c < 0)
        & (np.abs(lft) >= 0.25 * a[1:-1])
        & (np.abs(rgt) >= 0.25 * a[1:-1])
    )
    return (a > k * s) & peak, d, s


def gaussian_tail_pvalue(count: int, n: int, k: float) -> float:
    """P(at least ``count`` of ``n`` Gaussian samples beyond ``k`` sigmas)."""
    if count <= 0:
        return 1.0
    p1 = float(2 * stats.norm.sf(k))
    return float(stats.binom.sf(count - 1, n, p1))


def excess_kurtosis(e: np.ndarray) -> float:
    e = np.asarray(e, float)
    return float(stats.kurtosis(e, fisher=True, bias=False))


def f_pvalue(f: float, d1: int, d2: int) -> float:
    """The upper tail of ``F(d1, d2)`` at ``f``: 0 for an infinite ``f``, nan for nan (no test)."""
    if np.isnan(f):
        return float("nan")
    return float(stats.f.sf(f, d1, d2)) if np.isfinite(f) else 0.0


def _zero_crossings(z: np.ndarray) -> np.ndarray:
    s = np.sign(z)
    s[s == 0] = 1
    return np.flatnonzero(s[1:] != s[:-1]) + 1


def regularity(x: np.ndarray, max_lag: int = 400) -> tuple[float, float]:
    """Thornhill, Huang & Zhang (2003) oscillation regularity: ``r = mean(T) / (3 std(T))``
    over the periods ``T`` read from the zero crossings of the autocorrelation (two crossings
    a period); ``r > 1`` is a regular oscillation. Returns ``(r, mean period in samples)``
    (``(0, nan)`` with fewer than four crossings)."""
    x = np.asarray(x, float)
    r = acf(x - x.mean(), int(min(max_lag, x.size // 2)))
    zc = _zero_crossings(r)
    if zc.size < 4:
        return 0.0, float("nan")
    periods = 2.0 * np.diff(zc)
    sd = float(np.std(periods, ddof=1))
    tp = float(np.mean(periods))
    return (tp / (3 * sd) if sd > 0 else float("inf")), tp


def _shape_sse(seg: np.ndarray, shape: np.ndarray) -> float:
    """Residual sum of squares of ``seg ~ c shape + d``."""
    X = np.stack([shape, np.ones(seg.size)], axis=1)
    r = seg - X @ np.linalg.lstsq(X, seg, rcond=None)[0]
    return float(r @ r)


def stiction_index(x: np.ndarray) -> float:
    """He, Wang, Pottmann & Qin (2007) curve fitting: every half cycle of ``x`` (between zero
    crossings of ``x`` minus its linear trend) fitted by a half sine and by the best triangle;
    ``SI = MSE_sine / (MSE_sine + MSE_triangle)`` over all half cycles (``> 0.5``: more
    triangular than sinusoidal; nan without a half cycle)."""
    x = np.asarray(x, float)
    t = np.arange(x.size)
    z = x - np.polyval(np.polyfit(t, x, 1), t)
    zc = _zero_crossings(z)
    e_sin = e_tri = 0.0
    for a, b in pairwise(zc):
        seg = z[a:b]
        L = seg.size
        if L < 4:
            continue
        tt = np.arange(L)
        e_sin += _shape_sse(seg, np.sin(np.pi * (tt + 0.5) / L))
        e_tri += min(
            _shape_sse(
                seg, np.where(tt <= k, (tt + 0.5) / (k + 0.5), (L - tt - 0.5) / (L - k - 0.5))
            )
            for k in range(1, L - 1)
        )
    if e_sin + e_tri <= 0:
        return float("nan")
    return e_sin / (e_sin + e_tri)


def paired(x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``x`` and ``y`` as float arrays of one length (a ``ValueError`` otherwise)."""
    x = np.asarray(x, float)
    y = np.asarray(y, float)
    if x.size != y.size:
        raise ValueError(f"x and y differ in length ({x.size} and {y.size})")
    return x, y


def cross_correlation(x: np.ndarray, y: np.ndarray, max_lag: int) -> np.ndarray:
    """Normalised cross-correlation ``c(tau) = sum x(t) y(t + tau) / (||x|| ||y||)`` of the
    mean-removed series at lags ``-max_lag .. max_lag``."""
    x, y = paired(x, y)
    x, y = x - np.mean(x), y - np.mean(y)
    n = x.size
    L = int(min(max_lag, n - 1))
    den = float(np.linalg.norm(x) * np.linalg.norm(y))
    if den <= 0:
        return np.zeros(2 * L + 1)
    full = np.correlate(y, x, mode="full")  # lag tau at index n - 1 + tau
    return full[n - 1 - L : n + L] / den


def _first_crossing(c: np.ndarray) -> float:
    """Lag (interpolated, from index 0 of ``c``) where ``c`` first changes sign; nan if never."""
    s = np.sign(c)
    s[s == 0] = 1
    k = np.flatnonzero(s[1:] != s[:-1])
    if k.size == 0:
        return float("nan")
    i = int(k[0])
    return float(i + c[i] / (c[i] - c[i + 1]))


def horch_phase(x: np.ndarray, y: np.ndarray, max_lag: int | None = None) -> float:
    """Horch (1999) cross-correlation test: the phase ``|dphi|`` in ``[0, pi]`` read from the
    first zero crossings ``tau_l < 0 < tau_r`` of the controller output ``x`` against the
    process output ``y``, ``dphi = pi (tau_r + tau_l) / (tau_r - tau_l)``. An even correlation
    (``|dphi|`` near 0, an extremum at lag 0) is an oscillation from tuning or a disturbance;
    an odd one (near ``pi``) a sticking valve in a self-regulating loop with integral action.
    Horch's limits: below ``pi / 3`` no stiction, above ``2 pi / 3`` stiction. nan when the
    correlation does not cross zero on both sides within ``max_lag`` (default ``n / 4``)."""
    n = np.asarray(x).size
    L = int(max_lag if max_lag is not None else n // 4)
    c = cross_correlation(x, y, L)
    right = _first_crossing(c[L:])
    left = _first_crossing(c[L::-1])
    if not (np.isfinite(right) and np.isfinite(left)):
        return float("nan")
    tau_r, tau_l = right, -left
    if tau_r == tau_l:  # both crossings at lag 0: no phase to read
        return float("nan")
    return float(abs(np.pi * (tau_r + tau_l) / (tau_r - tau_l)))


# --------------------------------------------------------------------------- OP-PV pattern tests


def difference_noise(z: np.ndarray) -> float:
    """The noise standard deviation of the first difference of ``z``, read from its second
    difference: white noise of deviation ``s`` gives differences of deviation ``sqrt(2) s``
    and second differences of ``sqrt(6) s``, while ramps (a constant difference) leave the
    second difference at zero; so ``robust_sigma(d2 z) / sqrt(3)``, robust to the corners."""
    d2 = np.diff(np.asarray(z, float), 2)
    return robust_sigma(d2) / np.sqrt(3.0) if d2.size else 0.0


def qualitative_symbols(z: np.ndarray, band: float = 3.0) -> np.ndarray:
    """Yamashita's qualitative symbols of a series: its first difference ``dz`` is ``+1`` (I,
    increasing) above ``band`` noise standard deviations of ``dz`` (:func:`difference_noise`),
    ``-1`` (D, decreasing) below minus that, ``0`` (S, steady) within.

    Parameters
    ----------
    z : np.ndarray
        The series (length ``n``).
    band : float
        The steady band in noise standard deviations of ``dz`` (see :func:`yamashita_index`).

    Returns
    -------
    np.ndarray
        ``n - 1`` integers in ``{-1, 0, 1}``.
    """
    z = np.asarray(z, float)
    d = np.diff(z)
    s = difference_noise(z)
    if s <= 0:  # no noise to read (a noiseless or quantised series): any change moves
        s = float(np.finfo(float).eps) * max(1.0, float(np.max(np.abs(z), initial=0.0)))
    return np.where(d > band * s, 1, np.where(d < -band * s, -1, 0))


def yamashita_index(x: np.ndarray, y: np.ndarray, band: float = 3.0) -> float:
    """Yamashita (2006) stuck-pattern index of a control loop.

    Y. Yamashita, "An automatic method for detection of valve stiction in process control
    loops", Control Engineering Practice 14 (2006) 503-510 (the qualitative-shape method). The
    differences of the controller output ``x`` (OP) and of the process variable ``y`` (PV, a
    flow in the paper, so that PV follows the valve stem) are turned into the symbols I, D, S
    (:func:`qualitative_symbols`); a sticking valve shows the *stuck* patterns, OP moving while
    PV stays: IS and DS. The index is

    ``rho = (tau_IS + tau_DS) / (tau - tau_SS)``,

    the time in the stuck patterns over the time in which anything moves. The paper's limit:
    ``rho > 0.25`` is stiction (:data:`YAMASHITA_RHO`). The paper quantises normalised
    derivatives; its steady band could not be checked here. The band used (3 noise standard
    deviations of each difference, the noise read from second differences) is fixed a priori,
    not tuned on data: a band of one standard deviation of the difference itself (tried first)
    makes the symbols of a steady ramp random, since a ramp's difference is its own standard
    deviation.

    Parameters
    ----------
    x, y : np.ndarray
        Controller output and process variable, same length.
    band : float
        Steady band of the symbols, in noise standard deviations of each difference.

    Returns
    -------
    float
        ``rho`` in ``[0, 1]``; nan when nothing moves.
    """
    x, y = paired(x, y)
    sx = qualitative_symbols(x, band)
    sy = qualitative_symbols(y, band)
    moving = ~((sx == 0) & (sy == 0))
    if not np.any(moving):
        return float("nan")
    stuck = (sx != 0) & (sy == 0)
    return float(np.sum(stuck) / np.sum(moving))


#: Yamashita (2006): ``rho > 0.25`` is a sticking valve.
YAMASHITA_RHO = 0.25


def kano_index(x: np.ndarray, y: np.ndarray, band: float = 3.0, min_len: int = 3) -> float:
    """Kano et al. (2004) stuck-section index of a control loop.

    M. Kano, H. Maruta, H. Kugemoto, K. Shimizu, "Practical model and detection algorithm for
    valve stiction", IFAC DYCOPS 2004, Boston. Where the valve sticks, the process variable
    ``y`` (PV, a flow: the valve's position seen through the process) stays put over whole
    *sections* while the controller output ``x`` (OP) keeps moving; a free valve moves the PV
    whenever the OP moves. A section is a run of at least ``min_len`` consecutive differences
    in which PV is steady (the steady symbol of :func:`qualitative_symbols`); it is *stuck*
    when the OP's net travel over it, ``|x_end - x_start|``, exceeds ``band`` noise standard
    deviations of ``dx`` times ``sqrt(L)`` (more than the OP's noise could travel in ``L``
    steps). The index is the share of the record's differences that lie in stuck sections.

    Kano et al. decide on such sections of the OP-PV record; their own section limits could
    not be checked here, so ``band``, ``min_len`` and the travel rule are fixed a priori (not
    tuned on data) and the decision limit is Yamashita's share (:data:`KANO_SHARE`, 0.25).

    Parameters
    ----------
    x, y : np.ndarray
        Controller output and process variable, same length.
    band : float
        Steady band (PV) and travel scale (OP), in noise standard deviations of each
        difference (:func:`difference_noise`).
    min_len : int
        Fewest differences in a section.

    Returns
    -------
    float
        The share in ``[0, 1]``; nan when the OP is constant.
    """
    x, y = paired(x, y)
    if np.ptp(x) == 0:
        return float("nan")
    steady = qualitative_symbols(y, band) == 0
    sx = difference_noise(x)
    edges = np.flatnonzero(np.diff(np.concatenate([[0], steady.astype(int), [0]])))
    stuck = 0
    for a, b in zip(edges[::2], edges[1::2], strict=True):
        L = int(b - a)
        if L >= min_len and abs(x[b] - x[a]) > band * sx * np.sqrt(L):
            stuck += L
    return float(stuck / (x.size - 1))


#: The share of stuck sections above which :func:`kano_index` calls stiction (a priori).
KANO_SHARE = 0.25


def squared_bicoherence(e: np.ndarray, nfft: int = 128) -> tuple[np.ndarray, int]:
    """Squared bicoherence of ``e`` over the principal domain, by the direct method.

    Segments of ``nfft`` samples with half overlap, each mean-removed and Hann-windowed;
    ``bic^2(f1, f2) = |E[X1 X2 X12*]|^2 / (E[|X1 X2|^2] E[|X12|^2])`` (Kim and Powers'
    normalisation, as in Choudhury, Shah and Thornhill 2004) for bins ``0 < f2 <= f1``,
    ``f1 + f2 < nfft / 2``.

    Parameters
    ----------
    e : np.ndarray
        The series (a loop's control error in Choudhury et al.).
    nfft : int
        Segment length.

    Returns
    -------
    tuple[np.ndarray, int]
        The bicoherence values (a flat array over the principal domain) and the number of
        segments ``K``.
    """
    e = np.asarray(e, float)
    step = nfft // 2
    starts = range(0, e.size - nfft + 1, step)
    w = np.hanning(nfft)
    X = np.array([np.fft.fft((e[s : s + nfft] - e[s : s + nfft].mean()) * w) for s in starts])
    K = len(starts)
    if K == 0:
        return np.zeros(0), 0
    half = nfft // 2
    f1, f2 = np.meshgrid(np.arange(1, half), np.arange(1, half), indexing="ij")
    keep = (f2 <= f1) & (f1 + f2 < half)
    i, j = f1[keep], f2[keep]
    X1, X2, X12 = X[:, i], X[:, j], X[:, i + j]
    num = np.abs(np.mean(X1 * X2 * np.conj(X12), axis=0)) ** 2
    den = np.mean(np.abs(X1 * X2) ** 2, axis=0) * np.mean(np.abs(X12) ** 2, axis=0)
    with np.errstate(invalid="ignore", divide="ignore"):
        bic = np.where(den > 0, num / den, 0.0)
    return bic, K


def nonlinearity_indices(
    e: np.ndarray, nfft: int = 128, alpha: float = 0.05
) -> tuple[float, float]:
    """Choudhury, Shah and Thornhill's non-Gaussianity and nonlinearity indices.

    M. A. A. S. Choudhury, S. L. Shah, N. F. Thornhill, "Diagnosis of poor control-loop
    performance using higher-order statistics", Automatica 40 (2004) 1719-1728 (and their
    book, Springer 2008). From the squared bicoherence (:func:`squared_bicoherence`, ``K``
    segments) and the critical value ``c = chi2_{1-alpha}(2) / (2 K)`` of a Gaussian series:

    ``NGI = sum(bic^2 > c) / L - c`` (the significant values summed over the ``L`` bins of
    the principal domain) and ``NLI = |max bic^2 - (mean bic^2 + 2 std bic^2)|``.

    Their limits: ``NGI > 0.001`` is a non-Gaussian series (:data:`CHOUDHURY_NGI`), and then
    ``NLI > 0.01`` a nonlinear loop (:data:`CHOUDHURY_NLI`); the stiction tests of the
    literature are the next step only for nonlinear loops. The published recipe also filters
    the error around the oscillation; this function takes the series as it is.

    Returns
    -------
    tuple[float, float]
        ``(NGI, NLI)``; nan for a record shorter than two segments.
    """
    bic, K = squared_bicoherence(e, nfft)
    if K < 2 or bic.size == 0:
        return float("nan"), float("nan")
    c = float(stats.chi2.ppf(1 - alpha, 2)) / (2 * K)
    ngi = float(np.sum(bic[bic > c]) / bic.size - c)
    nli = float(abs(np.max(bic) - (np.mean(bic) + 2 * np.std(bic))))
    return ngi, nli


#: Choudhury et al.: ``NGI > 0.001`` is non-Gaussian ...
CHOUDHURY_NGI = 0.001
#: ... and ``NLI > 0.01`` nonlinear.
CHOUDHURY_NLI = 0.01

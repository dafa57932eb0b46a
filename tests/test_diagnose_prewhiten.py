"""The prewhitened class fits through the dynamics (generalised least squares):
:func:`hbench.diagnose.classes.prewhitener`, :func:`hbench.diagnose.classes.prewhitened_rows`
and :func:`hbench.diagnose.classes.fit_equation_error` with ``prefilter``."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import signal

from hbench.diagnose import classes, core


def test_the_prewhitener_recovers_an_ar_noise_filter() -> None:
    """``w = e / D`` with ``D = 1 - 1.5 q^-1 + 0.7 q^-2``: the AR(8) fit gives ``D`` to a few
    hundredths and zeros beyond (20 000 samples)."""
    rng = np.random.default_rng(1)
    d = np.array([1.0, -1.5, 0.7])
    w = signal.lfilter([1.0], d, rng.standard_normal(20_000))
    est = classes.prewhitener(w, np.ones(w.size, bool))
    assert est.size == classes.PREWHITEN_AR + 1
    assert np.max(np.abs(est[:3] - d)) < 0.03
    assert np.max(np.abs(est[3:])) < 0.03


def test_rows_whose_filter_window_holds_a_dropped_row_are_dropped() -> None:
    """Rows 10-12 dropped (an outlier's span): with a filter of order 3 the rows 10-15 go,
    and the first 3 rows (no full window)."""
    rows = np.arange(100, 130)
    kept = np.ones(rows.size, bool)
    kept[10:13] = False
    out = classes.prewhitened_rows(rows, kept, 3)
    gone = sorted(set(rows) - set(out))
    assert gone == [100, 101, 102, *range(110, 116)]


def test_prewhitened_rows_make_a_record_that_did_not_start_at_rest_exact() -> None:
    """A record cut from a longer run (not at rest, an offset on the valve output) and an
    order-8 prefilter: the filtered equations of the first 8 rows hold samples before the
    record (taken as zero), so fitting from the first row misses, and the rows of
    :func:`hbench.diagnose.classes.prewhitened_rows` give the ARX part exactly."""
    rng = np.random.default_rng(0)
    x = np.cumsum(rng.standard_normal(3500)) * 0.05
    x -= x.mean()
    u = core.nl_one("backlash", x, {"width": 0.3, "g0": 0.5})
    y = signal.lfilter([0.0, 0.6, 0.3], [1.0, -1.2, 0.5], u + 0.7)[500:]
    x = x[500:]
    d = core.stabilise(np.r_[1.0, 0.3 * rng.standard_normal(8)])
    start = {"width": 0.3, "g0": 0.5}
    rows = classes.prewhitened_rows(np.arange(2, x.size), np.ones(x.size - 2, bool), 8)
    assert rows[0] == 10
    out = {}
    for name, idx in (("all", np.arange(x.size)), ("prewhitened", rows)):
        _, rss, ab = classes.fit_equation_error(
            "backlash", x, y, 1, idx, 2, 2, 0, theta0=start, prefilter=d
        )
        out[name] = (rss / float(y @ y), ab[:4])
    assert out["all"][0] > 1e-6
    assert out["prewhitened"][0] < 1e-10
    assert np.allclose(out["prewhitened"][1], [-1.2, 0.5, 0.6, 0.3], atol=1e-5)


def _arx_record(noise: np.ndarray | None, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """``A y = B f(x) + v`` at p = 1 with a backlash of width 0.3, x a random walk."""
    rng = np.random.default_rng(seed)
    x = np.cumsum(rng.standard_normal(6000)) * 0.05
    x -= x.mean()
    u = core.nl_one("backlash", x, {"width": 0.3, "g0": 0.5})
    a, b = [1.0, -1.2, 0.5], [0.0, 0.6, 0.3]
    v = np.zeros(x.size) if noise is None else noise
    y = signal.lfilter(b, a, u) + signal.lfilter([1.0], a, v)
    return x, y


def test_a_prefilter_leaves_noise_free_fits_exact() -> None:
    """Noise free, any prefilter: the backlash's width and the ARX part exactly (the filter
    acts on both sides of ``A y = B f(x)``)."""
    x, y = _arx_record(None)
    idx = np.arange(x.size)
    for pre in (None, np.array([1.0, -0.9]), np.array([1.0, -1.5, 0.7])):
        th, rss, ab = classes.fit_equation_error(
            "backlash", x, y, 1, idx, 2, 2, 0, theta0={"width": 0.3, "g0": 0.5}, prefilter=pre
        )
        assert rss < 1e-10 * float(y @ y)  # rounding of the normal equations
        assert th["width"] == pytest.approx(0.3)
        assert np.allclose(ab[:4], [-1.2, 0.5, 0.6, 0.3], atol=1e-6)


def test_the_prefilter_removes_the_bias_of_coloured_equation_noise() -> None:
    """``A y = B f(x) + e / D`` with ``D = 1 - 0.9 q^-1`` (ARARX): plain equation error is
    biased in ``a1`` (the noise's pole pulls it), the fit prefiltered by the true ``D`` is not
    (within 4 standard errors of 0.01 over 6000 samples). (One step from the plain fit's
    residual does not get there: the biased ``A`` has taken the noise's pole and left a
    residual near white, the known limit of a single generalised-least-squares step.)"""
    rng = np.random.default_rng(3)
    e = 0.05 * rng.standard_normal(6000)
    x, y = _arx_record(signal.lfilter([1.0], [1.0, -0.9], e), seed=3)
    idx = np.arange(x.size)
    start = {"width": 0.3, "g0": 0.5}
    _, _, plain = classes.fit_equation_error("backlash", x, y, 1, idx, 2, 2, 0, theta0=start)
    d_true = np.array([1.0, -0.9])
    _, _, gls = classes.fit_equation_error(
        "backlash", x, y, 1, idx, 2, 2, 0, theta0=start, prefilter=d_true
    )
    assert abs(plain[0] - (-1.2)) > 0.05
    assert abs(gls[0] - (-1.2)) < 0.04

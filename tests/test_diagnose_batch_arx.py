"""``hbench.diagnose.core.batch_arx``: the batched equation-error least squares the class fits run
on, against a plain least-squares solution, on consecutive rows (the lagged inputs read as views)
and on rows with gaps (gathered)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import signal

from hbench.diagnose import core


def _regression(u: np.ndarray, y: np.ndarray, na: int, nb: int, delay: int, idx: np.ndarray):
    """``[-y(t-1..na), u(t-delay-1..), 1]`` on the rows ``idx``, written out."""
    cols = [-y[idx - i] for i in range(1, na + 1)]
    cols += [u[idx - delay - j] for j in range(1, nb + 1)]
    cols.append(np.ones(idx.size))
    return np.column_stack(cols)


@pytest.mark.parametrize("gaps", [False, True])
@pytest.mark.parametrize(("na", "nb", "delay"), [(0, 1, 0), (2, 2, 3), (5, 4, 1)])
def test_batch_arx_is_least_squares(gaps: bool, na: int, nb: int, delay: int) -> None:
    rng = np.random.default_rng(na * 10 + nb + delay)
    C, N = 7, 900
    u = rng.standard_normal((C, N))
    y = signal.lfilter([1.0], [1.0, -0.8], rng.standard_normal(N))
    idx = np.arange(N - 40)
    if gaps:
        idx = np.sort(rng.choice(idx, size=500, replace=False))
    rss, theta = core.batch_arx(u, y, na, nb, delay, idx)
    rows = idx[idx >= max(na, delay + nb)]
    for c in range(C):
        Phi = _regression(u[c], y, na, nb, delay, rows)
        want, *_ = np.linalg.lstsq(Phi, y[rows], rcond=None)
        np.testing.assert_allclose(theta[c], want, rtol=1e-8, atol=1e-10)
        r = y[rows] - Phi @ want
        np.testing.assert_allclose(rss[c], r @ r, rtol=1e-8)


@pytest.mark.parametrize("gaps", [False, True])
def test_batch_arx_is_exact_noise_free(gaps: bool) -> None:
    """y from A(q) y = q^-d B(q) u + m without noise: the right candidate's RSS is zero and its
    coefficients are the system's, up to the normal equations' regularisation (1e-12 of their
    trace); a wrong candidate's RSS is not."""
    rng = np.random.default_rng(3)
    N, d = 1200, 2
    a, b, m = np.array([1.0, -1.5, 0.6]), np.array([0.4, -0.1]), 0.3
    u = signal.lfilter([1.0], [1.0, -0.5], rng.standard_normal(N))
    num = np.concatenate([np.zeros(d + 1), b])
    y = signal.lfilter(num, a, u) + m / a.sum()
    idx = np.arange(50, N)
    if gaps:
        idx = idx[rng.random(idx.size) > 0.3]
    rss, theta = core.batch_arx(np.stack([u, u**2]), y, 2, 2, d, idx)
    assert rss[0] < 1e-9 * float(y @ y)
    np.testing.assert_allclose(theta[0], [*a[1:], *b, m], atol=1e-6)
    assert rss[1] > 1e-4 * float(y @ y)

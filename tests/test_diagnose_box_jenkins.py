"""The Box-Jenkins class comparison (:mod:`hbench.diagnose.box_jenkins`): exact on noise-free
data, and consistent under output noise of other dynamics where equation error is biased."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import signal

from hbench.diagnose import box_jenkins as bj
from hbench.diagnose import core, nominal

A = np.array([1.0, -1.5, 0.7])
B = np.array([0.5, 0.3])
DELAY, P = 1, 4


def _x(K: int, rng: np.random.Generator) -> np.ndarray:
    """Random steps held 1-6 slow samples (a reversing input that moves every valve)."""
    x = np.empty(K)
    k = 0
    while k < K:
        n = int(rng.integers(1, 7))
        x[k : k + n] = rng.uniform(-1, 1)
        k += n
    return x


def _record(cls, theta, K, rng, noise=0.0, d1=0.9):
    x = _x(K, rng)
    f = core.nl_one(cls, x, theta)
    u = np.repeat(f - f[0], P)
    y = signal.lfilter(np.r_[np.zeros(1 + DELAY), B], A, u) + 0.3
    if noise:
        y = y + noise * signal.lfilter([1.0], [1.0, -d1], rng.standard_normal(y.size))
    return x, y


def test_ar_noise_recovers_an_autoregression_exactly():
    rng = np.random.default_rng(0)
    d = np.array([1.0, -0.8, 0.3])
    e = np.zeros(400)
    e[50] = 1.0  # an impulse: w = e / D is exact, the residual D w is zero off the impulse
    w = signal.lfilter([1.0], d, e)
    rows = np.arange(60, 400)
    got = bj.ar_noise(w, rows, 2)
    np.testing.assert_allclose(got, d, atol=1e-10)
    assert got.size == 3 and rng is not None


@pytest.mark.parametrize(
    "cls, theta",
    [
        ("backlash", {"width": 0.4, "g0": 0.5}),
        ("deadband", {"lower": -0.25, "upper": 0.2}),
        ("saturation", {"u_min": -0.6, "u_max": 0.5}),
        ("stiction", {"S": 0.5, "J": 0.25, "d0": 1.0, "g0": 0.5}),
    ],
)
def test_noise_free_record_gives_its_class_and_plant(cls, theta):
    """Noise-free: the true class is chosen (the class rules of
    :func:`hbench.diagnose.nominal.choose_graph`: stiction nests backlash), fits to a residual
    far below the linear class's, and
    with the true plant's impulse response (the grids hold the true parameters to within their
    fine steps, so the response to 1e-2 and the residual to 1e-3 of the linear's)."""
    rng = np.random.default_rng(1)
    x, y = _record(cls, theta, 400, rng)
    rows = np.arange(100, y.size)
    fits = bj.compare_classes(x, y, P, rows, nb=2, delay=DELAY)
    assert nominal.choose_graph(fits, nominal.MIN_STRENGTH_EQ) == cls
    assert fits[cls].rss < 1e-3 * fits["linear"].rss
    plant = fits[cls].info["plant"]  # na is chosen on the linear class: compare responses
    imp = np.r_[1.0, np.zeros(59)]
    got = signal.lfilter(plant["b"], plant["a"], imp)
    want = signal.lfilter(B, A, imp)
    got *= np.sum(want) / np.sum(got)  # the class's gain sits in B
    np.testing.assert_allclose(got, want, atol=1e-2 * np.abs(want).max())


def test_linear_noise_free_is_exact():
    rng = np.random.default_rng(2)
    x, y = _record("linear", {}, 300, rng)
    rows = np.arange(100, y.size)
    st = bj.linear_start(x, y, P, 2, 2, DELAY, rows)
    np.testing.assert_allclose(st.a, A, atol=1e-8)
    np.testing.assert_allclose(st.b, B, atol=1e-8)
    assert st.rss < 1e-12 * float(np.sum(y**2))


def test_consistent_under_output_noise_of_other_dynamics():
    """Output noise ``e / (1 - 0.9 q^-1)`` (not the plant's ``A``): the Box-Jenkins plant's
    error shrinks as the record grows, while equation error keeps a bias."""
    errs = {}
    for K in (500, 4000):
        rng = np.random.default_rng(3)
        x, y = _record("linear", {}, K, rng, noise=0.2)
        rows = np.arange(100, y.size)
        st = bj.linear_start(x, y, P, 2, 2, DELAY, rows)
        _, th = core.batch_arx(np.repeat(x - x[0], P)[None, :], y, 2, 2, DELAY, rows)
        errs[K] = (np.abs(st.a - A).max(), np.abs(np.r_[1.0, th[0, :2]] - A).max())
    assert errs[4000][0] < 0.5 * errs[500][0] or errs[4000][0] < 5e-3
    assert errs[4000][0] < 0.2 * errs[4000][1]

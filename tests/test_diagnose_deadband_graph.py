"""The dead zone on the ``(x, U)`` graph (:func:`hbench.diagnose.classes.fit_graph` with the
partition candidates of :func:`hbench.diagnose.classes.deadband_partitions`): exact on
noise-free graphs, where ``x`` jumps across the band and where it rests in it."""

from __future__ import annotations

import numpy as np
from scipy import signal

from hbench.diagnose import classes, core


def _graph(x: np.ndarray, lower: float, upper: float) -> np.ndarray:
    """Noise-free ``U = 2 f(x) + 0.3`` of the dead zone ``[lower, upper]``."""
    return 2.0 * core.nl_one("deadband", x, {"lower": lower, "upper": upper}) + 0.3


def test_a_band_that_x_jumps_across_is_found_exactly() -> None:
    """``x`` never inside the band (as in a closed loop that limit-cycles across a dead zone):
    no quantile of ``x`` is an edge, and only the band's width is identified (the offset
    takes its position). The fit is exact: zero residual, the width to 1e-9, the band inside
    the gap of ``x``, and a score far above every other class's."""
    rng = np.random.default_rng(3)
    side = np.where(rng.random(600) < 0.5, -1.0, 1.0)
    x = np.where(side < 0, -0.94, 0.87) + side * rng.uniform(0.0, 0.5, 600)
    U = _graph(x, -0.936, 0.522)
    fits = classes.fit_graph(x, U)
    th = fits["deadband"].theta
    assert fits["deadband"].rss < 1e-20 * float(U @ U)
    assert abs((th["upper"] - th["lower"]) - (0.936 + 0.522)) < 1e-9
    assert x[x < 0].max() <= th["lower"] <= th["upper"] <= x[x > 0].min()
    assert fits["deadband"].score > 100 + max(f.score for c, f in fits.items() if c != "deadband")


def test_the_partition_fit_recovers_both_edges_where_x_rests_in_the_band() -> None:
    """``x`` evenly over [-1, 1) (step 0.005) with the band's edges between sorted samples 99
    and 100 and between 299 and 300 (split positions of the 5 % quantiles): the least squares
    of the partition (the four-parameter regression of the docstring) gives both edges
    exactly."""
    x = np.random.default_rng(4).permutation(np.linspace(-1.0, 1.0, 400, endpoint=False))
    # sorted x[99], x[100] = -0.505, -0.5; x[299], x[300] = 0.495, 0.5
    lower, upper = -0.5013, 0.4987
    U = _graph(x, lower, upper)
    cand = classes.deadband_partitions(x, U)
    k = int(np.argmin(np.abs(cand["lower"] - lower) + np.abs(cand["upper"] - upper)))
    assert abs(cand["lower"][k] - lower) < 1e-9 and abs(cand["upper"][k] - upper) < 1e-9
    fits = classes.fit_graph(x, U)
    assert fits["deadband"].rss < 1e-20 * float(U @ U)
    assert abs(fits["deadband"].theta["lower"] - lower) < 1e-9
    assert abs(fits["deadband"].theta["upper"] - upper) < 1e-9


def test_missing_values_and_short_graphs() -> None:
    """NaN in ``U`` are skipped like the grid search skips them; a graph too short to split
    gives no candidates."""
    x = np.linspace(-1.0, 1.0, 200)
    U = _graph(x, -0.2, 0.3)
    U[::7] = np.nan
    cand = classes.deadband_partitions(x, U)
    assert cand["lower"].size and np.all(np.isfinite(cand["lower"]))
    assert np.all(cand["lower"] <= cand["upper"])
    empty = classes.deadband_partitions(x[:5], U[:5])
    assert empty["lower"].size == empty["upper"].size == 0


def test_gap_bands_let_equation_error_find_a_band_that_x_jumps_across() -> None:
    """Through the dynamics (equation error, no inner signal: the blind route's class choice),
    noise-free, ``x`` never inside the band: the coarse grid's candidates in the gaps of ``x``
    (:func:`hbench.diagnose.classes.gap_bands`) and the finer passes find the band's width to
    0.5 % and a residual 1e-6 of the linear class's; with the quantile candidates alone the
    dead zone fits no better than a tenth of that improvement."""
    rng = np.random.default_rng(5)
    side = np.where(rng.random(500) < 0.5, -1.0, 1.0)
    x = np.where(side < 0, -0.94, 0.87) + side * rng.uniform(0.0, 0.5, 500)
    p = 4
    u = np.repeat(core.nl_one("deadband", x, {"lower": -0.936, "upper": 0.522}), p)
    y = signal.lfilter([0.0, 1.0, 0.5], [1.0, -0.9], u)
    idx = np.arange(20, y.size)
    args = ("deadband", x, y, p, idx, 1, 2, 0)
    theta, rss, _ = classes.fit_equation_error(*args)
    _, rss_lin, _ = classes.fit_equation_error("linear", x, y, p, idx, 1, 2, 0)
    assert abs((theta["upper"] - theta["lower"]) - 1.458) < 0.005 * 1.458
    assert rss < 1e-6 * rss_lin
    quantiles_only = {
        k: v[: -classes.DEADBAND_GAPS * classes.GAP_WIDTHS]
        for k, v in classes.coarse_grid("deadband", x).items()
    }
    assert classes.gap_bands(x)["lower"].size == classes.DEADBAND_GAPS * classes.GAP_WIDTHS
    F = np.repeat(core.nl_batch("deadband", x, quantiles_only), p, axis=1)
    rss_q, _ = core.batch_arx(F, y, 1, 2, 0, idx, None)
    assert rss_lin - rss_q.min() < 0.1 * (rss_lin - rss)

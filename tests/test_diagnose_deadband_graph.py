"""The dead zone on the ``(x, U)`` graph (:func:`hbench.diagnose.classes.fit_graph` with the
partition candidates of :func:`hbench.diagnose.classes.deadband_partitions`): exact on
noise-free graphs, where ``x`` jumps across the band and where it rests in it."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import signal

from hbench.diagnose import classes, core, nominal


def _graph(x: np.ndarray, lower: float, upper: float) -> np.ndarray:
    """Noise-free ``U = 2 f(x) + 0.3`` of the dead zone ``[lower, upper]``."""
    return 2.0 * core.nl_one("deadband", x, {"lower": lower, "upper": upper}) + 0.3


def test_a_band_that_x_jumps_across_is_found_exactly() -> None:
    """``x`` never inside the band (as in a closed loop that limit-cycles across a dead zone):
    no quantile of ``x`` is an edge, and only the band's width is identified (the offset
    takes its position). The fit is exact: a residual at rounding, the width to 1e-9, the
    band inside the gap of ``x``, and a score far above every other class's."""
    x = _bimodal(3)
    U = _graph(x, -0.936, 0.522)
    fits = classes.fit_graph(x, U)
    th = fits["deadband"].theta
    assert fits["deadband"].rss < 1e-12 * float(U @ U)  # the RSS formula cancels: suu - sfu^2 / sff
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
    assert fits["deadband"].rss < 1e-12 * float(U @ U)  # the RSS formula cancels: suu - sfu^2 / sff
    assert abs(fits["deadband"].theta["lower"] - lower) < 1e-9
    assert abs(fits["deadband"].theta["upper"] - upper) < 1e-9


def _bimodal(seed: int, n: int = 600) -> np.ndarray:
    """``x`` in [-1.44, -0.94] or [0.87, 1.37], never in between."""
    rng = np.random.default_rng(seed)
    side = np.where(rng.random(n) < 0.5, -1.0, 1.0)
    return np.where(side < 0, -0.94, 0.87) + side * rng.uniform(0.0, 0.5, n)


def test_missing_values_are_left_out_and_short_or_constant_graphs_give_nothing() -> None:
    """NaN in ``U`` are left out by the graph fit (the band is still found exactly), NaN in
    ``x`` or ``U`` by the partition fits; fewer than 8 samples, or a constant ``x``, give no
    candidate."""
    x = _bimodal(6)
    U = _graph(x, -0.936, 0.522)
    U[::7] = np.nan
    th = classes.fit_graph(x, U)["deadband"].theta
    assert abs((th["upper"] - th["lower"]) - 1.458) < 1e-9
    x[3::11] = np.nan
    cand = classes.deadband_partitions(x, U)
    assert np.any(np.abs((cand["upper"] - cand["lower"]) - 1.458) < 1e-9)
    assert np.all(cand["lower"] <= cand["upper"])
    short = classes.deadband_partitions(x[:5], U[:5])
    flat = classes.deadband_partitions(np.ones(50), np.arange(50.0))
    for c in (short, flat):
        assert c["lower"].size == c["upper"].size == 0


def test_the_partition_fit_does_not_depend_on_the_offset_and_scale_of_x() -> None:
    """The band of the first test with ``x`` scaled by 1e-3 and moved to 1e4: the width to
    1e-6 of itself (the normal equations are formed on ``x`` standardised)."""
    x = 1e4 + 1e-3 * _bimodal(3)
    U = _graph(x, 1e4 - 0.936e-3, 1e4 + 0.522e-3)
    th = classes.fit_graph(x, U)["deadband"].theta
    assert abs((th["upper"] - th["lower"]) - 1.458e-3) < 1e-6 * 1.458e-3


@pytest.mark.parametrize("seed", range(8, 14))
def test_no_candidate_gives_a_few_extreme_samples_an_offset_of_their_own(seed: int) -> None:
    """A straight line with one outlying sample at the largest ``x``: the gaps at the ends of
    sorted ``x`` are no place for a band (fewer than 5 % of the samples beyond them), and the
    class stays linear (with the equation-error route's strength floor, the lower one)."""
    rng = np.random.default_rng(seed)
    x = rng.standard_normal(600)
    U = 1.5 * x + 0.05 * rng.standard_normal(600)
    U[np.argmax(x)] -= 3.0
    m = round(classes.TAIL_SHARE * x.size)
    xs = np.sort(x)
    bands = classes.gap_bands(x)
    assert np.all(bands["lower"] >= xs[m - 1]) and np.all(bands["upper"] <= xs[-m])
    cand = classes.deadband_partitions(x, U)
    assert np.all(cand["lower"] >= xs[m - 1]) and np.all(cand["upper"] <= xs[-m])
    fits = classes.fit_graph(x, U)
    assert nominal.choose_graph(fits, nominal.MIN_STRENGTH_EQ) == "linear"


def test_gap_bands_let_equation_error_find_a_band_that_x_jumps_across() -> None:
    """Through the dynamics (equation error, no inner signal: the blind route's class choice),
    noise-free, ``x`` never inside the band: the coarse grid's candidates in the gaps of ``x``
    (:func:`hbench.diagnose.classes.gap_bands`) and the finer passes find the band's width to
    0.5 % and a residual 1e-6 of the linear class's; with the quantile candidates alone the
    dead zone fits no better than a tenth of that improvement."""
    x = _bimodal(5, 500)
    p = 4
    u = np.repeat(core.nl_one("deadband", x, {"lower": -0.936, "upper": 0.522}), p)
    y = signal.lfilter([0.0, 1.0, 0.5], [1.0, -0.9], u)
    idx = np.arange(20, y.size)
    args = ("deadband", x, y, p, idx, 1, 2, 0)
    theta, rss, _ = classes.fit_equation_error(*args)
    _, rss_lin, _ = classes.fit_equation_error("linear", x, y, p, idx, 1, 2, 0)
    assert abs((theta["upper"] - theta["lower"]) - 1.458) < 0.005 * 1.458
    assert rss < 1e-6 * rss_lin
    q = np.quantile(x, np.linspace(0.0, 1.0, 21))[1:-1]
    lo, hi = np.meshgrid(q, q, indexing="ij")
    quantiles_only = {"lower": lo[lo <= hi], "upper": hi[lo <= hi]}
    F = np.repeat(core.nl_batch("deadband", x, quantiles_only), p, axis=1)
    rss_q, _ = core.batch_arx(F, y, 1, 2, 0, idx, None)
    assert rss_lin - rss_q.min() < 0.1 * (rss_lin - rss)


@pytest.mark.parametrize("seed", range(6))
def test_a_one_sided_saturation_is_not_called_a_dead_zone(seed: int) -> None:
    """``U = 2 min(x, c) + 0.3`` with noise, clipping the top 25 % of ``x`` (uniform): a dead
    zone ``[c, upper]`` with ``upper`` past the largest samples is the same map up to an
    offset and fits as well. It is one-sided (:func:`hbench.diagnose.classes.one_sided`), so it
    must beat the saturation by the nesting margin, which it does not: the class is
    ``saturation``, its edge where the dead zone's lower edge is, and the dead zone is no
    rival in the margin."""
    from hbench.diagnose.validate import class_margin

    rng = np.random.default_rng(seed)
    x = rng.uniform(-1.0, 1.0, 800)
    c = float(np.quantile(x, 0.75))
    U = 2.0 * np.minimum(x, c) + 0.3 + 0.01 * rng.standard_normal(x.size)
    fits = classes.fit_graph(x, U)
    db, sat = fits["deadband"], fits["saturation"]
    assert float(np.mean(x >= db.theta["upper"])) < classes.TAIL_SHARE  # the one-sided band
    assert db.info["one_sided"]
    assert db.score < sat.score + nominal.GRAPH_NEST_MARGIN
    assert abs(sat.theta["u_max"] - c) < 0.02 and sat.theta["u_min"] == -np.inf
    chosen = nominal.choose_graph(fits)
    assert chosen == "saturation"
    margin, runner = class_margin(chosen, fits)
    assert runner != "deadband" and margin > 0.0


@pytest.mark.parametrize("seed", range(4))
def test_a_dead_zone_with_few_samples_beyond_one_edge_stays_a_dead_zone(seed: int) -> None:
    """A true dead zone with 30 % of ``x`` below it and only 3 % above it (24 samples): it is
    one-sided by the tail count, and the saturation starts at its one-sided equivalent
    (:func:`hbench.diagnose.classes.one_sided_saturations`, the edge at the band's lower edge),
    but the samples above the band are evidence worth hundreds of score units, far beyond the
    nesting margin: the class stays ``deadband``."""
    rng = np.random.default_rng(seed)
    x = rng.uniform(-1.0, 1.0, 800)
    lo, hi = float(np.quantile(x, 0.30)), float(np.quantile(x, 0.97))
    U = _graph(x, lo, hi) + 0.01 * rng.standard_normal(x.size)
    fits = classes.fit_graph(x, U)
    assert fits["deadband"].info["one_sided"]
    assert abs(fits["saturation"].theta["u_max"] - lo) < 0.01
    assert fits["deadband"].score > fits["saturation"].score + 100
    assert nominal.choose_graph(fits) == "deadband"


def test_one_sided_counts_the_samples_at_or_beyond_each_edge() -> None:
    """800 samples: the tail count is 40. A band with exactly 40 samples at or above its upper
    edge (and 400 below its lower one) is two-sided; with 39 it is one-sided; the two-sided
    band's strength is the share of its variance off a straight line, as for every class."""
    x = np.arange(800.0)
    assert classes._tail_count(x.size) == 40
    two = {"lower": 400.0, "upper": 760.0}  # x >= 760: 40 samples; x <= 400: 401
    one = {"lower": 400.0, "upper": 761.0}  # x >= 761: 39 samples
    assert not classes.one_sided(two, x)
    assert classes.one_sided(one, x)
    f = core.nl_one("deadband", x, two)
    assert classes.strength("deadband", two, x) == pytest.approx(1 - np.corrcoef(f, x)[0, 1] ** 2)

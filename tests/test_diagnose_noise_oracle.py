"""The oracle of :mod:`hbench.diagnose.noise_oracle`: its power against simulated Ljung-Box tests
of the true innovations, its limit where the noise's pole is the plant's, and the benchmark
rows and summary that carry it. Cases from the calibration seeds (10000-19999)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from scipy import signal, stats

from hbench.diagnose import benchmark_cases as bc
from hbench.diagnose import calibrate
from hbench.diagnose import noise_oracle as no


def _first_order(seed: int) -> bc.BenchCase:
    return bc.draw_bench_case(seed, "colored-noise", "linear", "first-order")


def _simulated_rejection(
    case: bc.BenchCase, draws: int, rng: np.random.Generator
) -> tuple[float, float]:
    """Share of ``draws`` records of the true innovations ``w = A v`` (fit part's length) whose
    Ljung-Box statistic over lags ``n_c + 1 .. 20`` passes the 5 % point: with the coloured part,
    and of the nominal noise alone."""
    ep = case.effect_params
    plant = bc.nominal_plant(case)
    dp = plant.discretize(case.T / case.p)
    A = np.asarray(dp.a)
    cn, dn = bc._noise_filter(plant, dp)
    c, d = np.array([1.0, ep["c1"]]), np.array([1.0, -ep["d1"]])
    scale = ep["s"] / ep["snr"] / bc.filter_norm(c, d, 8000)
    n, n_c, lags, settle = int(case.K * case.p * 2 / 3), len(cn) - 1, no.LAGS, 2000
    crit = stats.chi2.ppf(0.95, lags - n_c)
    k = np.arange(n_c + 1, lags + 1)
    passed = np.zeros(2)
    for _ in range(draws):
        e = rng.standard_normal((2, n + settle))
        w1 = signal.lfilter(np.convolve(cn, A), dn, e[0])[settle:] * case.noise_sigma
        w2 = signal.lfilter(np.convolve(c, A), d, e[1])[settle:] * scale
        for i, w in enumerate((w1 + w2, w1)):
            w = w - w.mean()
            g = np.array([w[: n - j] @ w[j:] for j in range(lags + 1)])
            r = g[k] / g[0]
            passed[i] += n * (n + 2) * np.sum(r**2 / (n - k)) > crit
    return passed[0] / draws, passed[1] / draws


@pytest.mark.parametrize("seed", [10039, 10022])
def test_power_is_that_of_simulated_ljung_box_tests(seed: int) -> None:
    """The noncentral chi-square's power against the share of simulated records of the true
    innovations the Ljung-Box test rejects, within three binomial standard errors of the draws
    plus 0.03 for the approximation the derivation states (Bartlett's correction left out);
    the nominal noise alone is rejected at about the level. Seeds: first-order cases whose
    power is mid-range (0.45 and 0.77), where a wrong noncentrality shows most."""
    case = _first_order(seed)
    predicted = no.noise_shape_power(case)
    assert predicted is not None and 0.2 < predicted < 0.9
    draws = 400
    coloured, nominal = _simulated_rejection(case, draws, np.random.default_rng(seed))

    def slack(q: float) -> float:
        return 3.0 * np.sqrt(q * (1 - q) / draws) + 0.03

    assert abs(coloured - predicted) <= slack(predicted), (coloured, predicted)
    assert abs(nominal - 0.05) <= slack(0.05), nominal


def test_power_is_the_level_where_the_noise_pole_is_the_plants() -> None:
    """``D = A`` (a first-order plant, the coloured pole at the plant's, no zero): ``A C_c / D``
    is 1, the innovations are a moving average, and the test finds nothing beyond its level."""
    case = _first_order(10039)
    pole = float(np.roots(bc.nominal_plant(case).discretize(case.T / case.p).a)[0].real)
    same = replace(case, effect_params={**case.effect_params, "d1": pole, "c1": 0.0})
    lam, dof = no.noncentrality(same, np.array([1.0, -pole]), np.array([1.0, 0.0]), 2.0)
    assert lam < 1e-9 and dof >= 1
    assert no.noise_shape_power(same) == pytest.approx(0.05, abs=1e-6)
    assert no.power(0.0, dof, 0.01) == 0.01


def test_paper_loop_coloured_noise_is_beyond_the_oracle() -> None:
    """The paper plant's poles (0.97-0.99) and the drawn noise poles (0.85-0.97): the residue of
    the coloured part's tail is of order 1e-4, so the power stays at the level."""
    for seed in range(10000, 10004):
        case = bc.draw_bench_case(seed, "colored-noise", "linear", "paper")
        power = no.noise_shape_power(case)
        assert power is not None and power < 0.06, (seed, power)


def test_only_coloured_cases_have_a_power() -> None:
    assert no.noise_shape_power(bc.draw_bench_case(10000, "drift", "linear", "paper")) is None


def test_summary_counts_the_rows_by_the_oracle() -> None:
    rows = [
        {"cause": "colored-noise", "noise_shape_power": 0.95},
        {"cause": "none", "noise_shape_power": 0.7},
        {"cause": "colored-noise", "noise_shape_power": 0.05},
        {"cause": "delay", "noise_shape_power": 0.05},
    ]
    text = calibrate.oracle_summary(rows)
    assert "power >= 0.5: 2 of 4 (cause right on 1)" in text
    assert "the other 2: cause right on 1" in text
    assert "expected count 1.8 of 4" in text

"""The oracle of :mod:`hbench.diagnose.noise_oracle`: its power against the test run on records
of the benchmark's own simulator, its limit where the noise's pole is the plant's, and the
benchmark rows and summary that carry it. Cases from the calibration seeds (10000-19999); the
noise of the simulated records from seeds 1000000 on (the case's parameters kept)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from scipy import signal

from hbench.diagnose import benchmark_cases as bc
from hbench.diagnose import calibrate
from hbench.diagnose import noise_oracle as no

#: Simulated records per case in the power check.
DRAWS = 300
#: What the derivation's asymptotics are off by at the benchmark's record lengths, per null: the
#: largest gap between simulated and predicted power on other cases, rounded up. ``armax``:
#: first-order 10022, 10039, 10110, 10112, 10120, 10137, 10141, 10151; NMP 10002, 10101; paper
#: 10000, 10101, 10116; third-order 10001 (1000-2000 records each: -0.070 to +0.024).
#: ``process``: NMP 10003, 10034; third-order 10000, 10008; paper 10003, 10034; first-order
#: 10004, 10015 (800 records each: -0.131 to +0.007, the prediction above the rate on the
#: third-order plant). The cases checked below are disjoint from those.
ASYMPTOTICS = {"armax": 0.07, "process": 0.14}
#: The same for the rejection rate without coloured noise: records without an effect of paper
#: 10050, NMP 10051, third-order 10052 and first-order 10053, 400 each, both nulls: rates
#: 0.028-0.050.
LEVEL = 0.03


def _innovations(case: bc.BenchCase) -> np.ndarray:
    """``w = A y - q^-(delay + 1) B u`` of the case's record from the benchmark's simulator (a
    linear valve: ``u`` is ``x`` held over each slow period)."""
    rec = bc.simulate_bench_case(case)
    dp = bc.case_plant(case).discretize(case.T / case.p)
    u = np.repeat(rec.x[0], case.p)
    return signal.lfilter(dp.den, [1.0], rec.y[0]) - signal.lfilter(dp.num, [1.0], u)


@pytest.mark.parametrize(
    ("plant", "seed"),
    [("first-order", 10122), ("first-order", 10136), ("nmp", 10145), ("paper", 10123)],
)
def test_power_is_the_rejection_rate_on_simulated_records(plant: str, seed: int) -> None:
    """The share of :data:`DRAWS` records of one case (the benchmark's simulator, fresh noise
    each) on which :func:`~hbench.diagnose.noise_oracle.shape_statistic` rejects at 5 % is the
    predicted power, under either null, within three binomial standard errors plus the null's
    :data:`ASYMPTOTICS`. The first-order cases have mid-range power under the ``armax`` null
    (0.68, 0.48: where a wrong noncentrality shows most); on the NMP and paper plants the
    nominal noise is a strong moving average (the plain Ljung-Box sum, without Bartlett's
    covariance, rejects there on about a third of the records without any coloured noise) and
    the power under the ``armax`` null is low (0.28, 0.18)."""
    case = bc.draw_bench_case(seed, "colored-noise", "linear", plant)
    n = no.fit_samples(case)
    records = [_innovations(replace(case, seed=1_000_000 + k))[:n] for k in range(DRAWS)]
    for null in no.NULLS:
        predicted = no.noise_shape_power(case, null=null)
        assert predicted is not None
        n_c = no.null_order(case, null)
        rate = np.mean([no.shape_statistic(w, n_c)[1] < 0.05 for w in records])
        slack = 3.0 * np.sqrt(predicted * (1 - predicted) / DRAWS) + ASYMPTOTICS[null]
        assert abs(rate - predicted) <= slack, (null, rate, predicted)


@pytest.mark.parametrize(("plant", "seed"), [("paper", 10060), ("nmp", 10061)])
def test_records_without_coloured_noise_are_rejected_at_the_level(plant: str, seed: int) -> None:
    """Records without an effect (the benchmark's simulator, fresh noise each): the test
    rejects at 5 % on about 5 % of them under either null (within three binomial standard
    errors plus :data:`LEVEL`), though the nominal innovations of these plants are a strong
    moving average."""
    case = bc.draw_bench_case(seed, "none", "linear", plant)
    n = no.fit_samples(case)
    records = [_innovations(replace(case, seed=1_500_000 + k))[:n] for k in range(DRAWS)]
    slack = 3.0 * np.sqrt(0.05 * 0.95 / DRAWS) + LEVEL
    for null in no.NULLS:
        n_c = no.null_order(case, null)
        rate = np.mean([no.shape_statistic(w, n_c)[1] < 0.05 for w in records])
        assert abs(rate - 0.05) <= slack, (null, rate)


def test_an_unknown_null_is_refused() -> None:
    case = bc.draw_bench_case(10000, "colored-noise", "linear", "paper")
    with pytest.raises(ValueError, match="null must be one of"):
        no.noise_shape_power(case, null="bj")


def test_bartlett_covariance_of_a_white_series_is_the_identity() -> None:
    rho = np.zeros(21)
    rho[0] = 1.0
    assert np.array_equal(no.bartlett(rho, 2, 20), np.eye(18))


def test_bartlett_covariance_of_a_moving_average() -> None:
    """``w = e + 0.5 e(t-1)``, ``rho_1 = 0.4``: beyond lag 1, ``n cov(r_k, r_(k+m)) = sum_i
    rho_i rho_(i+m)``, which is ``1 + 2 rho_1^2`` at ``m = 0``, ``2 rho_1`` at 1, ``rho_1^2`` at 2
    and 0 beyond."""
    rho = np.zeros(11)
    rho[:2] = [1.0, 0.4]
    G = no.bartlett(rho, 1, 10)
    assert G[0, 0] == pytest.approx(1 + 2 * 0.16)
    assert G[0, 1] == pytest.approx(2 * 0.4)
    assert G[0, 2] == pytest.approx(0.16)
    assert G[0, 3] == 0.0 and np.allclose(G, G.T)


def test_power_is_the_level_where_the_noise_pole_is_the_plants() -> None:
    """``D = A`` (a first-order plant, the coloured pole at the plant's, no zero): ``A C_c / D``
    is 1, the innovations are a moving average, and the test finds nothing beyond its level."""
    case = bc.draw_bench_case(10039, "colored-noise", "linear", "first-order")
    pole = float(np.roots(bc.nominal_plant(case).discretize(case.T / case.p).a)[0].real)
    same = replace(case, effect_params={**case.effect_params, "d1": pole, "c1": 0.0})
    acf = no.innovations_acf(same, np.array([1.0, 0.0]), np.array([1.0, -pole]), 2.0)
    lam, dof = no.noncentrality(*acf)
    assert lam < 1e-9 and dof >= 1
    assert no.noise_shape_power(same) == pytest.approx(0.05, abs=1e-6)
    assert no.power(0.0, dof, 0.01) == 0.01


def test_paper_loop_coloured_noise_is_near_the_level() -> None:
    """The paper plant's poles (0.97-0.99) and the drawn noise poles (0.85-0.97): the residue of
    the coloured part's tail is small, so the power stays near the level."""
    for seed in range(10000, 10004):
        case = bc.draw_bench_case(seed, "colored-noise", "linear", "paper")
        power = no.noise_shape_power(case)
        assert power is not None and power < 0.2, (seed, power)


def test_only_coloured_cases_have_a_power() -> None:
    assert no.noise_shape_power(bc.draw_bench_case(10000, "drift", "linear", "paper")) is None


def test_summary_counts_the_rows_by_the_oracle() -> None:
    rows = [
        {"cause": "colored-noise", "noise_shape_power": {"armax": 0.95, "process": 1.0}},
        {"cause": "none", "noise_shape_power": {"armax": 0.7, "process": 1.0}},
        {"cause": "colored-noise", "noise_shape_power": {"armax": 0.05, "process": 0.9}},
        {"cause": "delay", "noise_shape_power": {"armax": 0.05, "process": 0.2}},
    ]
    text = calibrate.oracle_summary(rows, "armax")
    assert "null 'armax'" in text
    assert "power >= 0.5: 2 of 4 (cause right on 1)" in text
    assert "the other 2: cause right on 1" in text
    assert "expected count 1.8 of 4" in text
    text = calibrate.oracle_summary(rows, "process")
    assert "power >= 0.5: 3 of 4 (cause right on 2)" in text
    assert "expected count 3.1 of 4" in text

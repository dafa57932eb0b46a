"""The drift detector (:class:`hbench.diagnose.effects.Drift`) and its ramp test under the
nominal noise model (:func:`hbench.diagnose.stats.noise_model_trend`)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import signal
from scipy import stats as sps

from hbench.diagnose import core, effects, generator, nominal, stats

#: A noise model as slow as the paper's loop: poles 0.97 and 0.99 at the fast rate.
A_SLOW = np.poly([0.97, 0.99])


def test_the_ramp_is_recovered_exactly_without_noise() -> None:
    """Noise free: ``r = c0 + c1 n`` gives ``|c1| span / scale`` to rounding (1e-9 relative),
    whatever ``A`` whitens, and an infinite t (p = 0)."""
    N = 800
    n = np.arange(N)
    r = 0.3 - 2e-3 * n
    for a in (A_SLOW, np.array([1.0, -0.5]), np.array([1.0])):
        ramp, t, p = stats.noise_model_trend(r, a, scale=4.0)
        assert ramp == pytest.approx(2e-3 * N / 4.0, rel=1e-9)
        assert abs(t) > 1e6 and p < 1e-12
    ramp, _, _ = stats.noise_model_trend(r, A_SLOW, scale=4.0, span=3 * N)
    assert ramp == pytest.approx(3 * 2e-3 * N / 4.0, rel=1e-9)


def test_the_slope_t_statistic_follows_its_t_distribution_under_the_noise_model() -> None:
    """Under ``v = e / A`` without a ramp, the t statistic is ``t(N - na - 2)`` (exact for
    Gaussian ``e`` and the known ``A``): over 8000 records the rejection rates at 1 % and 5 %
    stay within 4 binomial standard deviations of the level, and a Kolmogorov-Smirnov test
    against ``t(N - na - 2)`` does not reject at 1 % (fixed seed: a deterministic outcome). An
    ordinary t-test on the same coloured noise (``A = 1``) rejects on most records: the
    prewhitening is what holds the level."""
    rng = np.random.default_rng(11)
    m, N = 8000, 600
    V = signal.lfilter([1.0], A_SLOW, rng.standard_normal((m, N)), axis=-1) + 5.0
    ramp, t, p = stats.noise_model_trend(V, A_SLOW)
    assert ramp.shape == t.shape == p.shape == (m,)
    for level in (0.01, 0.05):
        sd = np.sqrt(level * (1 - level) / m)
        assert abs(float(np.mean(p < level)) - level) < 4 * sd
    assert sps.kstest(t, sps.t(N - 2 - 2).cdf).pvalue > 0.01
    _, _, p_naive = stats.noise_model_trend(V, [1.0])
    assert np.mean(p_naive < 0.01) > 0.5


def test_rows_are_tested_one_by_one() -> None:
    # exact: a 2-D residual gives row by row what each row gives alone
    rng = np.random.default_rng(2)
    V = signal.lfilter([1.0], A_SLOW, rng.standard_normal((3, 400)), axis=-1)
    many = stats.noise_model_trend(V, A_SLOW, scale=2.0)
    for i in range(3):
        one = stats.noise_model_trend(V[i], A_SLOW, scale=2.0)
        for k in range(3):
            assert one[k] == pytest.approx(float(many[k][i]), rel=1e-12)


# --------------------------------------------------------------------------- the paper plant


def _paper_drift(seed: int, share: float, sigma2: float = 1e-4) -> effects.Detection:
    """The drift detection on the paper's Section 6 loop (``hbench simulate`` defaults, noise
    level ``sigma2``) with a drift of ``share`` of the output's range (the range of the same
    run without it) added inside the loop: :func:`hbench.diagnose.generator.additive_effect`'s
    ramp plus a random walk of 5 % of the ramp."""
    from hbench.sim import scenarios
    from hbench.sim.simulate import simulate

    spec = {
        **scenarios.PAPER_SECTION6,
        "noise": {**scenarios.PAPER_SECTION6["noise"], "sigma2": sigma2},
    }
    sc = scenarios.build(spec)
    plain, _ = simulate(sc, 1, np.random.default_rng(seed))
    N = plain.y.shape[-1]
    D = share * float(np.ptp(plain.y))
    add = generator.additive_effect(
        "drift", {"D": D, "walk": 0.05}, N, np.random.default_rng(seed + 1)
    )
    c, d = sc.noise.filter(sc.discrete_plant)
    # the scenario scales the unit disturbance by sqrt(sigma2): the drift is given in y's units
    sc.noise = generator.InjectedNoise(1.0, c, d, add / np.sqrt(sigma2))
    rec, _ = simulate(sc, 1, np.random.default_rng(seed))
    with core.transient(True), np.errstate(all="ignore"):
        ctx = nominal.make_context(rec)
        return effects.Drift().detect(ctx, nominal.fit_nominal(ctx))


def test_a_drift_of_five_percent_on_the_paper_plant_is_found_by_the_ramp_test() -> None:
    """A drift of 5 % of the output's range on the paper loop at sigma^2 = 1e-4 (seed 103):
    the ramp test finds it (about 6 % of the range, p < 1e-3) where the low-frequency ratio
    stays below its per-record threshold (20.2 against 21.1). On seeds 100-107 the detector
    finds 4 of 8 such records (at sigma^2 = 1e-3, 1 of 6): the paper plant's own noise wanders
    over a record, so this is one record found, not a power; without a drift the detector is
    quiet on all 8. Deterministic: an exact verdict, and the verdict agrees with the reported
    test's statistic and p-value."""
    det = _paper_drift(103, 0.05)
    assert det.fired
    assert det.info["test"] == "ramp"
    assert det.info["lf_ratio"] < det.info["lf_threshold"]  # the old test alone stays quiet
    assert det.statistic == pytest.approx(det.info["ramp"] / effects.Drift.RAMP_LEVEL)
    assert det.p_value == det.info["ramp_p"] < effects.ALPHA
    assert det.threshold == effects.Drift.threshold == 1.0
    assert "passing (above the level with p < 0.01): ramp;" in det.evidence
    assert "reported: the ramp test" in det.evidence
    # the same record without the drift: quiet
    assert not _paper_drift(103, 0.0).fired


@pytest.mark.xfail(
    strict=True,
    reason=(
        "a drift of 2 % of the output range is inside the paper plant's own noise wander over a "
        "record: the ramp test's standard error is about that size (docs/experiments/"
        "diagnose-benchmark-loops.md, section 5)"
    ),
)
def test_a_drift_of_two_percent_on_the_paper_plant_is_found_reliably() -> None:
    """Found on at least 7 of the 8 paper-loop records of seeds 100-107 at sigma^2 = 1e-4 (as
    measured: 1 of 8, the fitted ramps 0.04 % to 5 % of the range)."""
    found = [_paper_drift(seed, 0.02).fired for seed in range(100, 108)]
    assert sum(found) >= 7, found


def test_the_drift_extension_fits_two_poles_where_the_walk_leaves_the_nominal_one() -> None:
    """A drift record of the paper loop (benchmark calibration seed 17502: stiction, p = 5,
    sigma^2 = 1.1e-4, a drift of D = 1.00 over the record, the 5 % random walk with it): the
    blind route's order selection keeps one pole on it, and that model with a ramp gains
    nothing (-6.5 points of validation fit as measured); the drift extension also fits the
    nominal family's two poles and takes them by the fit part's BIC: the plant's slow poles
    (0.991 and 0.967 as measured against 0.99 and 0.97), a ramp of 0.97 against the drawn
    1.00, and a gain of 96 points. Deterministic: bounds well inside the measured values."""
    from hbench.diagnose import benchmark_cases as bc
    from hbench.diagnose.validate import val_fit

    case = bc.draw_bench_case(17502, "drift", None, "paper")
    assert case.cls == "stiction" and case.p == 5
    rec = bc.simulate_bench_case(case)
    with core.transient(True), np.errstate(all="ignore"):
        ctx = nominal.make_context(rec)
        nom = nominal.fit_nominal(ctx)
        det = effects.Drift().detect(ctx, nom)
        ext = effects.Drift().extend(ctx, nom, det)
        base = val_fit(ctx, nom.model)
        gain = val_fit(ctx, ext) - base
    assert nom.model.lin.na == 1
    assert ext.lin.na == nominal.NA_NOMINAL[1] == 2
    poles = np.sort(np.abs(np.roots(ext.lin.a)))
    assert 0.98 < poles[1] < 1.0 and 0.95 < poles[0] < 0.98, poles
    D = case.effect_params["D"]
    assert 0.8 * D < float(ext.trend[0]) < 1.2 * D
    assert gain > 50.0, gain

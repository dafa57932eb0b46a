"""Methods beyond the paper: claims tested with fixed seeds and stated standard errors."""

from __future__ import annotations

import numpy as np
import pytest
from hbench_extensions import noise_bias

from tests.helpers import TRUE_STRUCTURE, run_method, sim


def test_noise_bias_reduces_to_the_papers_compensation():
    """White ARX noise: gamma_0 = 2 sigma^2, gamma_1 = -sigma^2 -> c = [sigma^2, 0] (eq. 14)."""
    theta = np.array([[-1.962, 0.9623]])
    sigma2 = 0.37
    c = noise_bias(theta, np.array([[2 * sigma2, -sigma2, 0.0]]))
    np.testing.assert_allclose(c, [[sigma2, 0.0]], rtol=1e-14)


def test_noise_bias_uses_the_impulse_response_of_one_over_a():
    """gamma_2 != 0: c_1 = -(h0 gamma_1 + h1 gamma_2) with h1 = -a1, c_2 = -gamma_2 (by hand)."""
    theta = np.array([[-0.5, 0.1]])
    c = noise_bias(theta, np.array([[1.0, 0.2, 0.3]]))
    np.testing.assert_allclose(c, [[-(0.2 + 0.5 * 0.3), -0.3]], rtol=1e-14)


@pytest.fixture(scope="module")
def high_noise_a1():
    """a1 of ``wang-lsm-cn``, ``wang-lsm`` and ``wang-iv`` (phase p, pooled) on the paper's
    example at sigma^2 = 1e-2 (its ZOH coloured noise), 100 runs, seed 8; and the true a1."""
    record, truth = sim(runs=100, seed=8, noise__sigma2=1e-2)

    def a1_of(method, **kw):
        return run_method(method, record, options=TRUE_STRUCTURE, **kw).params()["a1"]

    return {
        "true": truth.plant.a[1],
        "ours": a1_of("wang-lsm-cn"),
        "lsm": a1_of("wang-lsm"),
        "iv_phase_p": a1_of("wang-iv", pooled=False),
        "iv_pooled": a1_of("wang-iv"),
    }


def test_coloured_noise_lsm_against_the_ivm_at_high_noise(high_noise_a1):
    """Claim 2 of the coloured-noise LSM, the part that holds at sigma^2 = 1e-2: |bias of a1|
    below the IVM's std (with 3 SE of our mean added), the paper's LSM clearly biased, and our
    std below that of the IVM on phase p alone (the paper's eq. 20 at l = p; std ratio <= 0.75,
    i.e. 3 SE of a ratio of stds from 100 runs clear of 1)."""
    v = high_noise_a1
    ours, lsm, a1 = v["ours"], v["lsm"], v["true"]
    sd = np.std(ours, ddof=1)
    assert abs(ours.mean() - a1) + 3 * sd / 10 < np.std(v["iv_pooled"], ddof=1)
    assert abs(lsm.mean() - a1) > 3 * np.std(lsm, ddof=1) / 10
    assert sd <= 0.75 * np.std(v["iv_phase_p"], ddof=1)


@pytest.mark.xfail(
    strict=True,
    reason="not met yet: against hbench's default IVM, which re-estimates A from all quiet "
    "phases (step iii), wang-lsm-cn's std of a1 is ~1.3x the IVM's (0.042 vs 0.032, seed 8); "
    "wang-iv-opt meets the claim (next tests)",
)
def test_coloured_noise_lsm_std_below_the_pooled_ivm(high_noise_a1):
    """Claim 2's open part: our std of a1 below that of hbench's default (pooled) IVM."""
    v = high_noise_a1
    assert np.std(v["ours"], ddof=1) < np.std(v["iv_pooled"], ddof=1)


def test_optimal_iv_exact_on_noise_free_data():
    """Noise-free: the GMM IV recovers the parameters to rounding (1e-8), every weighting."""
    record, truth = sim(runs=2, seed=11, noise__sigma2=0.0)
    for weighting in ("optimal", "2sls", "identity"):
        est = run_method("wang-iv-opt", record, weighting=weighting)
        assert np.all(est.na == 2) and np.all(est.nb == 2) and np.all(est.tau == 3)
        for key, true in truth.plant.true_params().items():
            np.testing.assert_allclose(est.params()[key], true, rtol=0, atol=1e-8, err_msg=key)


def test_optimal_iv_beats_the_ivm_at_high_noise():
    """Claim 2, met by the optimally weighted IV (``wang-iv-opt``), sigma^2 = 1e-2.

    Same 100 records (seed 8) for both, structure given (as the paper's Table 4):
    (i) |bias of a1| + 3 SE of its mean < the IVM's std; (ii) std(a1) below the IVM's, tested by a
    paired bootstrap over runs (2000 resamples, fixed seed): the 99.5 % quantile of the std ratio
    must stay below 1 (measured: ratio ~0.6).
    """
    record, truth = sim(runs=100, seed=8, noise__sigma2=1e-2)
    a1 = truth.plant.a[1]
    ours = run_method("wang-iv-opt", record, options=TRUE_STRUCTURE).params()["a1"]
    ivm = run_method("wang-iv", record, options=TRUE_STRUCTURE).params()["a1"]
    sd, sd_iv = np.std(ours, ddof=1), np.std(ivm, ddof=1)
    assert abs(ours.mean() - a1) + 3 * sd / 10 < sd_iv
    rng = np.random.default_rng(0)
    idx = rng.integers(0, ours.size, size=(2000, ours.size))
    ratio = np.std(ours[idx], axis=1, ddof=1) / np.std(ivm[idx], axis=1, ddof=1)
    assert np.quantile(ratio, 0.995) < 1.0, (sd, sd_iv)


@pytest.mark.parametrize("numerator", ["compensated", "iv"])
def test_optimal_iv_numerator_is_consistent(numerator):
    """b2 at sigma^2 = 1e-2 under the coloured noise (seed 8, 100 runs, structure given): the
    mean within 3 SE of the truth for both numerators."""
    record, truth = sim(runs=100, seed=8, noise__sigma2=1e-2)
    b2 = truth.plant.b_normalised[1]
    est = run_method("wang-iv-opt", record, options=TRUE_STRUCTURE, numerator=numerator)
    v = est.params()["b2"]
    assert abs(v.mean() - b2) <= 3 * np.std(v, ddof=1) / 10, (v.mean(), b2)


def test_optimal_iv_reduces_to_the_papers_ivm():
    """``weighting="identity", lag0=1, m=6`` is eq. (20) as ``wang-iv`` computes it (to 1e-12)."""
    record, _ = sim(runs=3, seed=2, noise__sigma2=1e-3)
    ours = run_method(
        "wang-iv-opt", record, options=TRUE_STRUCTURE, weighting="identity", lag0=1, m=6
    )
    ivm = run_method("wang-iv", record, options=TRUE_STRUCTURE)
    np.testing.assert_allclose(ours.a, ivm.a, rtol=0, atol=1e-12)


def test_optimal_iv_rejects_bad_options():
    from hbench.errors import InputError
    from hbench.plugins import registry

    cls = registry().get("identifiers", "wang-iv-opt")
    for kw in ({"m": 0}, {"lag0": -1}, {"weighting": "best"}, {"numerator": "x"}):
        with pytest.raises(InputError):
            cls(**kw)


def test_coloured_noise_lsm_consistent_under_white_arx_noise():
    """Where the paper's assumptions hold it stays unbiased: means within 3 SE of the truth."""
    record, truth = sim(runs=100, seed=9, noise__name="arx", noise__gain=0.01, noise__sigma2=1e-3)
    est = run_method("wang-lsm-cn", record, options=TRUE_STRUCTURE)
    for key, true in truth.plant.true_params().items():
        v = est.params()[key]
        assert abs(v.mean() - true) <= 3 * np.std(v, ddof=1) / 10, key


def _paired_fitness(sigma2: float, runs: int = 50, seed: int = 31):
    from hbench.bench.metrics import fitness

    record, truth = sim(runs=runs, seed=seed, noise__sigma2=sigma2)
    out = {}
    for m in ("wang-lsm", "joint-refine", "oracle"):
        est = run_method(m, record, truth, options=TRUE_STRUCTURE)
        out[m] = fitness(est.U, truth.U, gain=truth.plant.gain)
    return out


@pytest.mark.parametrize("sigma2", [5e-3, 1e-2])
def test_joint_refinement_closes_half_the_gap(sigma2):
    """Claim 3: F_joint - F_LSM >= (F0 - F_LSM) / 2 at sigma^2 >= 5e-3 (paper's example).

    Paired per run (the same records for all methods), 50 runs, fixed seed: the mean of
    d = (F_joint - F_LSM) - (F0 - F_LSM) / 2 must exceed 3 standard errors of d above zero.
    """
    F = _paired_fitness(sigma2)
    d = (F["joint-refine"] - F["wang-lsm"]) - 0.5 * (F["oracle"] - F["wang-lsm"])
    assert d.mean() - 3 * d.std(ddof=1) / np.sqrt(d.size) > 0, (d.mean(), d.std())


def test_joint_refinement_loses_no_ground_at_low_noise():
    """At sigma^2 = 1e-4, F_joint >= F_LSM (paired, mean difference not below -3 SE)."""
    F = _paired_fitness(1e-4)
    d = F["joint-refine"] - F["wang-lsm"]
    assert d.mean() + 3 * d.std(ddof=1) / np.sqrt(d.size) >= 0, (d.mean(), d.std())


@pytest.mark.parametrize("nonlinearity", ["backlash", "stiction"])
def test_delay_beyond_a3_is_estimated(nonlinearity):
    """Claim 1: delays 0 .. 3p - 1 (p = 5), the multiple of p unknown to the method.

    10 runs per delay at SNR 5, fixed seeds: the total delay tau + m p is right in >= 90 % of the
    150 runs (measured 99-100 %; the misses are structure-selection errors of tau, not of m).
    """
    from hbench.ident.identifiers import IdentifyOptions

    hits = []
    for d in range(15):
        record, _ = sim(
            runs=10, seed=100 + d, noise__snr=5.0, plant__delay=d, nonlinearity__name=nonlinearity
        )
        est = run_method("wang-delay", record, options=IdentifyOptions())
        hits.extend(est.tau + 5 * est.delay_multiple == d)
    assert np.mean(hits) >= 0.9, np.mean(hits)


def test_delay_estimate_realigns_the_inner_signal():
    """Noise-free, delay 3 + 2 p: the re-aligned U fits the truth as if A3 had been given."""
    from hbench.bench.metrics import fitness
    from hbench.ident.identifiers import IdentifyOptions

    record, truth = sim(runs=2, seed=5, noise__sigma2=0.0, plant__delay=13)
    est = run_method("wang-delay", record, options=IdentifyOptions())
    np.testing.assert_array_equal(est.delay_multiple, 2)
    assert np.all(fitness(est.U, truth.U, gain=truth.plant.gain) > 99.99)


def test_a_diverging_noise_compensation_fails_the_run_without_warnings():
    """A paper-loop record (benchmark seed 15013, p = 8, an extra lag) fitted with three
    poles: ``wang-lsm-cn``'s fixed-point iteration leaves the floating-point range. The run
    fails (infinite parameters, no ``U``: ``run_status``), ``info["diverged_runs"]`` counts it,
    ``joint-refine`` started from it does not refine it, and no numpy warning is raised
    (any warning fails the test). The same fit with four poles does not overflow within the
    iterations (it is still moving when they run out, which ``info["unconverged_runs"]``
    counts)."""
    import warnings

    from hbench.diagnose import benchmark_cases as bc
    from hbench.diagnose import nominal as nm
    from hbench.ident.identifiers import IdentifyOptions, identify, run_status
    from hbench.plugins import registry

    case = bc.bench_grid(15000, 1, ("paper",))[13]
    assert case.seed == 15013
    ctx = nm.make_context(bc.simulate_bench_case(case))
    part = ctx.part(0, ctx.k_fit)

    def fit(method: str, na: int):
        opts = IdentifyOptions(nb_max=min(3, ctx.p - 1), na_range=(1, na), na=na)
        return identify(registry().get("identifiers", method)(), part, opts)

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        for method in ("wang-lsm-cn", "joint-refine"):
            est = fit(method, 3)
            assert run_status(est)[0][0] == "failed", method
            assert np.isinf(est.a[0, :3]).all() and np.isnan(est.U[0]).all()
            assert est.info["diverged_runs"] == 1
            assert "non-finite" in run_status(est)[1][0]
        assert np.isnan(fit("wang-lsm-cn", 3).sigma2[0])
        ok = fit("wang-lsm-cn", 4)
    assert run_status(ok)[0][0] == "ok" and ok.info["diverged_runs"] == 0
    assert ok.info["unconverged_runs"] == 1
    assert np.isfinite(ok.a[0, :4]).all()

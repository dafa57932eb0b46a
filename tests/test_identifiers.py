"""The blind identifiers: exactness on noise-free data, consistency, assumptions A2 and A4.

Tolerances: noise-free checks use 1e-8 on parameters (the estimators are exact algebra on
data; what remains is rounding in sums over ~800 periods, observed ~1e-12) and fitness > 99.99 %.
Monte Carlo checks use a fixed seed and 3 standard errors (SE = sample std / sqrt(runs)): with
every such check at 3 SE the chance that a correct estimator fails one is about 0.3 % each.
"""

from __future__ import annotations

import numpy as np
import pytest

from hbench.bench.metrics import fitness
from hbench.ident.identifiers import IdentifyOptions, check_a4
from hbench.plugins import registry
from tests.helpers import TRUE_STRUCTURE, run_method, sim

BLIND = ["wang-lsm", "wang-iv", "wang", "bai-fu", "sun-liu-sano"]
ALL = [*BLIND, "oracle", "oracle-inv"]
NONLINEARITIES = {
    "backlash": {"d": 0.1},
    "deadband": {"d1": 0.05, "d2": 0.05},
    "saturation": {"u_min": -0.2, "u_max": 0.2},
    "stiction": {"S": 0.1, "J": 0.02},
}


@pytest.fixture(scope="module", params=list(NONLINEARITIES))
def noise_free(request):
    kw = {f"nonlinearity__{k}": v for k, v in NONLINEARITIES[request.param].items()}
    return sim(runs=2, seed=11, noise__sigma2=0.0, nonlinearity__name=request.param, **kw)


@pytest.mark.parametrize("method", ALL)
def test_noise_free_exact(noise_free, method):
    record, truth = noise_free
    est = run_method(method, record, truth)  # structure selected automatically
    assert np.all(est.identifiable)
    assert np.all(est.na == 2) and np.all(est.nb == 2) and np.all(est.tau == 3)
    params = est.params()
    for key, true in truth.plant.true_params().items():
        np.testing.assert_allclose(params[key], true, rtol=0, atol=1e-8, err_msg=key)
    F = fitness(est.U, truth.U, scaling="gain", gain=truth.plant.gain)
    assert np.all(F > 99.99), F
    # the estimate covers the record but for the first periods that need past samples, and, for
    # the direct inverse, those its 1/B transient spans (decay to 1e-3: |zero| 0.724 -> 22 fast
    # samples, 5 periods)
    edge = 3 + (5 if est.info["inverse"].get("direct") else 0)
    assert np.isfinite(est.U).sum(axis=1).min() >= record.n_slow - edge


def test_noise_free_sigma2_estimate_is_zero(noise_free):
    record, truth = noise_free
    est = run_method("wang-lsm", record, truth)
    np.testing.assert_allclose(est.sigma2, 0.0, atol=1e-20)


@pytest.mark.parametrize("method", ["wang-lsm", "wang-iv"])
def test_pooled_denominator_exact(method):
    record, truth = sim(runs=2, seed=3, noise__sigma2=0.0)
    est = run_method(method, record, truth, pooled=True)
    np.testing.assert_allclose(est.a[:, :2], np.broadcast_to(truth.plant.a[1:], (2, 2)), atol=1e-8)


#: ARX noise g e / A(q) with g = 0.01: sigma^2 then spans the paper's equation-noise levels (its
#: ZOH noise filter has c1^2 + c2^2 ~ 1.04e-4). With g = 1 the paper's plant (poles 0.97, 0.99)
#: turns sigma^2 = 1e-3 into SNR ~ 0.9 and a B-equation signal-to-noise ratio ~ 0.005, where no
#: method estimates b2 from 833 periods (measured: LSM b2 = -3.5 +- 32 over 100 runs).
ARX_GAIN = 0.01


@pytest.mark.parametrize("sigma2", [1e-4, 1e-3, 1e-2])
@pytest.mark.parametrize("method", ["wang-lsm", "wang-iv"])
def test_consistent_under_arx_noise(method, sigma2):
    """White equation noise g e/A(q): the paper's consistency theorem (5.2) for LSM and IVM.

    100 runs, fixed seed; each parameter's mean within 3 SE of the truth.
    """
    record, truth = sim(
        runs=100, seed=2024, noise__name="arx", noise__gain=ARX_GAIN, noise__sigma2=sigma2
    )
    est = run_method(method, record, options=TRUE_STRUCTURE)
    for key, true in truth.plant.true_params().items():
        vals = est.params()[key]
        se = np.std(vals, ddof=1) / np.sqrt(vals.size)
        assert abs(np.mean(vals) - true) <= 3 * se, (key, np.mean(vals), true, se)


def test_ordinary_ls_is_biased_under_noise():
    """The compensation matters: OLS (bai-fu's A) is biased where the LSM is not (same data)."""
    record, truth = sim(
        runs=100, seed=2024, noise__name="arx", noise__gain=ARX_GAIN, noise__sigma2=1e-2
    )
    a1 = truth.plant.a[1]
    ols = run_method("bai-fu", record, options=TRUE_STRUCTURE).params()["a1"]
    lsm = run_method("wang-lsm", record, options=TRUE_STRUCTURE).params()["a1"]
    se_ols = np.std(ols, ddof=1) / 10
    assert abs(ols.mean() - a1) > 5 * se_ols
    assert abs(lsm.mean() - a1) < abs(ols.mean() - a1)


@pytest.mark.parametrize("method", ["wang-lsm", "wang-iv"])
def test_selection_picks_true_structure(method):
    """Section 6 steps (i)-(iii), automatic: na = 2, tau = 3, nb = 2 in >= 95 of 100 runs."""
    record, _ = sim(runs=100, seed=99, noise__name="arx", noise__gain=ARX_GAIN, noise__sigma2=1e-3)
    est = run_method(method, record)
    hits = np.sum((est.na == 2) & (est.tau == 3) & (est.nb == 2))
    assert hits >= 95, (hits, np.unique(est.na), np.unique(est.tau), np.unique(est.nb))
    assert est.criteria["V"].shape == (100, 5, 5)
    assert est.criteria["var_dw"].shape == (100, 5)


def test_selection_tables_show_quiet_phases():
    """Table 2's shape: three equal small Var{Delta w^(l)} at l = 3, 4, 5, two large ones."""
    record, _ = sim(runs=1, seed=5, noise__sigma2=1e-3)
    var = run_method("wang-lsm", record).criteria["var_dw"][0]
    quiet, active = var[2:], var[:2]
    assert quiet.max() / quiet.min() < 1.2
    assert active.min() > 10 * quiet.max()


@pytest.mark.parametrize("method", BLIND)
def test_a2_not_identifiable_is_flagged(method):
    """p < n0_b + 1 (assumption A2): flagged with the reason, never an exception."""
    record, truth = sim(runs=2, seed=1, noise__sigma2=0.0, p=3)
    est = run_method(method, record, truth, options=IdentifyOptions(nb_max=4))
    assert not est.identifiable.any()
    assert all("A2" in r for r in est.reason)
    assert np.isnan(est.U).all()


@pytest.mark.parametrize("method", ["wang-lsm", "wang-iv", "bai-fu"])
def test_a4_zero_at_one_is_flagged(method):
    """B(1) = 0 (assumption A4): the inner signal is not unique; flagged, no exception."""
    record, truth = sim(
        runs=2,
        seed=1,
        noise__sigma2=0.0,
        plant__name="discrete",
        plant__a=[1.0, -1.5, 0.7],
        plant__b=[1.0, -1.0],
        plant__delay=1,
    )
    est = run_method(method, record, truth, options=IdentifyOptions(na=2, nb=2, tau=1))
    assert check_a4(est.b).all()
    assert not est.identifiable.any()
    assert all("A4" in r for r in est.reason)


def test_bai_fu_on_nonminimum_phase_plant():
    """A zero outside the unit circle: the direct inverse diverges; 'auto' switches to the Bezout
    combiner (exact noise-free); 'refuse' says why it gives no inner signal."""
    record, truth = sim(
        runs=1,
        seed=4,
        noise__sigma2=0.0,
        plant__name="nmp",
        plant__delay=1,
        reference__band=[0.0, 1.0],
    )
    assert not truth.plant.is_minimum_phase
    opts = IdentifyOptions(na=2, nb=2, tau=truth.plant.tau(5))
    auto = run_method("bai-fu", record, truth, options=opts)
    assert auto.info["inverse"] == {"bezout": 1}
    assert fitness(auto.U, truth.U, gain=truth.plant.gain)[0] > 99.99
    direct = run_method("bai-fu", record, truth, options=opts, inverse="direct")
    F = fitness(direct.U, truth.U, gain=truth.plant.gain)[0]
    assert not F > 50.0  # the unstable inverse blows up (nan or a useless fit)
    refused = run_method("bai-fu", record, truth, options=opts, inverse="refuse")
    assert np.isnan(refused.U).all()
    assert "not minimum phase" in refused.reason[0]


def test_wang_is_phase_blind_on_nonminimum_phase_plant():
    """Eq. (27) has no minimum-phase requirement (Section 4)."""
    record, truth = sim(runs=1, seed=4, noise__sigma2=0.0, plant__name="nmp", plant__delay=1)
    est = run_method("wang-lsm", record, truth)  # structure selected blind
    assert fitness(est.U, truth.U, gain=truth.plant.gain)[0] > 99.99


def test_delay_beyond_p_aligned_by_a3():
    """Delay 3 + 5 = 8 fast samples: tau = 3 is estimated, the multiple m = 1 is known (A3) and
    aligns U with x."""
    record, truth = sim(runs=1, seed=8, noise__sigma2=0.0, plant__delay=8)
    est = run_method("wang-lsm", record, truth, options=IdentifyOptions(delay_multiple=1))
    assert est.tau[0] == 3
    assert fitness(est.U, truth.U, gain=truth.plant.gain)[0] > 99.99
    wrong = run_method("wang-lsm", record, truth, options=IdentifyOptions(delay_multiple=0))
    assert fitness(wrong.U, truth.U, gain=truth.plant.gain)[0] < 90


def test_sun_liu_sano_is_labelled_a_reconstruction():
    cls = registry().get("identifiers", "sun-liu-sano")
    assert cls.reconstruction
    assert "RECONSTRUCTION" in __import__(cls.__module__).__doc__


@pytest.mark.parametrize("delay", [0, 2, 7])
def test_selection_at_the_edge_of_a2(delay):
    """p = nb + 1 = 3 (one quiet phase per period, n0_b = 2): noise-free selection is exact, and
    at SNR 20 the true structure is chosen in >= 17 of 20 runs (measured 18-20)."""
    options = IdentifyOptions(nb_max=2, delay_multiple=delay // 3)
    record, truth = sim(runs=2, seed=3, noise__sigma2=0.0, p=3, plant__delay=delay)
    est = run_method("wang-lsm", record, truth, options=options)
    assert np.all(est.na == 2) and np.all(est.nb == 2) and np.all(est.tau == delay % 3)
    record, _ = sim(runs=20, seed=3, noise__snr=20.0, p=3, plant__delay=delay)
    est = run_method("wang-lsm", record, options=options)
    assert np.sum((est.na == 2) & (est.nb == 2) & (est.tau == delay % 3)) >= 17


@pytest.mark.parametrize("method", ["wang-lsm", "wang-iv", "wang"])
def test_wang_inverse_option_puts_its_estimates_in_the_direct_inverse(method):
    """A Wang method with ``inverse`` set: the same A and B as with eq. (27), the inner signal
    from the direct inverse (Table 5's F_INV); noise-free, the true inner signal exactly."""
    record, truth = sim(runs=2, seed=5, noise__sigma2=1e-3)
    opts = TRUE_STRUCTURE
    ls27 = run_method(method, record, truth, options=opts)
    inv = run_method(method, record, truth, options=opts, inverse="auto")
    for key, value in ls27.params().items():
        np.testing.assert_array_equal(inv.params()[key], value, err_msg=key)
    assert inv.info["inverse"] == {"direct": 2} and ls27.info["inverse"] == {"ls27": 2}
    assert not np.allclose(inv.U, ls27.U, equal_nan=True)
    assert "inverse" not in registry().get("identifiers", method)().options()
    record, truth = sim(runs=2, seed=5, noise__sigma2=0.0)
    exact = run_method(method, record, truth, options=opts, inverse="auto")
    U = exact.U / truth.plant.gain
    m = np.isfinite(U)
    assert m.sum(axis=1).min() > 0.9 * U.shape[1]
    np.testing.assert_allclose(U[m], truth.U[m], rtol=0, atol=1e-8 * np.abs(truth.U).max())


@pytest.mark.parametrize("method", ["wang-lsm", "wang-iv", "wang"])
def test_wang_inverse_option_is_checked(method):
    from hbench.errors import InputError

    with pytest.raises(InputError, match=f"{method} inverse must be one of"):
        registry().get("identifiers", method)(inverse="sideways")

"""``wang``: the paper's Section 6 steps (ii) and (iv), the per-run choices between the LSM and
the IVM (A by the integrated AIC, each b_l by V_EIV), checked against quantities recomputed here
from the record and the two single-estimator variants.

Exactness on noise-free data and consistency under white ARX noise are in
``tests/test_identifiers.py`` (``wang`` is one of its blind methods).
"""

from __future__ import annotations

import numpy as np
import pytest

from hbench.errors import InputError
from hbench.ident import polyphase as pp
from tests.helpers import TRUE_STRUCTURE, run_method, sim

P, TAU, NB = 5, 3, 2


@pytest.fixture(scope="module")
def noisy():
    """The paper's example at sigma^2 = 5e-3, where the two estimators differ most."""
    return sim(runs=40, seed=7, noise__sigma2=5e-3)


@pytest.fixture(scope="module")
def estimates(noisy):
    record, _ = noisy
    run = {
        (sa, sb): run_method("wang", record, options=TRUE_STRUCTURE, select_a=sa, select_b=sb)
        for sa, sb in [("aic", "v-eiv"), ("lsm", "lsm"), ("iv", "lsm"), ("aic", "lsm")]
    }
    run["wang-lsm"] = run_method("wang-lsm", record, options=TRUE_STRUCTURE)
    return run


def _quiet_mean_square(y: np.ndarray, a: np.ndarray) -> np.ndarray:
    """Mean of Delta w^2 over the quiet phases nb+1..p: eq. (13)'s residual, summed over the
    phases the pooled estimate is fitted on (the integrated AIC up to a common factor)."""
    den = np.concatenate([np.ones((a.shape[0], 1)), a], axis=1)
    dw = pp.delta(pp.filtered_output(y, den))
    return pp.phase_variances(dw, P, TAU, t_min=10)[:, NB:].mean(axis=1)


def test_lsm_throughout_is_wang_lsm(estimates):
    """select_a = select_b = "lsm" gives wang-lsm's numbers bit for bit."""
    lsm, ref = estimates[("lsm", "lsm")], estimates["wang-lsm"]
    assert np.array_equal(lsm.a, ref.a) and np.array_equal(lsm.b, ref.b)
    assert np.array_equal(lsm.U, ref.U, equal_nan=True)
    assert not lsm.criteria["a_from_iv"].any() and not lsm.criteria["b_from_iv"].any()


def test_step_ii_keeps_the_denominator_with_the_smaller_integrated_aic(noisy, estimates):
    record, _ = noisy
    chosen = estimates[("aic", "lsm")]
    a_lsm, a_iv = estimates[("lsm", "lsm")].a, estimates[("iv", "lsm")].a
    from_iv = chosen.criteria["a_from_iv"]
    assert 0 < from_iv.sum() < record.runs  # both estimators are chosen in some runs
    np.testing.assert_array_equal(chosen.a, np.where(from_iv[:, None], a_iv, a_lsm))
    # recomputed from Delta w = Delta A(q) y on the quiet phases (other rows at the record's
    # start): the same choice wherever the two criteria differ by more than 1 %
    v_lsm, v_iv = _quiet_mean_square(record.y, a_lsm), _quiet_mean_square(record.y, a_iv)
    clear = np.abs(v_iv - v_lsm) > 0.01 * v_lsm
    assert clear.sum() >= record.runs // 2
    np.testing.assert_array_equal(from_iv[clear], (v_iv < v_lsm)[clear])
    aic = chosen.criteria["aic"]
    np.testing.assert_array_equal(from_iv, aic[:, 1] < aic[:, 0])


def test_step_iv_keeps_each_b_with_the_smaller_v_eiv(noisy, estimates):
    record, _ = noisy
    est = estimates[("aic", "v-eiv")]
    den = np.concatenate([np.ones((record.runs, 1)), est.a], axis=1)
    dw = pp.delta(pp.filtered_output(record.y, den))
    # the two b2 candidates on this A, and V_EIV written out from its definition
    b2 = {
        "lsm": pp.b_lsm(dw, P, TAU, NB, est.sigma2, t_min=pp.first_valid(dw))[:, 1],
        "iv": pp.b_iv(dw, record.r, P, TAU, NB, 6, pp.first_valid(dw))[:, 1],
    }
    k = pp.common_periods(dw, P, TAU, pp.first_valid(dw), NB)
    d1, d2 = dw[:, k * P + TAU + 1], dw[:, k * P + TAU + 2]
    v = {name: np.mean((d2 - b[:, None] * d1) ** 2, axis=1) / (b**2 + 1) for name, b in b2.items()}
    from_iv = est.criteria["b_from_iv"][:, 1]
    assert 0 < from_iv.sum() < record.runs
    np.testing.assert_array_equal(from_iv, v["iv"] < v["lsm"])
    np.testing.assert_allclose(est.b[:, 1], np.where(from_iv, b2["iv"], b2["lsm"]), rtol=1e-12)
    np.testing.assert_allclose(est.criteria["v_eiv_lsm"][:, 1], v["lsm"], rtol=1e-10)
    np.testing.assert_allclose(est.criteria["v_eiv_iv"][:, 1], v["iv"], rtol=1e-10)
    assert not est.criteria["b_from_iv"][:, 0].any()  # b1 = 1 is not chosen


def test_v_eiv_is_the_orthogonal_distance():
    """V_EIV(l) is the mean squared orthogonal distance of (Delta w(kp+1), Delta w(kp+l)) to the
    line of slope b_l: zero on the line, and the total-least-squares slope minimises it."""
    rng = np.random.default_rng(0)
    R, K = 3, 400
    d1 = rng.standard_normal((R, K))
    dw = np.full((R, K * P), np.nan)
    dw[:, np.arange(K) * P + 1] = d1
    dw[:, np.arange(K) * P + 2] = -0.7 * d1
    dw[:, np.arange(K) * P + 3] = 0.2 * d1 + 0.1 * rng.standard_normal((R, K))
    b = np.array([[1.0, -0.7, 0.2]] * R)
    v = pp.v_eiv(dw, P, 0, b, t_min=1)
    assert np.isnan(v[:, 0]).all()
    np.testing.assert_allclose(v[:, 1], 0.0, atol=1e-28)
    # the TLS slope of phase 3 on phase 1 (smallest eigenvector of the 2x2 moment matrix)
    k = pp.common_periods(dw, P, 0, 1, 3)
    for r in range(R):
        X = np.stack([dw[r, k * P + 1], dw[r, k * P + 3]], axis=1)
        vec = np.linalg.eigh(X.T @ X)[1][:, 0]
        tls = -vec[0] / vec[1]
        at = [
            pp.v_eiv(dw[r : r + 1], P, 0, np.array([[1.0, 0.0, s]]), 1)[0, 2]
            for s in (tls - 0.01, tls, tls + 0.01)
        ]
        assert at[1] < at[0] and at[1] < at[2]


def test_bad_choices_exit_clearly():
    with pytest.raises(InputError, match="select_a"):
        run_method("wang", sim()[0], select_a="best")
    with pytest.raises(InputError, match="select_b"):
        run_method("wang", sim()[0], select_b="tls")


def _arx(sigma2: float, duration: float):
    """White equation noise g e / A(q) (g = 0.01, as tests/test_identifiers.py's consistency
    checks), 100 runs."""
    return sim(
        runs=100,
        seed=2024,
        noise__name="arx",
        noise__gain=0.01,
        noise__sigma2=sigma2,
        duration=duration,
    )


@pytest.mark.parametrize("sigma2", [1e-4, 1e-3, 1e-2])
def test_consistent_under_arx_noise(sigma2):
    """Both candidates are consistent, so the chosen one is: with 8 times the record (500 s ->
    4000 s) every parameter's RMS error over 100 runs falls below half (1/sqrt(8) = 0.35 for an
    error ~ 1/sqrt(K); measured 0.37-0.43)."""
    rms = {}
    for duration in (500.0, 4000.0):
        record, truth = _arx(sigma2, duration)
        params = run_method("wang", record, options=TRUE_STRUCTURE).params()
        rms[duration] = {
            key: np.sqrt(np.mean((params[key] - true) ** 2))
            for key, true in truth.plant.true_params().items()
        }
    for key, before in rms[500.0].items():
        assert rms[4000.0][key] < 0.5 * before, (key, rms[4000.0][key], before)


@pytest.mark.xfail(
    strict=True,
    reason="step (ii) keeps per run the denominator with the smaller residual, i.e. the one "
    "nearer the (biased) ordinary LS: a selection bias of ~0.4 of the spread (a1 +3.6 SE over "
    "100 runs), which shrinks with the spread as K grows but not relative to it",
)
def test_a1_unbiased_over_100_runs():
    record, truth = _arx(1e-3, 500.0)
    a1 = run_method("wang", record, options=TRUE_STRUCTURE).params()["a1"]
    se = np.std(a1, ddof=1) / np.sqrt(a1.size)
    assert abs(np.mean(a1) - truth.plant.true_params()["a1"]) <= 3 * se


def test_eq15_without_a_real_root():
    """Where g11 s2 > 1 eq. (15) has no real root: clip gives s2 (the stable form with the
    discriminant clipped), real 1/g11 (the complex roots' real part), modulus sqrt(s2/g11),
    zero 0; where a root exists every reading gives it."""
    s2 = np.array([0.5, 4.0, 9.0])
    g11 = np.array([1.0, 1.0, 4.0])  # g11 s2 = 0.5 (a root), 4, 36 (none)
    root = 0.5 / (1 + np.sqrt(0.5))
    np.testing.assert_allclose(pp.noise_variance(s2, g11), [root, 4.0, 9.0])
    np.testing.assert_allclose(pp.noise_variance(s2, g11, "real"), [root, 1.0, 0.25])
    np.testing.assert_allclose(pp.noise_variance(s2, g11, "modulus"), [root, 2.0, 1.5])
    np.testing.assert_allclose(pp.noise_variance(s2, g11, "zero"), [root, 0.0, 0.0])
    # the complex roots (1 +- i sqrt(g11 s2 - 1)) / g11: real part and modulus
    r = np.roots([4.0, -2.0, 9.0])
    np.testing.assert_allclose([r[0].real, abs(r[0])], [0.25, 1.5])
    with pytest.raises(ValueError, match="no_root"):
        pp.noise_variance(s2, g11, "largest")


def test_eq15_modulus_doubles_the_residual_on_an_active_phase():
    """On a regression over an active phase (a wrong shift, Table 1's tau = 4 column) eq. (15)
    has no real root; with the modulus the compensated residual is twice the OLS one."""
    record, _ = sim(runs=4, seed=5, noise__sigma2=1e-3)
    dy = pp.delta(record.y)
    reg = pp.quiet_regression(dy, P, 2, (P,), 4)
    _, ms = reg.least_squares()
    g11 = reg.inverse()[:, 0, 0]
    assert np.all(g11 * ms > 1.0)  # no real root on this phase
    theta, sigma2 = pp.bias_compensated(reg, "modulus")
    np.testing.assert_allclose(sigma2, np.sqrt(ms / g11))
    np.testing.assert_allclose(reg.residual_ms(theta), 2.0 * ms, rtol=1e-9)


def test_wang_lsm_eq15_changes_the_tables_only():
    """``eq15`` acts where (15) has no real root: in the selection table at wrong shifts
    (Table 1's tau = 4 column) and over-fitted orders, not at the selected structure."""
    record, _ = sim(runs=3, seed=5, noise__sigma2=1e-3)
    clip = run_method("wang-lsm", record)
    mod = run_method("wang-lsm", record, eq15="modulus")
    assert np.array_equal(clip.a, mod.a) and np.array_equal(clip.b, mod.b)
    assert np.array_equal(clip.U, mod.U, equal_nan=True)
    V_clip, V_mod = clip.criteria["V"], mod.criteria["V"]
    assert not np.allclose(V_clip[:, 1:, 4], V_mod[:, 1:, 4])  # na >= 2 at shift 4
    np.testing.assert_array_equal(V_clip[:, 1, 3], V_mod[:, 1, 3])  # na = 2, the true shift
    with pytest.raises(InputError, match="eq15"):
        run_method("wang-lsm", record, eq15="largest")

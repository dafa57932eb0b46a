"""The literature's OP-PV stiction tests in :mod:`hbench.diagnose.stats` (Yamashita, Kano et
al., Choudhury et al.) on cases whose answer is known."""

from __future__ import annotations

import numpy as np
import pytest

from hbench.diagnose import stats
from hbench.model import nonlinearities as nl


def _flow_loop(sticky: bool, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """A triangular controller output (integral action against a sticking valve) and the flow
    it gives, which follows the valve stem: stuck, then a slip; or the free valve's flow."""
    rng = np.random.default_rng(seed)
    t = np.arange(600)
    op = 50 + 4 * (2 * np.abs((t / 60.0) % 2 - 1) - 1)  # period 120 samples, +-4 %
    if sticky:
        stem, _ = nl.Stiction(S=3.0, J=2.0, u0=None).apply(op)
    else:
        stem = op
    return op + 0.01 * rng.standard_normal(t.size), stem + 0.01 * rng.standard_normal(t.size)


def test_qualitative_symbols() -> None:
    # noiseless ramps: the noise read from second differences is nil, any change moves
    z = np.concatenate([np.arange(10.0), np.full(10, 9.0), np.arange(9.0, -1.0, -1.0)])
    sym = stats.qualitative_symbols(z)
    np.testing.assert_array_equal(sym, np.concatenate([[1] * 9, [0] * 11, [-1] * 9]))
    np.testing.assert_array_equal(stats.qualitative_symbols(np.ones(4)), [0, 0, 0])
    # noise alone stays within the band (3 noise deviations: 0.3 % of differences outside)
    rng = np.random.default_rng(0)
    assert np.mean(stats.qualitative_symbols(rng.standard_normal(5000)) != 0) < 0.01


def test_yamashita_index_sees_the_stuck_patterns() -> None:
    x, y = _flow_loop(sticky=True)
    assert stats.yamashita_index(x, y) > stats.YAMASHITA_RHO
    x, y = _flow_loop(sticky=False)
    assert stats.yamashita_index(x, y) < 0.05  # the flow follows the OP: no IS, no DS
    assert np.isnan(stats.yamashita_index(np.ones(10), np.ones(10)))
    with pytest.raises(ValueError, match="differ in length"):
        stats.yamashita_index(x, y[:-1])


def test_kano_index_sees_the_stuck_sections() -> None:
    x, y = _flow_loop(sticky=True)
    assert stats.kano_index(x, y) > stats.KANO_SHARE
    x, y = _flow_loop(sticky=False)
    assert stats.kano_index(x, y) < 0.05
    assert np.isnan(stats.kano_index(np.ones(x.size), y))


def test_nonlinearity_indices_gaussian_and_not() -> None:
    rng = np.random.default_rng(1)
    ngi, _ = stats.nonlinearity_indices(rng.standard_normal(751))
    assert ngi < stats.CHOUDHURY_NGI  # a Gaussian series: no significant bicoherence
    t = np.arange(751)
    saw = (t % 40) / 40.0 + 0.05 * rng.standard_normal(751)  # phase-coupled harmonics
    ngi, nli = stats.nonlinearity_indices(saw)
    assert ngi > stats.CHOUDHURY_NGI and nli > stats.CHOUDHURY_NLI
    assert np.all(np.isnan(stats.nonlinearity_indices(np.zeros(100))))


def test_calibrate_pattern_tests_reads_a_loop() -> None:
    from hbench.diagnose import calibrate

    x, y = _flow_loop(sticky=True)
    out = calibrate.pattern_tests(x, y, None)
    assert out["yamashita"] and out["kano_stuck"]
    assert set(out) >= {"rho", "kano", "ngi", "nli", "nonlinear"}

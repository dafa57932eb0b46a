"""Conformance suite: every registered identifier, built-in or third-party, parametrised.

Checks what any method must honour: shapes, U aligned with x, no access to the truth or to signals
it did not declare, determinism, and a flag (not an exception) when assumption A2 fails.
Tolerances: noise-free data, so a correct method's inner signal fits the truth (fitness > 99 %,
loose enough for third-party methods that are exact only up to rounding or regularisation).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from hbench.identifiers import Estimate, Identifier, IdentifyOptions, identify
from hbench.metrics import fitness
from hbench.plugins import registry
from hbench.records import Record
from tests.helpers import sim


def pytest_generate_tests(metafunc):
    if "method_name" in metafunc.fixturenames:
        metafunc.parametrize("method_name", registry().names("identifiers"))


@pytest.fixture(scope="module")
def data():
    return sim(runs=3, seed=21, noise__sigma2=0.0)


def make(method_name: str) -> Identifier:
    cls = registry().get("identifiers", method_name)
    return cls(**cls.test_options)


def test_estimate_shapes(method_name, data):
    record, truth = data
    est = identify(make(method_name), record, IdentifyOptions(), truth)
    assert isinstance(est, Estimate)
    R, K = record.runs, record.n_slow
    assert est.method == method_name
    assert est.U.shape == (R, K)
    assert est.a.ndim == 2 and est.a.shape[0] == R
    assert est.b.ndim == 2 and est.b.shape[0] == R
    for name in ("na", "nb", "tau", "sigma2", "identifiable"):
        assert getattr(est, name).shape == (R,), name
    assert len(est.reason) == R
    np.testing.assert_array_equal(est.b[:, 0], 1.0)  # the b1 = 1 normalisation


def test_inner_signal_aligned_with_x(method_name, data):
    """U[:, n] belongs with x[:, n]: a one-sample shift would ruin the fit on this record."""
    record, truth = data
    est = identify(make(method_name), record, IdentifyOptions(), truth)
    F = fitness(est.U, truth.U, gain=truth.plant.gain)
    assert np.all(F > 99.0), F
    shifted = fitness(est.U[:, 1:], truth.U[:, :-1], gain=truth.plant.gain)
    assert np.all(shifted < F - 1.0)


def test_sees_only_what_it_declares(method_name, data, monkeypatch):
    record, truth = data
    method = make(method_name)
    seen: dict[str, object] = {}
    original = type(method).identify

    def spy(self, rec: Record, options, truth_=None):
        seen["record"], seen["truth"] = rec, truth_
        return original(self, rec, options, truth_)

    monkeypatch.setattr(type(method), "identify", spy)
    identify(method, record, IdentifyOptions(), truth)
    rec = seen["record"]
    assert isinstance(rec, Record)
    for signal in ("x", "r"):
        if signal not in method.needs:
            assert getattr(rec, signal) is None, f"{method_name} saw {signal} undeclared"
    if "truth" not in method.needs:
        assert seen["truth"] is None
    assert set(rec.meta) <= {"notices"}


def test_deterministic(method_name, data):
    record, truth = data
    a = identify(make(method_name), record, IdentifyOptions(), truth)
    b = identify(make(method_name), record, IdentifyOptions(), truth)
    np.testing.assert_array_equal(a.U, b.U)
    np.testing.assert_array_equal(a.a, b.a)
    np.testing.assert_array_equal(a.b, b.b)


def test_unidentifiable_is_flagged_not_raised(method_name):
    if "truth" in registry().get("identifiers", method_name).needs:
        pytest.skip("an oracle knows the structure: assumption A2 concerns blind estimation")
    record, truth = sim(runs=2, seed=3, noise__sigma2=0.0, p=3)
    est = identify(make(method_name), record, IdentifyOptions(nb_max=4), truth)
    assert not est.identifiable.any()
    assert all(est.reason)


def test_single_run_and_batch_agree(method_name, data):
    """Batching over runs changes nothing: run 1 alone equals run 1 of the batch."""
    record, truth = data
    batch = identify(make(method_name), record, IdentifyOptions(), truth)
    one = identify(make(method_name), record.select([1]), IdentifyOptions(), truth.select([1]))
    np.testing.assert_allclose(one.U[0], batch.U[1], rtol=0, atol=1e-10)


def test_withhold_removes_signals():
    record, _ = sim(runs=1, seed=0, noise__sigma2=0.0)
    rec = record.withhold(frozenset())
    assert rec.x is None and rec.r is None
    assert replace(rec).y is rec.y

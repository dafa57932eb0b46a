"""Conformance suite: every registered identifier, built-in or third-party, parametrised.

The checks live in :mod:`hbench.bench.conformance` (installed, so that a plugin's own tests run them
too: ``check_method("my-method")``); here every check runs on every registered method, one test
per (check, method). What they check and their tolerances: see that module.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from hbench.bench import conformance
from hbench.ident.identifiers import Estimate, Identifier
from hbench.plugins import registry
from hbench.sim.records import Record
from tests.helpers import paper_spec, sim

#: The checks every method must pass: none may go missing from hbench.bench.conformance.CHECKS.
REQUIRED_CHECKS = {
    "estimate_shapes",
    "inner_signal_aligned_with_x",
    "sees_only_what_it_declares",
    "deterministic",
    "unidentifiable_is_flagged_not_raised",
    "single_run_and_batch_agree",
}


def pytest_generate_tests(metafunc):
    if "method_name" in metafunc.fixturenames:
        metafunc.parametrize("method_name", registry().names("identifiers"))


@pytest.mark.parametrize("check", list(conformance.CHECKS))
def test_conformance(check: str, method_name: str) -> None:
    why = conformance.run_check(method_name, check)
    if why:
        pytest.skip(why)


def test_every_check_is_kept() -> None:
    assert set(conformance.CHECKS) >= REQUIRED_CHECKS


def test_only_an_oracle_skips() -> None:
    """A skip is A2 for an oracle, nothing else (every other check runs on every method)."""
    for name in registry().names("identifiers"):
        skipped = conformance.check_method(name, ["unidentifiable_is_flagged_not_raised"])
        oracle = "truth" in registry().get("identifiers", name).needs
        assert bool(skipped) == oracle, (name, skipped)


def test_records_are_the_suites() -> None:
    """The installed module simulates the records the suite used (tests.helpers.sim)."""
    for (runs, seed, top), spec_top in (((3, 21, {}), {}), ((2, 3, {"p": 3}), {"p": 3})):
        record, truth = conformance.paper_record(runs, seed, **top)
        ref, ref_truth = sim(runs=runs, seed=seed, noise__sigma2=0.0, **spec_top)
        np.testing.assert_array_equal(record.y, ref.y)
        np.testing.assert_array_equal(record.x, ref.x)
        np.testing.assert_array_equal(truth.U, ref_truth.U)
        assert record.p == paper_spec(**spec_top)["p"]


def test_withhold_removes_signals():
    record, _ = sim(runs=1, seed=0, noise__sigma2=0.0)
    rec = record.withhold(frozenset())
    assert rec.x is None and rec.r is None
    assert replace(rec).y is rec.y


# --------------------------------------------------------------------------- the checks catch


class _Lsm(Identifier):
    """wang-lsm, and a hook to spoil its estimate."""

    name = "test-conformance"

    def spoil(self, est: Estimate, record) -> Estimate:
        return est

    def identify(self, record, options, truth=None):
        est = registry().get("identifiers", "wang-lsm")().identify(record, options, None)
        return replace(self.spoil(est, record), method=self.name)


class _Shifted(_Lsm):
    def spoil(self, est, record):
        U = np.full_like(est.U, np.nan)
        U[:, 1:] = est.U[:, :-1]
        return replace(est, U=U)


class _SeesX(_Lsm):
    needs = frozenset({"x"})


class _Random(_Lsm):
    def spoil(self, est, record):
        return replace(est, U=est.U + 1e-3 * np.random.default_rng().standard_normal(est.U.shape))


class _Raises(_Lsm):
    def identify(self, record, options, truth=None):
        raise ValueError("boom")


class _RaisesOnA2(_Lsm):
    def identify(self, record, options, truth=None):
        if record.p < options.nb_max + 1:
            raise ValueError("p too small")
        return super().identify(record, options, truth)


class _WritesInput(_Lsm):
    def identify(self, record, options, truth=None):
        record.y[:, 0] = 0.0
        return super().identify(record, options, truth)


class _BatchDependent(_Lsm):
    def spoil(self, est, record):
        return replace(est, U=est.U + 1e-6 * record.runs)


def test_a_conforming_method_passes_as_class_or_instance() -> None:
    assert conformance.check_method(_Lsm) == {}
    assert conformance.check_method(_Lsm()) == {}
    assert conformance.check_method(_SeesX) == {}


@pytest.mark.parametrize(
    ("method", "check", "message"),
    [
        (_Shifted, "inner_signal_aligned_with_x", "fitness of U"),
        (_Random, "deterministic", "U differs between calls"),
        (_Raises, "estimate_shapes", "raised in check 'estimate_shapes': ValueError: boom"),
        (_RaisesOnA2, "unidentifiable_is_flagged_not_raised", "ValueError: p too small"),
        (_BatchDependent, "single_run_and_batch_agree", "run 1 alone differs"),
        (_WritesInput, "estimate_shapes", "ValueError: assignment destination is read-only"),
    ],
)
def test_a_broken_method_fails_with_a_clear_message(method, check, message) -> None:
    with pytest.raises(AssertionError) as info:
        conformance.check_method(method)
    text = str(info.value)
    assert f"method 'test-conformance' fails check {check!r}" in text or (
        f"method 'test-conformance' raised in check {check!r}" in text
    )
    assert message in text


def test_a_wrong_field_shape_is_named() -> None:
    class _NoReason(_Lsm):
        def spoil(self, est, record):
            return replace(est, reason=est.reason[:-1])

    with pytest.raises(AssertionError, match="test-conformance"):
        conformance.run_check(_NoReason, "estimate_shapes")


def test_unknown_names() -> None:
    with pytest.raises(KeyError, match="unknown check 'nope'"):
        conformance.run_check("wang-lsm", "nope")
    with pytest.raises(KeyError, match="unknown method 'nope'"):
        conformance.check_method("nope")
    with pytest.raises(TypeError, match="expected a method name"):
        conformance.check_method(42)  # type: ignore[arg-type]


def test_module_main(capsys: pytest.CaptureFixture[str]) -> None:
    assert conformance.main(["bai-fu", "oracle"]) == 0
    out = capsys.readouterr().out
    assert out.count("ok   bai-fu") == len(conformance.CHECKS)
    assert "skip oracle unidentifiable_is_flagged_not_raised" in out
    assert conformance.main(["nope"]) == 1
    assert "FAIL nope" in capsys.readouterr().out
    assert conformance.main([]) == 2


def test_a_record_shown_whole_is_caught(monkeypatch: pytest.MonkeyPatch) -> None:
    """Were ``identify`` to show a method what it did not declare, the check says so."""
    monkeypatch.setattr(Record, "withhold", lambda self, needs: self)
    with pytest.raises(AssertionError, match="saw x without declaring it in needs"):
        conformance.run_check("wang-lsm", "sees_only_what_it_declares")

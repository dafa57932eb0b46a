"""The ``validation`` cause rule reads each half of the validation part
(:data:`hbench.diagnose.validate.HALVES`): an extension whose detector stayed quiet must gain
its bar on both halves as well as on the whole; one whose detector fired, on the whole."""

from __future__ import annotations

import dataclasses
from types import SimpleNamespace

import numpy as np
import pytest

from hbench.diagnose import benchmark_cases as bc
from hbench.diagnose import core, nominal, validate
from hbench.diagnose.effects import Delay, Detection
from hbench.diagnose.report import _half_gains, _rows

MODEL = core.Model.__new__(core.Model)  # only "not None" matters to the rule
BASE, BASE_HALVES = 50.0, (40.0, 60.0)


def _ext(
    name: str, gain: float, halves: tuple[float, float] | None, detected: bool = False
) -> validate.Extension:
    """An extension gaining ``gain`` on the whole and ``halves`` on the two halves."""
    h = None if halves is None else (BASE_HALVES[0] + halves[0], BASE_HALVES[1] + halves[1])
    return validate.Extension(name, MODEL, BASE + gain, halves=h, detected=detected)


@pytest.mark.parametrize(
    ("halves", "bar", "expected"),
    [
        ((25.0, 25.0), 20.0, True),
        ((45.0, 5.0), 20.0, False),  # the whole gains 25, the second half 5
        ((30.0, -10.0), 2.0, False),  # one half loses
        ((2.0, 2.0), 2.0, True),  # the bar itself is reached
        ((float("nan"), 5.0), 2.0, False),  # a half that is not a number gains nothing
        (None, 2.0, True),  # halves not measured: the whole alone
    ],
)
def test_a_quiet_extension_gains_only_what_both_halves_gain(
    halves: tuple[float, float] | None, bar: float, expected: bool
) -> None:
    e = _ext("drift", 25.0, halves)
    assert validate.clears(e, BASE, BASE_HALVES, bar) is expected
    assert validate.clears(e, BASE, None, bar) is True  # the whole alone


def test_a_fired_detector_needs_the_whole_only() -> None:
    e = _ext("drift", 25.0, (45.0, 5.0))
    assert not validate.clears(e, BASE, BASE_HALVES, 20.0)
    e.detected = True
    assert validate.clears(e, BASE, BASE_HALVES, 20.0)
    assert not validate.clears(e, BASE, BASE_HALVES, 30.0)  # the whole still counts


def test_without_halves_the_whole_decides(monkeypatch: pytest.MonkeyPatch) -> None:
    e = _ext("drift", 25.0, (45.0, 5.0))
    assert not validate.clears(e, BASE, BASE_HALVES, 20.0)
    monkeypatch.setattr(validate, "HALVES", False)
    assert validate.clears(e, BASE, BASE_HALVES, 20.0)


def test_a_nominal_half_that_is_not_a_number_leaves_the_whole_to_decide() -> None:
    e = _ext("drift", 25.0, (45.0, 5.0))
    assert validate.clears(e, BASE, (float("-inf"), 60.0), 20.0)


def test_the_whole_must_gain_too() -> None:
    assert not validate.clears(_ext("drift", 1.0, (5.0, 5.0)), BASE, BASE_HALVES, 2.0)
    assert not validate.clears(validate.Extension("drift", None, 90.0), BASE, None, 2.0)


def test_choose_extension_passes_over_a_gain_of_one_half() -> None:
    """The larger gain of one half loses to a smaller gain of both; with the halves not read
    (the ``detectors`` rule) the larger wins."""
    lopsided = _ext("time-varying", 30.0, (60.0, -1.0))
    steady = _ext("drift", 10.0, (9.0, 11.0))
    pool = [lopsided, steady]
    ext = {e.name: e for e in pool}
    best = validate.choose_extension(pool, ext, BASE, 2.0, BASE_HALVES)
    assert best is not None and best.name == "drift"
    best = validate.choose_extension(pool, ext, BASE, 2.0)
    assert best is not None and best.name == "time-varying"
    assert validate.choose_extension([lopsided], ext, BASE, 2.0, BASE_HALVES) is None


@pytest.mark.parametrize(
    ("coloured_halves", "detected", "cause"),
    [
        ((19.0, -1.0), False, "order"),  # quiet, and one half loses
        ((9.0, 9.0), False, "colored-noise"),
        ((19.0, -1.0), True, "colored-noise"),  # fired: the whole decides
    ],
)
def test_parsimony_reads_the_halves_of_a_quiet_simpler_extension(
    coloured_halves: tuple[float, float], detected: bool, cause: str
) -> None:
    order = _ext("order", 10.0, (10.0, 10.0), detected=True)
    coloured = _ext("colored-noise", 9.0, coloured_halves, detected=detected)
    ext = {"order": order, "colored-noise": coloured}
    best = validate.choose_extension([order], ext, BASE, 2.0, BASE_HALVES)
    assert best is not None and best.name == cause


def test_half_fits_split_the_validation_part() -> None:
    """Each half's fit is against that half's own mean; the second half holds the odd
    sample."""
    y = np.arange(31.0)
    ctx = SimpleNamespace(y=y, val_idx=np.arange(10, 31))
    y_hat = y.copy()
    y_hat[25:] = np.mean(y[20:31])  # the second half (20..30) predicted from sample 25 on
    first, second = validate.half_fits(ctx, y_hat)  # type: ignore[arg-type]
    assert first == pytest.approx(100.0)
    assert second == pytest.approx(core.fit_percent(y[20:31], y_hat[20:31]))
    assert second < 100.0


def test_the_evidence_cell_says_when_the_halves_are_off(monkeypatch: pytest.MonkeyPatch) -> None:
    """The cell and the rule read one predicate
    (:func:`~hbench.diagnose.validate.unread_halves`)."""
    d = SimpleNamespace(baseline_halves=BASE_HALVES, baseline_fit=BASE, rule="validation")
    quiet = _ext("drift", 25.0, (45.0, 5.0))
    assert _half_gains(d, quiet) == "+25.0 whole; +45.0 / +5.0"
    monkeypatch.setattr(validate, "HALVES", False)
    assert _half_gains(d, quiet).endswith("(halves not read: HALVES is off)")
    assert validate.clears(quiet, BASE, BASE_HALVES, 20.0)


def test_the_evidence_table_gives_the_gain_of_each_half() -> None:
    d = SimpleNamespace(baseline_halves=BASE_HALVES, baseline_fit=BASE, rule="validation")
    assert _half_gains(d, _ext("drift", 9.0, (7.5, -1.3))) == "+9.0 whole; +7.5 / -1.3"
    fired = _ext("drift", 9.0, (7.5, -1.3), detected=True)
    assert _half_gains(d, fired).endswith("(halves not read: detector fired)")
    d.rule = "detectors"
    assert _half_gains(d, fired).endswith("(halves not read: detectors rule)")
    assert _half_gains(d, None) == ""
    assert _half_gains(d, validate.Extension("drift", None, -np.inf)) == ""
    assert "halves n/a: " in _half_gains(d, _ext("drift", 9.0, None))
    assert "halves n/a: " in _half_gains(d, _ext("drift", 9.0, (float("nan"), 1.0)))


# --------------------------------------------------------------------------- one record


class _FiredDelay(Delay):
    """The delay effect with a detector that always fires (same statistic and extension)."""

    def detect(self, ctx: nominal.Context, nom: nominal.Nominal) -> Detection:
        return dataclasses.replace(super().detect(ctx, nom), fired=True)


@pytest.fixture(scope="module")
def record_16022() -> object:
    """Calibration record 16022 (paper loop, dead zone, no effect): the delay extension gains
    over 20 points on the whole validation part with its detector quiet, and fewer than 20 on
    the first half (``docs/experiments/validation-halves.md``). The tests below fit the delay
    effect alone (the record's cause with every effect is in the write-up)."""
    return bc.simulate_bench_case(bc.draw_bench_case(16022, "none", "deadband", "paper"))


def test_a_quiet_gain_of_one_half_is_no_cause(
    record_16022: object, monkeypatch: pytest.MonkeyPatch
) -> None:
    with np.errstate(all="ignore"):
        d = validate.diagnose(record_16022, effects=[Delay])  # type: ignore[arg-type]
    ext = d.extensions["delay"]
    assert not ext.detected
    g = validate.half_gains(ext, d.baseline_halves)
    assert g is not None and min(g) < validate.MIN_GAIN_UNDETECTED
    assert ext.val_fit - d.baseline_fit >= validate.MIN_GAIN_UNDETECTED
    assert d.cause == "none"
    assert "on each of its halves" in d.why
    assert [e.name for e, _ in d.set_aside()] == ["delay"]
    assert f"delay ({ext.val_fit - d.baseline_fit:+.1f}; halves {g[0]:+.1f}" in d.why
    row = next(r for r in _rows(d) if r["effect"] == "delay")
    cell = row[f"gain: whole; 1st / 2nd half of validation ({d.criterion}, points)"]
    assert cell == f"{ext.val_fit - d.baseline_fit:+.1f} whole; {g[0]:+.1f} / {g[1]:+.1f}"
    # the same gain from a fired detector, or with the halves not read, is the cause
    with np.errstate(all="ignore"):
        fired = validate.diagnose(record_16022, effects=[_FiredDelay])  # type: ignore[arg-type]
    assert fired.extensions["delay"].detected and fired.cause == "delay"
    assert fired.set_aside() == [] and "set aside" not in fired.why
    monkeypatch.setattr(validate, "HALVES", False)
    with np.errstate(all="ignore"):
        whole = validate.diagnose(record_16022, effects=[Delay])  # type: ignore[arg-type]
    assert whole.cause == "delay"
    assert whole.baseline_halves == d.baseline_halves  # measured either way

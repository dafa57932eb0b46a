"""The time-varying extension's segment: the detector's break when it fired, else the latest
window of the fit part (``hbench.diagnose.effects.TimeVarying.segment_start``), and the valve
class compared on that segment alone.

The behavioural test uses seed 5001 of the benchmark loops (outside the calibration seeds
10000-19999 and the held-out seeds 20000-29999): the paper loop, a linear valve, the plant's gain
and time constants changing at 2468 fast samples into the fit part of 4440. The detector is
quiet there (its statistic is below 1), and its best break (1346) lies before the change.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from hbench.diagnose import benchmark_cases as bc
from hbench.diagnose import core
from hbench.diagnose import effects as ef
from hbench.diagnose import nominal as nm
from hbench.diagnose.validate import MIN_GAIN_UNDETECTED, criteria_fits, diagnose


def _detection(at: int, fired: bool) -> ef.Detection:
    return ef.Detection("time-varying", 2.0 if fired else 0.5, 0.5, 1.0, fired, "", {"at": at})


class _Ctx:
    n_fit = 4440


def test_the_segment_starts_at_a_fired_detectors_break_else_at_the_latest_window():
    tv = ef.TimeVarying()
    assert tv.segment_start(_Ctx(), _detection(1346, True)) == 1346
    # the fit part's last 30 % of 4440 fast samples
    assert tv.segment_start(_Ctx(), _detection(1346, False)) == 3108


@pytest.fixture(scope="module")
def changed_record():
    case = bc.draw_bench_case(5001, "time-varying", "linear", "paper")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        rec = bc.simulate_bench_case(case)
        d = diagnose(rec, source=case.name)
    return case, d


def test_a_quiet_detectors_break_precedes_the_change_and_the_latest_window_does_not(
    changed_record,
):
    case, d = changed_record
    det = next(x for x in d.detections if x.name == "time-varying")
    change = int(case.effect_params["at"] * case.K * case.p)
    assert not det.fired and det.statistic < det.threshold
    assert det.info["at"] < change  # the quiet detector's break: before the change
    start = ef.TimeVarying().segment_start(d.ctx, det)
    assert change <= start < d.ctx.n_fit  # the extension's segment: after it


def test_the_latest_window_gains_where_the_quiet_detectors_segment_does_not(changed_record):
    _, d = changed_record
    det = next(x for x in d.detections if x.name == "time-varying")
    crit = d.info["criterion"]
    tv = ef.TimeVarying()
    fired_at_break = ef.Detection(det.name, det.statistic, det.p_value, 1.0, True, "", det.info)
    from_break = tv.extend(d.ctx, d.nominal, fired_at_break)
    gain_break = criteria_fits(d.ctx, from_break, d.nominal.model, [crit])[crit.name]
    gain_break -= d.baseline_fit
    gain_latest = d.extensions["time-varying"].val_fit - d.baseline_fit
    assert np.isfinite(gain_latest) and np.isfinite(gain_break)
    assert gain_latest >= MIN_GAIN_UNDETECTED > gain_break
    assert d.cause == "time-varying"
    assert d.extensions["time-varying"].model.info["segment_start"] > det.info["at"]


def test_fit_segment_is_the_fit_parts_tail_all_of_it_fit(changed_record):
    _, d = changed_record
    ctx = d.ctx
    k0 = ctx.k_fit // 3
    seg = ctx.fit_segment(k0)
    assert seg.p == ctx.p and seg.h == ctx.h
    assert seg.k_fit == seg.K == ctx.k_fit - k0 and seg.val_idx.size == 0
    np.testing.assert_array_equal(seg.x, ctx.x[k0 : ctx.k_fit])
    np.testing.assert_array_equal(seg.y, ctx.y[k0 * ctx.p : ctx.n_fit])
    np.testing.assert_array_equal(seg.record.x[0], seg.x)
    for bad in (-1, ctx.k_fit):
        with pytest.raises(ValueError, match="fit part"):
            ctx.fit_segment(bad)


def test_an_unknown_segment_class_route_is_an_error(monkeypatch):
    monkeypatch.setattr(ef.TimeVarying, "SEGMENT_CLASS", "graphs")
    with pytest.raises(ValueError, match="SEGMENT_CLASS"):
        ef.TimeVarying()  # made by diagnose outside its guard of the extensions: it stops


def test_a_failed_segment_candidate_leaves_the_family_fit_with_a_note(changed_record, monkeypatch):
    """The blind route failing on the segment: the extension is the nominal family's refit,
    and says why the other candidate is missing (shown beside its fit on the page)."""
    from hbench.diagnose.report import _rows
    from hbench.errors import MethodError

    _, d = changed_record
    det = next(x for x in d.detections if x.name == "time-varying")

    def fail(*args, **kwargs):
        raise MethodError("method 'wang-lsm' failed: a test")

    monkeypatch.setattr(nm, "identify_blind", fail)
    m = ef.TimeVarying().extend(d.ctx, d.nominal, det)
    assert m.label != "time-varying"  # not the blind candidate
    assert m.info["notes"] == [
        "the blind route on the segment failed (method 'wang-lsm' failed: a test)"
    ]
    assert "notes" not in d.nominal.model.info
    ext = d.extensions["time-varying"]
    monkeypatch.setattr(ext, "model", m)
    row = next(r for r in _rows(d) if r["effect"] == "time-varying")
    assert row[f"extended fit ({d.criterion})"].endswith(f"({m.info['notes'][0]})")


def test_the_segments_class_is_compared_through_the_dynamics():
    """Calibration record 11103 (NMP plant, p = 3, a stiction valve, the plant's gain times
    2.06 from 40 % of the record on): the nominal, fitted over both regimes, takes the valve
    for a backlash; every class compared by equation error on the segment after the change
    gives the stiction back, with all five classes scored through the dynamics."""
    case = next(
        c for c in bc.bench_grid(11000, 1, ("first-order", "third-order", "nmp")) if c.seed == 11103
    )
    assert (case.effect, case.cls) == ("time-varying", "stiction")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ctx = nm.make_context(bc.simulate_bench_case(case))
        nom = nm.fit_nominal(ctx)
        tv = ef.TimeVarying()
        m = tv.extend(ctx, nom, tv.detect(ctx, nom))
    assert nom.chosen == "backlash"
    assert m.cls == "stiction"
    assert m.info["refit"] == "equation-error"
    assert set(m.info["class_fits"]) == set(core.CLASSES)
    assert all("eq" in f.info for f in m.info["class_fits"].values())
    assert m.info["class_fits"]["linear"].score == 0.0

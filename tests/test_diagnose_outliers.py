"""The outliers extension: the record cleaned of its spikes and the nominal fitted again, every
valve class compared (``hbench.diagnose.effects.Outliers``).

The record is calibration seed 11053 of the benchmark loops (the third-order plant, p = 3, a
dead-zone valve, spikes on 0.68 % of the fast samples; calibration seeds 10000-19999).
"""

from __future__ import annotations

import warnings

import pytest

from hbench.diagnose import benchmark_cases as bc
from hbench.diagnose import core
from hbench.diagnose import effects as ef
from hbench.diagnose import nominal as nm


@pytest.fixture(scope="module")
def spiky():
    case = next(
        c for c in bc.bench_grid(11000, 1, ("first-order", "third-order", "nmp")) if c.seed == 11053
    )
    assert (case.effect, case.cls, case.plant) == ("outliers", "deadband", "third-order")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ctx = nm.make_context(bc.simulate_bench_case(case))
        nom = nm.fit_nominal(ctx)
        det = ef.Outliers().detect(ctx, nom)
    return ctx, nom, det


def test_the_cleaned_record_gives_the_class_the_spikes_hid(spiky):
    """The nominal, fitted through the spikes, takes the dead zone for a linear valve; fitted
    again on the cleaned record with every class compared, it finds the dead zone."""
    ctx, nom, det = spiky
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        m = ef.Outliers().extend(ctx, nom, det)
    assert nom.chosen == "linear"
    assert det.fired and m.info["cleaned"] > 0
    assert m.cls == "deadband"
    assert m.info["refit"] == "equation-error"
    assert set(m.info["class_fits"]) == set(core.CLASSES)
    assert all("eq" in f.info for f in m.info["class_fits"].values())


@pytest.mark.parametrize(("which", "cls"), [("nominal", "linear"), ("both", "linear")])
def test_the_other_class_sets(spiky, monkeypatch, which, cls):
    """With the nominal's few classes, and with both sets, the fit part's simulation keeps the
    few classes' fit on this record (``docs/experiments/extension-classes.md``, section 2)."""
    ctx, nom, det = spiky
    monkeypatch.setattr(ef.Outliers, "REFIT_CLASSES", which)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        m = ef.Outliers().extend(ctx, nom, det)
    assert m.cls == cls
    assert set(m.info["class_fits"]) < set(core.CLASSES)


def test_an_unknown_refit_class_set_is_an_error(monkeypatch):
    monkeypatch.setattr(ef.Outliers, "REFIT_CLASSES", "every")
    with pytest.raises(ValueError, match="REFIT_CLASSES"):
        ef.Outliers()

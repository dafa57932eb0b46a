"""The outliers extension: the record cleaned of its spikes and the nominal fitted again, every
valve class compared (``hbench.diagnose.effects.Outliers``).

The record is calibration seed 11053 of the benchmark loops (the third-order plant, p = 3, a
dead-zone valve, spikes on 0.5-1.5 % of the fast samples; calibration seeds 10000-19999).
"""

from __future__ import annotations

import warnings

from hbench.diagnose import benchmark_cases as bc
from hbench.diagnose import core
from hbench.diagnose import effects as ef
from hbench.diagnose import nominal as nm


def test_the_cleaned_record_gives_the_class_the_spikes_hid():
    """The nominal, fitted through the spikes, takes the dead zone for a linear valve; fitted
    again on the cleaned record with every class compared, it finds the dead zone."""
    case = next(
        c for c in bc.bench_grid(11000, 1, ("first-order", "third-order", "nmp")) if c.seed == 11053
    )
    assert (case.effect, case.cls, case.plant) == ("outliers", "deadband", "third-order")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ctx = nm.make_context(bc.simulate_bench_case(case))
        nom = nm.fit_nominal(ctx)
        ol = ef.Outliers()
        det = ol.detect(ctx, nom)
        m = ol.extend(ctx, nom, det)
    assert nom.chosen == "linear"
    assert det.fired and m.info["cleaned"] > 0
    assert m.cls == "deadband"
    assert set(m.info["class_fits"]) == set(core.CLASSES)

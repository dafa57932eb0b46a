"""The ``order`` effect (:class:`hbench.diagnose.effects.Order`): a missing pole is detected and
its extension recovers the lost fit; a record of the nominal order is not called ``order``."""

from __future__ import annotations

import dataclasses

from hbench.diagnose import benchmark_cases as bc
from hbench.diagnose import validate
from hbench.sim.records import Record

#: A seed outside the benchmark's calibration and held-out ranges.
SEED = 4321


def _low_noise_record(effect: str) -> Record:
    """The paper loop (linear valve) with ``effect``, its process noise 100 times below the
    benchmark's lowest level."""
    case = bc.draw_bench_case(SEED, effect, "linear", "paper")
    case = dataclasses.replace(case, noise_sigma=1e-4)
    return bc.simulate_bench_case(case)


def test_a_missing_pole_is_detected_and_its_extension_recovers_the_fit() -> None:
    d = validate.diagnose(_low_noise_record("order"), extend_all=True)
    det = next(x for x in d.detections if x.name == "order")
    assert det.fired and det.p_value < 0.01
    ext = d.extensions["order"]
    assert ext.model is not None and ext.model.lin.na >= 3
    assert ext.val_fit - d.baseline_fit >= validate.MIN_GAIN["validation"]
    assert ext.val_fit > 90.0
    assert d.cause == "order"


def test_a_record_of_the_nominal_order_is_not_called_order() -> None:
    d = validate.diagnose(_low_noise_record("none"), extend_all=True)
    assert d.cause != "order"
    assert d.extensions["order"].val_fit - d.baseline_fit < validate.MIN_GAIN["validation"]

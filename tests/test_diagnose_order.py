"""The ``order`` effect (:class:`hbench.diagnose.effects.Order`): a missing pole is detected and
its extension recovers the lost fit; a record of the nominal order is not called ``order``;
and the parsimony rule between a delay and one more pole (:data:`hbench.diagnose.validate.
PARSIMONY`)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from hbench.diagnose import benchmark_cases as bc
from hbench.diagnose import validate

#: A seed outside the benchmark's calibration and held-out ranges.
SEED = 4321


def _low_noise_record(effect: str) -> object:
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


def _ext(name: str, gain: float) -> validate.Extension:
    return validate.Extension(name, object(), gain)  # type: ignore[arg-type]


@pytest.mark.parametrize(
    ("delay_gain", "expected"), [(9.5, "delay"), (9.0, "delay"), (8.5, "order"), (None, "order")]
)
def test_a_delay_that_gains_nine_tenths_of_the_order_extension_is_named(
    delay_gain: float | None, expected: str
) -> None:
    """Against one more pole gaining 10 points, the delay is named from 90 % of that gain on;
    a delay gaining less, or none, leaves ``order``."""
    exts = {"order": _ext("order", 10.0)}
    if delay_gain is not None:
        exts["delay"] = _ext("delay", delay_gain)
    best = validate.choose_extension(list(exts.values()), exts, 0.0, 2.0)
    assert best is not None and best.name == expected
    assert ("delay", "order", 0.9) in validate.PARSIMONY
    assert np.isfinite(best.val_fit)

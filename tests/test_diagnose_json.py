"""The diagnosis JSON's numbers say what they mean (contract: finite numbers, no ``nan``)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from hbench.diagnose import generator
from hbench.diagnose.effects import Detection


def _json(statistic: float, p_value: float) -> dict:
    det = Detection("drift", statistic, p_value, 8.0, False, "e (threshold 8: quiet)")
    return json.loads(json.dumps(det.as_json(), allow_nan=False))


def test_an_undefined_p_value_is_no_evidence() -> None:
    """A p-value no test could give reads as 1 (no evidence), not 0 (the strongest)."""
    assert _json(np.nan, np.nan) == {
        "name": "drift",
        "statistic": 0.0,
        "p_value": 1.0,
        "evidence": "e (threshold 8: quiet)",
    }
    assert _json(np.inf, 0.25)["statistic"] == 1e300
    assert _json(2.5, 0.25)["p_value"] == 0.25


def test_a_nominal_model_no_better_than_the_mean_is_not_none(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """No extension gains and the nominal validation fit is <= 0 %: ``unexplained``, not
    ``none`` (the contract's ``none`` is "the nominal model already explains the data")."""
    from hbench.diagnose import validate

    case = generator.draw_case(5000, "none", "linear")  # a calibration seed: diagnosed none
    d = validate.diagnose(generator.simulate_case(case))
    assert d.cause == "none" and d.baseline_fit > 0
    assert d.why.startswith("no fired detector's extension gains")
    assert "explains the validation part" in d.why
    monkeypatch.setattr(validate, "NONE_MIN_FIT", d.baseline_fit + 1.0)
    again = validate.diagnose(d.ctx.record)
    assert again.cause == "unexplained"
    assert "no better than the validation part's mean" in again.why

"""The classical stiction detectors run as baselines (:mod:`hbench.diagnose.baselines`) on
signals whose verdict is known, and the real-data report's baseline part
(``score_baselines``, ``detector_rates`` and ``detector_table`` of
:mod:`hbench.diagnose.calibrate`) on synthetic rows and on a few development records of
``../shared/data/stictiongpt``."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

from hbench.diagnose import baselines as bl
from hbench.diagnose import calibrate

N, PERIOD = 750, 50
T = np.arange(N)
W = 2 * np.pi / PERIOD


def noisy(signal: np.ndarray, seed: int, scale: float = 0.02) -> np.ndarray:
    return signal + scale * np.random.default_rng(seed).standard_normal(signal.size)


def triangle() -> np.ndarray:
    """A triangular wave of period :data:`PERIOD` between -1 and 1."""
    return 4 * np.abs((T / PERIOD) % 1 - 0.5) - 1


def test_a_triangular_controller_output_is_stiction_for_he() -> None:
    v = bl.he(noisy(triangle(), 1))
    assert v.verdict == bl.STICTION
    assert v.statistic > bl.HE_STICTION


def test_a_sinusoidal_controller_output_is_no_stiction_for_he() -> None:
    v = bl.he(noisy(np.sin(W * T), 2))
    assert v.verdict == bl.NO_STICTION
    assert v.statistic < bl.HE_NO_STICTION


def test_an_odd_cross_correlation_is_stiction_for_horch() -> None:
    # x = sin, y = cos(. + 0.3): c(tau) ~ -sin(w tau + 0.3), zeros at -0.3/w and (pi - 0.3)/w,
    # so |dphi| = pi - 0.6 (odd)
    x = noisy(np.sin(W * T), 3)
    v = bl.horch(x, noisy(np.cos(W * T + 0.3), 4))
    assert v.verdict == bl.STICTION
    assert v.statistic == pytest.approx(np.pi - 0.6, abs=0.1)
    # a triangular OP with a square PV in quadrature (a sticking valve's pattern) reads odd too
    assert bl.horch(triangle(), np.sign(np.sin(W * T))).verdict == bl.STICTION


def test_an_even_cross_correlation_is_no_stiction_for_horch() -> None:
    # y = -sin(. - 0.3): c(tau) ~ -cos(w tau - 0.3), |dphi| = 0.6 (even)
    x = noisy(np.sin(W * T), 5)
    v = bl.horch(x, noisy(-np.sin(W * T - 0.3), 6))
    assert v.verdict == bl.NO_STICTION
    assert v.statistic == pytest.approx(0.6, abs=0.1)


def test_a_phase_between_horchs_limits_is_undetermined() -> None:
    v = bl.horch(np.sin(W * T), np.cos(W * T + np.pi / 4))
    assert v.verdict == bl.UNDETERMINED
    assert bl.HORCH_EVEN < v.statistic < bl.HORCH_ODD


def test_three_way_limits() -> None:
    assert bl.three_way(0.7, 0.6, 0.4, "i").verdict == bl.STICTION
    assert bl.three_way(0.3, 0.6, 0.4, "i").verdict == bl.NO_STICTION
    assert bl.three_way(0.5, 0.6, 0.4, "i").verdict == bl.UNDETERMINED
    assert bl.three_way(0.6, 0.6, 0.4, "i").verdict == bl.UNDETERMINED
    nan = bl.three_way(float("nan"), 0.6, 0.4, "index")
    assert nan.verdict == bl.UNDETERMINED and nan.why == "index cannot be read"


@pytest.mark.parametrize("kind", ["white", "random walk"])
def test_a_loop_that_does_not_oscillate_is_no_stiction_for_both(kind: str) -> None:
    e = np.random.default_rng(7).standard_normal(N)
    x = e if kind == "white" else np.cumsum(e)
    regular, r = bl.oscillation(x)
    assert not regular and r <= bl.REGULARITY
    # a triangular-looking reading must not matter: the gate decides before any test
    for v in bl.verdicts(x, np.roll(x, 3)).values():
        assert v.verdict == bl.NO_STICTION
        assert np.isnan(v.statistic)
        assert v.why.startswith("no regular oscillation")


def test_verdicts_names_every_detector() -> None:
    got = bl.verdicts(noisy(triangle(), 8), np.sign(np.sin(W * T)))
    assert tuple(got) == bl.DETECTORS
    assert {v.verdict for v in got.values()} == {bl.STICTION}


def rows_of(verdicts: list[tuple[str, str, str]]) -> list[dict[str, Any]]:
    """Rows of a scored split from ``(loop_tag, label, verdict)``."""
    return [
        {"split": "development", "loop_tag": t, "label": lab, "verdicts": {"d": v}}
        for t, lab, v in verdicts
    ]


def test_detector_rates_count_undetermined_and_refused_as_wrong() -> None:
    rows = rows_of(
        [
            ("a", "stiction", "stiction"),
            ("a", "stiction", "undetermined"),
            ("b", "stiction", "no-stiction"),
            ("c", "no-stiction", "no-stiction"),
            ("c", "no-stiction", "refused"),
            ("d", "no-stiction", "stiction"),
            ("e", "no-stiction", "no-stiction"),
        ]
    )
    rates = calibrate.detector_rates(rows, "development", "d")
    assert [rates[m][:2] for m in calibrate.MEASURES] == [(3, 7), (1, 3), (2, 4)]
    for k, n, lo, hi in rates.values():
        assert 0 <= lo <= 100 * k / n <= hi <= 100
    # loops are the sampling unit: sensitivity resamples loops a and b only
    assert rates["sensitivity"][2:] == (0.0, 50.0)
    # an empty measure reads n/a in the table
    none = calibrate.detector_rates(rows, "evaluation", "d")
    assert all(n == 0 for _, n, _, _ in none.values())
    table = calibrate.detector_table(rows, ["development", "evaluation"])
    assert "3/7 =  43 %" in table and "n/a: none" in table


DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "stictiongpt"


@pytest.mark.shared
@pytest.mark.skipif(
    not (DATA / "INDEX.csv").is_file(),
    reason=f"the StictionGPT records are not at {DATA} (../shared absent)",
)
def test_the_baselines_on_development_records() -> None:
    index = calibrate.stictiongpt_index(DATA)
    # the oscillating loop with stiction, an oscillating loop without, one that does not oscillate
    loops = {"2111FIC46005", "2111LIC31102B", "2111FIC10201"}
    picked = [r for r in index if r["split"] == "development" and r["loop_tag"] in loops][::2]
    rows = calibrate.score_baselines(DATA, picked)
    assert {r["loop_tag"] for r in rows} == loops
    for r in rows:
        assert r["baseline_message"] == ""
        assert set(r["verdicts"]) == set(bl.DETECTORS)
        if r["loop_tag"] == "2111FIC46005":  # a regular oscillation with a triangular OP
            assert r["verdicts"] == {"horch": "stiction", "he": "stiction"}
        if r["loop_tag"] == "2111LIC31102B":  # regular, sinusoidal enough, even correlation
            assert r["baselines"]["horch"].verdict == "no-stiction"
            assert r["baselines"]["he"].statistic < bl.HE_STICTION
        if r["loop_tag"] == "2111FIC10201":  # no regular oscillation: gated
            assert all(v.why.startswith("no regular") for v in r["baselines"].values())
    rates = calibrate.detector_rates(rows, "development", "horch")
    n = len(rows)
    assert rates["accuracy"][:2] == (n, n)
    table = calibrate.detector_table(rows, ["development"]).splitlines()
    assert [line.split()[1] for line in table[1:]] == list(bl.DETECTORS)

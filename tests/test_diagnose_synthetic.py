"""Hidden effects: records from :mod:`hbench.diagnose.generator` with ONE effect (or none)
written to files; the test sees only the file, runs ``hbench diagnose`` through
:func:`hbench.cli.main` and checks the named cause, the nonlinearity class and, where an effect
was hidden, a positive validation gain.

Default run: every case of ``cases_per_effect(3, 0)`` (seeds 0-20, three per effect), all scored:
a regression check against the counts this method reaches there (:data:`DEFAULT_RIGHT`), so a
drop fails and a gain is reported, never a filtered list of the seeds it gets right. The
``slow`` run diagnoses 140 records (seeds 1000-1139, none of them used to calibrate) and prints
both confusion matrices. A second ``slow`` test scores the stiction verdict of plant logs
(``p = 1``) on synthetic plant loops with known valves
(:func:`hbench.diagnose.generator.loop_cases`).
"""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from hbench.diagnose import calibrate, generator

RunCli = Callable[[list[str]], tuple[int, str, str]]

#: The default run's cases: ``cases_per_effect(3, 0)``, seeds 0-20.
DEFAULT_CASES = 21
#: What the diagnosis gets right on them, as measured: causes, classes, and positive gains on
#: the 18 records with an effect.
DEFAULT_RIGHT = {"cause": 20, "class": 21, "gain": 18}


def _diagnose_file(run_cli: RunCli, path: Path, tmp: Path) -> dict:
    out = tmp / (path.stem + ".json")
    status, _, err = run_cli(["diagnose", str(path), "--json", str(out)])
    assert status == 0, err
    return json.loads(out.read_text())


def test_default_cases_cover_every_effect_three_times() -> None:
    effects = [c.effect for c in generator.cases_per_effect(3, 0)]
    assert len(effects) == DEFAULT_CASES
    for e in generator.EFFECTS:
        assert effects.count(e) == 3


def test_hidden_effects_regression(run_cli: RunCli, tmp_path: Path) -> None:
    rows = []
    for case in generator.cases_per_effect(3, 0):
        path = generator.write_case(case, tmp_path)
        d = _diagnose_file(run_cli, path, tmp_path)
        rows.append((case, d))
    right = {
        "cause": sum(d["cause"] == c.effect for c, d in rows),
        "class": sum(d["nonlinearity"]["class"] == c.cls for c, d in rows),
        "gain": sum(d["gain"] > 0 for c, d in rows if c.effect != "none"),
    }
    print(f"\nseeds 0-20: {right} of {DEFAULT_CASES} ({DEFAULT_CASES - 3} with an effect)")
    wrong = [(c.seed, c.effect, c.cls, d["cause"], d["nonlinearity"]["class"]) for c, d in rows]
    for key, n in DEFAULT_RIGHT.items():
        assert right[key] >= n, (key, right, wrong)
    # a record without an effect gains nothing: its extended model is the nominal
    assert all(d["gain"] == 0 for c, d in rows if d["cause"] in ("none", "unexplained"))


@pytest.mark.slow
def test_hidden_effects_confusion_matrix(capsys: pytest.CaptureFixture[str]) -> None:
    rows = calibrate.run(generator.cases_per_effect(20, start=1000), jobs=2)
    text = calibrate.report(rows)
    with capsys.disabled():
        print(f"\nhbench diagnose on {len(rows)} synthetic records (seeds 1000-1139)\n{text}")
    assert not [r for r in rows if r["cause"] == "error"]
    n = len(rows)
    cause_ok = sum(r["cause"] == calibrate.cause_label(r["effect"]) for r in rows) / n
    class_ok = sum(r["cls"] == r["found_cls"] for r in rows) / n
    hidden = [r for r in rows if r["effect"] != "none"]
    gain_ok = sum(r["gain"] > 0 for r in hidden) / len(hidden)
    # the rates this method reaches on seeds 1000-1139 (the printed matrices); the bounds
    # leave room for a record or two
    assert cause_ok >= SLOW_RATES["cause"]
    assert class_ok >= SLOW_RATES["class"]
    assert gain_ok >= SLOW_RATES["gain"]


#: Measured on seeds 1000-1139 (cause 126/140, class 140/140, positive gain 113/120), less a
#: record or two.
SLOW_RATES = {"cause": 0.87, "class": 0.94, "gain": 0.90}


#: The stiction verdict on 128 synthetic plant loops held out from every design choice
#: (``generator.loop_cases(128, start=1000)``; seeds 0-127 were looked at while designing):
#: p = 1; flow, pressure, level and slow loops under PI control with load, set-point,
#: outside-oscillation and drift disturbances; records called ``stiction`` per true valve, as
#: measured once (``python -m hbench.diagnose.calibrate loops --start 1000``). Most sticking
#: valves here are hidden by the disturbances: the verdict is a check against false alarms
#: more than a detection rate.
LOOP_START = 1000
LOOP_CALLED_STICTION = {
    "stiction": (9, 64),
    "linear": (3, 16),
    "backlash": (2, 16),
    "deadband": (0, 16),
    "saturation": (2, 16),
}


@pytest.mark.slow
def test_stiction_verdict_on_synthetic_plant_loops(capsys: pytest.CaptureFixture[str]) -> None:
    rows = calibrate.parallel_map(
        calibrate.run_loop, generator.loop_cases(128, start=LOOP_START), jobs=2
    )
    assert not [r["name"] for r in rows if r["error"]]  # a crash must not pass for a "no"
    found = calibrate.loop_verdicts(rows)
    with capsys.disabled():
        print("\nstiction verdict on 128 synthetic plant loops (called stiction / records):")
        for cls, (k, n) in found.items():
            print(f"  {cls:11s} {k}/{n}")
    # one record either way for each class (a numerical library update can move a record
    # lying on a margin)
    for cls, (k, n) in LOOP_CALLED_STICTION.items():
        assert found[cls][1] == n
        if cls == "stiction":
            assert found[cls][0] >= k - 1
        else:
            assert found[cls][0] <= k + 1


def test_loop_type_breakdown_counts_hits_and_false_alarms() -> None:
    rows = [
        {"loop": "level", "cls": "stiction", "verdict": True},
        {"loop": "level", "cls": "stiction", "verdict": False},
        {"loop": "level", "cls": "backlash", "verdict": True},
        {"loop": "flow", "cls": "linear", "verdict": False},
    ]
    out = calibrate.loop_type_verdicts(rows)
    assert list(out) == list(generator.LOOP_TYPES)
    assert out["level"] == (1, 2, 1, 1)
    assert out["flow"] == (0, 0, 0, 1)
    assert out["slow"] == (0, 0, 0, 0)


def test_the_valve_position_is_returned_beside_the_record_never_in_it():
    gen = generator
    case = gen.loop_cases(1, 0)[0]
    rec, u = gen.simulate_loop_truth(case)
    np.testing.assert_array_equal(rec.y, gen.simulate_loop(case).y)
    assert u.shape == rec.x[0].shape and "u" not in rec.meta
    assert case.cls == "stiction" and np.any(u != rec.x[0])  # the valve sticks somewhere
    row = calibrate.valve_position_gain(case)
    assert np.isfinite(row["fit_x"]) and np.isfinite(row["gain_u"])

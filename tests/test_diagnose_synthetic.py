"""Hidden effects: records from :mod:`hbench.diagnose.generator` with ONE effect (or none)
written to files; the test sees only the file, runs ``hbench diagnose`` through
:func:`hbench.cli.main` and checks the named cause, the nonlinearity class and, where an effect
was hidden, a positive validation gain.

Default run: two records per effect and two nominal ones (14). They are the first two cases of
each effect in the generator's seeds 0, 1, 2, ... (``cases_per_effect(3, 0)``, 21 cases) on
which the diagnosis is right: seed 5 (time-varying; the nominal model's validation fit is 0 %
there) and seed 15 (coloured noise, named ``order``) are misses of the method and are left
out, so this is a regression check, not an accuracy estimate. The ``slow`` run diagnoses 140
records (seeds 1000-1139, none of them used to calibrate) and prints both confusion matrices.
A second ``slow`` test scores the stiction verdict of plant logs (``p = 1``) on synthetic plant
loops with known valves (:func:`hbench.diagnose.generator.loop_cases`).
"""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from hbench.diagnose import calibrate, generator

RunCli = Callable[[list[str]], tuple[int, str, str]]

#: Seeds of the default run (see the module notes): two per effect.
DEFAULT_SEEDS = (0, 7, 1, 8, 2, 9, 3, 10, 4, 11, 12, 19, 6, 13)


def _case(seed: int) -> generator.Case:
    """The case of ``seed`` in ``cases_per_effect(.., start=0)``."""
    effect = generator.EFFECTS[seed % len(generator.EFFECTS)]
    cls = generator.CLASSES[seed % len(generator.CLASSES)]
    return generator.draw_case(seed, effect, cls)


def _diagnose_file(run_cli: RunCli, path: Path, tmp: Path) -> dict:
    out = tmp / (path.stem + ".json")
    status, _, err = run_cli(["diagnose", str(path), "--json", str(out)])
    assert status == 0, err
    return json.loads(out.read_text())


def test_default_seeds_cover_every_effect_twice() -> None:
    effects = [_case(s).effect for s in DEFAULT_SEEDS]
    for e in generator.EFFECTS:
        assert effects.count(e) >= 2


@pytest.mark.parametrize("seed", DEFAULT_SEEDS)
def test_hidden_effect_is_found(run_cli: RunCli, tmp_path: Path, seed: int) -> None:
    case = _case(seed)
    path = generator.write_case(case, tmp_path)
    d = _diagnose_file(run_cli, path, tmp_path)
    assert d["cause"] == case.effect, d["effects"]
    assert d["nonlinearity"]["class"] == case.cls
    if case.effect != "none":
        assert d["gain"] > 0
    else:
        assert d["gain"] == 0


@pytest.mark.slow
def test_hidden_effects_confusion_matrix(
    run_cli: RunCli, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    cases = generator.cases_per_effect(20, start=1000)
    rows = []
    for case in cases:
        path = generator.write_case(case, tmp_path)
        d = _diagnose_file(run_cli, path, tmp_path)
        rows.append(
            {
                "effect": case.effect,
                "cls": case.cls,
                "cause": d["cause"],
                "found_cls": d["nonlinearity"]["class"],
                "gain": d["gain"],
            }
        )
        path.unlink()
    text = calibrate.report(rows)
    with capsys.disabled():
        print(f"\nhbench diagnose on {len(rows)} synthetic records (seeds 1000-1139)\n{text}")
    n = len(rows)
    cause_ok = sum(r["cause"] == calibrate.cause_label(r["effect"]) for r in rows) / n
    class_ok = sum(r["cls"] == r["found_cls"] for r in rows) / n
    hidden = [r for r in rows if r["effect"] != "none"]
    gain_ok = sum(r["gain"] > 0 for r in hidden) / len(hidden)
    # the rates this method reaches on seeds 1000-1139 (the printed matrices): cause 123/140,
    # class 130/140, positive gain 109/120; the bounds leave room for a record or two
    assert cause_ok >= 0.84
    assert class_ok >= 0.90
    assert gain_ok >= 0.88


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
    "linear": (4, 16),
    "backlash": (2, 16),
    "deadband": (0, 16),
    "saturation": (2, 16),
}


@pytest.mark.slow
def test_stiction_verdict_on_synthetic_plant_loops(capsys: pytest.CaptureFixture[str]) -> None:
    rows = [calibrate.run_loop(c) for c in generator.loop_cases(128, start=LOOP_START)]
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

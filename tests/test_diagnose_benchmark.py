"""``hbench diagnose`` on the benchmark's own loops (:mod:`hbench.diagnose.benchmark_cases`):
the paper's Section 6 loop and the built-in first-order, third-order and NMP plants under P and
PI control, every valve class with every hidden cause.

Seeds: thresholds and levels were chosen on :data:`~hbench.diagnose.benchmark_cases.
CALIBRATION_SEEDS` (10000-19999); the ``slow`` matrices below are measured on
:data:`~hbench.diagnose.benchmark_cases.HELD_OUT_SEEDS` (20000-29999), never used to choose
anything: the paper loop from seed 20000 (5 classes x 7 causes x 3 seeds), the other plants from
seed 21000 (5 x 7 x 1 each). The issue's targets (class and cause right on 90 % of records, at
most 10 % of records without an effect given a cause, a positive gain on 90 % of records with one)
are not all met yet: each is its own test, ``xfail(strict=True)`` while it is not, so meeting it
turns the suite red until the mark is removed. Printing the matrices:
``pytest tests/test_diagnose_benchmark.py -m slow -s`` (or ``python -m
hbench.diagnose.calibrate bench --start 20000 --per-cell 3 --plants paper``).
"""

from __future__ import annotations

import warnings
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from hbench.diagnose import benchmark_cases as bc
from hbench.diagnose import calibrate

PAPER_START, OTHERS_START = 20_000, 21_000


def _rate(rows: list[dict[str, Any]], ok: Callable[[dict[str, Any]], bool]) -> float:
    return sum(bool(ok(r)) for r in rows) / max(len(rows), 1)


def _class_right(r: dict[str, Any]) -> bool:
    return r["found_cls"] == r["cls"]


def _cause_right(r: dict[str, Any]) -> bool:
    return r["cause"] == calibrate.cause_label(r["effect"])


@pytest.fixture(scope="module")
def held_out_rows(request: pytest.FixtureRequest) -> dict[str, list[dict[str, Any]]]:
    paper = calibrate.run(bc.bench_grid(PAPER_START, 3, ("paper",)), jobs=2)
    others = calibrate.run(
        bc.bench_grid(OTHERS_START, 1, ("first-order", "third-order", "nmp")), jobs=2
    )
    capman = request.config.pluginmanager.getplugin("capturemanager")
    with capman.global_and_fixture_disabled():
        print(f"\nhbench diagnose on the paper loop (held-out seeds from {PAPER_START}):")
        print(calibrate.bench_summary(paper))
        print(f"\non the other benchmark plants (held-out seeds from {OTHERS_START}):")
        print(calibrate.bench_summary(others))
    return {"paper": paper, "others": others}


@pytest.mark.slow
def test_no_record_fails(held_out_rows: dict[str, list[dict[str, Any]]]) -> None:
    errors = [r for rows in held_out_rows.values() for r in rows if r["cause"] == "error"]
    assert not errors, [(r["seed"], r["error"]) for r in errors]


_TARGETS = {
    "class": (_class_right, None, 0.9),
    "cause": (_cause_right, None, 0.9),
    "gain": (lambda r: r.get("gain", 0) > 0, lambda r: r["effect"] != "none", 0.9),
    "none-kept": (lambda r: r["cause"] == "none", lambda r: r["effect"] == "none", 0.9),
}


def _target(rows: list[dict[str, Any]], which: str) -> float:
    ok, keep, _ = _TARGETS[which]
    return _rate([r for r in rows if keep is None or keep(r)], ok)


#: (group, target) pairs not met on the held-out seeds: strict xfails. The measured rates are
#: printed by the ``held_out_rows`` fixture and stated in the README, not repeated here.
NOT_MET = {
    ("paper", "class"): "valve class right on paper-loop records",
    ("paper", "cause"): "cause right on paper-loop records",
    ("paper", "gain"): "positive gain on paper-loop records with an effect",
    ("others", "class"): "valve class right on records of the other plants",
    ("others", "cause"): "cause right on records of the other plants",
    ("others", "gain"): "positive gain on records of the other plants with an effect",
    ("others", "none-kept"): "cause none on records of the other plants without an effect",
}


def _cases() -> list[Any]:
    out = []
    for group in ("paper", "others"):
        for which in _TARGETS:
            why = NOT_MET.get((group, which))
            marks = [pytest.mark.slow]
            if why:
                marks.append(pytest.mark.xfail(strict=True, reason=f"target 90 % not met: {why}"))
            out.append(pytest.param(group, which, marks=marks, id=f"{group}-{which}"))
    return out


@pytest.mark.parametrize(("group", "which"), _cases())
def test_target(held_out_rows: dict[str, list[dict[str, Any]]], group: str, which: str) -> None:
    assert _target(held_out_rows[group], which) >= _TARGETS[which][2]


def _simulate_and_diagnose(seed: int) -> tuple[int, str, dict[str, Any]]:
    """``hbench simulate --seed seed`` then ``hbench diagnose`` on its record, through the
    command line: (simulate's status and stderr, :func:`calibrate.diagnose_cli`'s answer)."""
    import contextlib
    import io
    import tempfile

    from hbench import cli

    with tempfile.TemporaryDirectory() as tmp:
        rec = Path(tmp) / f"s{seed}.csv"
        err = io.StringIO()
        with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(err):
            simulated = cli.main(["simulate", "--out", str(rec), "--seed", str(seed)])
        if simulated != 0:
            return simulated, err.getvalue(), {}
        return simulated, err.getvalue(), calibrate.diagnose_cli(rec)


@pytest.mark.slow
def test_paper_example_without_effect_is_none() -> None:
    """``hbench simulate`` defaults (the paper's example, backlash d = 0.1, sigma^2 = 1e-3),
    30 fresh seeds (3000-3029, used nowhere else): the cause is ``none`` on at least 27."""
    results = calibrate.parallel_map(_simulate_and_diagnose, range(3000, 3030), jobs=2)
    for simulated, err, diagnosed in results:
        assert simulated == 0, err
        assert diagnosed["status"] == 0, diagnosed["message"]
    causes = [diagnosed["cause"] for *_, diagnosed in results]
    print(f"\npaper example, seeds 3000-3029: causes {sorted(causes)}")
    assert causes.count("none") >= 27, causes


#: The default run's regression check: the first seven calibration seeds of the paper loop
#: with a backlash (one per cause, seeds 10000-10006), as measured.
REGRESSION_START = 10_000


def test_regression_on_the_paper_loop() -> None:
    cases = [
        bc.draw_bench_case(REGRESSION_START + i, e, "backlash", "paper")
        for i, e in enumerate(bc.EFFECTS)
    ]
    rows = calibrate.run(cases, jobs=1)
    assert not [r for r in rows if r["cause"] == "error"]
    classes = sum(r["found_cls"] == r["cls"] for r in rows)
    assert classes >= REGRESSION_CLASSES, [(r["effect"], r["found_cls"]) for r in rows]
    right = sum(_cause_right(r) for r in rows)
    assert right >= REGRESSION_CAUSES, [(r["effect"], r["cause"]) for r in rows]


#: Valve classes and causes right on the regression records, as measured (a drop fails the
#: default suite). The cause misses: drift (named delay), delay (none: the delay extension gains
#: nothing), order (colored-noise and delay both gain more than the order extension).
REGRESSION_CLASSES = 7
REGRESSION_CAUSES = 3


def test_bench_chooses_the_cause_on_the_criterion_it_is_given(monkeypatch, capsys) -> None:
    monkeypatch.setattr(calibrate, "OPTIONS", dict(calibrate.OPTIONS))
    ran: list[Any] = []
    monkeypatch.setattr(calibrate, "run", lambda cases, jobs, progress=False: ran.append(1) or [])
    with pytest.raises(SystemExit) as exc:
        calibrate.main_bench(["--criterion", "bogus"])
    err = capsys.readouterr().err
    assert exc.value.code == 2 and "unknown validation criterion" in err
    assert len(err.strip().splitlines()) == 1 and not ran  # one line, before any work
    calibrate.main_bench(["--criterion", "closed-loop", "--per-cell", "1", "--plants", "paper"])
    assert ran and calibrate.OPTIONS["criterion"] == "closed-loop"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        row = calibrate.run_case(bc.draw_bench_case(5000, "none", "linear", "third-order"))
    assert row["criterion"] == "closed-loop"

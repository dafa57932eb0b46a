"""``hbench.diagnose.calibrate.parallel_map``, through which every calibration command and
``python -m hbench.diagnose.class_ceiling`` fit their records: each call runs with one BLAS
thread, in this process and in worker processes alike, so that a row does not depend on the
machine's core count or on ``--jobs``."""

from __future__ import annotations

import warnings

import pytest
from threadpoolctl import threadpool_info, threadpool_limits

from hbench.diagnose import benchmark_cases as bc
from hbench.diagnose.calibrate import parallel_map
from hbench.diagnose.class_ceiling import run_one


def blas_threads(_: object = None) -> list[int]:
    """The BLAS libraries' thread limits of the calling process."""
    return [p["num_threads"] for p in threadpool_info() if p["user_api"] == "blas"]


def test_every_call_has_one_blas_thread_in_this_process_and_in_workers() -> None:
    with threadpool_limits(2, user_api="blas"):
        before = blas_threads()
        here = parallel_map(blas_threads, [0, 1], jobs=1)
        assert blas_threads() == before  # the process's limit as it was
    workers = parallel_map(blas_threads, [0, 1, 2], jobs=2)
    assert all(t and set(t) == {1} for t in here + workers)


def test_a_class_ceiling_row_is_the_same_whatever_the_blas_thread_count() -> None:
    """Seed 5000 (outside the calibration and held-out seeds; third-order plant, linear valve,
    no effect): the blind route's class scores and parameters are fitted outside
    ``validate.diagnose`` and differ in their 6th digit between one and two BLAS threads
    unless the call pins one."""
    case = bc.draw_bench_case(5000, "none", "linear", "third-order")
    rows = []
    for threads in (1, 2):
        with threadpool_limits(threads, user_api="blas"), warnings.catch_warnings():
            warnings.simplefilter("ignore")
            rows.append(parallel_map(run_one, [case], jobs=1)[0])
    assert rows[0]["scores"] == rows[1]["scores"]
    assert rows[0] == rows[1]


def _square(v: int) -> int:
    return v * v


@pytest.mark.parametrize("jobs", [1, 2])
def test_on_result_sees_every_result_in_order(jobs: int) -> None:
    seen: list[tuple[int, int, int]] = []
    out = parallel_map(_square, [3, 1, 2], jobs=jobs, on_result=lambda *a: seen.append(a))
    assert out == [9, 1, 4]
    assert seen == [(1, 3, 9), (2, 3, 1), (3, 3, 4)]


def test_the_progress_line_names_the_record_and_its_answer(capsys) -> None:
    from hbench.diagnose.calibrate import say_row

    row = {"seed": 20011, "plant": "paper", "p": 5, "cls": "backlash", "effect": "drift"}
    say_row(2, 105, {**row, "found_cls": "backlash", "cause": "drift", "seconds": 3.24})
    say_row(3, 105, {**row, "cause": "error", "error": "MethodError: no estimate"})
    err = capsys.readouterr().err.splitlines()
    assert err[0] == (
        "[calibrate 2/105] seed 20011 paper p=5 backlash / drift: class backlash, cause drift "
        "(3.2 s)"
    )
    assert err[1].endswith("backlash / drift: MethodError: no estimate")

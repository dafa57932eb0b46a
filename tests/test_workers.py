"""hbench.workers: worker processes forked per cell or kept for a scope (issue 7).

The kept scope must give the rows of one process, reuse its workers between cells, never run a
cell with code the parent no longer has (for the cell's method classes), and never hang when a
worker dies.
"""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from dataclasses import dataclass, field

import pandas as pd
import pytest

from hbench import workers

pytestmark = pytest.mark.skipif(
    "fork" not in __import__("multiprocessing").get_all_start_methods(),
    reason="worker processes are forked (no fork start method here)",
)
PIECES = [(0, 2), (2, 2), (4, 2), (6, 2), (8, 2), (10, 2)]


class Tag:
    """A stand-in for a method class: what kept workers compute comes from its code."""

    def value(self) -> str:
        return "old"


@dataclass
class Work:
    parent: int
    methods: dict[str, object] = field(default_factory=dict)


def whose(work: Work, start: int, n: int) -> tuple[int, int, int, str]:
    """The chunk, the process that computed it, and what the method class says there."""
    value = work.methods["m"].value() if work.methods else ""
    return start, n, os.getpid(), value


def dies_in_a_worker(work: Work, start: int, n: int) -> tuple[int, int, int, str]:
    if os.getpid() != work.parent:
        os._exit(3)  # as if killed by the OOM killer mid-chunk
    return whose(work, start, n)


def _run(fn, work, classes=()):
    return list(workers.map_chunks(fn, work, PIECES, 2, classes=classes))


def test_kept_workers_are_reused_between_cells_and_closed_with_the_scope():
    work = Work(os.getpid())
    with workers.kept_workers():
        first, second = _run(whose, work), _run(whose, work)
        kept = set(workers._SCOPE.pool._processes)
        with workers.kept_workers():  # nested: the outer scope's workers serve
            third = _run(whose, work)
    assert [c[:2] for c in first] == PIECES == [c[:2] for c in second]
    pids = [{c[2] for c in cell[1::2]} for cell in (first, second, third)]
    assert pids[0] == pids[1] == pids[2] and os.getpid() not in pids[0]
    assert {c[2] for c in first[0::2]} == {os.getpid()}  # every other chunk here (warm)
    assert workers._SCOPE is None and kept == pids[0]
    for pid in kept:  # shut down and reaped with the scope
        with pytest.raises(ProcessLookupError):
            os.kill(pid, 0)


def test_without_a_scope_every_cell_forks_its_own_workers():
    work = Work(os.getpid())
    a, b = _run(whose, work), _run(whose, work)
    assert {c[2] for c in a[1::2]}.isdisjoint({c[2] for c in b[1::2]})


def test_a_redefined_method_class_is_not_run_with_the_workers_old_code(monkeypatch):
    """The workers were forked with the old ``Tag``; after the class is redefined in its module
    (as in a notebook), the cell must compute with the new one, and the next cell's workers are
    forked anew."""
    with workers.kept_workers():
        old = _run(whose, Work(os.getpid(), {"m": Tag()}), classes=[Tag])
        assert {c[3] for c in old} == {"old"}

        class Tag2:
            def value(self) -> str:
                return "new"

        Tag2.__module__, Tag2.__qualname__, Tag2.__name__ = __name__, "Tag", "Tag"
        monkeypatch.setattr(sys.modules[__name__], "Tag", Tag2)
        work = Work(os.getpid(), {"m": Tag2()})
        new = _run(whose, work, classes=[Tag2])
        assert {c[3] for c in new} == {"new"}
        again = _run(whose, work, classes=[Tag2])  # fresh workers: they have the new class
    assert {c[3] for c in again} == {"new"}
    assert os.getpid() not in {c[2] for c in again[1::2]}
    assert {c[2] for c in again[1::2]}.isdisjoint({c[2] for c in old[1::2]})


def test_work_that_does_not_pickle_is_computed_by_workers_forked_for_the_cell():
    class Local:  # defined in a function: pickle cannot name it
        def value(self) -> str:
            return "local"

    work = Work(os.getpid(), {"m": Local()})
    with workers.kept_workers():
        out = _run(whose, work, classes=[Local])
        assert workers._SCOPE.pool is None  # no kept worker was started
    assert {c[3] for c in out} == {"local"} and [c[:2] for c in out] == PIECES
    assert os.getpid() not in {c[2] for c in out[1::2]}


def test_a_worker_dying_mid_cell_loses_no_chunk():
    work = Work(os.getpid())
    with workers.kept_workers():
        with pytest.warns(RuntimeWarning, match="kept worker process died"):
            out = _run(dies_in_a_worker, work)
        assert [c[:2] for c in out] == PIECES and {c[2] for c in out} == {os.getpid()}
        after = _run(whose, work)  # the next cell forks new workers
    assert os.getpid() not in {c[2] for c in after[1::2]}


def test_a_worker_killed_while_idle_does_not_hang_the_next_cell(tmp_path):
    """Session 9's kept ``multiprocessing.Pool`` waited forever here: run in a subprocess with a
    time limit so a regression fails instead of hanging the suite."""
    script = textwrap.dedent(
        """
        import os, signal, time, warnings
        from hbench import workers
        from tests.test_workers import PIECES, Work, whose
        work = Work(os.getpid())
        with workers.kept_workers():
            first = list(workers.map_chunks(whose, work, PIECES, 2))
            (pid,) = {c[2] for c in first[1::2]}
            os.kill(pid, signal.SIGKILL)
            time.sleep(0.5)
            with warnings.catch_warnings():
                warnings.simplefilter("error")  # nothing was lost: no warning expected
                second = list(workers.map_chunks(whose, work, PIECES, 2))
        assert [c[:2] for c in second] == PIECES
        assert pid not in {c[2] for c in second}
        print("ok")
        """
    )
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    done = subprocess.run(
        [sys.executable, "-c", script],
        cwd=root,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode == 0 and done.stdout.strip() == "ok", done.stderr


def test_run_cell_in_a_kept_scope_gives_the_rows_of_one_process():
    """Two different cells (other scenario, other methods) through the same kept workers."""
    from hbench import scenarios
    from hbench.runner import methods_from_names, run_cell
    from tests.helpers import paper_spec

    key = ["method", "run", "quantity"]

    def rows(sc, methods, **kw):
        r = run_cell(sc, methods, 8, 5, **kw).rows
        return r[r["quantity"] != "seconds"].sort_values(key).reset_index(drop=True)

    cells = [
        (scenarios.build(paper_spec(duration=60.0)), methods_from_names(["wang-lsm", "bai-fu"])),
        (
            scenarios.build(paper_spec(duration=60.0, nonlinearity__name="stiction")),
            methods_from_names(["wang-iv", "oracle"]),
        ),
    ]
    ref = [rows(sc, m) for sc, m in cells]
    with workers.kept_workers():
        kept = [rows(sc, m, jobs=2, chunk=2) for sc, m in cells]
    for a, b in zip(ref, kept, strict=True):
        assert len(a) > 0
        pd.testing.assert_frame_equal(a, b, check_exact=True)

"""hbench.bench.workers: worker processes forked per cell or kept for a scope.

The kept scope must give the rows of one process, reuse its workers between cells, never run a
cell with code or settings the parent no longer has, never hang or leave processes behind when
a worker or the parent dies or is interrupted, and lose nothing a worker logs or warns.
"""

from __future__ import annotations

import contextlib
import ctypes
import logging
import os
import re
import signal
import subprocess
import sys
import textwrap
import threading
import time
import warnings
from dataclasses import dataclass, field

import pandas as pd
import pytest

from hbench.bench import workers
from hbench.numerics import kernels

pytestmark = pytest.mark.skipif(
    "fork" not in __import__("multiprocessing").get_all_start_methods(),
    reason="worker processes are forked (no fork start method here)",
)
PIECES = [(0, 2), (2, 2), (4, 2), (6, 2), (8, 2), (10, 2)]
ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SUFFIX = "-v1"  # a module constant the chunks read (patched by a test)


class Tag:
    """A stand-in for a method class: what kept workers compute comes from its code."""

    factor = 1

    def value(self) -> str:
        return f"old{self.factor}{helper()}"


def helper() -> str:
    return SUFFIX


@dataclass
class Work:
    parent: int
    methods: dict[str, object] = field(default_factory=dict)
    payload: object = None


def whose(work: Work, start: int, n: int) -> tuple[int, int, int, str]:
    """The chunk, the process that computed it, and what the method class says there."""
    value = work.methods["m"].value() if work.methods else ""
    return start, n, os.getpid(), value


def dies_in_a_worker(work: Work, start: int, n: int) -> tuple[int, int, int, str]:
    if os.getpid() != work.parent:
        os._exit(3)  # as if killed by the OOM killer mid-chunk
    return whose(work, start, n)


def talks(work: Work, start: int, n: int) -> tuple[int, int, int, str]:
    logging.getLogger("hbench.test_workers").warning("chunk %d logs", start)
    warnings.warn(f"chunk {start} warns", UserWarning, stacklevel=1)
    return whose(work, start, n)


def warns_in_a_worker(work: Work, start: int, n: int) -> tuple[int, int, int, str]:
    if os.getpid() != work.parent:
        warnings.warn(f"chunk {start} warns", UserWarning, stacklevel=1)
    return whose(work, start, n)


def logs_badly(work: Work, start: int, n: int) -> tuple[int, int, int, str]:
    log = logging.getLogger("hbench.test_workers")
    if os.getpid() != work.parent:  # (pytest's log capture raises on a bad call here)
        log.warning("value %d", "not a number")  # logging reports it and goes on
    log.warning("with a lock", extra={"lock": threading.Lock()})  # does not pickle
    return whose(work, start, n)


def backend(work: Work, start: int, n: int) -> tuple[int, int, int, str]:
    return start, n, os.getpid(), kernels._asked()


def slow(work: Work, start: int, n: int) -> tuple[int, int, int, str]:
    time.sleep(3.0)
    return whose(work, start, n)


def _run(fn, work):
    return list(workers.map_chunks(fn, work, PIECES, 2))


def _pids(cell):
    return {c[2] for c in cell[3:]}  # the chunks the workers computed (after this process's)


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    return True


def test_kept_workers_are_reused_between_cells_and_closed_with_the_scope():
    work = Work(os.getpid())
    with workers.kept_workers() as scope:
        first, second = _run(whose, work), _run(whose, work)
        kept = {proc.pid for proc in scope.processes}
        with workers.kept_workers() as inner:  # nested: the outer scope's workers serve
            third = _run(whose, work)
        assert inner is scope
    assert [c[:2] for c in first] == PIECES == [c[:2] for c in second]
    assert _pids(first) == _pids(second) == _pids(third) == kept
    assert os.getpid() not in kept
    assert {c[2] for c in first[:3]} == {os.getpid()}  # the first half here, in order
    assert scope.stats == {"remote": 9, "forks": 1, "fallback": 0}
    assert workers._SCOPE is None and not any(_alive(pid) for pid in kept)


def test_without_a_scope_every_cell_forks_its_own_workers():
    work = Work(os.getpid())
    a, b = _run(whose, work), _run(whose, work)
    assert _pids(a).isdisjoint(_pids(b)) and os.getpid() not in _pids(a)


@pytest.mark.parametrize("change", ["class", "attribute", "helper", "constant"])
def test_code_changed_after_the_fork_is_not_run_by_the_old_workers(monkeypatch, change):
    """The workers were forked with the old code; after a change in the test module (as in a
    notebook: a class redefined, a class attribute, a helper function or a constant patched)
    the cell must compute with the new code everywhere, through workers forked anew."""
    module = sys.modules[__name__]
    with workers.kept_workers() as scope:
        old = _run(whose, Work(os.getpid(), {"m": Tag()}))
        assert {c[3] for c in old} == {"old1-v1"}
        cls = Tag
        if change == "class":

            class Tag2:
                factor = 1

                def value(self) -> str:
                    return "new"

            Tag2.__module__, Tag2.__qualname__, Tag2.__name__ = __name__, "Tag", "Tag"
            monkeypatch.setattr(module, "Tag", Tag2)
            cls, expected = Tag2, "new"
        elif change == "attribute":
            monkeypatch.setattr(Tag, "factor", 2)
            expected = "old2-v1"
        elif change == "helper":
            monkeypatch.setattr(module, "helper", lambda: "-patched")
            expected = "old1-patched"
        else:
            monkeypatch.setattr(module, "SUFFIX", "-v2")
            expected = "old1-v2"
        new = _run(whose, Work(os.getpid(), {"m": cls()}))
        again = _run(whose, Work(os.getpid(), {"m": cls()}))
    assert {c[3] for c in new} == {c[3] for c in again} == {expected}
    assert _pids(new).isdisjoint(_pids(old)) and os.getpid() not in _pids(new)
    assert _pids(again) == _pids(new)  # no change since: the same workers
    assert scope.stats["forks"] == 2 and scope.stats["fallback"] == 0


@pytest.mark.parametrize("kind", ["local class", "ctypes pointer"])
def test_work_that_does_not_pickle_is_computed_by_workers_forked_for_the_cell(kind):
    class Local:  # defined in a function: pickle cannot name it
        def value(self) -> str:
            return "local"

    if kind == "local class":
        work = Work(os.getpid(), {"m": Local()})
    else:  # pickling a ctypes pointer raises ValueError
        work = Work(os.getpid(), payload=ctypes.pointer(ctypes.c_int(3)))
    with workers.kept_workers() as scope:
        out = _run(whose, work)
        assert scope.pool is None  # no kept worker was started
    assert [c[:2] for c in out] == PIECES and os.getpid() not in _pids(out)


def test_large_work_reaches_kept_workers_through_a_file_once_per_cell(tmp_path, monkeypatch):
    monkeypatch.setattr("tempfile.tempdir", str(tmp_path))
    work = Work(os.getpid(), payload=b"x" * (workers.INLINE_LIMIT + 1))
    with workers.kept_workers() as scope:
        out = _run(whose, work)
    assert [c[:2] for c in out] == PIECES and scope.stats["remote"] == 3
    assert not list(tmp_path.iterdir())  # the cell's file is removed after it


def test_the_kernel_backend_of_each_cell_reaches_kept_workers():
    with workers.kept_workers():
        first = _run(backend, Work(os.getpid()))
        with kernels.use("numpy"):
            second = _run(backend, Work(os.getpid()))
    assert {c[3] for c in first} == {kernels._asked()}
    assert {c[3] for c in second} == {"numpy"} and _pids(first) == _pids(second)


@pytest.mark.parametrize("kept", [True, False])
def test_what_a_worker_logs_and_warns_is_replayed_here_in_chunk_order(caplog, kept):
    with workers.kept_workers() if kept else contextlib.nullcontext():
        with caplog.at_level(logging.WARNING, logger="hbench.test_workers"):
            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter("always")
                out = _run(talks, Work(os.getpid()))
    assert os.getpid() not in _pids(out)
    starts = [s for s, _ in PIECES]
    assert [r.getMessage() for r in caplog.records] == [f"chunk {s} logs" for s in starts]
    assert [str(w.message) for w in caught] == [f"chunk {s} warns" for s in starts]


def test_a_worker_dying_mid_cell_loses_no_chunk():
    work = Work(os.getpid())
    with workers.kept_workers() as scope:
        with pytest.warns(RuntimeWarning, match="kept worker process died"):
            out = _run(dies_in_a_worker, work)
        assert [c[:2] for c in out] == PIECES and {c[2] for c in out} == {os.getpid()}
        after = _run(whose, work)  # the next cell forks new workers
    assert os.getpid() not in _pids(after)
    assert scope.stats["fallback"] == 1 and scope.stats["forks"] == 2


def _script(body: str) -> subprocess.CompletedProcess[str]:
    """``body`` in a fresh interpreter with a time limit: a hang fails instead of hanging the
    suite."""
    return subprocess.run(
        [sys.executable, "-c", textwrap.dedent(body)],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=120,
    )


def test_a_worker_killed_while_idle_does_not_hang_the_next_cell():
    """A kept ``multiprocessing.Pool`` would wait forever here (``concurrent.futures`` raises)."""
    body = """
        import os, signal, time, warnings
        from hbench.bench import workers
        from tests.test_workers import PIECES, Work, whose
        work = Work(os.getpid())
        with workers.kept_workers():
            first = list(workers.map_chunks(whose, work, PIECES, 2))
            (pid,) = {c[2] for c in first[3:]}
            os.kill(pid, signal.SIGKILL)
            time.sleep(0.5)
            with warnings.catch_warnings():
                warnings.simplefilter("error")  # nothing was lost: no warning expected
                second = list(workers.map_chunks(whose, work, PIECES, 2))
        assert [c[:2] for c in second] == PIECES
        assert pid not in {c[2] for c in second}
        print("ok")
        """
    done = _script(body)
    assert done.returncode == 0 and done.stdout.strip() == "ok", done.stderr


def _start(body: str) -> tuple[subprocess.Popen[str], list[int]]:
    """``body`` in a fresh interpreter that prints its kept workers' pids on one line."""
    proc = subprocess.Popen(
        [sys.executable, "-c", textwrap.dedent(body)],
        cwd=ROOT,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    kids = [int(v) for v in proc.stdout.readline().split()]
    if not kids:
        proc.kill()
        pytest.fail(proc.communicate()[1])
    return proc, kids


def test_ctrl_c_ends_the_scope_at_once_and_leaves_no_worker():
    """Two SIGINTs 0.1 s apart during 3 s chunks (a review found this hung): the process exits
    well before its queued chunks would have ended, and its workers are gone."""
    proc, kids = _start(
        """
        import os, threading, time
        from hbench.bench import workers
        from tests.test_workers import PIECES, Work, slow
        with workers.kept_workers() as scope:
            def report():
                time.sleep(1.0)
                print(*(proc.pid for proc in scope.processes), flush=True)
            threading.Thread(target=report, daemon=True).start()
            list(workers.map_chunks(slow, Work(os.getpid()), PIECES, 2))
        """
    )
    try:
        t0 = time.monotonic()
        proc.send_signal(signal.SIGINT)
        time.sleep(0.1)
        proc.send_signal(signal.SIGINT)
        proc.wait(timeout=30)
        waited = time.monotonic() - t0
    finally:
        proc.kill()
    assert proc.returncode != 0 and waited < 3.0, waited
    deadline = time.monotonic() + 5
    while any(_alive(pid) for pid in kids) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert not any(_alive(pid) for pid in kids)


def test_kept_workers_exit_when_their_parent_is_killed():
    proc, kids = _start(
        """
        import os, time
        from hbench.bench import workers
        from tests.test_workers import PIECES, Work, whose
        with workers.kept_workers() as scope:
            list(workers.map_chunks(whose, Work(os.getpid()), PIECES, 2))
            print(*(proc.pid for proc in scope.processes), flush=True)
            time.sleep(60)  # between cells
        """
    )
    try:
        assert all(_alive(pid) for pid in kids)
    finally:
        proc.kill()
        proc.wait()
    deadline = time.monotonic() + 10
    while any(_alive(pid) for pid in kids) and time.monotonic() < deadline:
        time.sleep(0.1)
    left = [pid for pid in kids if _alive(pid)]
    for pid in left:  # never leave them behind, even when failing
        os.kill(pid, signal.SIGKILL)
    assert not left


def test_run_cell_in_a_kept_scope_gives_the_rows_of_one_process():
    """Two different cells (other scenario, other methods) through the same kept workers,
    twice each: no fork after the first, every cell's worker chunks computed by them."""
    from hbench.bench.runner import methods_from_names, run_cell
    from hbench.sim import scenarios
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
    with workers.kept_workers() as scope:
        kept = [rows(sc, m, jobs=2, chunk=2) for sc, m in cells * 2]
    assert scope.stats["remote"] == 8 and scope.stats["fallback"] == 0  # 2 of 4 chunks x 4
    assert scope.stats["forks"] == 2  # the second cell's plugin packages were not watched yet
    for a, b in zip(ref * 2, kept, strict=True):
        assert len(a) > 0
        pd.testing.assert_frame_equal(a, b, check_exact=True)


@pytest.mark.parametrize("kept", [True, False])
def test_a_bad_log_call_in_a_worker_does_not_fail_the_cell(caplog, kept):
    with workers.kept_workers() if kept else contextlib.nullcontext():
        with caplog.at_level(logging.WARNING, logger="hbench.test_workers"):
            out = _run(logs_badly, Work(os.getpid()))
    assert [c[:2] for c in out] == PIECES
    locks = [r for r in caplog.records if r.getMessage() == "with a lock"]
    assert len(locks) == len(PIECES)  # every chunk's record, this process's as they are
    assert all(isinstance(r.lock, str) for r in locks if os.getpid() != r.process)


@pytest.mark.parametrize("kept", [True, False])
def test_a_module_filter_applies_to_a_workers_warnings(kept):
    """``-W error::UserWarning:tests.test_workers`` (pytest's filterwarnings) must turn a
    worker's warning into an error as it would this process's."""
    with workers.kept_workers() if kept else contextlib.nullcontext():
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            warnings.filterwarnings("error", category=UserWarning, module=re.escape(__name__))
            with pytest.raises(UserWarning, match="chunk 6 warns"):
                _run(warns_in_a_worker, Work(os.getpid()))


def test_orphan_files_of_dead_processes_are_removed_by_the_next_scope(tmp_path, monkeypatch):
    monkeypatch.setattr("tempfile.tempdir", str(tmp_path))
    dead = subprocess.run(
        [sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True
    ).stdout.strip()
    orphan = tmp_path / f"hbench-cell-{dead}-abc.pkl"
    mine = tmp_path / f"hbench-cell-{os.getpid()}-abc.pkl"
    orphan.write_bytes(b"x")
    mine.write_bytes(b"x")
    with workers.kept_workers():
        pass
    assert not orphan.exists() and mine.exists()


def test_a_scripts_loop_variables_do_not_refork_kept_workers():
    """A method class and the cell loop in ``__main__`` (a script, a notebook): rebinding the
    loop variable between cells is not a code change."""
    body = """
        import os
        from hbench.bench import workers
        from tests.test_workers import PIECES

        class Method:
            def value(self):
                return "main"

        def chunk(work, start, n):
            return start, n, os.getpid(), work.value()

        with workers.kept_workers() as scope:
            for i in range(3):
                out = list(workers.map_chunks(chunk, Method(), PIECES, 2))
                assert {c[3] for c in out} == {"main"}
        print(scope.stats["forks"], scope.stats["remote"])
        """
    done = _script(body)
    assert done.returncode == 0, done.stderr
    assert done.stdout.split() == ["1", "9"]

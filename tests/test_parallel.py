"""hbench.bench.parallel: one standard executor for a cell's chunks, per cell or kept for a scope.

A cell's rows must be those of one process whatever the processes and the chunking; a worker's
logs, warnings and errors must reach this process; a dying worker must lose no chunk and hang
nothing; a kept scope must reuse its workers and leave none behind.
"""

from __future__ import annotations

import contextlib
import logging
import multiprocessing as mp
import os
import subprocess
import sys
import textwrap
import warnings
from dataclasses import dataclass, field

import pandas as pd
import pytest

from hbench.bench import parallel
from hbench.errors import InputError
from hbench.numerics import kernels

pytestmark = pytest.mark.skipif(
    "fork" not in mp.get_all_start_methods(),
    reason="hbench's worker processes are forked (no fork start method here)",
)
PIECES = [(0, 2), (2, 2), (4, 2), (6, 2), (8, 2), (10, 2)]
ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


@dataclass
class Work:
    parent: int
    payload: dict[str, object] = field(default_factory=dict)


def whose(work: Work, start: int, n: int) -> tuple[int, int, int, str]:
    """The chunk, the process that computed it, and the kernel backend asked for there."""
    return start, n, os.getpid(), kernels._asked()


def blas_threads(work: Work, start: int, n: int) -> tuple[int, int, int, list[int]]:
    from threadpoolctl import threadpool_info

    threads = [p["num_threads"] for p in threadpool_info() if p["user_api"] == "blas"]
    return start, n, os.getpid(), threads


def dies_in_a_worker(work: Work, start: int, n: int) -> tuple[int, int, int, str]:
    if os.getpid() != work.parent:
        os._exit(3)  # as if killed by the OOM killer mid-chunk
    return whose(work, start, n)


def fails_in_a_worker(work: Work, start: int, n: int) -> tuple[int, int, int, str]:
    if os.getpid() != work.parent:
        raise ValueError(f"chunk {start} is bad")
    return whose(work, start, n)


def input_error_in_a_worker(work: Work, start: int, n: int) -> tuple[int, int, int, str]:
    if os.getpid() != work.parent:
        raise InputError("a bad option")
    return whose(work, start, n)


def talks(work: Work, start: int, n: int) -> tuple[int, int, int, str]:
    logging.getLogger("hbench.test_parallel").warning("chunk %d logs", start)
    warnings.warn(f"chunk {start} warns", UserWarning, stacklevel=1)
    return whose(work, start, n)


def _run(fn, work, jobs=2):
    return list(parallel.map_chunks(fn, work, PIECES, jobs))


def _pids(cell):
    return {c[2] for c in cell[3:]}  # the chunks the workers computed (after this process's)


def _scope(kept: bool):
    return parallel.kept_workers() if kept else contextlib.nullcontext()


@pytest.mark.parametrize("jobs", [2, 3])
def test_this_process_computes_its_share_first_and_the_workers_the_rest(jobs):
    out = _run(whose, Work(os.getpid()), jobs)
    assert [c[:2] for c in out] == PIECES
    mine = len(PIECES) // jobs
    assert {c[2] for c in out[:mine]} == {os.getpid()}
    assert os.getpid() not in {c[2] for c in out[mine:]}
    assert len({c[2] for c in out[mine:]}) <= jobs - 1


@pytest.mark.parametrize("kept", [True, False])
def test_workers_compute_with_one_blas_thread_and_this_processs_kernel_backend(kept):
    with _scope(kept):
        threads = _run(blas_threads, Work(os.getpid()))
        with kernels.use("numpy"):
            backends = _run(whose, Work(os.getpid()))
    assert all(c[3] and set(c[3]) == {1} for c in threads[3:])
    assert {c[3] for c in backends} == {"numpy"}


def test_a_kept_scope_reuses_its_workers_and_ends_them_with_it():
    with parallel.kept_workers():
        a = _run(whose, Work(os.getpid()))
        with parallel.kept_workers():  # nested: the outer scope's workers serve
            b = _run(whose, Work(os.getpid()))
        workers = [p for p in mp.active_children() if p.pid in _pids(a)]
        assert workers
    assert _pids(a) == _pids(b) and os.getpid() not in _pids(a)
    for proc in workers:
        proc.join(timeout=10)
        assert not proc.is_alive()


def test_without_a_scope_every_cell_starts_its_own_workers():
    a, b = _run(whose, Work(os.getpid())), _run(whose, Work(os.getpid()))
    assert _pids(a).isdisjoint(_pids(b)) and os.getpid() not in _pids(a)


def test_work_that_does_not_pickle_is_computed_by_workers_started_for_the_cell():
    class Local:  # defined in a function: pickle cannot name it
        pass

    with parallel.kept_workers():
        out = _run(whose, Work(os.getpid(), {"m": Local()}))
    assert [c[:2] for c in out] == PIECES and os.getpid() not in _pids(out)


@pytest.mark.parametrize("kept", [True, False])
def test_a_worker_dying_mid_cell_loses_no_chunk_and_hangs_nothing(kept):
    work = Work(os.getpid())
    with _scope(kept):
        with pytest.warns(RuntimeWarning, match="worker process died"):
            out = _run(dies_in_a_worker, work)
        assert [c[:2] for c in out] == PIECES and {c[2] for c in out} == {os.getpid()}
        after = _run(whose, work)  # the next cell has live workers again
    assert [c[:2] for c in after] == PIECES and os.getpid() not in _pids(after)


@pytest.mark.parametrize("kept", [True, False])
def test_a_workers_error_is_raised_here_with_its_traceback(kept):
    with _scope(kept), pytest.raises(RuntimeError, match="failed in a worker process") as info:
        _run(fails_in_a_worker, Work(os.getpid()))
    text = str(info.value)
    assert "runs 6..7" in text  # the first worker chunk, in chunk order
    assert "ValueError: chunk 6 is bad" in text and "fails_in_a_worker" in text


def test_hbench_input_errors_from_a_worker_are_raised_as_they_are():
    with pytest.raises(InputError, match="a bad option"):
        _run(input_error_in_a_worker, Work(os.getpid()))


@pytest.mark.parametrize("kept", [True, False])
def test_what_a_worker_logs_and_warns_is_issued_here_in_chunk_order(caplog, kept):
    with _scope(kept):
        with caplog.at_level(logging.WARNING, logger="hbench.test_parallel"):
            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter("always")
                out = _run(talks, Work(os.getpid()))
    assert os.getpid() not in _pids(out)
    starts = [s for s, _ in PIECES]
    assert [r.getMessage() for r in caplog.records] == [f"chunk {s} logs" for s in starts]
    assert [str(w.message) for w in caught] == [f"chunk {s} warns" for s in starts]
    assert {w.filename for w in caught} == {__file__}


def test_kept_workers_exit_when_their_parent_is_killed():
    """A parent killed mid-scope (SIGKILL: no clean-up runs) leaves no worker behind."""
    body = f"""
        import os, sys
        sys.path.insert(0, {ROOT!r})
        from hbench.bench import parallel
        from tests.test_parallel import PIECES, Work, whose
        with parallel.kept_workers():
            out = list(parallel.map_chunks(whose, Work(os.getpid()), PIECES, 2))
            print(*sorted({{c[2] for c in out[3:]}}), flush=True)
            os.kill(os.getpid(), 9)
    """
    done = subprocess.run(
        [sys.executable, "-c", textwrap.dedent(body)], capture_output=True, text=True, timeout=120
    )
    pids = [int(p) for p in done.stdout.split()]
    assert pids, done.stderr
    for pid in pids:
        for _ in range(100):
            try:
                os.kill(pid, 0)
            except ProcessLookupError:
                break
            __import__("time").sleep(0.1)
        else:
            pytest.fail(f"worker {pid} outlived its parent")


def test_run_cell_gives_the_rows_of_one_process_whatever_the_processes_and_chunks():
    from hbench.bench.runner import methods_from_names, run_cell
    from hbench.sim import scenarios
    from tests.helpers import paper_spec

    key = ["method", "run", "quantity"]
    sc = scenarios.build(paper_spec(duration=60.0))
    methods = methods_from_names(["wang-lsm", "bai-fu"])

    def rows(**kw):
        r = run_cell(sc, methods, 9, 5, **kw).rows
        return r[r["quantity"] != "seconds"].sort_values(key).reset_index(drop=True)

    ref = rows()
    assert len(ref) > 0
    with parallel.kept_workers():
        kept = [rows(jobs=2, chunk=2), rows(jobs=3, chunk=4)]
    alone = [rows(jobs=2, chunk=3), rows(jobs=1, chunk=2)]
    for other in (*kept, *alone):
        pd.testing.assert_frame_equal(ref, other, check_exact=True)

"""Processes computing a cell's chunks (issue 7): forked for one cell, or kept for a scope.

:func:`hbench.runner.run_cell` with ``jobs = n > 1`` computes every n-th chunk in this process
and the others in ``n - 1`` worker processes; every run draws from its own stream and its numbers
do not depend on the runs batched with it, so the rows are the same whatever the processes.

* **Forked for the cell** (the default). The workers are forked when the cell starts and end
  with it: they see exactly the code and objects of that moment, and nothing outlives the cell.
  The price is per cell: after the fork every page of this process's heap is copy-on-write in
  both processes (~36 000 page faults and ~0.17 s of system time for a 1000-run cell of the
  paper's example), so two processes gave 70-78 % of what two independent processes give.
* **Kept for a scope** (:func:`kept_workers`). Inside ``with kept_workers():`` the workers are
  forked at the first cell with ``jobs > 1`` and kept until the scope ends; each cell's work is
  pickled once and sent with its chunks, and a worker unpickles it once per cell. ``hbench
  sweep`` opens this scope around its jobs (a sweep is a finished program running many cells).

  - *Code.* Kept workers run the modules as they were when forked. The classes of the cell's
    methods are checked: a method class the workers do not have, or whose functions' code
    differs from this process's (a class redefined in a notebook), makes the workers be forked
    anew for that cell. Other changes (a module function patched after the first cell) are not
    seen by the workers, nor are environment variables set after the fork (the kernels'
    ``HBENCH_KERNELS``: the same numbers either way): open the scope around a finished program,
    not around an editing session.
  - *Work that does not pickle* (a method class defined inside a function) is computed by
    workers forked for that cell, as by default: the same rows.
  - *A dead worker* (the OOM killer, a signal) never hangs the cell: :mod:`concurrent.futures`
    reports it, the chunks it had are computed in this process with a :class:`RuntimeWarning`,
    and the next cell forks new workers.

Processes are forked, so this needs the ``fork`` start method (Linux, macOS); elsewhere every
chunk is computed in this process. One thread of a process at a time may use a scope.
"""

from __future__ import annotations

import contextlib
import hashlib
import itertools
import marshal
import multiprocessing as mp
import pickle
import traceback
import warnings
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import Future, ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from typing import Any

from hbench.errors import InputError
from hbench.runtime import batch_settings

#: ``fn(work, start, n)``: computes runs ``start .. start + n - 1`` of a cell.
ChunkFn = Callable[[Any, int, int], Any]
Piece = tuple[int, int]


def map_chunks(
    fn: ChunkFn, work: Any, pieces: Sequence[Piece], jobs: int, classes: Sequence[type] = ()
) -> Iterator[Any]:
    """``fn(work, *piece)`` for every piece, in order; with ``jobs > 1`` computed by this process
    (every ``jobs``-th piece: its memory is warm) and ``jobs - 1`` worker processes.

    Parameters
    ----------
    fn : callable
        ``fn(work, start, n)``, a module-level function (kept workers receive it pickled).
    work : object
        What every piece needs; shared with forked workers, pickled for kept ones.
    pieces : sequence of (start, n)
        The chunks.
    jobs : int
        Processes, this one included.
    classes : sequence of type
        Classes whose code kept workers must share with this process (the cell's methods');
        see the module docstring.
    """
    if jobs <= 1 or len(pieces) < 2 or "fork" not in mp.get_all_start_methods():
        for piece in pieces:
            yield fn(work, *piece)
        return
    jobs = min(jobs, len(pieces))
    if _SCOPE is not None:
        blob = _pickled(fn, work, tuple(classes))
        if blob is not None:
            yield from _SCOPE.map(fn, work, blob, _fingerprint(classes), pieces, jobs)
            return
    yield from _fork_for_cell(fn, work, pieces, jobs)


# --- forked for one cell ---------------------------------------------------------------------

_FORKED: tuple[ChunkFn, Any] | None = None


def _guarded(fn: ChunkFn, work: Any, piece: Piece) -> Any:
    """A worker's chunk; an exception that could not be unpickled would break the pool, so any
    but hbench's own (one-line messages, exit status 2) travels back as text."""
    try:
        return fn(work, *piece)
    except InputError:
        raise
    except BaseException as exc:
        raise RuntimeError(
            f"runs {piece[0]}..{piece[0] + piece[1] - 1} failed in a worker process:\n"
            + "".join(traceback.format_exception(exc))
        ) from None


def _forked_chunk(piece: Piece) -> Any:
    assert _FORKED is not None
    return _guarded(*_FORKED, piece)


def _fork_for_cell(fn: ChunkFn, work: Any, pieces: Sequence[Piece], jobs: int) -> Iterator[Any]:
    global _FORKED
    mine = set(range(0, len(pieces), jobs))
    theirs = [piece for i, piece in enumerate(pieces) if i not in mine]
    _FORKED = (fn, work)
    try:
        with mp.get_context("fork").Pool(jobs - 1) as pool:
            done = pool.imap(_forked_chunk, theirs)  # dispatched at once, computed meanwhile
            for i, piece in enumerate(pieces):
                yield fn(work, *piece) if i in mine else next(done)
    finally:
        _FORKED = None


# --- kept for a scope ------------------------------------------------------------------------


class _Stale(Exception):
    """A kept worker cannot run a cell's work as this process would (see the module docstring)."""


def _pickled(fn: ChunkFn, work: Any, classes: tuple[type, ...]) -> bytes | None:
    """What a kept worker needs of a cell, or ``None`` where it does not pickle (classes and
    functions travel by reference to their module, so a kept worker uses its own)."""
    try:
        return pickle.dumps((fn, work, classes), protocol=pickle.HIGHEST_PROTOCOL)
    except (pickle.PicklingError, AttributeError, TypeError):
        return None


def _fingerprint(classes: Sequence[type]) -> str:
    """A hash of the code of the functions defined in ``classes`` and their bases."""
    h = hashlib.sha256()
    for cls in classes:
        for klass in cls.__mro__:
            if klass is object:
                continue
            h.update(f"{klass.__module__}.{klass.__qualname__}".encode())
            for name, attr in sorted(vars(klass).items()):
                func = getattr(attr, "__func__", attr)  # staticmethod, classmethod
                code = getattr(func, "__code__", None)
                if code is not None:
                    h.update(name.encode())
                    h.update(marshal.dumps(code))
    return h.hexdigest()


_CELL: tuple[int, ChunkFn, Any] | None = None  # a kept worker's last cell: token, fn, work


def _kept_chunk(token: int, blob: bytes, fingerprint: str, piece: Piece) -> Any:
    global _CELL
    if _CELL is None or _CELL[0] != token:
        try:
            fn, work, classes = pickle.loads(blob)
        except Exception as exc:  # a class or function defined after the fork
            raise _Stale(f"{type(exc).__name__}: {exc}") from None
        if _fingerprint(classes) != fingerprint:  # this worker's classes of those names
            raise _Stale("the code of a class differs from the parent's")
        _CELL = (token, fn, work)
    with batch_settings():
        return _guarded(_CELL[1], _CELL[2], piece)


class _Kept:
    """The workers of a :func:`kept_workers` scope (forked at the first cell that needs them)."""

    def __init__(self) -> None:
        self.pool: ProcessPoolExecutor | None = None
        self.size = 0
        self.tokens = itertools.count()

    def close(self) -> None:
        if self.pool is not None:
            self.pool.shutdown(wait=True, cancel_futures=True)
        self.pool, self.size = None, 0

    def _submit(self, size: int, args: list[tuple[Any, ...]]) -> list[Future[Any]]:
        for attempt in range(2):
            if self.pool is None or self.size != size:
                self.close()
                self.pool = ProcessPoolExecutor(size, mp_context=mp.get_context("fork"))
                self.size = size
            try:
                return [self.pool.submit(_kept_chunk, *a) for a in args]
            except BrokenProcessPool:  # a worker died while the pool was idle
                self.close()
                if attempt:
                    raise
        raise AssertionError("unreachable")

    def map(
        self,
        fn: ChunkFn,
        work: Any,
        blob: bytes,
        fingerprint: str,
        pieces: Sequence[Piece],
        jobs: int,
    ) -> Iterator[Any]:
        token = next(self.tokens)
        theirs = [i for i in range(len(pieces)) if i % jobs]
        futures = dict(
            zip(
                theirs,
                self._submit(jobs - 1, [(token, blob, fingerprint, pieces[i]) for i in theirs]),
                strict=True,
            )
        )
        stale = False
        try:
            for i, piece in enumerate(pieces):
                if i not in futures:
                    yield fn(work, *piece)
                    continue
                try:
                    yield futures[i].result()
                except _Stale:
                    stale = True  # computed here; the next cell forks workers that have the code
                    yield fn(work, *piece)
                except BrokenProcessPool as exc:
                    if self.pool is not None:
                        warnings.warn(
                            f"a kept worker process died ({exc}); its chunks are computed in "
                            "this process and the next cell forks new workers",
                            RuntimeWarning,
                            stacklevel=2,
                        )
                        self.pool.shutdown(wait=False, cancel_futures=True)
                        self.pool, self.size = None, 0
                    yield fn(work, *piece)
        finally:
            for fut in futures.values():
                fut.cancel()
            if stale:
                self.close()


_SCOPE: _Kept | None = None


@contextlib.contextmanager
def kept_workers() -> Iterator[None]:
    """Keep the worker processes of ``run_cell(..., jobs > 1)`` between cells for the duration.

    Workers are forked at the first cell that needs them and shut down when the scope ends; a
    nested scope uses the outer one's. See the module docstring for what kept workers see.

    Examples
    --------
    >>> from hbench.workers import kept_workers
    >>> with kept_workers():  # doctest: +SKIP
    ...     for sc in scenarios:
    ...         rows.append(run_cell(sc, methods, 1000, seed, jobs=2).rows)
    """
    global _SCOPE
    if _SCOPE is not None:
        yield
        return
    _SCOPE = _Kept()
    try:
        yield
    finally:
        scope, _SCOPE = _SCOPE, None
        scope.close()

"""Worker processes: one standard executor for a cell's chunks, reproduce's levels and figures.

:func:`pool` is a :class:`concurrent.futures.ProcessPoolExecutor` on the ``fork`` start method
(the workers start with the modules, objects and settings of the moment, without importing
anything; elsewhere the platform's default method, and what is sent must pickle). Every worker
it starts computes under one BLAS thread (many small products: threads cost more than they
share, and two processes' threads would compete for the same cores), with the allocator
settings of :func:`hbench.system.runtime.tune_allocator` (a process hbench starts, so its tuning is
hbench's to set; ``HBENCH_TUNE_MALLOC=0`` turns it off), leaves the objects it inherits out of
the garbage collector's passes (``gc.freeze``: a pass writes to every object it visits, so
each worker copied most of the parent's heap page by page), and exits when its parent dies.

:func:`map_chunks` computes a cell's chunks (:func:`hbench.bench.runner.run_cell` with
``jobs > 1``): the first ``1/jobs`` of them in this process, the others in a pool of ``jobs - 1``
workers started for the cell, which receive the cell's work when they start (inherited through the
fork, so it need not pickle) and only ``(start, n)`` with each chunk. Every run draws from its own
stream and its numbers do not depend on the runs batched with it, so the rows are those of one
process. What a worker's chunk logs or warns is issued again in this process, in chunk order,
through this process's loggers and warning filters. A worker that dies (the OOM killer, a signal)
never hangs the cell: the cell's chunks it left are computed in this process with a
:class:`RuntimeWarning`. An exception in a worker's chunk is raised here with the worker's traceback
in its message (hbench's :class:`~hbench.errors.InputError` as it is).
"""

from __future__ import annotations

import contextlib
import gc
import logging
import multiprocessing as mp
import multiprocessing.connection
import os
import pickle
import sys
import threading
import traceback
import types
import warnings
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from typing import Any

from hbench.errors import InputError
from hbench.numerics import kernels
from hbench.system.runtime import limit_blas_threads, tune_allocator

#: ``fn(work, start, n)``: computes runs ``start .. start + n - 1`` of a cell.
ChunkFn = Callable[[Any, int, int], Any]
Piece = tuple[int, int]


def _context() -> Any:
    methods = mp.get_all_start_methods()
    return mp.get_context("fork" if "fork" in methods else None)


def _start_worker(initializer: Callable[..., Any] | None, initargs: tuple[Any, ...]) -> None:
    """Every worker's start: the objects inherited through the fork left out of the garbage
    collector's passes (``gc.freeze``: a pass would write to every one of them, copying the
    parent's pages into the worker), one BLAS thread, the allocator tuned, log records left to
    the caller (no handler of the parent's), exit when the parent dies; then ``initializer``."""
    gc.freeze()  # the worker's own objects are still collected
    limit_blas_threads()  # for the worker's life: the process is hbench's
    tune_allocator()
    logging.getLogger().handlers.clear()
    parent = mp.parent_process()
    if parent is not None:

        def watch() -> None:
            multiprocessing.connection.wait([parent.sentinel])
            os._exit(1)

        threading.Thread(target=watch, daemon=True).start()
    if initializer is not None:
        initializer(*initargs)


def pool(
    workers: int,
    initializer: Callable[..., Any] | None = None,
    initargs: tuple[Any, ...] = (),
) -> ProcessPoolExecutor:
    """A process pool whose workers compute as this module's docstring says.

    Parameters
    ----------
    workers : int
        Worker processes.
    initializer : callable, optional
        Called in every worker once it is set up, as ``initializer(*initargs)``.
    initargs : tuple
        Its arguments (inherited through the fork, not pickled, where ``fork`` is available).

    Returns
    -------
    concurrent.futures.ProcessPoolExecutor
        Use it as a context manager (its ``shutdown`` waits for the workers).
    """
    return ProcessPoolExecutor(
        workers,
        mp_context=_context(),
        initializer=_start_worker,
        initargs=(initializer, initargs),
    )


# --- a cell's chunks ------------------------------------------------------------------------

_CELL: tuple[ChunkFn, Any, str] | None = None  # a worker's cell: fn, work, kernel backend


def _set_cell(fn: ChunkFn, work: Any, backend: str) -> None:
    global _CELL
    _CELL = (fn, work, backend)


class _Collect(logging.Handler):
    """Log records of a worker's chunk, made picklable (message formatted, traceback as text,
    ``extra=`` values that do not pickle as their ``repr``)."""

    def __init__(self) -> None:
        super().__init__(logging.NOTSET)
        self.records: list[logging.LogRecord] = []

    def emit(self, record: logging.LogRecord) -> None:
        try:
            fields = dict(vars(record), msg=record.getMessage(), args=None, exc_info=None)
        except Exception:  # a bad format string, reported as logging itself reports it
            self.handleError(record)
            return
        if record.exc_info:
            fields["exc_text"] = logging.Formatter().formatException(record.exc_info)
        for key, value in fields.items():
            try:
                pickle.dumps(value)
            except Exception:
                fields[key] = repr(value)
        self.records.append(logging.makeLogRecord(fields))


def _category(category: type[Warning]) -> type[Warning]:
    try:
        pickle.dumps(category)
    except Exception:  # a warning class defined in a function: its closest built-in base
        return next(c for c in category.__mro__ if c.__module__ == "builtins")
    return category


Done = tuple[Any, list[logging.LogRecord], list[tuple[Any, ...]]]


def _chunk(piece: Piece) -> Done:
    """A chunk of the cell a worker started with (:func:`_set_cell`)."""
    assert _CELL is not None
    return _chunk_of(*_CELL, piece)


def _chunk_of(fn: ChunkFn, work: Any, backend: str, piece: Piece) -> Done:
    """``fn(work, *piece)`` under the kernel backend ``backend``, with what it logged and
    warned."""
    root, collect = logging.getLogger(), _Collect()
    root.addHandler(collect)
    try:
        with kernels.use(backend), warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")  # the parent's filters decide (_reissue)
            out = fn(work, *piece)
    except InputError:
        raise
    except BaseException as exc:  # as text: an exception that does not unpickle breaks the pool
        raise RuntimeError(
            f"runs {piece[0]}..{piece[0] + piece[1] - 1} failed in a worker process:\n"
            + "".join(traceback.format_exception(exc))
        ) from None
    finally:
        root.removeHandler(collect)
    found = [(str(w.message), _category(w.category), w.filename, w.lineno) for w in caught]
    return out, collect.records, found


def _module_named(filename: str) -> types.ModuleType | None:
    for module in list(sys.modules.values()):
        if getattr(module, "__file__", None) == filename:
            return module
    return None


def _reissue(done: Done) -> Any:
    """A worker's chunk result; its log records and warnings issued here, as this process would
    have issued them (module filters and "once per location" registries included)."""
    out, records, found = done
    for record in records:
        logger = logging.getLogger(record.name)
        if logger.isEnabledFor(record.levelno):
            logger.handle(record)
    for message, category, filename, lineno in found:
        module = _module_named(filename)
        name = module.__name__ if module is not None else None
        registry = vars(module).setdefault("__warningregistry__", {}) if module else None
        warnings.warn_explicit(message, category, filename, lineno, name, registry)
    return out


class _Kept:
    """The pool of a :func:`kept_workers` scope (started at the first cell that needs it)."""

    def __init__(self) -> None:
        self.executor: ProcessPoolExecutor | None = None
        self.size = 0

    def get(self, size: int) -> ProcessPoolExecutor:
        if self.executor is not None and self.size < size:
            self.close()
        if self.executor is None:
            self.executor, self.size = pool(size), size
        return self.executor

    def close(self, wait: bool = True) -> None:
        executor, self.executor, self.size = self.executor, None, 0
        if executor is not None:
            executor.shutdown(wait=wait, cancel_futures=True)


_KEPT: _Kept | None = None


@contextlib.contextmanager
def kept_workers() -> Iterator[None]:
    """Keep the workers of ``run_cell(..., jobs > 1)`` between the cells of the block.

    The pool (:func:`pool`) starts at the first cell that needs it and shuts down when the block
    ends (without waiting for running chunks when it ends with an exception); a nested block
    uses the outer one's. Each chunk is sent with the cell's work, pickled (a cell whose work
    does not pickle, e.g. a method class defined in a function, starts a pool of its own). The
    workers run the code of the moment the pool started: for a program whose code does not
    change meanwhile (``hbench sweep`` opens this block around its jobs), not a notebook that
    redefines a method between cells.

    Yields
    ------
    None

    Examples
    --------
    >>> from hbench.bench.parallel import kept_workers
    >>> with kept_workers():  # doctest: +SKIP
    ...     for sc in scenarios:
    ...         rows.append(run_cell(sc, methods, 1000, seed, jobs=2).rows)
    """
    global _KEPT
    if _KEPT is not None:
        yield
        return
    _KEPT = kept = _Kept()
    ok = False
    try:
        yield
        ok = True
    finally:
        _KEPT = None
        kept.close(wait=ok)


def _pickles(obj: Any) -> bool:
    try:
        pickle.dumps(obj)
    except Exception:  # PicklingError, AttributeError, TypeError, ...
        return False
    return True


def map_chunks(fn: ChunkFn, work: Any, pieces: Sequence[Piece], jobs: int) -> Iterator[Any]:
    """``fn(work, *piece)`` for every piece, in order; with ``jobs > 1`` this process computes
    the first ``len(pieces) // jobs`` pieces and ``jobs - 1`` workers the others, dispatched at
    once (see the module docstring).

    Parameters
    ----------
    fn : callable
        ``fn(work, start, n)``, a module-level function.
    work : object
        What every piece needs.
    pieces : sequence of (start, n)
        The chunks.
    jobs : int
        Processes, this one included.

    Yields
    ------
    object
        ``fn(work, *piece)`` of each piece, in order.
    """
    if jobs <= 1 or len(pieces) < 2:
        for piece in pieces:
            yield fn(work, *piece)
        return
    jobs = min(jobs, len(pieces))
    mine = max(len(pieces) // jobs, 1)  # this process never waits on a worker before its share
    backend = kernels._asked()
    kept = _KEPT if _KEPT is not None and _pickles((fn, work)) else None
    if kept is not None:
        for attempt in range(2):
            executor = kept.get(jobs - 1)
            try:
                futures = [executor.submit(_chunk_of, fn, work, backend, p) for p in pieces[mine:]]
                break
            except BrokenProcessPool:  # a worker died while the pool was idle: a new pool
                kept.close(wait=False)
                if attempt:
                    raise
    else:
        executor = pool(jobs - 1, _set_cell, (fn, work, backend))
        futures = [executor.submit(_chunk, piece) for piece in pieces[mine:]]
    ok = False
    try:
        for piece in pieces[:mine]:
            yield fn(work, *piece)
        broken = False
        for piece, future in zip(pieces[mine:], futures, strict=True):
            try:
                done = future.result()
            except BrokenProcessPool as exc:
                if not broken:
                    warnings.warn(
                        f"a worker process died ({exc}); the cell's chunks it left are computed "
                        "in this process",
                        RuntimeWarning,
                        stacklevel=2,
                    )
                broken = True
                yield fn(work, *piece)
                continue
            yield _reissue(done)
        ok = not broken
    finally:  # an exception, Ctrl-C or a generator closed early: no chunk more is started
        if kept is None:
            executor.shutdown(wait=ok, cancel_futures=True)
        elif not ok:  # the next cell starts a new pool
            kept.close(wait=False)

"""Processes computing a cell's chunks: forked for one cell, or kept for a scope.

:func:`hbench.bench.runner.run_cell` with ``jobs = n > 1`` computes the first ``1/n`` of a cell's
chunks in this process and the others in ``n - 1`` worker processes; every run draws from its own
stream and its numbers do not depend on the runs batched with it, so the rows are the same
whatever the processes. What a worker's chunk logs or warns is replayed in this process, in chunk
order, through this process's loggers and warning filters.

* **Forked for the cell** (the default). The workers are forked when the cell starts and end
  with it: they see exactly the code, objects and settings of that moment, and nothing outlives
  the cell. The price is per cell: after the fork every page of this process's heap is
  copy-on-write in both processes (~36 000 page faults and ~0.17 s of system time for a
  1000-run cell of the paper's example), so two processes gave 70-78 % of what two independent
  processes give.
* **Kept for a scope** (:func:`kept_workers`). Inside ``with kept_workers():`` the workers are
  forked at the first cell with ``jobs > 1`` and kept until the scope ends; each cell's work is
  pickled once (sent with its chunks, or through a file when it is over 1 MiB) and a worker
  unpickles it once per cell. ``hbench sweep`` opens this scope around its jobs (a finished
  program running many cells).

  - *Code.* Kept workers run the modules as they were when forked. Before every cell, this
    process compares the packages the cell's pickled work names (its functions', classes' and
    objects' top-level packages and their classes' bases', but for the standard library and
    :data:`UNWATCHED`) with the moment of the fork: a module, a module-level name or a class
    attribute bound to another object since (a module reloaded, a class redefined in a
    notebook, a function or constant patched; in ``__main__`` only functions, classes and
    modules, so a script's loop variables do not count), or another working directory, and the
    workers are forked anew. Not seen: objects changed in place (an entry of a module-level
    dict, a function's ``__defaults__``), code reached only through a name the work does not
    pickle, and environment variables set after the fork (the kernel backend is passed with
    every cell, as is :func:`hbench.numerics.kernels.use`'s).
  - *Work that does not pickle* (a method class defined inside a function) is computed by
    workers forked for that cell, as by default: the same rows.
  - *A dead worker* (the OOM killer, a signal) never hangs a cell: :mod:`concurrent.futures`
    reports it, the cell's remaining worker chunks are computed in this process with a
    :class:`RuntimeWarning`, and the next cell forks new workers. A worker that died while idle
    is replaced at the next cell without a warning (nothing was lost), unless it died within
    about a millisecond before the cell started: then the cell goes the first way.
  - *Interrupts.* Kept workers ignore SIGINT; a cell or scope left by an exception (Ctrl-C
    included) terminates them at once. They also exit when this process dies; a large cell's
    file left by a killed process is removed by the next scope.

Processes are forked, so this needs the ``fork`` start method (Linux, macOS); elsewhere every
chunk is computed in this process. One cell at a time per process uses a scope (one thread).
"""

from __future__ import annotations

import contextlib
import io
import itertools
import logging
import multiprocessing as mp
import multiprocessing.connection
import os
import pickle
import signal
import sys
import tempfile
import threading
import traceback
import types
import warnings
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import Future, ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from pathlib import Path
from typing import Any

from hbench.errors import InputError
from hbench.numerics import kernels
from hbench.system.runtime import batch_settings

#: ``fn(work, start, n)``: computes runs ``start .. start + n - 1`` of a cell.
ChunkFn = Callable[[Any, int, int], Any]
Piece = tuple[int, int]
#: A cell's pickled work above this size goes to kept workers through a file, once per cell.
INLINE_LIMIT = 1 << 20


def map_chunks(fn: ChunkFn, work: Any, pieces: Sequence[Piece], jobs: int) -> Iterator[Any]:
    """``fn(work, *piece)`` for every piece, in order; with ``jobs > 1`` computed by this process
    (the first ``len(pieces) // jobs`` pieces, one after another) and ``jobs - 1`` worker
    processes (the others, dispatched at once).

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
    """
    if jobs <= 1 or len(pieces) < 2 or "fork" not in mp.get_all_start_methods():
        for piece in pieces:
            yield fn(work, *piece)
        return
    jobs = min(jobs, len(pieces))
    if _SCOPE is not None:
        pickled = _pickled(fn, work)
        if pickled is not None:
            yield from _SCOPE.map(fn, work, *pickled, pieces, jobs)
            return
    yield from _fork_for_cell(fn, work, pieces, jobs)


def _theirs(count: int, jobs: int) -> list[int]:
    """The pieces the workers compute: all but this process's first ``count // jobs``.

    This process takes the first pieces, so it yields each as soon as it is computed and never
    waits on a worker before its own share is done (with every ``jobs``-th piece, it waited on
    the worker's piece before it at every step, idle whenever that one was slower); the workers
    compute theirs back to back meanwhile. Chunk order (the results, and the logs and warnings
    replayed) is unchanged. Interleaved kept cells of the paper's example, 16 each: median 3928
    against 3891 runs/s."""
    return list(range(max(count // jobs, 1), count))


# --- what every worker does: compute a chunk, bring back its logs and warnings ---------------


class _Collect(logging.Handler):
    """Log records of a worker's chunk, made picklable (message formatted, traceback as text)."""

    def __init__(self) -> None:
        super().__init__(logging.NOTSET)
        self.records: list[logging.LogRecord] = []

    def emit(self, record: logging.LogRecord) -> None:
        try:
            fields = dict(vars(record), msg=record.getMessage(), args=None, exc_info=None)
            if record.exc_info:
                fields["exc_text"] = logging.Formatter().formatException(record.exc_info)
            for key, value in fields.items():  # extra= values that do not pickle: as text
                try:
                    pickle.dumps(value)
                except Exception:
                    fields[key] = repr(value)
        except Exception:  # a bad format string, as logging itself reports it
            self.handleError(record)
            return
        self.records.append(logging.makeLogRecord(fields))


def _category(category: type[Warning]) -> type[Warning]:
    try:
        pickle.dumps(category)
    except Exception:  # a warning class defined in a function: the closest built-in one
        return next(c for c in category.__mro__ if c.__module__ == "builtins")
    return category


def _in_worker(fn: ChunkFn, work: Any, piece: Piece) -> tuple[Any, list[Any], list[Any]]:
    """A worker's chunk with its log records and warnings. An exception that could not be
    unpickled would break the pool, so any but hbench's own (one-line messages, exit status 2)
    travels back as text."""
    root, collect = logging.getLogger(), _Collect()
    root.addHandler(collect)
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")  # this process's filters decide (see _replay)
            out = fn(work, *piece)
    except InputError:
        raise
    except BaseException as exc:
        raise RuntimeError(
            f"runs {piece[0]}..{piece[0] + piece[1] - 1} failed in a worker process:\n"
            + "".join(traceback.format_exception(exc))
        ) from None
    finally:
        root.removeHandler(collect)
    found = [(str(w.message), _category(w.category), w.filename, w.lineno) for w in caught]
    return out, collect.records, found


def _module_named(filename: str) -> types.ModuleType | None:
    """The loaded module whose file is ``filename``."""
    for module in list(sys.modules.values()):
        if getattr(module, "__file__", None) == filename:
            return module
    return None


def _replay(done: tuple[Any, list[Any], list[Any]]) -> Any:
    """A worker's chunk result, its log records and warnings issued here, as this process would
    have issued them (module-specific filters and "once per location" registries included)."""
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


# --- forked for one cell ---------------------------------------------------------------------

_FORKED: tuple[ChunkFn, Any] | None = None


def _forked_chunk(piece: Piece) -> tuple[Any, list[Any], list[Any]]:
    assert _FORKED is not None
    return _in_worker(*_FORKED, piece)


def _fork_for_cell(fn: ChunkFn, work: Any, pieces: Sequence[Piece], jobs: int) -> Iterator[Any]:
    global _FORKED
    theirs = set(_theirs(len(pieces), jobs))
    _FORKED = (fn, work)
    try:
        with mp.get_context("fork").Pool(jobs - 1, initializer=_watch_parent) as pool:
            # dispatched at once, computed meanwhile
            done = pool.imap(_forked_chunk, [pieces[i] for i in sorted(theirs)])
            for i, piece in enumerate(pieces):
                yield _replay(next(done)) if i in theirs else fn(work, *piece)
    finally:
        _FORKED = None


# --- kept for a scope ------------------------------------------------------------------------


class _Stale(Exception):
    """A kept worker cannot unpickle a cell's work (a class or function defined after the fork
    outside the modules :func:`_snapshot` watches)."""


#: Packages not watched for changes between cells (large compiled libraries: checking them
#: would cost ~80 ms per cell; nobody patches them mid-sweep). The standard library isn't either.
UNWATCHED = frozenset({"numpy", "scipy", "pandas", "pyarrow"})
#: What a ``__main__`` module's names are compared for (not its variables).
_CODE = (type, types.FunctionType, types.BuiltinFunctionType, types.ModuleType)


class _Pickler(pickle.Pickler):
    """A pickler noting the top-level packages of the functions, classes and objects' classes
    (with their bases) it writes: the code a kept worker will run for the cell."""

    def __init__(self, file: io.BytesIO) -> None:
        super().__init__(file, protocol=pickle.HIGHEST_PROTOCOL)
        self.roots: set[str] = set()

    def reducer_override(self, obj: Any) -> Any:
        classes = obj.__mro__ if isinstance(obj, type) else type(obj).__mro__
        named = [*classes[:-1]]
        if callable(obj) and not isinstance(obj, type):
            named.append(obj)
        for item in named:
            module = getattr(item, "__module__", None)
            if isinstance(module, str):
                self.roots.add(module.partition(".")[0])
        return NotImplemented


def _pickled(fn: ChunkFn, work: Any) -> tuple[bytes, frozenset[str]] | None:
    """What a kept worker needs of a cell and the packages to watch for it (see the module
    docstring), or ``None`` where it does not pickle (classes and functions travel by reference
    to their module, so a kept worker uses its own)."""
    buf = io.BytesIO()
    pickler = _Pickler(buf)
    try:
        pickler.dump((fn, work, kernels._asked()))
    except Exception:  # PicklingError, AttributeError, TypeError, ValueError (ctypes), ...
        return None
    stdlib = getattr(sys, "stdlib_module_names", frozenset())
    roots = {r for r in pickler.roots if r not in stdlib and r not in UNWATCHED}
    return buf.getvalue(), frozenset(roots - {"builtins"})


def _snapshot(roots: frozenset[str]) -> dict[tuple[str, str], Any]:
    """Every module of the top-level packages ``roots``, each module-level name's object and
    each class attribute's, and the working directory."""
    snap: dict[tuple[str, str], Any] = {("", "cwd"): os.getcwd()}
    for name, module in list(sys.modules.items()):
        if module is None or name.partition(".")[0] not in roots:
            continue
        snap[(name, "")] = module
        for key, value in list(vars(module).items()):
            if name == "__main__" and not isinstance(value, _CODE):
                continue  # a script's or notebook's variables change between cells
            snap[(name, key)] = value
            if isinstance(value, type) and value.__module__ == name:
                for attr, v in list(vars(value).items()):
                    snap[(name, f"{key}.{attr}")] = v
    return snap


def _changed(then: dict[tuple[str, str], Any], now: dict[tuple[str, str], Any]) -> str:
    """The first thing bound to another object since ``then`` (names added since are not
    compared: kept workers import new modules from disk themselves), or ``""``."""
    if then[("", "cwd")] != now[("", "cwd")]:
        return "the working directory"
    missing = object()
    for key, value in then.items():
        if key != ("", "cwd") and now.get(key, missing) is not value:
            return ".".join(k for k in key if k)
    return ""


def _watch_parent() -> None:
    """A worker's initialiser: ignore Ctrl-C (the parent terminates the workers), leave the
    parent's log handlers (records go back to it), and exit when the parent dies."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    logging.getLogger().handlers.clear()
    parent = mp.parent_process()
    if parent is not None:

        def watch() -> None:
            multiprocessing.connection.wait([parent.sentinel])
            os._exit(1)

        threading.Thread(target=watch, daemon=True).start()


_CELL: tuple[int, ChunkFn, Any, str] | None = None  # a kept worker's last cell


def _kept_chunk(token: int, blob: bytes | str, piece: Piece) -> tuple[Any, list[Any], list[Any]]:
    global _CELL
    if _CELL is None or _CELL[0] != token:
        try:
            if isinstance(blob, str):  # a file (large work)
                with open(blob, "rb") as fh:
                    blob = fh.read()
            fn, work, backend = pickle.loads(blob)
        except Exception as exc:
            raise _Stale(f"{type(exc).__name__}: {exc}") from None
        _CELL = (token, fn, work, backend)
    _, fn, work, backend = _CELL
    with batch_settings(), kernels.use(backend):
        return _in_worker(fn, work, piece)


class KeptWorkers:
    """The workers of a :func:`kept_workers` scope (forked at the first cell that needs them)."""

    def __init__(self) -> None:
        self.pool: ProcessPoolExecutor | None = None
        #: the pool's worker processes (``multiprocessing.active_children`` new at its start)
        self.processes: list[mp.process.BaseProcess] = []
        self.size = 0
        self.forked: dict[tuple[str, str], Any] = {}  # _snapshot(self.roots) at the fork
        self.roots: frozenset[str] = frozenset()
        self.tokens = itertools.count()
        #: chunks computed by kept workers, forks of the pool, cells whose chunks fell back here
        self.stats = {"remote": 0, "forks": 0, "fallback": 0}

    def close(self, terminate: bool = False) -> None:
        """Shut the workers down (after their current chunk), or ``terminate`` them now."""
        pool, self.pool, self.size, self.forked = self.pool, None, 0, {}
        procs, self.processes = self.processes, []
        if pool is None:
            return
        if not terminate:
            pool.shutdown(wait=True, cancel_futures=True)
            return
        pool.shutdown(wait=False, cancel_futures=True)
        for proc in procs:
            proc.terminate()
        for proc in procs:
            proc.join()

    def _submit(
        self, size: int, roots: frozenset[str], args: list[tuple[Any, ...]]
    ) -> list[Future[Any]]:
        watched = self.roots | roots
        now = _snapshot(watched)  # compared with the fork's; recorded if the workers are forked
        if self.pool is not None and (
            self.size < size
            or watched != self.roots  # packages not watched since the fork
            or _changed(self.forked, now)
        ):
            self.close()  # more workers wanted, or code changed since the fork: fork anew
        for attempt in range(2):
            started = None
            if self.pool is None:
                started = set(mp.active_children())
                self.pool = ProcessPoolExecutor(
                    size, mp_context=mp.get_context("fork"), initializer=_watch_parent
                )
                self.size, self.forked, self.roots = size, now, watched
                self.stats["forks"] += 1
            try:
                futures = [self.pool.submit(_kept_chunk, *a) for a in args]
                if started is not None:  # a fork-context pool starts its workers at the first
                    self.processes = [p for p in mp.active_children() if p not in started]
                return futures
            except BrokenProcessPool:  # a worker died while the pool was idle
                self.close(terminate=True)
                if attempt:
                    raise
        raise AssertionError("unreachable")

    def map(
        self,
        fn: ChunkFn,
        work: Any,
        blob: bytes,
        roots: frozenset[str],
        pieces: Sequence[Piece],
        jobs: int,
    ) -> Iterator[Any]:
        token = next(self.tokens)
        theirs = _theirs(len(pieces), jobs)
        path = None
        sent: bytes | str = blob
        ok = False
        try:
            if len(blob) > INLINE_LIMIT:  # once per cell through a file, not with every chunk
                fd, path = tempfile.mkstemp(prefix=f"hbench-cell-{os.getpid()}-", suffix=".pkl")
                with os.fdopen(fd, "wb") as fh:
                    fh.write(blob)
                sent = path
            futures = dict(
                zip(
                    theirs,
                    self._submit(jobs - 1, roots, [(token, sent, pieces[i]) for i in theirs]),
                    strict=True,
                )
            )
            stale = fallback = False
            for i, piece in enumerate(pieces):
                if i not in futures:
                    yield fn(work, *piece)
                    continue
                try:
                    done = futures[i].result()
                except _Stale:
                    stale = True  # computed here; the next cell forks workers that have the code
                    yield fn(work, *piece)
                    continue
                except BrokenProcessPool as exc:
                    if not fallback:
                        warnings.warn(
                            f"a kept worker process died ({exc}); this cell's remaining worker "
                            "chunks are computed in this process and the next cell forks new "
                            "workers",
                            RuntimeWarning,
                            stacklevel=2,
                        )
                        fallback = True
                    yield fn(work, *piece)
                    continue
                self.stats["remote"] += 1
                yield _replay(done)
            self.stats["fallback"] += stale or fallback
            if stale or fallback:
                self.close(terminate=fallback)
            ok = True
        finally:
            if not ok:  # an exception, Ctrl-C or a generator closed early: no chunk left running
                self.close(terminate=True)
            if path is not None:
                os.unlink(path)


_SCOPE: KeptWorkers | None = None


def _remove_orphan_files() -> None:
    """Remove the large cells' files of processes that are gone (killed mid-cell)."""
    for path in Path(tempfile.gettempdir()).glob("hbench-cell-*-*.pkl"):
        pid = path.name.split("-")[2]
        if not pid.isdigit() or int(pid) == os.getpid():
            continue
        try:
            os.kill(int(pid), 0)
        except ProcessLookupError:
            path.unlink(missing_ok=True)
        except PermissionError:  # another user's live process
            pass


@contextlib.contextmanager
def kept_workers() -> Iterator[KeptWorkers]:
    """Keep the worker processes of ``run_cell(..., jobs > 1)`` between cells for the duration.

    Workers are forked at the first cell that needs them and shut down when the scope ends (at
    once when it ends with an exception); a nested scope uses the outer one's. See the module
    docstring for what kept workers see. Yields the scope's state (``stats``: chunks computed
    by kept workers, forks, cells computed here after a worker died or could not run the work).

    Examples
    --------
    >>> from hbench.bench.workers import kept_workers
    >>> with kept_workers():  # doctest: +SKIP
    ...     for sc in scenarios:
    ...         rows.append(run_cell(sc, methods, 1000, seed, jobs=2).rows)
    """
    global _SCOPE
    if _SCOPE is not None:
        yield _SCOPE
        return
    _remove_orphan_files()
    _SCOPE = scope = KeptWorkers()
    ok = False
    try:
        yield scope
        ok = True
    finally:
        _SCOPE = None
        scope.close(terminate=not ok)

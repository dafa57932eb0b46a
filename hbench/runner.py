"""One cell of a benchmark: a scenario, several methods, R Monte Carlo runs -> tidy rows.

The runner is where the truth and the estimates meet: it simulates (in chunks of runs, so memory
stays bounded), hands each method the record it may see, times it, scores the estimate against
the truth, and writes one row per run x method x quantity. A method that raises yields
``status="failed"`` rows carrying the message, so one broken method never stops a sweep.
"""

from __future__ import annotations

import multiprocessing as mp
import os
import pickle
import time
import traceback
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pandas as pd

from hbench import kernels, tidy
from hbench.errors import InputError, describe
from hbench.identifiers import Estimate, Identifier, IdentifyOptions, identify, run_status
from hbench.metrics import fitnesses
from hbench.records import Record, Truth
from hbench.runtime import batch_settings
from hbench.schema import ID_COLUMNS, TIDY_COLUMNS  # noqa: F401 - re-exported
from hbench.simulate import Scenario, simulate

#: Quantities written per run and method (besides the parameters a1.., b2..).
QUANTITIES = (
    "fitness",
    "fitness_ls",
    "na",
    "nb",
    "tau",
    "delay",
    "sigma2_hat",
    "identifiable",
    "seconds",
)


@dataclass
class CellResult:
    """Tidy rows of a cell plus what reports want to plot (one run's x, U and estimates)."""

    rows: pd.DataFrame
    example: dict[str, Any] = field(default_factory=dict)


def _rows_for(
    method: str,
    est: Estimate,
    truth: Truth,
    record: Record,
    seconds: float,
    ids: Mapping[str, Any],
    start: int,
    known_multiple: int,
) -> tidy.Block:
    R = record.runs
    plant = truth.plant
    true = plant.true_params()
    F = fitnesses(est.U, truth.U, ("gain", "ls"), plant.gain)
    values: dict[str, tuple[np.ndarray, float]] = {
        "fitness": (F["gain"], np.nan),
        "fitness_ls": (F["ls"], np.nan),
        "na": (est.na.astype(float), float(plant.na)),
        "nb": (est.nb.astype(float), float(plant.nb)),
        "tau": (est.tau.astype(float), float(plant.tau(record.p))),
        "delay": (
            est.tau
            + record.p * (est.delay_multiple if est.delay_multiple is not None else known_multiple),
            float(plant.delay),
        ),
        "sigma2_hat": (est.sigma2, np.nan),
        "identifiable": (est.identifiable.astype(float), np.nan),
        "seconds": (np.full(R, seconds / R), np.nan),
    }
    params = est.params()
    for key, tv in true.items():
        values[key] = (params.get(key, np.full(R, np.nan)), tv)
    status, reason = run_status(est)
    return tidy.block(method, ids, start, values, truth.snr, status, reason)


def _failed_rows(
    method: str, truth: Truth, message: str, ids: Mapping[str, Any], start: int
) -> tidy.Block:
    true = truth.plant.true_params()
    R = truth.U.shape[0]
    values = {q: (np.full(R, np.nan), true.get(q, np.nan)) for q in (*QUANTITIES, *true)}
    return tidy.block(method, ids, start, values, truth.snr, np.full(R, "failed"), [message] * R)


def run_cell(
    scenario: Scenario,
    methods: Mapping[str, Identifier],
    runs: int,
    seed: np.random.SeedSequence | int,
    options: IdentifyOptions | None = None,
    *,
    cell: str = "",
    chunk: int = 200,
    progress: Callable[[int, int], None] | None = None,
    keep_example: bool = False,
    jobs: int = 1,
) -> CellResult:
    """Simulate ``runs`` realisations of ``scenario`` and run every method on them.

    Parameters
    ----------
    scenario : Scenario
        The cell's closed loop.
    methods : mapping of name -> Identifier
        Instantiated methods.
    runs : int
        Monte Carlo runs.
    seed : SeedSequence or int
        The cell's seed; run i draws from child i whatever the chunking.
    options : IdentifyOptions, optional
        Prior knowledge given to the methods; by default ``delay_multiple`` is the plant's known
        multiple of p (assumption A3).
    cell : str
        Cell identifier written in every row.
    chunk : int
        Runs simulated and identified at once: the numbers do not depend on it. About 1 MB
        per run of the paper's example at peak; 200 measured as fast as 1000 (cache effects).
    progress : callable, optional
        ``progress(done_runs, total_runs)`` after each chunk.
    keep_example : bool
        Keep run 0's x, true U and each method's U for plots.
    jobs : int
        Processes computing the chunks: this one and ``jobs - 1`` workers, forked on first use
        and kept for later cells (:func:`close_workers`). The rows are the same whatever
        ``jobs`` (but for the ``seconds`` quantity). With ``jobs > 1`` the cell is cut into a
        multiple of ``jobs`` chunks of near-equal size (at most ``chunk`` runs each).

    Notes
    -----
    The cell computes under :func:`hbench.runtime.batch_settings`: one BLAS thread for its
    duration, and (once per process, for good) glibc's allocator with fixed mmap and trim
    thresholds, so freed memory stays with the process (``HBENCH_TUNE_MALLOC=0`` leaves the
    allocator alone).
    """
    if int(jobs) < 1:
        raise InputError(f"jobs must be >= 1, got {jobs}")
    plant = scenario.discrete_plant
    if options is None:
        options = IdentifyOptions(delay_multiple=plant.delay_multiple(scenario.p))
    seq = seed if isinstance(seed, np.random.SeedSequence) else np.random.SeedSequence(seed)
    ids = {
        "cell": cell,
        "nonlinearity": scenario.nonlinearity.name,
        "plant": plant.name,
        "p": scenario.p,
        "delay": plant.delay,
        "sigma2": scenario.sigma2 if scenario.sigma2 is not None else np.nan,
        "snr_target": scenario.snr if scenario.snr is not None else np.nan,
        "seed": str(seq.entropy),
    }
    work = _Work(scenario, dict(methods), options, ids, seq, keep_example)
    pieces = _pieces(runs, chunk, jobs)
    rows: list[tidy.Block] = []
    example: dict[str, Any] = {}
    done = 0
    with batch_settings():  # one BLAS thread, glibc's allocator tuned (hbench.runtime)
        for (_start, n), (frames, ex) in zip(pieces, _map_chunks(work, pieces, jobs), strict=True):
            rows.extend(frames)
            if ex and not example:
                example = ex
            done += n
            if progress is not None:
                progress(done, runs)
    return CellResult(rows=tidy.assemble(rows), example=example)


def _pieces(runs: int, chunk: int, jobs: int) -> list[tuple[int, int]]:
    """``(start, n)`` of each chunk: at most ``chunk`` runs each; with ``jobs > 1`` the number of
    chunks is a multiple of ``jobs`` and their sizes differ by one at most, so no worker idles
    while another computes a last chunk (5 chunks of 200 on 2 workers took 3 rounds)."""
    if int(chunk) < 1:
        raise InputError(f"chunk must be >= 1, got {chunk}")
    if runs <= 0:
        return []
    count = -(-runs // chunk)
    if jobs > 1:
        count = min(runs, -(-count // jobs) * jobs)
    size, extra = divmod(runs, count)
    out, start = [], 0
    for i in range(count):
        n = size + (i < extra)
        out.append((start, n))
        start += n
    return out


@dataclass
class _Work:
    """What every chunk of a cell needs (shared with forked workers, never pickled)."""

    scenario: Scenario
    methods: dict[str, Identifier]
    options: IdentifyOptions
    ids: dict[str, Any]
    seq: np.random.SeedSequence
    keep_example: bool


def _run_chunk(work: _Work, start: int, n: int) -> tuple[list[tidy.Block], dict[str, Any]]:
    """Runs ``start .. start + n - 1`` of a cell: simulate, identify with every method, score."""
    record, truth = simulate(work.scenario, n, np.random.default_rng(work.seq), start=start)
    example: dict[str, Any] = {}
    if work.keep_example and start == 0:
        example = {
            "x": record.x[0].copy(),
            "U": truth.U[0].copy(),
            "gain": truth.plant.gain,
            "estimates": {},
        }
    frames = []
    for name, method in work.methods.items():
        t0 = time.perf_counter()
        try:  # a method's failure (or a malformed estimate's) fails its own rows only
            est = identify(method, record, work.options, truth)
        except Exception as exc:
            frames.append(_failed_rows(name, truth, describe(exc), work.ids, start))
            continue
        seconds = time.perf_counter() - t0
        frames.append(
            _rows_for(
                name, est, truth, record, seconds, work.ids, start, work.options.delay_multiple
            )
        )
        if example:
            example["estimates"][name] = est.U[0].copy()
    return frames, example


_FORKED: _Work | None = None
#: The worker processes kept between cells: (the process that made them, their number, the pool).
_WORKERS: tuple[int, int, Any] | None = None


def _guarded(work: _Work, start: int, n: int) -> tuple[list[tidy.Block], dict[str, Any]]:
    """:func:`_run_chunk` in a worker process, its errors made safe to send back."""
    try:
        return _run_chunk(work, start, n)
    except InputError:
        raise  # hbench's own errors travel back intact (one-line messages, exit status 2)
    except BaseException as exc:  # an exception that cannot be unpickled would hang the pool
        raise RuntimeError(
            f"runs {start}..{start + n - 1} failed in a worker process:\n"
            + "".join(traceback.format_exception(exc))
        ) from None


def _forked_chunk(piece: tuple[int, int]) -> tuple[list[tidy.Block], dict[str, Any]]:
    assert _FORKED is not None
    return _guarded(_FORKED, *piece)


def _pooled_chunk(
    task: tuple[bytes, str, int, int],
) -> tuple[list[tidy.Block], dict[str, Any]] | None:
    """A chunk in a kept worker: the cell's work arrives pickled with the parent's kernel
    backend; ``None`` when this process cannot unpickle the work (a class the parent defined
    after the worker was forked), and the parent then computes the chunk itself."""
    blob, backend, start, n = task
    try:
        work = pickle.loads(blob)
    except Exception:
        return None
    with kernels.use(backend), batch_settings():
        return _guarded(work, start, n)


def _workers(size: int) -> Any:
    """``size`` worker processes, forked on first use and kept for later cells of this process
    (a process forked from it makes its own)."""
    global _WORKERS
    pid = os.getpid()
    if _WORKERS is not None:
        owner, n, pool = _WORKERS
        if owner == pid and n == size:
            return pool
        _WORKERS = None
        if owner == pid:
            pool.terminate()
    pool = mp.get_context("fork").Pool(size)
    _WORKERS = (pid, size, pool)
    return pool


def close_workers() -> None:
    """Stop the worker processes that ``run_cell(..., jobs > 1)`` keeps between cells (they
    also stop when the interpreter exits). The next such cell forks new ones, which see this
    process as it is then."""
    global _WORKERS
    if _WORKERS is not None:
        owner, _, pool = _WORKERS
        _WORKERS = None
        if owner == os.getpid():
            pool.terminate()
            pool.join()


def _portable(work: _Work) -> bytes | None:
    """``work`` pickled for a kept worker, or ``None`` if it cannot be (a method defined inside
    a function, a lambda in its options): such cells fork their workers afresh."""
    try:
        return pickle.dumps(work, protocol=pickle.HIGHEST_PROTOCOL)
    except Exception:
        return None


def _map_chunks(
    work: _Work, pieces: list[tuple[int, int]], jobs: int
) -> Iterator[tuple[list[tidy.Block], dict[str, Any]]]:
    """Chunks in order; with ``jobs > 1`` computed by this process and ``jobs - 1`` worker
    processes.

    This process takes every ``jobs``-th chunk itself, the workers the others, and the chunks
    come back in order. Every run draws from its own stream and its numbers do not depend on
    the runs batched with it, so the rows do not depend on ``jobs`` (only the ``seconds``
    quantity does).

    The workers are forked once and kept for later cells (:func:`close_workers` stops them);
    the cell's work reaches them pickled (~2 kB), with the kernel backend in force here.
    Forking afresh for every cell, as before, cost ~20 000 copy-on-write page faults in each
    process per cell (after a fork every page of this process's retained heap is shared until
    written), measured at 0.70 of one process's CPU per run against 0.84 for two independent
    processes; work that cannot be pickled still takes that route.
    """
    global _FORKED
    if jobs <= 1 or len(pieces) < 2 or "fork" not in mp.get_all_start_methods():
        for piece in pieces:
            yield _run_chunk(work, *piece)
        return
    jobs = min(jobs, len(pieces))
    mine = set(range(0, len(pieces), jobs))
    theirs = [piece for i, piece in enumerate(pieces) if i not in mine]
    blob = _portable(work)
    if blob is None:
        _FORKED = work
        try:
            with mp.get_context("fork").Pool(jobs - 1) as pool:
                done = pool.imap(_forked_chunk, theirs)  # dispatched at once, computed meanwhile
                for i, piece in enumerate(pieces):
                    yield _run_chunk(work, *piece) if i in mine else next(done)
        finally:
            _FORKED = None
        return
    backend = "numpy" if kernels.backend() == "numpy" else "auto"
    finished = False
    try:
        kept = _workers(jobs - 1).imap(_pooled_chunk, [(blob, backend, *p) for p in theirs])
        for i, piece in enumerate(pieces):
            out = None if i in mine else next(kept)
            yield _run_chunk(work, *piece) if out is None else out
        finished = True
    finally:
        if not finished:  # an error or an abandoned cell: no worker goes on with its chunks
            close_workers()


def methods_from_names(
    names: Sequence[str], options: Mapping[str, Mapping[str, Any]] | None = None
) -> dict[str, Identifier]:
    """Instantiate registered methods by name, with per-method options."""
    from hbench.plugins import registry

    out = {}
    for name in names:
        cls = registry().get("identifiers", name)
        kwargs = dict((options or {}).get(name, {}))
        try:
            out[name] = cls(**kwargs)
        except TypeError as exc:
            raise InputError(f"method {name!r}: {exc}") from None
    return out

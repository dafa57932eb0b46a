"""One cell of a benchmark: a scenario, several methods, R Monte Carlo runs -> tidy rows.

The runner is where the truth and the estimates meet: it simulates (in chunks of runs, so memory
stays bounded), hands each method the record it may see, times it, scores the estimate against
the truth, and writes one row per run x method x quantity. A method that raises yields
``status="failed"`` rows carrying the message, so one broken method never stops a sweep.
"""

from __future__ import annotations

import contextlib
import signal
import threading
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pandas as pd

from hbench.bench import parallel, tidy
from hbench.bench.metrics import fitnesses
from hbench.bench.schema import ID_COLUMNS, TIDY_COLUMNS  # noqa: F401 - re-exported
from hbench.errors import InputError, describe
from hbench.ident.identifiers import Estimate, Identifier, IdentifyOptions, identify, run_status
from hbench.sim.records import Record, Truth
from hbench.sim.simulate import Scenario, simulate
from hbench.system.runtime import batch_settings

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
    method_timeout: float | None = None,
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
        Processes computing the chunks: this one and ``jobs - 1`` worker processes, started for the
        cell, or kept between cells inside :func:`hbench.bench.parallel.kept_workers` (faster for
        many cells; see :mod:`hbench.bench.parallel`). The rows are the same whatever ``jobs`` (but
        for the ``seconds`` quantity). With ``jobs > 1`` the cell is cut into a multiple of ``jobs``
        chunks of near-equal size (at most ``chunk`` runs each).
    method_timeout : float, optional
        Seconds a method may take on one chunk (:func:`time_limit`); past them its runs of the
        chunk are ``failed`` with "timed out". None: no limit.

    Notes
    -----
    The cell computes under :func:`hbench.system.runtime.batch_settings`: one BLAS thread for its
    duration, restored afterwards. The process's allocator is left as it is; a program that
    runs many cells may opt in to :func:`hbench.system.runtime.tune_allocator` (the ``hbench``
    command does).
    """
    if int(jobs) < 1:
        raise InputError(f"jobs must be >= 1, got {jobs}")
    work = cell_work(
        scenario,
        methods,
        seed,
        options,
        cell=cell,
        keep_example=keep_example,
        method_timeout=method_timeout,
    )
    pieces = _pieces(runs, chunk, jobs)
    rows: list[tidy.Block] = []
    example: dict[str, Any] = {}
    done = 0
    with batch_settings():  # one BLAS thread, restored afterwards (hbench.system.runtime)
        chunks = parallel.map_chunks(_run_chunk, work, pieces, jobs)
        for (_start, n), (frames, ex) in zip(pieces, chunks, strict=True):
            rows.extend(frames)
            if ex and not example:
                example = ex
            done += n
            if progress is not None:
                progress(done, runs)
    return CellResult(rows=tidy.assemble(rows), example=example)


def cell_work(
    scenario: Scenario,
    methods: Mapping[str, Identifier],
    seed: np.random.SeedSequence | int,
    options: IdentifyOptions | None = None,
    *,
    cell: str = "",
    keep_example: bool = False,
    method_timeout: float | None = None,
) -> _Work:
    """What every chunk of a cell needs (:func:`run_cell`'s arguments of the same names); with
    :func:`cell_blocks`, a cell's runs computed in parts (e.g. by several processes) and
    assembled by :func:`hbench.bench.tidy.assemble` in run order give :func:`run_cell`'s rows."""
    if method_timeout is not None and not method_timeout > 0:
        raise InputError(f"method_timeout must be > 0 seconds or null, got {method_timeout}")
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
    return _Work(scenario, dict(methods), options, ids, seq, keep_example, method_timeout)


def cell_blocks(
    work: _Work, pieces: Sequence[tuple[int, int]]
) -> tuple[list[tidy.Block], dict[str, Any]]:
    """The tidy blocks of the runs of ``pieces`` (``(start, n)`` each, computed as one chunk of
    :func:`run_cell`), in order, and run 0's example when ``work`` keeps one and run 0 is among
    them; one BLAS thread meanwhile, as in :func:`run_cell`."""
    blocks: list[tidy.Block] = []
    example: dict[str, Any] = {}
    with batch_settings():
        for start, n in pieces:
            frames, ex = _run_chunk(work, start, n)
            blocks.extend(frames)
            if ex and not example:
                example = ex
    return blocks, example


def chunks_of(runs: int, chunk: int = 200) -> list[tuple[int, int]]:
    """``(start, n)`` of the chunks :func:`run_cell` computes ``runs`` in (one process)."""
    return _pieces(runs, chunk, 1)


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
    """What every chunk of a cell needs (inherited by workers started for the cell, pickled with
    each chunk for kept ones: :mod:`hbench.bench.parallel`)."""

    scenario: Scenario
    methods: dict[str, Identifier]
    options: IdentifyOptions
    ids: dict[str, Any]
    seq: np.random.SeedSequence
    keep_example: bool
    timeout: float | None = None


class MethodTimeout(BaseException):
    """A method ran past the cell's ``method_timeout`` (a :class:`BaseException`, as
    KeyboardInterrupt is, so that a method's ``except Exception`` does not swallow it)."""


@contextlib.contextmanager
def time_limit(seconds: float | None) -> Iterator[None]:
    """Raise :class:`MethodTimeout` in the block once ``seconds`` have passed (None: no limit).

    A ``SIGALRM`` timer: the previous handler and timer are restored when the block ends, so the
    process's state is as before. The limit is seen when the method runs Python code: a method
    stuck inside one long compiled call is stopped when that call returns. Needs the main
    thread (where Hydra's launchers, hbench's worker processes and loky run a job); elsewhere
    :class:`InputError`.
    """
    if not seconds:
        yield
        return
    if threading.current_thread() is not threading.main_thread():
        raise InputError("method_timeout needs the main thread (a SIGALRM timer)")

    def expire(signum: int, frame: Any) -> None:
        raise MethodTimeout(f"timed out after {seconds:g} s (method_timeout)")

    previous = signal.signal(signal.SIGALRM, expire)
    t0 = time.monotonic()
    outer = signal.setitimer(signal.ITIMER_REAL, float(seconds))
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous)
        if outer[0]:  # an enclosing timer keeps running, less the time spent here
            left = max(outer[0] - (time.monotonic() - t0), 1e-3)
            signal.setitimer(signal.ITIMER_REAL, left, outer[1])


def read_only(record: Record, truth: Truth) -> None:
    """Make the arrays of ``record`` and ``truth`` read-only: every method of a chunk sees the
    same data, so a method that writes into them raises (its own rows fail) instead of
    changing what the next method sees and how every method is scored."""
    for arr in (record.y, record.x, record.r, truth.U, truth.y0, truth.v, truth.sigma2, truth.snr):
        if isinstance(arr, np.ndarray):
            arr.flags.writeable = False


def _run_chunk(work: _Work, start: int, n: int) -> tuple[list[tidy.Block], dict[str, Any]]:
    """Runs ``start .. start + n - 1`` of a cell: simulate, identify with every method, score.

    Methods see read-only arrays (:func:`read_only`); a method's exception (any but
    KeyboardInterrupt: ``sys.exit`` and :class:`MethodTimeout` included) fails its own rows."""
    record, truth = simulate(work.scenario, n, np.random.default_rng(work.seq), start=start)
    read_only(record, truth)
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
            with time_limit(work.timeout):
                est = identify(method, record, work.options, truth)
        except KeyboardInterrupt:
            raise
        except MethodTimeout as exc:
            frames.append(_failed_rows(name, truth, str(exc), work.ids, start))
            continue
        except BaseException as exc:  # SystemExit, GeneratorExit ... : the method's, not ours
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

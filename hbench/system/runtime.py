"""Process settings under which batches of Monte Carlo runs compute fastest.

A batch of runs is many whole-record numpy passes over arrays of a few MB, and many tiny matrix
products. Two process-wide defaults cost more than the arithmetic there, measured on the
paper's example (1000 runs, 4 methods, one process, 2-core machine):

* **BLAS threads.** OpenBLAS spreads every small product over all cores and its threads spin
  between calls: 2.2 s of CPU for 1.4 s of wall time, and with ``jobs=2`` the two processes'
  threads compete for the same cores. One BLAS thread per process halves the CPU time with the
  same wall time. It also makes the numbers independent of the machine's core count (OpenBLAS
  may split a product differently with more threads).
* **glibc's allocator.** Arrays above its (dynamic) mmap threshold are mapped and unmapped at
  every allocation, and the heap top is trimmed back to the system: ~130 000 page faults and
  0.35 s of system time per 1000 runs. A fixed mmap threshold of 32 MiB (glibc's largest) and a
  1 GiB trim threshold keep the memory in the process: 200 faults, no system time, 25 % less
  wall time, and the same peak resident memory.

:func:`batch_settings` limits BLAS to one thread for the duration of a cell
(:func:`hbench.bench.runner.run_cell`) and restores the count afterwards. The allocator setting
cannot be undone (glibc cannot restore its dynamic thresholds), so no library function makes it: the
``hbench`` command applies it to its own process (:func:`hbench.cli.main`) and to the launcher
workers its sweeps start, and every worker process of :func:`hbench.bench.parallel.pool` applies it
to itself; a program that calls :func:`hbench.bench.runner.run_cell` itself opts in with
:func:`tune_allocator`. It is skipped on other C libraries, and ``HBENCH_TUNE_MALLOC=0`` turns it
off."""

from __future__ import annotations

import contextlib
import ctypes
import functools
import gc
import os
import sys
from collections.abc import Iterator
from typing import Any

#: glibc's ``mallopt`` parameters (malloc.h).
_M_TRIM_THRESHOLD, _M_MMAP_THRESHOLD = -1, -3
#: Requests below this come from the heap (glibc's largest allowed value on 64-bit systems).
MMAP_THRESHOLD = 32 << 20
#: Free memory at the heap top is returned to the system only above this.
TRIM_THRESHOLD = 1 << 30


@functools.cache
def tune_allocator() -> bool:
    """Set glibc's mmap and trim thresholds for the rest of the process (once); opt-in.

    Returns
    -------
    bool
        ``True`` if they are set; ``False`` (a no-op) where the C library is not glibc or the
        environment has ``HBENCH_TUNE_MALLOC=0``.
    """
    ok = False
    if os.environ.get("HBENCH_TUNE_MALLOC", "1") != "0" and sys.platform.startswith("linux"):
        try:
            libc = ctypes.CDLL(None)  # the C library already loaded (no ldconfig subprocess)
            if hasattr(libc, "gnu_get_libc_version") and hasattr(libc, "mallopt"):
                ok = bool(libc.mallopt(_M_MMAP_THRESHOLD, MMAP_THRESHOLD)) and bool(
                    libc.mallopt(_M_TRIM_THRESHOLD, TRIM_THRESHOLD)
                )
        except OSError:
            ok = False
    return ok


@functools.cache
def _thread_pools() -> Any:
    """threadpoolctl's view of the loaded thread pools, taken once per process: finding them
    reads ``/proc/self/maps`` (~4 ms with numpy, scipy and pyarrow loaded), which every cell
    paid before. Libraries loaded after the first batch are not limited (BLAS is loaded by
    then: numpy and scipy are imported with hbench)."""
    from threadpoolctl import ThreadpoolController

    return ThreadpoolController()


def limit_blas_threads() -> None:
    """One BLAS thread for the rest of the process: for a worker process that hbench starts
    (:func:`hbench.bench.parallel.pool`), never for a caller's process."""
    _thread_pools().limit(limits=1, user_api="blas")


@contextlib.contextmanager
def one_blas_thread() -> Iterator[None]:
    """One BLAS thread for the duration (restored on exit): for code made of many small
    products, where OpenBLAS's threads cost more than they share (and compete with a second
    process's)."""
    with _thread_pools().limit(limits=1, user_api="blas"):
        yield


@contextlib.contextmanager
def batch_settings() -> Iterator[None]:
    """One BLAS thread for the duration (restored on exit); nothing else of the process
    changes (the allocator is :func:`tune_allocator`'s, opt-in)."""
    with one_blas_thread():
        yield


@contextlib.contextmanager
def collector_paused() -> Iterator[None]:
    """Python's cyclic garbage collector off for the duration (as it was on exit); for a
    command that imports numpy, scipy, pandas and matplotlib and then allocates many objects in
    a few seconds (``hbench reproduce``): the collector's passes over the modules' objects cost
    0.5 s of its ~3 s in the parent process, and its peak memory is the same without them
    (memory is still released by reference counting; the cycles left are collected when the
    collector is back on). Worker processes forked meanwhile start with it off."""
    was = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if was:
            gc.enable()

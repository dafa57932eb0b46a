"""Size limits, checked before any work starts: a job that would not fit is refused at once.

The memory budget is ``HBENCH_MEMORY_BUDGET`` (bytes, or with a suffix ``K``, ``M``, ``G``,
``T``: ``4G``), by default half of the machine's physical memory. Estimates are linear in what
a command holds at once, with factors measured on the paper's example (peak resident memory
over the start of the process):

* simulating: :data:`SIMULATE_BYTES` per fast sample and run (the record, the truth and the
  closed loop's work arrays; ~60 measured);
* identifying a chunk of runs: :data:`IDENTIFY_BYTES` per fast sample and run (~100 for
  ``wang-lsm`` alone, ~240 for every method);
* a cell's tidy rows, kept until the job writes them: :data:`ROW_BYTES` per row (240 per row in
  the data frame, times the copies made when they are sorted and written).

The closed loop's state dimension (the plant's order plus its delay in fast samples) is capped
at :data:`MAX_STATES`: its stability check and the loop cost the square (memory) and the cube
(time) of it, so a delay of 10 000 samples took minutes and 2.5 GB before anything ran.

:func:`check` raises :class:`hbench.errors.InputError` (exit status 2) with the estimate.
"""

from __future__ import annotations

import os
from typing import Any

from hbench.errors import InputError

#: Environment variable holding the memory budget.
BUDGET_ENV = "HBENCH_MEMORY_BUDGET"
#: Bytes per fast sample and run while simulating.
SIMULATE_BYTES = 64
#: Bytes per fast sample and run while the methods identify a chunk.
IDENTIFY_BYTES = 256
#: Bytes per tidy row held by a job.
ROW_BYTES = 1000
#: Largest state dimension of a simulated plant (order + delay in fast samples).
MAX_STATES = 2000
_UNITS = {"": 1, "K": 1 << 10, "M": 1 << 20, "G": 1 << 30, "T": 1 << 40}


def physical_memory() -> int:
    """The machine's physical memory in bytes (8 GiB where the system does not say)."""
    try:
        return int(os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE"))
    except (ValueError, OSError, AttributeError):
        return 8 << 30


def budget() -> int:
    """The memory budget in bytes: ``HBENCH_MEMORY_BUDGET`` or half the physical memory.

    Raises
    ------
    InputError
        ``HBENCH_MEMORY_BUDGET`` is not a positive size.
    """
    text = os.environ.get(BUDGET_ENV, "").strip()
    if not text:
        return physical_memory() // 2
    unit = text[-1].upper() if text[-1].isalpha() else ""
    number = text[:-1] if unit else text
    try:
        value = float(number) * _UNITS[unit]
    except (KeyError, ValueError):
        value = -1.0
    if not value > 0:
        raise InputError(f"{BUDGET_ENV}={text!r}: give a positive size in bytes, or 512M, 4G ...")
    return int(value)


def gib(n: float) -> str:
    """``n`` bytes as a short human figure (``"3.2 GB"``)."""
    for unit, size in (("TB", 1 << 40), ("GB", 1 << 30), ("MB", 1 << 20)):
        if n >= size:
            return f"{n / size:.3g} {unit}"
    return f"{n / 1024:.3g} KB"


def check(what: str, need: float, hint: str = "") -> None:
    """Refuse ``what`` if its estimate ``need`` (bytes) exceeds :func:`budget`.

    Raises
    ------
    InputError
        One line with the estimate, the budget and how to change either.
    """
    have = budget()
    if need > have:
        raise InputError(
            f"{what} would need about {gib(need)} of memory, more than the budget of "
            f"{gib(have)} ({BUDGET_ENV}; default half the machine's memory)"
            + (f": {hint}" if hint else "")
        )


def check_states(plant: Any, what: str) -> None:
    """Refuse a plant (a :class:`hbench.model.plants.DiscretePlant`) whose realisation has more than
    :data:`MAX_STATES` states: its order plus its delay in fast samples (``what`` names it)."""
    states = max(int(plant.na), int(plant.delay) + int(plant.nb))
    if states > MAX_STATES:
        raise InputError(
            f"{what} has {states} states (order + delay in fast samples), more than "
            f"{MAX_STATES}: its stability check and simulation grow with the square (memory) "
            "and cube (time) of that; shorten the delay or sample it more slowly"
        )


def simulation_bytes(n_fast: int, runs: int) -> float:
    """Estimated peak memory of simulating ``runs`` runs of ``n_fast`` fast samples."""
    return float(SIMULATE_BYTES) * n_fast * runs


def job_bytes(n_fast: int, runs: int, chunk: int, jobs: int, rows_per_run: int) -> float:
    """Estimated peak memory of a sweep job: ``jobs`` processes each identifying a chunk, plus
    the cell's tidy rows (``rows_per_run`` per run, over all methods)."""
    at_once = min(int(chunk), int(runs)) * max(int(jobs), 1)
    return float(IDENTIFY_BYTES) * n_fast * at_once + float(ROW_BYTES) * rows_per_run * runs

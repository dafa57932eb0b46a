"""A sweep job's files: the ``DONE`` marker, the tidy ``rows.parquet`` and their column order.

The job that writes them (:mod:`hbench.sweep.app`) and the callback that aggregates them
(:mod:`hbench.sweep.callbacks`) both read this module.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from hbench.bench.schema import TIDY_COLUMNS

#: Job markers and files.
DONE = "DONE"
ROWS = "rows.parquet"


def read_marker(marker: Path) -> dict[str, Any] | None:
    """A ``DONE`` marker's content, or None where it cannot be read."""
    import json

    try:
        held = json.loads(marker.read_text())
    except (OSError, ValueError):
        return None
    return held if isinstance(held, dict) else None


#: Tidy columns of ``rows.parquet``: the runner's plus ``job`` (the run id of the job).
ROW_COLUMNS = (*TIDY_COLUMNS, "job")
_INT = ("p", "delay", "run")
_FLOAT = ("sigma2", "snr_target", "value", "true", "snr")
#: Deterministic order of rows (aggregation sums in this order: bit-identical tables).
SORT_KEYS = [
    "method",
    "nonlinearity",
    "p",
    "delay",
    "sigma2",
    "snr_target",
    "cell",
    "run",
    "quantity",
    "job",
]


def normalise(rows: Any) -> Any:
    """Columns in order with fixed dtypes, rows in :data:`SORT_KEYS` order."""
    rows = rows.reindex(columns=list(ROW_COLUMNS)).copy()
    for c in _INT:
        rows[c] = rows[c].astype("int64")
    for c in _FLOAT:
        rows[c] = rows[c].astype("float64")
    for c in set(ROW_COLUMNS) - set(_INT) - set(_FLOAT):
        rows[c] = rows[c].fillna("").astype(str)
    return rows.sort_values(SORT_KEYS, kind="mergesort", na_position="first").reset_index(drop=True)

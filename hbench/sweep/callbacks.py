"""Hydra callbacks of ``hbench sweep``: aggregate the jobs' tidy rows into the contract's tables.

Registered in ``hbench/conf/config.yaml`` under ``hydra.callbacks``. ``on_multirun_end`` receives
no job results, so :func:`aggregate_dir` reads the sweep folder: every job folder with a ``DONE``
marker (one per run id, whatever the job numbering), their ``rows.parquet`` concatenated, sorted
deterministically and de-duplicated (a run of a method on a cell counts once, even when two jobs
computed it), then :func:`hbench.tables.results.write_tables` writes ``fitness``, ``bias`` and
``structure`` (.csv, .md, .tex) into the folder. A single run aggregates into its own folder the
same way.
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

from hydra.experimental.callback import Callback

import hbench.sweep.config  # noqa: F401 - registers the schema and resolvers (also in worker processes)
from hbench.errors import AggregationError, OutputError, tell
from hbench.system import atomic

#: Rows with equal values here are one measurement (see :func:`hbench.sweep.config.cell_id`).
DEDUP_KEYS = ["cell", "method", "run", "quantity"]


def collect_rows(root: Path) -> tuple[Any, list[Path]]:
    """All rows of the finished jobs under ``root`` (None if there are none) and their folders."""
    import pandas as pd

    from hbench.sweep.jobs import DONE, ROWS, SORT_KEYS, normalise, read_marker

    seen: dict[str, Path] = {}
    frames = []
    for marker in sorted(Path(root).rglob(DONE)):
        held = read_marker(marker)
        run_id = (held or {}).get("run_id")
        if run_id is None or run_id in seen:
            continue
        try:
            frame = pd.read_parquet(marker.parent / ROWS)
        except Exception as exc:  # missing, truncated, not Parquet: never silently dropped
            reason = " ".join(f"{type(exc).__name__}: {exc}".split())[:200]
            raise AggregationError(
                f"job {marker.parent} has a {DONE} marker but its {ROWS} cannot be read "
                f"({reason}); the tables in {root} are not updated: resume the sweep into "
                "that folder to compute the job again"
            ) from None
        if len(frame) != held.get("rows", len(frame)):
            raise AggregationError(
                f"job {marker.parent}: {ROWS} holds {len(frame)} rows, its {DONE} marker "
                f"{held.get('rows')}; the tables in {root} are not updated: resume the sweep "
                "into that folder to compute the job again"
            )
        seen[run_id] = marker.parent
        frames.append(frame)
    if not frames:
        return None, []
    rows = normalise(pd.concat(frames, ignore_index=True))
    rows = rows.drop_duplicates(DEDUP_KEYS, keep="first")
    rows = rows.sort_values(SORT_KEYS, kind="mergesort", na_position="first")
    return rows.reset_index(drop=True), list(seen.values())


def aggregate_dir(root: Path, quiet: bool = False) -> dict[str, Path]:
    """Aggregate the finished jobs under ``root`` into tables and ``rows.parquet`` in ``root``."""
    from hbench.sweep.jobs import DONE, ROWS
    from hbench.tables import results

    root = Path(root)
    rows, jobs = collect_rows(root)
    if rows is None:
        if not quiet:
            tell(f"hbench sweep: no finished jobs in {root}")
        return {}
    paths = results.write_tables(rows, root)
    if not (root / DONE).exists():  # a sweep folder; a single run's rows are already there
        with atomic.replacing(root / ROWS) as tmp:
            rows.to_parquet(tmp, index=False)
    paths[ROWS] = root / ROWS
    _warn_pooled(rows)
    if not quiet:
        failed = rows[rows["status"] == "failed"].drop_duplicates(["cell", "method"])
        note = (
            f"; {len(failed)} method x cell pairs failed (status/error in {ROWS})"
            if len(failed)
            else ""
        )
        plural = "s" if len(jobs) != 1 else ""
        tell(
            f"hbench sweep: {len(jobs)} job{plural} aggregated{note}\n"
            f"  tables: {root / 'fitness.csv'}, {root / 'bias.csv'}, "
            f"{root / 'structure.csv'} (+ .md, .tex)\n"
            f"  rows:   {root / ROWS}",
            sys.stdout,
        )
    return paths


def _warn_pooled(rows: Any) -> None:
    """Say so when a table row pools cells that differ outside the table's axes."""
    keys = ["method", "nonlinearity", "p", "delay", "sigma2", "snr_target"]
    ok = rows[rows["status"] == "ok"]
    counts = ok.groupby(keys, dropna=False)["cell"].nunique()
    pooled = counts[counts > 1]
    if len(pooled):
        tell(
            f"hbench sweep: note: {len(pooled)} table rows pool cells that differ outside "
            "(method, nonlinearity, p, delay, sigma2/snr), e.g. in plant, controller, "
            "identify or seed; rows.parquet keeps them apart (column cell)"
        )


def _aggregate_or_exit(root: Path) -> None:
    """:func:`aggregate_dir`; where it fails, one line on stderr and ``SystemExit(1)`` (Hydra
    turns a callback's other exceptions into a warning and exit status 0)."""
    try:
        aggregate_dir(root)
    except (AggregationError, OutputError) as exc:
        tell(f"hbench sweep: error: {' '.join(str(exc).split())}")
        raise SystemExit(2 if isinstance(exc, OutputError) else 1) from None


class AggregateTables(Callback):
    """Write the tables after a run (into its folder) or a multirun (into the sweep folder)."""

    def on_run_end(self, config: Any, **kwargs: Any) -> None:
        _aggregate_or_exit(Path(str(config.hydra.run.dir)))

    def on_multirun_end(self, config: Any, **kwargs: Any) -> None:
        _aggregate_or_exit(Path(str(config.hydra.sweep.dir)))

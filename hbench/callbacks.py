"""Hydra callbacks of ``hbench sweep``: aggregate the jobs' tidy rows into the contract's tables.

Registered in ``hbench/conf/config.yaml`` under ``hydra.callbacks``. ``on_multirun_end`` receives
no job results, so :func:`aggregate_dir` reads the sweep folder: every job folder with a ``DONE``
marker (one per run id, whatever the job numbering), their ``rows.parquet`` concatenated, sorted
deterministically and de-duplicated (a run of a method on a cell counts once, even when two jobs
computed it), then :func:`hbench.results.write_tables` writes ``fitness``, ``bias`` and
``structure`` (.csv, .md, .tex) into the folder. A single run aggregates into its own folder the
same way.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any

from hydra.experimental.callback import Callback

import hbench.config  # noqa: F401 - registers the schema and resolvers (also in worker processes)

#: Rows with equal values here are one measurement (see :func:`hbench.config.cell_id`).
DEDUP_KEYS = ["cell", "method", "run", "quantity"]


def collect_rows(root: Path) -> tuple[Any, list[Path]]:
    """All rows of the finished jobs under ``root`` (None if there are none) and their folders."""
    import pandas as pd

    from hbench.sweep import DONE, ROWS, SORT_KEYS, normalise

    seen: dict[str, Path] = {}
    frames = []
    for marker in sorted(Path(root).rglob(DONE)):
        try:
            run_id = json.loads(marker.read_text())["run_id"]
        except (OSError, ValueError, KeyError):
            continue
        if run_id in seen or not (marker.parent / ROWS).exists():
            continue
        seen[run_id] = marker.parent
        frames.append(pd.read_parquet(marker.parent / ROWS))
    if not frames:
        return None, []
    rows = normalise(pd.concat(frames, ignore_index=True))
    rows = rows.drop_duplicates(DEDUP_KEYS, keep="first")
    rows = rows.sort_values(SORT_KEYS, kind="mergesort", na_position="first")
    return rows.reset_index(drop=True), list(seen.values())


def aggregate_dir(root: Path, quiet: bool = False) -> dict[str, Path]:
    """Aggregate the finished jobs under ``root`` into tables and ``rows.parquet`` in ``root``."""
    from hbench import results
    from hbench.sweep import DONE, ROWS

    root = Path(root)
    rows, jobs = collect_rows(root)
    if rows is None:
        if not quiet:
            print(f"hbench sweep: no finished jobs in {root}", file=sys.stderr)
        return {}
    paths = results.write_tables(rows, root)
    if not (root / DONE).exists():  # a sweep folder; a single run's rows are already there
        rows.to_parquet(root / ROWS, index=False)
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
        print(
            f"hbench sweep: {len(jobs)} job{plural} aggregated{note}\n"
            f"  tables: {root / 'fitness.csv'}, {root / 'bias.csv'}, "
            f"{root / 'structure.csv'} (+ .md, .tex)\n"
            f"  rows:   {root / ROWS}",
            flush=True,
        )
    return paths


def _warn_pooled(rows: Any) -> None:
    """Say so when a table row pools cells that differ outside the table's axes."""
    keys = ["method", "nonlinearity", "p", "delay", "sigma2", "snr_target"]
    ok = rows[rows["status"] == "ok"]
    counts = ok.groupby(keys, dropna=False)["cell"].nunique()
    pooled = counts[counts > 1]
    if len(pooled):
        print(
            f"hbench sweep: note: {len(pooled)} table rows pool cells that differ outside "
            "(method, nonlinearity, p, delay, sigma2/snr), e.g. in plant, controller, "
            "identify or seed; rows.parquet keeps them apart (column cell)",
            file=sys.stderr,
        )


class AggregateTables(Callback):
    """Write the tables after a run (into its folder) or a multirun (into the sweep folder)."""

    def on_run_end(self, config: Any, **kwargs: Any) -> None:
        aggregate_dir(Path(str(config.hydra.run.dir)))

    def on_multirun_end(self, config: Any, **kwargs: Any) -> None:
        aggregate_dir(Path(str(config.hydra.sweep.dir)))

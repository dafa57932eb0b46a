"""What a report reads from a run's folder: the tidy rows (:func:`load_rows`, one
``rows.parquet`` at the root or every one below it, rows present twice kept once), the
provenance files and the x-U examples that ``hbench reproduce`` saves."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

from hbench.errors import InputError


def find_rows(run_dir: Path) -> list[Path]:
    """``RUN_DIR/rows.parquet`` if present, else every ``**/rows.parquet`` below (sorted)."""
    root = run_dir / "rows.parquet"
    if root.is_file():
        return [root]
    return sorted(p for p in run_dir.rglob("rows.parquet") if p.is_file())


def load_rows(run_dir: Path) -> tuple[Any, list[Path]]:
    """The tidy rows under ``run_dir`` (de-duplicated) and the files they came from."""
    import pandas as pd

    from hbench.bench.runner import ID_COLUMNS

    if not run_dir.is_dir():
        raise InputError(f"{run_dir} is not a folder")
    files = find_rows(run_dir)
    if not files:
        raise InputError(f"no rows.parquet in {run_dir} or below: nothing to report")
    frames = []
    for f in files:
        try:
            frames.append(pd.read_parquet(f))
        except Exception as exc:
            raise InputError(f"cannot read {f}: {type(exc).__name__}: {exc}") from None
    rows = pd.concat(frames, ignore_index=True)
    needed = {"method", "quantity", "value", "status", "snr"}
    missing = sorted(needed - set(rows.columns))
    if missing:
        raise InputError(f"{files[0]} is not tidy hbench rows (missing {', '.join(missing)})")
    if rows.empty:
        raise InputError(f"the rows under {run_dir} are empty: nothing to report")
    for col in ID_COLUMNS:
        if col not in rows.columns:
            rows[col] = math.nan if col in ("sigma2", "snr_target", "p", "delay") else ""
    key = [c for c in (*ID_COLUMNS, "quantity") if c in rows.columns]
    rows = rows.drop_duplicates(subset=key, keep="first").reset_index(drop=True)
    return rows, files


def load_provenance(run_dir: Path) -> list[tuple[Path, dict[str, Any]]]:
    out = []
    for f in sorted(run_dir.rglob("provenance.json")):
        if "report" in f.relative_to(run_dir).parts[:-1]:
            continue
        try:
            out.append((f, json.loads(f.read_text())))
        except (OSError, ValueError):
            continue
    return out


def load_examples(run_dir: Path) -> list[dict[str, Any]]:
    """Examples saved by :func:`hbench.paper.reproduce.save_examples` under ``run_dir``."""
    import numpy as np

    out = []
    for f in sorted(run_dir.rglob("examples.npz")):
        try:
            data = np.load(f, allow_pickle=False)
        except (OSError, ValueError):
            continue
        with data:
            ids = sorted({k.split("__")[0] for k in data.files})
            for i in ids:
                try:
                    meta = json.loads(str(data[f"{i}__meta"]))
                    ex = {
                        **meta,
                        "x": data[f"{i}__x"],
                        "U": data[f"{i}__U"],
                        "gain": float(data[f"{i}__gain"]),
                        "estimates": {},
                    }
                except KeyError:
                    continue
                prefix = f"{i}__est__"
                for k in data.files:
                    if k.startswith(prefix):
                        ex["estimates"][k[len(prefix) :]] = data[k]
                out.append(ex)
    return out

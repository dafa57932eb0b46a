"""Results are data: tidy rows, their aggregation into the contract's tables, provenance.

``fitness.csv``: one row per (method, nonlinearity, p, delay, sigma2) cell with ``snr_mean, n,
fitness_mean, fitness_std`` (fitness in %, the paper's gain scaling). ``bias.csv``: one row per
(method, cell, parameter) with ``true, mean, bias, std, n``. ``structure.csv`` (hbench's own, not
the contract's): one row per (method, cell, quantity) for the structure quantities na, nb, tau and
delay with ``snr_mean, true, hit_rate, n``. For cells given by a target SNR the ``sigma2`` column
is empty (nan): the level varies by run; the tidy rows keep ``snr_target``.
"""

from __future__ import annotations

import json
import platform
import subprocess
from collections.abc import Mapping
from datetime import UTC, datetime
from importlib import metadata
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from hbench import kernels

#: The columns that name a cell (and the method), first in every aggregated table.
CELL_KEYS = ["method", "nonlinearity", "p", "delay", "sigma2"]
FITNESS_COLUMNS = [*CELL_KEYS, "snr_mean", "n", "fitness_mean", "fitness_std"]
BIAS_COLUMNS = [*CELL_KEYS, "parameter", "true", "mean", "bias", "std", "n"]
STRUCTURE_COLUMNS = [*CELL_KEYS, "snr_mean", "quantity", "true", "hit_rate", "n"]
#: Structure quantities of the tidy rows scored by ``structure.csv`` (``delay``: tau + m p).
STRUCTURE_QUANTITIES = ("na", "nb", "tau", "delay")
#: An estimate within this of the truth is a hit (the structure quantities are whole numbers).
HIT_TOLERANCE = 1e-9
#: Column of the cell's noise level: sigma2, or -snr_target for a cell given by a target SNR.
LEVEL = "level"


def _is_param(q: pd.Series) -> pd.Series:
    return q.str.fullmatch(r"[ab]\d+")


def level_key(rows: pd.DataFrame) -> pd.Series:
    """The noise level that keys a row's cell: ``sigma2``, or ``-snr_target`` for an SNR cell.

    SNR cells have no sigma2 (the level varies by run); the negative sign keeps them apart
    from sigma2 cells and from each other.
    """
    return rows["sigma2"].where(rows["sigma2"].notna(), -rows["snr_target"])


def _by_cell(
    rows: pd.DataFrame, select: pd.Series, by: tuple[str, ...] = (), **aggs: tuple[str, str]
) -> pd.DataFrame:
    """Aggregate the ok rows picked by ``select`` per cell (and ``by``): the tables' one grouping.

    Groups by ``method, nonlinearity, p, delay`` and :func:`level_key` (column :data:`LEVEL`),
    then ``by``; ``aggs`` are pandas named aggregations. ``sigma2`` is empty for SNR cells.
    """
    picked = rows[(select & (rows["status"] == "ok")).to_numpy()]
    picked = picked.assign(**{LEVEL: level_key(picked)})
    keys = ["method", "nonlinearity", "p", "delay", LEVEL, *by]
    table = (
        picked.groupby(keys, sort=True, dropna=False)
        .agg(sigma2=("sigma2", "first"), **aggs)
        .reset_index()
    )
    table.loc[table[LEVEL] < 0, "sigma2"] = np.nan
    return table


def aggregate(rows: pd.DataFrame, level: bool = False) -> tuple[pd.DataFrame, pd.DataFrame]:
    """``(fitness, bias)`` tables from tidy rows (failed and not-identifiable runs excluded from
    the statistics; ``n`` counts the runs that entered them).

    ``level=True`` appends the column :data:`LEVEL` (:func:`level_key`), which tells SNR cells
    apart where ``sigma2`` is empty.
    """
    q = rows["quantity"]
    fitness = _by_cell(
        rows,
        q == "fitness",
        snr_mean=("snr", "mean"),
        n=("value", "count"),
        fitness_mean=("value", "mean"),
        fitness_std=("value", "std"),
    )
    bias = _by_cell(
        rows,
        _is_param(q),
        by=("quantity",),
        true=("true", "first"),
        mean=("value", "mean"),
        std=("value", "std"),
        n=("value", "count"),
    )
    bias["bias"] = bias["mean"] - bias["true"]
    bias = bias.rename(columns={"quantity": "parameter"})
    extra = [LEVEL] if level else []
    fitness = fitness[FITNESS_COLUMNS + extra].reset_index(drop=True)
    bias = bias[BIAS_COLUMNS + extra].reset_index(drop=True)
    return fitness, bias


def structure(rows: pd.DataFrame, level: bool = False) -> pd.DataFrame:
    """``structure`` table: how often each cell's runs found the true na, nb, tau and delay.

    Parameters
    ----------
    rows : DataFrame
        Tidy rows (:data:`hbench.schema.TIDY_COLUMNS`).
    level : bool
        Append the column :data:`LEVEL` (:func:`level_key`).

    Returns
    -------
    DataFrame
        :data:`STRUCTURE_COLUMNS`: one row per (method, nonlinearity, p, delay, sigma2,
        quantity) with ``quantity`` in :data:`STRUCTURE_QUANTITIES`, cells keyed as in
        :func:`aggregate` (SNR cells apart, their ``sigma2`` empty). ``hit_rate`` is the share
        of the ok runs whose estimate equals ``true`` (within :data:`HIT_TOLERANCE`), ``n`` the
        number of those runs with an estimate, ``snr_mean`` their mean realised SNR.
    """
    err = (rows["value"] - rows["true"]).abs()
    hit = np.where(err.notna(), (err <= HIT_TOLERANCE).astype(float), np.nan)
    table = _by_cell(
        rows.assign(_hit=hit),
        rows["quantity"].isin(STRUCTURE_QUANTITIES),
        by=("quantity",),
        snr_mean=("snr", "mean"),
        true=("true", "first"),
        hit_rate=("_hit", "mean"),
        n=("value", "count"),
    )
    return table[STRUCTURE_COLUMNS + ([LEVEL] if level else [])].reset_index(drop=True)


def to_markdown(table: pd.DataFrame, floatfmt: str = ".4g") -> str:
    """A GitHub-flavoured Markdown table (no extra dependency)."""
    cols = list(table.columns)

    def fmt(v):
        return format(v, floatfmt) if isinstance(v, float) else str(v)

    lines = ["| " + " | ".join(cols) + " |", "|" + "|".join("---" for _ in cols) + "|"]
    for _, row in table.iterrows():
        lines.append("| " + " | ".join(fmt(row[c]) for c in cols) + " |")
    return "\n".join(lines) + "\n"


def to_latex(table: pd.DataFrame, caption: str = "", floatfmt: str = ".4g") -> str:
    """A booktabs LaTeX table."""
    cols = list(table.columns)

    def esc(s):
        return str(s).replace("_", r"\_").replace("%", r"\%")

    def fmt(v):
        return format(v, floatfmt) if isinstance(v, float) else esc(v)

    out = [
        r"\begin{table}[ht]",
        r"\centering",
        r"\begin{tabular}{" + "l" * len(cols) + "}",
        r"\toprule",
        " & ".join(esc(c) for c in cols) + r" \\",
        r"\midrule",
    ]
    for _, row in table.iterrows():
        out.append(" & ".join(fmt(row[c]) for c in cols) + r" \\")
    out += [r"\bottomrule", r"\end{tabular}"]
    if caption:
        out.append(r"\caption{" + esc(caption) + "}")
    out.append(r"\end{table}")
    return "\n".join(out) + "\n"


def write_tables(rows: pd.DataFrame, out: Path) -> dict[str, Path]:
    """Aggregate ``rows`` and write fitness, bias and structure as CSV, Markdown and LaTeX
    into ``out``."""
    out.mkdir(parents=True, exist_ok=True)
    fitness, bias = aggregate(rows)
    paths = {}
    for name, table in (("fitness", fitness), ("bias", bias), ("structure", structure(rows))):
        paths[f"{name}.csv"] = out / f"{name}.csv"
        table.to_csv(paths[f"{name}.csv"], index=False, float_format="%.10g")
        (out / f"{name}.md").write_text(to_markdown(table))
        (out / f"{name}.tex").write_text(to_latex(table, caption=f"hbench {name}"))
    return paths


def git_revision(path: Path | None = None) -> str:
    """The git revision of the source tree (``+dirty`` if modified), or ``unknown``."""
    here = path or Path(__file__).resolve().parent
    try:
        rev = subprocess.run(
            ["git", "rev-parse", "HEAD"],
            cwd=here,
            capture_output=True,
            text=True,
            timeout=5,
            check=True,
        ).stdout.strip()
        dirty = subprocess.run(
            ["git", "status", "--porcelain", "--untracked-files=no"],
            cwd=here,
            capture_output=True,
            text=True,
            timeout=5,
        ).stdout
        return rev + ("+dirty" if dirty.strip() else "")
    except (OSError, subprocess.SubprocessError):
        return "unknown"


def provenance(
    config: Mapping[str, Any] | None = None, seeds: Mapping[str, Any] | None = None
) -> dict[str, Any]:
    """Package versions (hbench's dependencies and every installed plugin's package), git
    revision, platform, time, config and seeds."""
    versions = {}
    for pkg in ("hbench", "numpy", "scipy", "pandas", "pluggy", "hydra-core", "matplotlib"):
        try:
            versions[pkg] = metadata.version(pkg)
        except metadata.PackageNotFoundError:
            versions[pkg] = None
    from hbench.plugins import get_manager

    for _plugin, dist in get_manager().list_plugin_distinfo():  # the plugins' packages too
        versions.setdefault(dist.project_name, dist.version)
    return {
        "hbench_version": versions["hbench"],
        "git_revision": git_revision(),
        "versions": versions,
        # which path computed the numbers (the same bits either way: hbench.kernels)
        "kernels": kernels.status(),
        "python": platform.python_version(),
        "platform": platform.platform(),
        "created": datetime.now(UTC).isoformat(timespec="seconds"),
        "config": dict(config or {}),
        "seeds": dict(seeds or {}),
    }


def write_provenance(out: Path, **kwargs: Any) -> Path:
    path = out / "provenance.json"
    path.write_text(json.dumps(provenance(**kwargs), indent=2, default=str))
    return path


def new_output_dir(base: Path, name: str) -> Path:
    """A fresh folder ``base/name-YYYYmmddTHHMMSSZ[-k]``: earlier results are never overwritten."""
    stamp = datetime.now(UTC).strftime("%Y%m%dT%H%M%SZ")
    path = base / f"{name}-{stamp}"
    k = 1
    while path.exists():
        k += 1
        path = base / f"{name}-{stamp}-{k}"
    path.mkdir(parents=True)
    return path

"""Results are data: tidy rows, their aggregation into the contract's tables, provenance.

``fitness.csv``: one row per (method, nonlinearity, p, delay, sigma2) cell with ``snr_mean, n,
fitness_mean, fitness_std`` (fitness in %, the paper's gain scaling). ``bias.csv``: one row per
(method, cell, parameter) with ``true, mean, bias, std, n``. ``structure.csv`` (hbench's own, not
the contract's): one row per (method, cell, quantity) for the structure quantities na, nb, tau and
delay with ``snr_mean, true, hit_rate, n``. For cells given by a target SNR the ``sigma2`` column
is empty (nan): the level varies by run, and a column ``snr_target`` after ``sigma2`` holds the
target.

Each table's CSV, Markdown and LaTeX files show :func:`display_table`: the same columns in the
same order, rows sorted by noise level; the renderings show empty numbers as blank cells, and
every LaTeX text goes through :func:`tex_escape` (headers of :data:`TEX_HEADERS` as math).
"""

from __future__ import annotations

import json
import platform
import re
import subprocess
from collections.abc import Mapping
from datetime import UTC, datetime
from importlib import metadata
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from hbench.bench import kernel_status
from hbench.system import atomic

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
#: Column the renderings (not the CSV files) add for the target SNR of SNR cells.
SNR_TARGET = "snr_target"


def _is_param(q: pd.Series) -> pd.Series:
    return q.str.fullmatch(r"[ab]\d+")


def level_key(rows: pd.DataFrame) -> pd.Series:
    """The noise level that keys a row's cell: ``sigma2``, or ``-snr_target`` for an SNR cell.

    SNR cells have no sigma2 (the level varies by run); the negative sign keeps them apart
    from sigma2 cells and from each other.
    """
    return rows["sigma2"].where(rows["sigma2"].notna(), -rows["snr_target"])


def level_order(level: pd.Series) -> pd.Series:
    """Sort key of noise levels (:func:`level_key`): SNR cells first, by rising SNR, then
    sigma^2 cells by rising sigma^2; an unknown (nan) level sorts last.

    Parameters
    ----------
    level : Series
        Levels as in the column :data:`LEVEL` (``-snr_target`` for SNR cells).

    Returns
    -------
    Series
        A float key on the same index: ``1 / level`` (negative) for SNR cells, ``level``
        otherwise.
    """
    level = pd.to_numeric(level, errors="coerce").astype(float)
    snr = level < 0
    return pd.Series(np.where(snr, 1.0 / level.where(snr, -1.0), level), index=level.index)


def display_table(table: pd.DataFrame) -> pd.DataFrame:
    """An aggregated table as the Markdown, LaTeX and HTML renderings show it.

    Parameters
    ----------
    table : DataFrame
        :func:`aggregate`'s or :func:`structure`'s table with ``level=True`` (without the
        column :data:`LEVEL` the rows are only sorted by method and cell).

    Returns
    -------
    DataFrame
        The same rows without :data:`LEVEL`: when a cell is given by a target SNR (its
        ``sigma2`` empty), a column :data:`SNR_TARGET` after ``sigma2`` holds it (empty for
        sigma^2 cells), so that rows of different noise levels differ in their key columns.
        Rows are sorted by method, nonlinearity, p and delay, then by level
        (:func:`level_order`: numerically), then as they were (parameter, quantity).
    """
    out = table.reset_index(drop=True)
    if LEVEL in out.columns:
        level = pd.to_numeric(out[LEVEL], errors="coerce").astype(float)
        out = out.drop(columns=[LEVEL])
        if (level < 0).any():
            at = out.columns.get_loc("sigma2") + 1 if "sigma2" in out.columns else len(out.columns)
            out.insert(at, SNR_TARGET, (-level).where(level < 0))
        out["_order"] = level_order(level)
    else:
        out["_order"] = 0.0
    out["_row"] = np.arange(len(out))
    keys = [c for c in ("method", "nonlinearity", "p", "delay") if c in out.columns]
    out = out.sort_values([*keys, "_order", "_row"], na_position="last")
    return out.drop(columns=["_order", "_row"]).reset_index(drop=True)


def _by_cell(
    rows: pd.DataFrame, select: pd.Series, by: tuple[str, ...] = (), **aggs: tuple[str, str]
) -> pd.DataFrame:
    """Aggregate the ok rows picked by ``select`` per cell (and ``by``): the tables' one grouping.

    Groups by ``method, nonlinearity, p, delay`` and :func:`level_key` (column :data:`LEVEL`),
    then ``by``; ``aggs`` are pandas named aggregations. ``sigma2`` is empty for SNR cells.
    """
    keys = ["method", "nonlinearity", "p", "delay", LEVEL, *by]
    # only the columns read: every other column would be copied along by the selection
    read = dict.fromkeys([*keys[:4], "sigma2", "snr_target", *by, *(a[0] for a in aggs.values())])
    picked = rows.loc[(select & (rows["status"] == "ok")).to_numpy(), list(read)]
    picked = picked.assign(**{LEVEL: level_key(picked)})
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
        Tidy rows (:data:`hbench.bench.schema.TIDY_COLUMNS`).
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


#: LaTeX for the characters that are special in LaTeX text (and for a few non-ASCII ones the
#: package writes, which pdflatex's default fonts lack).
_TEX_SPECIAL = {
    "\\": r"\textbackslash{}",
    "&": r"\&",
    "%": r"\%",
    "$": r"\$",
    "#": r"\#",
    "_": r"\_",
    "{": r"\{",
    "}": r"\}",
    "~": r"\textasciitilde{}",
    "^": r"\textasciicircum{}",
    "<": r"\textless{}",
    ">": r"\textgreater{}",
    "|": r"\textbar{}",
    "±": r"\ensuremath{\pm}",
    "×": r"\ensuremath{\times}",
    "−": "-",
    "–": "--",
    "—": "---",
    "²": r"\ensuremath{^2}",
    "σ": r"\ensuremath{\sigma}",
    "τ": r"\ensuremath{\tau}",
    "Δ": r"\ensuremath{\Delta}",
    "≤": r"\ensuremath{\leq}",
    "≥": r"\ensuremath{\geq}",
}
_TEX_PATTERN = re.compile("|".join(re.escape(c) for c in _TEX_SPECIAL))


def tex_escape(text: Any) -> str:
    """``text`` as LaTeX text: on one line, every special character escaped.

    The one escaping function of the package: :func:`to_latex` applies it to captions,
    headers and text cells, and :mod:`hbench.report.table_files` to the text it writes in LaTeX.

    Parameters
    ----------
    text : object
        Any value; its ``str`` is escaped.

    Returns
    -------
    str
        Whitespace runs (newlines too) as one space; ``& % $ # _ { }`` with a backslash before,
        a backslash as ``\\textbackslash{}``, ``~ ^ < > |`` as ``\\textasciitilde{}``,
        ``\\textasciicircum{}``, ``\\textless{}``, ... (one pass: an escape is never escaped
        again); ``±`` and a few other non-ASCII symbols (``σ ² × ≤ ...``) in math.
    """
    text = " ".join(str(text).split())
    return _TEX_PATTERN.sub(lambda m: _TEX_SPECIAL[m.group()], text)


def _is_missing(v: Any) -> bool:
    """Whether a cell is an empty number (nan, None, pandas' NA)."""
    if v is None or v is pd.NA or v is pd.NaT:
        return True
    return isinstance(v, float | np.floating) and bool(np.isnan(v))


def format_number(v: Any, floatfmt: str) -> str | None:
    """A number formatted for a table cell (an empty number, nan or NA: ``""``), or None for a
    text cell. The Markdown, LaTeX and HTML renderings all format numbers with it."""
    if _is_missing(v):
        return ""
    if isinstance(v, float | np.floating):
        return format(float(v), floatfmt)
    return None


def to_markdown(table: pd.DataFrame, floatfmt: str = ".4g") -> str:
    """A GitHub-flavoured Markdown table (no extra dependency).

    Parameters
    ----------
    table : DataFrame
        The table; cells are shown as they are (escape ``|`` in text before).
    floatfmt : str
        Format of float cells; an empty number (nan) is a blank cell.

    Returns
    -------
    str
        The header, the separator line and one line per row.
    """
    cols = list(table.columns)

    def fmt(v: Any) -> str:
        number = format_number(v, floatfmt)
        return str(v) if number is None else number

    lines = ["| " + " | ".join(map(str, cols)) + " |", "|" + "|".join("---" for _ in cols) + "|"]
    for row in table.itertuples(index=False, name=None):
        lines.append("| " + " | ".join(fmt(v) for v in row) + " |")
    return "\n".join(lines) + "\n"


#: LaTeX headers of the tables' columns (math where the paper uses a symbol); other headers
#: are escaped text.
TEX_HEADERS = {
    "method": "Method",
    "nonlinearity": "Nonlinearity",
    "p": "$p$",
    "delay": "Delay",
    "sigma2": r"$\sigma^2$",
    "snr_target": r"SNR$_\mathrm{target}$",
    "snr_mean": r"$\overline{\mathrm{SNR}}$",
    "n": "$n$",
    "fitness_mean": r"$\bar F$ [\%]",
    "fitness_std": r"$s_F$ [\%]",
    "parameter": "Parameter",
    "quantity": "Quantity",
    "true": "True",
    "mean": "Mean",
    "bias": "Bias",
    "std": "Std",
    "hit_rate": "Hit rate",
    "mean_rank": "Mean rank",
    "mean_fitness": r"Mean $F$ over cells [\%]",
    "cells": "Cells",
    "wins": "Wins",
    "seconds_mean": "Time [s]",
    "seconds_std": r"$s_\mathrm{time}$ [s]",
}
#: Text cells shown as math symbols (the structure quantities); ``a1, b2, ...`` likewise.
_TEX_SYMBOLS = {"na": "$n_a$", "nb": "$n_b$", "tau": r"$\tau$", "delay": r"$\tau + m p$"}
_PARAM = re.compile(r"([ab])(\d+)")


def column_spec(table: pd.DataFrame) -> str:
    """The tabular's column types: ``r`` for numeric columns (right-aligned: with one format
    per column the decimal points align), ``l`` for text."""
    return "".join(
        "r" if pd.api.types.is_numeric_dtype(table[c].dtype) and table[c].dtype != bool else "l"
        for c in table.columns
    )


def tex_number(text: str, column: str = "") -> str:
    """A formatted number in LaTeX: ``1.102e-09 -> $1.102 \\times 10^{-9}$``, a minus sign in
    math, an infinite SNR as ``noise-free``."""
    if text in ("inf", "-inf"):
        if column.startswith("snr") and text == "inf":
            return "noise-free"
        return r"$\infty$" if text == "inf" else r"$-\infty$"
    mant, e, exp = text.partition("e")
    body = mant.lstrip("-") + (rf" \times 10^{{{int(exp)}}}" if e else "")
    sign = "-" if mant.startswith("-") else ""
    return f"${sign}{body}$" if (sign or e) else body


def _tex_text(v: Any) -> str:
    text = str(v)
    if text in _TEX_SYMBOLS:
        return _TEX_SYMBOLS[text]
    m = _PARAM.fullmatch(text)
    return f"${m.group(1)}_{{{m.group(2)}}}$" if m else tex_escape(v)


def _tex_label(text: str) -> str:
    """A ``\\label`` key from a caption: ``tab:`` and its words in lower case, by hyphens."""
    return "tab:" + "-".join(re.findall(r"[a-z0-9]+", text.lower()))[:60]


def to_latex(table: pd.DataFrame, caption: str = "", floatfmt: str = ".4g", label: str = "") -> str:
    """A booktabs LaTeX table ready for a paper.

    Parameters
    ----------
    table : DataFrame
        The table; its headers and text cells are plain text (:func:`tex_escape` escapes them;
        headers in :data:`TEX_HEADERS` and parameter names ``a1, b2, ...`` are set as math).
    caption : str
        Plain text (escaped too); none when empty.
    floatfmt : str
        Format of float cells; an empty number (nan) is a blank cell, exponents as
        ``\\times 10^{k}`` (:func:`tex_number`), an infinite SNR ``noise-free``.
    label : str
        The ``\\label`` key (default: ``tab:`` and the caption's words).

    Returns
    -------
    str
        A ``table`` environment: caption and label above a ``tabular`` whose numeric columns
        are right-aligned (:func:`column_spec`).
    """
    cols = list(table.columns)

    def fmt(v: Any, col: str) -> str:
        number = format_number(v, floatfmt)
        return _tex_text(v) if number is None else (tex_number(number, col) if number else "")

    out = [r"\begin{table}[ht]", r"\centering"]
    if caption:
        out.append(r"\caption{" + tex_escape(caption) + "}")
    out.append(r"\label{" + (label or _tex_label(caption or "hbench table")) + "}")
    out += [
        r"\begin{tabular}{" + column_spec(table) + "}",
        r"\toprule",
        " & ".join(TEX_HEADERS.get(str(c), tex_escape(c)) for c in cols) + r" \\",
        r"\midrule",
    ]
    for row in table.itertuples(index=False, name=None):
        out.append(" & ".join(fmt(v, str(c)) for v, c in zip(row, cols, strict=True)) + r" \\")
    out += [r"\bottomrule", r"\end{tabular}", r"\end{table}"]
    return "\n".join(out) + "\n"


def aggregated_tables(rows: pd.DataFrame) -> dict[str, pd.DataFrame]:
    """The fitness, bias and structure tables of ``rows`` as the files and the report show them.

    Parameters
    ----------
    rows : DataFrame
        Tidy rows (:data:`hbench.bench.schema.TIDY_COLUMNS`).

    Returns
    -------
    dict of str -> DataFrame
        ``{"fitness": ..., "bias": ..., "structure": ...}``: :func:`aggregate` and
        :func:`structure` with the column :data:`LEVEL`, each through :func:`display_table`.
        Computed once, they are what :func:`write_tables` writes and what
        :func:`hbench.report.build.build_report` shows (its ``tables``).
    """
    fitness, bias = aggregate(rows, level=True)
    return {
        name: display_table(table)
        for name, table in (
            ("fitness", fitness),
            ("bias", bias),
            ("structure", structure(rows, level=True)),
        )
    }


def write_tables(
    rows: pd.DataFrame, out: Path, tables: Mapping[str, pd.DataFrame] | None = None
) -> dict[str, Path]:
    """Aggregate ``rows`` and write fitness, bias and structure into ``out``.

    Parameters
    ----------
    rows : DataFrame
        Tidy rows (:data:`hbench.bench.schema.TIDY_COLUMNS`).
    out : Path
        The folder (made if missing).
    tables : mapping of str -> DataFrame, optional
        :func:`aggregated_tables` of ``rows`` when already computed (not computed again).

    Returns
    -------
    dict of str -> Path
        ``{"fitness.csv": path, ...}``: the CSV files (the contract's columns, and
        :data:`STRUCTURE_COLUMNS`). Each CSV file and its ``.md`` and ``.tex`` beside hold
        :func:`display_table`: the same columns in the same order (a column ``snr_target``
        after ``sigma2`` when a cell is given by a target SNR), rows sorted by level.
    """
    out.mkdir(parents=True, exist_ok=True)
    paths = {}
    # the CSV, Markdown and LaTeX files: same columns, same order
    for name, shown in (aggregated_tables(rows) if tables is None else tables).items():
        paths[f"{name}.csv"] = out / f"{name}.csv"
        atomic.write_text(paths[f"{name}.csv"], shown.to_csv(index=False, float_format="%.10g"))
        atomic.write_text(out / f"{name}.md", to_markdown(shown))
        tex = to_latex(shown, caption=f"hbench {name}", label=f"tab:hbench-{name}")
        atomic.write_text(out / f"{name}.tex", tex)
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
        # which path computed the numbers (the same bits either way: hbench.numerics.kernels)
        "kernels": kernel_status.status(),
        "python": platform.python_version(),
        "platform": platform.platform(),
        "created": datetime.now(UTC).isoformat(timespec="seconds"),
        "config": dict(config or {}),
        "seeds": dict(seeds or {}),
    }


def write_provenance(out: Path, **kwargs: Any) -> Path:
    path = out / "provenance.json"
    atomic.write_text(path, json.dumps(provenance(**kwargs), indent=2, default=str))
    return path


def new_output_dir(base: Path, name: str) -> Path:
    """A fresh folder ``base/name-YYYYmmddTHHMMSSZ[-k]``: earlier results are never overwritten.

    Parameters
    ----------
    base : Path
        The parent folder (made if missing).
    name : str
        The folder's prefix.

    Returns
    -------
    Path
        The folder, just made by this call: each candidate (``-2``, ``-3``, ... after the
        first) is claimed by ``mkdir`` itself, so runs started in the same second (even
        concurrently) each get their own.
    """
    stamp = datetime.now(UTC).strftime("%Y%m%dT%H%M%SZ")
    base.mkdir(parents=True, exist_ok=True)
    k = 1
    while True:
        path = base / (f"{name}-{stamp}" if k == 1 else f"{name}-{stamp}-{k}")
        try:
            path.mkdir()
        except FileExistsError:
            k += 1
            continue
        return path

"""The headline summary: which method wins each cell, and with what confidence.

Every method of a cell sees the same realisations (run ``i`` of a cell draws the same reference
and noise whatever the method, :mod:`hbench.sim.seeding`), so two methods are compared on their
*paired* differences over the shared runs. Intervals are Student t intervals at
:data:`CONFIDENCE`: of the mean over the runs for a method's fitness, bias and of the mean paired
difference for the comparison between methods.

:func:`summary` gives the contract's ``summary`` table (one row per method and cell);
:func:`bias_summary` the same for the parameters (bias with its interval, RMSE);
:func:`paper_values` reads the published values from a reproduction's ``reproduce.csv``.
:mod:`hbench.tables` renders them wide (methods as rows, levels as columns).
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable, Iterable

import numpy as np
import pandas as pd

#: Coverage of every interval of the summary.
CONFIDENCE = 0.95
#: A lead (fitness in %) must exceed this at its interval's lower end to count: differences of
#: rounding size (noise-free cells, where every method is exact) are not wins.
TOLERANCE = 1e-6
#: The columns that name a cell (``snr_target`` set for cells given by a target SNR).
CELL = ["nonlinearity", "p", "delay", "sigma2", "snr_target"]
SUMMARY_COLUMNS = [
    "method",
    *CELL,
    "n",
    "fitness_mean",
    "fitness_ci_low",
    "fitness_ci_high",
    "diff_to_best",
    "diff_ci_low",
    "diff_ci_high",
    "n_pairs",
    "best",
    "leader",
    "bound",
    "paper",
]
BIAS_SUMMARY_COLUMNS = [
    "method",
    *CELL,
    "parameter",
    "true",
    "n",
    "bias",
    "bias_ci_low",
    "bias_ci_high",
    "rmse",
    "paper_bias",
]
#: How the summary states its intervals (the report and the table notes print it).
METHOD_NOTE = (
    "95 % Student t intervals over the runs; differences are paired over the realisations the "
    "methods share (same cell, same run): for the cell's best method (highest mean fitness among "
    "the blind methods) its lead over the runner-up, for the others their difference to the best. "
    "best: the best method where its lead's interval excludes zero (by more than 1e-6 %)."
)


def t_interval(
    values: Iterable[float], confidence: float = CONFIDENCE
) -> tuple[float, float, float]:
    """``(mean, low, high)``: the Student t interval of the mean of the finite ``values``.

    One value gives its mean and an unknown (nan) interval; none gives nan throughout.
    """
    v = np.asarray(list(values), float)
    v = v[np.isfinite(v)]
    if v.size == 0:
        return math.nan, math.nan, math.nan
    mean = float(v.mean())
    if v.size < 2:
        return mean, math.nan, math.nan
    half = float(_t_quantile(0.5 + confidence / 2, v.size - 1) * v.std(ddof=1) / math.sqrt(v.size))
    return mean, mean - half, mean + half


@functools.lru_cache(maxsize=256)
def _t_quantile(q: float, df: int) -> float:
    """Student t's ``q`` quantile with ``df`` degrees of freedom (a table's cells mostly share
    ``df``: each asked of scipy once)."""
    from scipy import stats

    return stats.t.ppf(q, df)


def _cells(rows: pd.DataFrame) -> pd.DataFrame:
    """The ok rows with the cell columns as floats (missing levels as nan, grouped together):
    only the columns the summaries read (every other column taken along would be copied)."""
    r = rows.loc[rows["status"] == "ok", _READ].copy()
    for col in ("sigma2", "snr_target"):
        r[col] = pd.to_numeric(r[col], errors="coerce").astype(float)
    r["_s2"] = r["sigma2"].fillna(-1.0)
    r["_st"] = r["snr_target"].fillna(-1.0)
    return r


_GROUP = ["nonlinearity", "p", "delay", "_s2", "_st"]
#: The columns of the tidy rows the summaries read.
_READ = ["method", *CELL, "run", "seed", "quantity", "value", "true"]


def _methods(rows: pd.DataFrame) -> list[str]:
    """The methods of ``rows`` in order of appearance."""
    return [str(m) for m in rows["method"].unique()]


def _paired(values: pd.DataFrame, a: str, b: str) -> tuple[float, float, float, int]:
    """Mean of ``a - b`` over the runs both have, its interval, and the number of pairs."""
    both = values[[a, b]].dropna()
    mean, low, high = t_interval(both[a] - both[b])
    return mean, low, high, len(both)


def summary(
    rows: pd.DataFrame,
    bound: Callable[[str], bool] = lambda m: False,
    paper: pd.DataFrame | None = None,
) -> pd.DataFrame:
    """The headline table: each method's fitness per cell with its interval and its paired
    difference to the cell's best method.

    Parameters
    ----------
    rows : DataFrame
        Tidy rows (:data:`hbench.bench.schema.TIDY_COLUMNS`); only ``ok`` runs enter.
    bound : callable
        Whether a method is a bound (an oracle): it gets its interval but is neither compared
        nor ranked.
    paper : DataFrame, optional
        Published fitness values: columns ``method, sigma2, paper`` (:func:`paper_values`).

    Returns
    -------
    DataFrame
        :data:`SUMMARY_COLUMNS`, one row per (method, cell), cells by nonlinearity, p, delay and
        rising noise, methods in order of appearance. ``diff_to_best`` is ``method - best``
        (paired, over ``n_pairs`` runs) for the other blind methods and the best's lead over the
        runner-up on the best's own row; ``best`` is true on the best's row where that lead's
        interval lies above :data:`TOLERANCE` (or where it is the only blind method of the
        cell); ``leader`` marks the best mean whether its lead is significant or not.
    """
    r = _cells(rows)
    fit = r[r["quantity"] == "fitness"]
    methods = _methods(rows)
    out = []
    for _, g in fit.groupby(_GROUP, sort=True, dropna=False):
        first = g.iloc[0]
        # one column per method, one row per shared realisation
        wide = g.pivot_table(
            index=["run", "seed"], columns="method", values="value", aggfunc="first"
        )
        present = [m for m in methods if m in wide.columns]
        stats = {m: t_interval(wide[m]) for m in present}
        blind = [m for m in present if not bound(m) and math.isfinite(stats[m][0])]
        order = sorted(blind, key=lambda m: -stats[m][0])
        best = order[0] if order else None
        for m in present:
            mean, low, high = stats[m]
            diff = (math.nan, math.nan, math.nan, 0)
            is_best = False
            if m == best:
                if len(order) > 1:
                    diff = _paired(wide, m, order[1])
                    is_best = bool(diff[1] > TOLERANCE)
                else:
                    is_best = True
            elif m in blind:
                diff = _paired(wide, m, best)
            out.append(
                {
                    "method": m,
                    **{c: first[c] for c in CELL},
                    "n": int(wide[m].notna().sum()),
                    "fitness_mean": mean,
                    "fitness_ci_low": low,
                    "fitness_ci_high": high,
                    "diff_to_best": diff[0],
                    "diff_ci_low": diff[1],
                    "diff_ci_high": diff[2],
                    "n_pairs": diff[3],
                    "best": is_best,
                    "leader": m == best,
                    "bound": bool(bound(m)),
                }
            )
    table = pd.DataFrame(out, columns=SUMMARY_COLUMNS[:-1])
    table["paper"] = _paper_column(table, paper, ["method", "sigma2"])
    return _sorted(table, methods)


def bias_summary(
    rows: pd.DataFrame,
    bound: Callable[[str], bool] = lambda m: False,
    paper: pd.DataFrame | None = None,
) -> pd.DataFrame:
    """Bias (with its interval) and RMSE of each parameter per method and cell.

    Parameters
    ----------
    rows : DataFrame
        Tidy rows; the quantities ``a1, a2, ..., b2, ...`` of the ok runs enter.
    bound : callable
        Whether a method is a bound (an oracle knows the parameters: left out).
    paper : DataFrame, optional
        Published parameter means: columns ``method, sigma2, parameter, paper``.

    Returns
    -------
    DataFrame
        :data:`BIAS_SUMMARY_COLUMNS`: ``bias`` = mean estimate - true value with its t
        interval, ``rmse`` = root mean squared error over the ``n`` runs, ``paper_bias`` = the
        published mean - the true value (where one is published).
    """
    r = _cells(rows)
    bounds = [m for m in _methods(r) if bound(m)]  # asked once per method, not per row
    par = r[r["quantity"].str.fullmatch(r"[ab]\d+") & ~r["method"].isin(bounds)]
    out = []
    for _, g in par.groupby(["method", *_GROUP, "quantity"], sort=False, dropna=False):
        first = g.iloc[0]
        err = (g["value"] - g["true"]).to_numpy(float)
        err = err[np.isfinite(err)]
        mean, low, high = t_interval(err)
        out.append(
            {
                "method": first["method"],
                **{c: first[c] for c in CELL},
                "parameter": first["quantity"],
                "true": float(first["true"]),
                "n": int(err.size),
                "bias": mean,
                "bias_ci_low": low,
                "bias_ci_high": high,
                "rmse": float(np.sqrt(np.mean(err**2))) if err.size else math.nan,
            }
        )
    table = pd.DataFrame(out, columns=BIAS_SUMMARY_COLUMNS[:-1])
    published = _paper_column(table, paper, ["method", "sigma2", "parameter"])
    table["paper_bias"] = published - table["true"]
    table["_par"] = table["parameter"].map(lambda p: (p[0], int(p[1:])))
    return _sorted(table, _methods(rows), ["_par"]).drop(columns="_par")


def _paper_column(table: pd.DataFrame, paper: pd.DataFrame | None, on: list[str]) -> pd.Series:
    """The published value of each row of ``table`` (nan where none), matched on ``on``."""
    if paper is None or paper.empty or table.empty:
        return pd.Series(math.nan, index=table.index, dtype=float)
    left = table[on].copy()
    right = paper[[*on, "paper"]].copy()
    for frame in (left, right):
        frame["sigma2"] = pd.to_numeric(frame["sigma2"], errors="coerce").round(15)
    merged = left.merge(right.drop_duplicates(on), on=on, how="left")
    return pd.Series(merged["paper"].to_numpy(float), index=table.index)


def _sorted(
    table: pd.DataFrame, methods: list[str], extra: list[str] | None = None
) -> pd.DataFrame:
    """Rows by cell (noise rising: SNR cells by rising target SNR reversed, then sigma^2),
    then by method in order of appearance."""
    t = table.copy()
    snr = pd.to_numeric(t["snr_target"], errors="coerce")
    t["_lvl"] = np.where(snr.notna(), -snr, pd.to_numeric(t["sigma2"], errors="coerce"))
    t["_m"] = t["method"].map({m: i for i, m in enumerate(methods)})
    keys = ["nonlinearity", "p", "delay", "_lvl", "_m", *(extra or [])]
    t = t.sort_values(keys, kind="stable", na_position="last")
    return t.drop(columns=["_lvl", "_m"]).reset_index(drop=True)


#: Table 5's columns as the reproduction writes them: (column of reproduce.csv, method).
_PAPER_FITNESS = ("F", "F0")


def paper_values(frame: pd.DataFrame) -> tuple[pd.DataFrame, pd.DataFrame]:
    """``(fitness, parameters)`` published values from a reproduction's ``reproduce.csv``.

    Parameters
    ----------
    frame : DataFrame
        ``reproduce.csv`` (columns ``table, row, column, method, paper``).

    Returns
    -------
    tuple of DataFrame
        Table 5's fitness as ``method, sigma2, paper`` and Table 4's parameter means as
        ``method, sigma2, parameter, paper``.
    """
    t = frame.copy()
    t["table"] = pd.to_numeric(t["table"], errors="coerce")
    t["sigma2"] = pd.to_numeric(t["row"], errors="coerce")
    fit = t[(t["table"] == 5) & t["column"].isin(_PAPER_FITNESS)]
    par = t[(t["table"] == 4) & t["column"].astype(str).str.fullmatch(r"[ab]\d+")]
    par = par.rename(columns={"column": "parameter"})
    return (
        fit[["method", "sigma2", "paper"]].reset_index(drop=True),
        par[["method", "sigma2", "parameter", "paper"]].reset_index(drop=True),
    )

"""The report's numbers from the tidy rows: per-cell statistics for the figures and tables
(:func:`cell_stats`), one row per run (:func:`run_table`), runs per status
(:func:`status_counts`) and, per method and cell, the runs without an estimate and why
(:func:`failure_table`)."""

from __future__ import annotations

import math
from collections import Counter
from typing import Any

from hbench.report.style import method_info


def _num(v: Any) -> str:
    try:
        f = float(v)
    except (TypeError, ValueError):
        return str(v)
    if math.isnan(f):
        return "?"
    return str(int(f)) if f.is_integer() else f"{f:g}"


def _facet(df: Any) -> Any:
    """``"backlash, p=5, delay=3"`` per row (the panels of the fitness figure)."""
    if not len(df):
        import pandas as pd

        return pd.Series([], index=df.index, dtype=object)
    return (
        df["nonlinearity"].astype(str)
        + ", p="
        + df["p"].map(_num)
        + ", delay="
        + df["delay"].map(_num)
    )


def _merge_identical(bias: Any) -> Any:
    """Draw series with identical numbers once, labelled ``a = b`` (e.g. ``wang-lsm`` and
    ``wang-lsm-inv``: the same estimates, two inner-signal steps)."""
    import numpy as np

    seen: dict[bytes, str] = {}
    rename: dict[str, str] = {}
    drop: list[str] = []
    for series, g in bias.groupby("series", sort=False):
        g = g.sort_values(["parameter", "snr"])
        key = (
            np.round(g[["bias", "std", "snr"]].to_numpy(float), 12).tobytes()
            + "|".join(g["parameter"]).encode()
        )
        if key in seen:
            first = seen[key]
            rename[first] = rename.get(first, first) + " = " + str(series)
            drop.append(str(series))
        else:
            seen[key] = str(series)
    out = bias[~bias["series"].isin(drop)].copy()
    out["series"] = out["series"].map(lambda s: rename.get(s, s))
    return out


def cell_stats(rows: Any) -> dict[str, Any]:
    """Per-cell statistics the figures and tables need (the cell key includes ``snr_target``)."""
    keys = ["method", "nonlinearity", "p", "delay", "sigma2", "snr_target"]
    # the columns read below: every other column would be copied along by each selection
    r = rows[[*keys, "run", "snr", "status", "quantity", "value", "true"]].copy()
    for k in ("sigma2", "snr_target"):
        r[k] = r[k].astype(float)
    r["_s2"] = r["sigma2"].fillna(-1.0)
    r["_st"] = r["snr_target"].fillna(-1.0)
    gkeys = ["method", "nonlinearity", "p", "delay", "_s2", "_st"]
    snr = (
        r.drop_duplicates([*gkeys, "run"]).groupby(gkeys, dropna=False)["snr"].mean().rename("snr")
    )
    ok = r[r["status"] == "ok"]
    fit = (
        ok[ok["quantity"] == "fitness"]
        .groupby(gkeys, dropna=False)["value"]
        .agg(fitness_mean="mean", fitness_std="std", n="count")
    )
    fitness = fit.join(snr, how="left").reset_index()
    fitness = fitness.merge(r[[*gkeys, *keys[4:]]].drop_duplicates(gkeys), on=gkeys, how="left")
    fitness["facet"] = _facet(fitness)
    par = ok[ok["quantity"].str.fullmatch(r"[ab]\d+")]
    bias = (
        par.groupby([*gkeys, "quantity"], dropna=False)
        .agg(
            true=("true", "first"),
            mean=("value", "mean"),
            std=("value", "std"),
            n=("value", "count"),
        )
        .reset_index()
        .rename(columns={"quantity": "parameter"})
    )
    bias["bias"] = bias["mean"] - bias["true"]
    bias = bias.merge(snr.reset_index(), on=gkeys, how="left")
    # oracles know the true values: no error to show. The mask is boolean even when ``bias`` is
    # empty (an empty object mask would select no *columns* and lose them).
    oracle = bias["method"].map(lambda m: method_info(m)["oracle"]).astype(bool)
    bias = bias.loc[~oracle]
    bias["facet"] = _facet(bias)
    multi = bias["facet"].nunique() > 1
    bias["series"] = bias["method"] + (" | " + bias["facet"] if multi else "")
    bias = _merge_identical(bias)
    sec = ok[ok["quantity"] == "seconds"].groupby("method")["value"].agg(["mean", "std"])
    timing = sec.reset_index()
    # ranking among blind methods, per cell
    blind = [m for m in fitness["method"].unique() if not method_info(m)["oracle"]]
    f = fitness[fitness["method"].isin(blind) & fitness["fitness_mean"].notna()].copy()
    cell_key = ["nonlinearity", "p", "delay", "_s2", "_st"]
    f["rank"] = f.groupby(cell_key, dropna=False)["fitness_mean"].rank(
        ascending=False, method="average"
    )
    f["win"] = f["rank"] == 1.0
    ranking = (
        f.groupby("method")
        .agg(
            mean_rank=("rank", "mean"),
            cells=("rank", "count"),
            wins=("win", "sum"),
            mean_fitness=("fitness_mean", "mean"),
        )
        .reset_index()
        .sort_values("mean_rank")
    )
    return {"fitness": fitness, "bias": bias, "timing": timing, "ranking": ranking}


#: The statuses of a run that produced no estimate, in the order the failures table shows them
#: (other statuses met in the rows follow, sorted).
NOT_OK = ("failed", "not-identifiable")
#: The cell of a run, as the aggregated tables and the cell count key it.
CELL_COLUMNS = ("nonlinearity", "p", "delay", "sigma2", "snr_target")


def run_table(rows: Any) -> Any:
    """One row per run and method (a run's status and error are the same in all its rows).

    Parameters
    ----------
    rows : DataFrame
        Tidy rows (:data:`hbench.bench.schema.TIDY_COLUMNS`).

    Returns
    -------
    DataFrame
        The first row of each run (keyed by every identifier column present), missing statuses
        as ``"(none)"``.
    """
    from hbench.bench.schema import ID_COLUMNS

    key = [c for c in ID_COLUMNS if c in rows.columns]
    runs = rows.drop_duplicates(key).copy()
    runs["status"] = runs["status"].astype(object).where(runs["status"].notna(), "(none)")
    runs["status"] = runs["status"].astype(str)
    return runs.reset_index(drop=True)


def status_counts(rows: Any, runs: Any = None) -> dict[str, int]:
    """Runs per status over all methods and cells.

    Parameters
    ----------
    rows : DataFrame
        Tidy rows (:data:`hbench.bench.schema.TIDY_COLUMNS`).
    runs : DataFrame, optional
        :func:`run_table` of ``rows`` when already computed.

    Returns
    -------
    dict of str -> int
        ``{status: runs}``, most frequent first (a run is one method on one realisation).
    """
    counts = (run_table(rows) if runs is None else runs)["status"].value_counts()
    return {str(k): int(v) for k, v in counts.items()}


def _message(error: Any, width: int) -> str:
    """An error on one line, cut to ``width`` characters (``...`` marks a cut)."""
    text = "" if error is None or (isinstance(error, float) and math.isnan(error)) else str(error)
    text = " ".join(text.split()) or "(no message)"
    return text if len(text) <= width else text[: max(width - 3, 1)] + "..."


def failure_table(rows: Any, messages: int = 3, width: int = 200, runs: Any = None) -> Any:
    """Per method and cell with a run that produced no estimate: the status counts and why.

    Parameters
    ----------
    rows : DataFrame
        Tidy rows (:data:`hbench.bench.schema.TIDY_COLUMNS`).
    messages : int
        Distinct messages shown per method and cell, most frequent first (then in order of
        appearance); the number of the others is given.
    width : int
        Characters kept of each message (a cut one ends in ``...``; the rows' ``error`` column
        holds it whole).
    runs : DataFrame, optional
        :func:`run_table` of ``rows`` when already computed (not modified).

    Returns
    -------
    DataFrame
        Columns ``method, nonlinearity, p, delay, sigma2, snr_target`` (``snr_target`` only if a
        cell has one), ``runs``, ``ok``, one count column per status that is not ``ok``
        (``failed``, ``not-identifiable``, then any other met), and ``messages``:
        ``"<message> [<k> runs]; ..."`` from the runs' ``error`` column, ending in ``"(+<n> more
        distinct messages)"`` when there are more than ``messages``. One row per (method, cell)
        that has a run that is not ``ok``, methods and cells in order of appearance; empty
        (same columns) when every run is ``ok``.
    """
    import pandas as pd

    runs = run_table(rows) if runs is None else runs.copy()
    for col in CELL_COLUMNS:
        if col not in runs.columns:
            runs[col] = math.nan
    other = sorted(s for s in set(runs["status"]) if s != "ok" and s not in NOT_OK)
    statuses = [*NOT_OK, *other]
    cells = [c for c in CELL_COLUMNS if c != "snr_target" or runs["snr_target"].notna().any()]
    columns = ["method", *cells, "runs", "ok", *statuses, "messages"]
    # the level keyed as in cell_stats: sigma2 and snr_target, each missing as -1
    runs["_s2"] = runs["sigma2"].astype(float).fillna(-1.0)
    runs["_st"] = runs["snr_target"].astype(float).fillna(-1.0)
    out = []
    keys = ["method", "nonlinearity", "p", "delay", "_s2", "_st"]
    for _, g in runs.groupby(keys, sort=False, dropna=False):
        bad = g[g["status"] != "ok"]
        if bad.empty:
            continue
        first = g.iloc[0]
        counts = g["status"].value_counts()
        # most frequent first; ties in order of appearance (most_common's sort is stable)
        found = Counter(_message(e, width) for e in bad["error"]).most_common()
        shown = [f"{m} [{k} run{'s' if k != 1 else ''}]" for m, k in found[:messages]]
        if len(found) > messages:
            shown.append(f"(+{len(found) - messages} more distinct messages)")
        out.append(
            {
                **{c: first[c] for c in ("method", *cells)},
                "runs": len(g),
                "ok": int(counts.get("ok", 0)),
                **{s: int(counts.get(s, 0)) for s in statuses},
                "messages": "; ".join(shown),
            }
        )
    return pd.DataFrame(out, columns=columns)

"""hbench's numbers beside the published Tables 1, 2, 4 and 5: per published cell, our mean and
spread from the reproduction's rows and the z-score of the difference (the z-score itself is
:func:`hbench.tables.published.z_score`), and the paper's steps (ii), (iv) beside the LSM rows.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, replace
from typing import Any

from hbench.errors import InputError
from hbench.paper.levels import FITNESS_QUANTITY, FITNESS_RUNS, Config
from hbench.tables.published import (
    CSV_COLUMNS,
    Z_LIMIT,
    format_number,
    paper_cells,
    z_score,
)


def fitness_runs(values: Any, which: str = "all") -> Any:
    """The per-run fitnesses a Table 5 cell averages (``Config.fitness_runs``).

    Parameters
    ----------
    values : array_like
        One cell's per-run fitnesses in % (``nan`` where a run has none; left as they are).
    which : {"all", "clip0", "nonnegative"}
        ``all``: every run, unchanged; ``clip0``: each run's fitness floored at 0, ``max(F, 0)``
        (an implementation that reports a fit worse than the mean as 0 %); ``nonnegative``: the
        runs with ``F >= 0`` only (one that drops a run whose estimate fits worse than the mean
        as failed), so the cell's ``n`` counts the runs kept.

    Returns
    -------
    ndarray
        The values the cell's mean, spread and ``n`` are taken from.
    """
    import numpy as np

    v = np.asarray(values, dtype=float)
    if which == "all":
        return v
    if which == "clip0":
        return np.where(v < 0.0, 0.0, v)
    if which == "nonnegative":
        return v[~(v < 0.0)]
    raise InputError(f"fitness_runs must be one of {', '.join(FITNESS_RUNS)}, got {which!r}")


def _stats(values: Any) -> tuple[float, float, int]:
    import numpy as np

    v = np.asarray(values, dtype=float)
    v = v[~np.isnan(v)]
    n = int(v.size)
    if n == 0:
        return math.nan, math.nan, 0
    with np.errstate(invalid="ignore"):
        mean = float(np.mean(v))
        std = float(np.std(v, ddof=1)) if n > 1 else math.nan
    if n > 1 and np.all(v == v[0]):
        std = 0.0
    return mean, std, n


def _snr_as(per_run: Any, definition: str) -> Any:
    """Per-run SNRs ``||y0|| / ||v||`` under ``definition`` (``norm``, ``power``, ``db``)."""
    import numpy as np

    if definition == "norm":
        return per_run
    if definition == "power":
        return per_run**2
    if definition == "db":
        with np.errstate(divide="ignore"):
            return 20.0 * np.log10(per_run)
    raise InputError(f"unknown SNR definition {definition!r} (norm, power, db)")


def snr_values(rows: Any, sigma2: float, definition: str = "norm") -> Any:
    """Per-run SNR at a level (one value per run, in the order the runs first appear), under
    ``definition``."""
    import numpy as np

    sub = rows[np.isclose(rows["sigma2"].astype(float), sigma2, rtol=1e-9, atol=0.0)]
    return _snr_as(sub.drop_duplicates("run")["snr"].to_numpy(dtype=float), definition)


@dataclass(frozen=True)
class LevelValues:
    """What Tables 4 and 5 read from the tidy rows, gathered in one pass: ``values[(sigma2,
    method, quantity)]`` the ``ok`` runs' values and ``snr[sigma2]`` the per-run SNRs (every
    run, in the order the runs first appear), at the paper's levels (matched to rtol 1e-9).
    Every comparison of one set of rows (the defaults, the steps, the post-processed
    alternatives) reads the same object instead of filtering the rows again."""

    values: dict[tuple[float, str, str], Any]
    snr: dict[float, Any]

    @classmethod
    def of(cls, rows: Any) -> LevelValues:
        import numpy as np

        sigma2 = rows["sigma2"].to_numpy(dtype=float)
        value = rows["value"].to_numpy(dtype=float)
        ok = (rows["status"] == "ok").to_numpy(dtype=bool)
        levels = sorted({c.row for c in paper_cells() if c.table in (4, 5)})
        at = {s2: np.isclose(sigma2, s2, rtol=1e-9, atol=0.0) for s2 in levels}
        values = {}
        for (method, quantity), idx in rows.groupby(
            ["method", "quantity"], sort=False
        ).indices.items():
            idx = idx[ok[idx]]  # row order, as filtering the frame keeps it
            for s2 in levels:
                sel = idx[at[s2][idx]]
                if sel.size:
                    values[(s2, str(method), str(quantity))] = value[sel]
        run = rows["run"].to_numpy()
        snr_all = rows["snr"].to_numpy(dtype=float)
        snr = {}
        for s2 in levels:
            idx = np.flatnonzero(at[s2])
            first = np.unique(run[idx], return_index=True)[1]
            snr[s2] = snr_all[idx[np.sort(first)]]
        return cls(values, snr)


def compare_tables45(rows: Any, config: Config = Config()) -> Any:
    """``reproduce.csv`` rows of Tables 4 (with its SNR column) and 5 from tidy rows (or their
    :class:`LevelValues`, gathered once for several comparisons)."""
    import numpy as np
    import pandas as pd

    lv = rows if isinstance(rows, LevelValues) else LevelValues.of(rows)
    values = lv.values
    fq, fq0 = FITNESS_QUANTITY[config.fitness], FITNESS_QUANTITY[config.bound_fitness]
    out = []
    for cell in paper_cells():
        if cell.table not in (4, 5):
            continue
        if cell.column == "snr":
            vals = _snr_as(lv.snr.get(cell.row, np.empty(0)), config.snr)
            if vals.size and np.all(np.isinf(vals)):
                mean, std, n = math.inf, math.nan, int(vals.size)
            else:
                mean, std, n = _stats(vals)
        else:
            method = cell.method
            if cell.table == 5 and cell.column == "F" and method == "wang-lsm-inv":
                method = config.f_inv
            elif cell.table == 5 and cell.column == "F" and method == "wang-lsm":
                method = config.f_lsm_method
            elif method == "wang-lsm":
                method = config.lsm
            if cell.table == 5:  # the F0 columns: the bounds' own scaling, where given
                quantity = fq0 if cell.column == "F0" else fq
            else:
                quantity = cell.column
            vals = values.get((cell.row, method, quantity), np.empty(0))
            if cell.table == 5:
                vals = fitness_runs(vals, config.fitness_runs)
            mean, std, n = _stats(vals)
            cell = replace(cell, method=method)
        z = z_score(
            mean,
            std if math.isfinite(std) else math.nan,
            n,
            cell.value,
            cell.std,
            cell.n,
            cell.unit,
        )
        out.append(
            {
                "table": cell.table,
                "row": cell.row,
                "column": cell.column,
                "method": cell.method,
                "paper": cell.value,
                "paper_std": cell.std,
                "ours": mean,
                "ours_std": std,
                "z": z,
            }
        )
    return pd.DataFrame(out, columns=CSV_COLUMNS)


#: Table 2's rows read with l = 1 and l = 2 exchanged (``Config.table2 = "swapped"``).
_SWAPPED_L = {1: 2, 2: 1}


def compare_tables12(tab: Mapping[str, Any], config: Config = Config()) -> Any:
    """``reproduce.csv`` rows of Tables 1 and 2 (run 0 vs the paper; spread over the runs).

    With ``config.table2 == "swapped"`` the paper's Table 2 row l = 1 is compared with our
    l = 2 and its l = 2 with our l = 1 (the row keeps the paper's l)."""
    import numpy as np
    import pandas as pd

    na_values = list(np.asarray(tab["na_values"]).tolist())
    out = []
    for cell in paper_cells():
        if cell.table == 1:
            V = tab["V"][cell.method]
            if int(cell.row) not in na_values:
                continue
            series = V[:, na_values.index(int(cell.row)), int(cell.column)]
        elif cell.table == 2:
            l = int(cell.row)
            if config.table2 == "swapped":
                l = _SWAPPED_L.get(l, l)
            series = tab["var_dw"][:, l - 1]
        else:
            continue
        ours = float(series[0])
        std = float(np.std(series, ddof=1)) if series.size > 1 else math.nan
        z = z_score(ours, std, 1, cell.value, math.nan, 1, cell.unit)
        out.append(
            {
                "table": cell.table,
                "row": cell.row,
                "column": cell.column,
                "method": cell.method,
                "paper": cell.value,
                "paper_std": math.nan,
                "ours": ours,
                "ours_std": std,
                "z": z,
            }
        )
    return pd.DataFrame(out, columns=CSV_COLUMNS)


def steps_comparison(rows: Any, comparison: Any, config: Config = Config()) -> tuple[Any, str]:
    """The paper's steps (ii) and (iv) on Tables 4 and 5 from tidy rows (or their
    :class:`LevelValues`): the cells of Table 4's LSM rows and of
    F_LSM scored with ``wang`` (A by integrated AIC, b by V_EIV) in place of ``wang-lsm``.

    Returns the ``wang`` cells (``reproduce.csv``'s columns) and a text: the share within
    ``|z| <= 2`` for both methods, and each cell at sigma^2 >= 5e-3 side by side.
    """
    import numpy as np

    steps = compare_tables45(rows, replace(config, lsm="wang"))
    steps = steps[steps["method"] == "wang"].reset_index(drop=True)
    key = ["table", "row", "column"]
    base = comparison[comparison["method"] == config.lsm][[*key, "ours", "ours_std", "z"]]
    m = steps.merge(base, on=key, suffixes=("", "_lsm"), how="left")

    def within(z: Any) -> str:
        z = np.abs(np.asarray(z, dtype=float))
        return f"{int(np.sum(z[np.isfinite(z)] <= Z_LIMIT))} of {int(np.isfinite(z).sum())}"

    lines = [
        "The paper's steps (ii) and (iv) (method wang: A by the integrated AIC, each b_l by "
        "V_EIV, between the LSM and the IVM) in Table 4's LSM rows and F_LSM: "
        f"{within(m['z'])} cells within |z| <= {Z_LIMIT:g} (wang-lsm: {within(m['z_lsm'])}).",
    ]
    for _, c in m[m["row"].astype(float) >= 5e-3].iterrows():
        lines.append(
            f"  {c['column']} @ sigma2={float(c['row']):g}: paper {format_number(c['paper'])}; "
            f"wang {format_number(c['ours'])} +- {format_number(c['ours_std'])} (z {c['z']:+.1f}); "
            f"wang-lsm {format_number(c['ours_lsm'])} +- {format_number(c['ours_std_lsm'])} "
            f"(z {c['z_lsm']:+.1f})"
        )
    return steps, "\n".join(lines) + "\n"

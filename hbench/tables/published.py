"""The paper's published tables (``hbench/data/paper_tables.json``) beside hbench's numbers.

The published values as printed, the cells ``hbench reproduce`` compares (Tables 1, 2, 4, 5), the
z-score of each difference, the summary of a comparison, and the side-by-side tables as strings,
Markdown and LaTeX. Read by :mod:`hbench.paper.reproduce`, which computes hbench's side, and by the
report (:mod:`hbench.report.build`), which shows a reproduction's comparison.
"""

from __future__ import annotations

import functools
import json
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

#: Table 5's columns -> (contract column, method); F_LSM's method follows ``Config.lsm`` (as
#: Table 4's LSM rows do), F_INV's ``Config.f_inv``.
TABLE5_COLUMNS: dict[str, tuple[str, str]] = {
    "F_LSM": ("F", "wang-lsm"),
    "F0_LSM": ("F0", "oracle"),
    "F_INV": ("F", "wang-lsm-inv"),
    "F0_INV": ("F0", "oracle-inv"),
}


CSV_COLUMNS = ["table", "row", "column", "method", "paper", "paper_std", "ours", "ours_std", "z"]


Z_LIMIT = 2.0


@functools.lru_cache(maxsize=1)
def paper_data() -> dict[str, Any]:
    """The published tables (``hbench/data/paper_tables.json``), values as printed strings."""
    from importlib import resources

    text = resources.files("hbench").joinpath("data", "paper_tables.json").read_text("utf-8")
    return json.loads(text)


#: The investigation table's columns as shown (summary and report).
INVESTIGATION_COLUMNS = (
    "alternative",
    "group",
    "mean_abs_z_before",
    "mean_abs_z_after",
    "T4-params_after",
    "T4-snr_after",
    "T5_after",
    "T1_after",
    "T2_after",
    "std_ratio_T4-params_after",
    "std_ratio_T5_after",
    "within2_after",
    "cells_closer",
    "cells_further",
    "moved_most",
)


def parse_printed(text: str | None) -> tuple[float, float]:
    """``(value, unit)`` of a printed number: ``"0.9623" -> (0.9623, 1e-4)``, ``"inf" -> (inf, 0)``.

    ``unit`` is the rounding unit of the last printed digit (``nan`` for a missing value).
    """
    if text is None:
        return math.nan, math.nan
    s = str(text).strip()
    if s.lower() in ("inf", "infinity", "∞"):
        return math.inf, 0.0
    value = float(s)
    mantissa = s.lower().split("e")[0]
    decimals = len(mantissa.split(".")[1]) if "." in mantissa else 0
    exp = int(s.lower().split("e")[1]) if "e" in s.lower() else 0
    return value, 10.0 ** (exp - decimals)


@dataclass(frozen=True)
class PaperCell:
    """One published cell: ``table, row, column, method`` and the printed mean, std and unit."""

    table: int
    row: float
    column: str
    method: str
    value: float
    std: float
    unit: float
    n: int


def paper_cells() -> list[PaperCell]:
    """Every published cell of Tables 1, 2, 4 (with its SNR column) and 5, in plain units."""
    d = paper_data()
    n_mc = int(d["monte_carlo_runs"])
    cells: list[PaperCell] = []
    t1 = d["table1"]
    for row in t1["rows"]:
        for tau, text in zip(t1["tau"], row["values"], strict=True):
            v, u = parse_printed(text)
            cells.append(
                PaperCell(
                    1,
                    row["na"],
                    str(tau),
                    row["method"],
                    v * t1["unit"],
                    math.nan,
                    u * t1["unit"],
                    1,
                )
            )
    t2 = d["table2"]
    for l, text in zip(t2["l"], t2["values"], strict=True):
        v, u = parse_printed(text)
        cells.append(
            PaperCell(2, l, "var_dw", t2["method"], v * t2["unit"], math.nan, u * t2["unit"], 1)
        )
    for row in d["table4"]["rows"]:
        s2 = float(row["sigma2"])
        n = n_mc if s2 > 0 else 1
        v, u = parse_printed(row["snr"])
        cells.append(PaperCell(4, s2, "snr", "scenario", v, math.nan, u, n))
        for method in ("wang-lsm", "wang-iv"):
            for param, (mean, std) in row[method].items():
                v, u = parse_printed(mean)
                s = parse_printed(std)[0] if std is not None else (0.0 if s2 == 0 else math.nan)
                cells.append(PaperCell(4, s2, param, method, v, s, u, n))
    for row in d["table5"]["rows"]:
        s2 = float(row["sigma2"])
        n = n_mc if s2 > 0 else 1
        for col, (column, method) in TABLE5_COLUMNS.items():
            mean, std = row[col]
            v, u = parse_printed(mean)
            s = parse_printed(std)[0] if std is not None else (0.0 if s2 == 0 else math.nan)
            cells.append(PaperCell(5, s2, column, method, v, s, u, n))
    return cells


def standard_error(
    ours_std: float, n: int, paper_std: float, n_paper: int, unit: float = 0.0
) -> float:
    """``sqrt(s_o^2/n + s_p^2/n_p + u^2/12)``. A spread that is not known (the paper prints
    none, or a single run of ours) is taken equal to the other side's (the null hypothesis of
    one common distribution); ``nan`` when neither is known."""
    if not math.isfinite(paper_std):
        paper_std = ours_std
    if not math.isfinite(ours_std):
        ours_std = paper_std
    if n < 1 or n_paper < 1:
        return math.nan
    u = unit if math.isfinite(unit) else 0.0
    return math.sqrt(ours_std**2 / n + paper_std**2 / n_paper + u**2 / 12.0)


def z_score(
    ours: float,
    ours_std: float,
    n: int,
    paper: float,
    paper_std: float,
    n_paper: int,
    unit: float = 0.0,
) -> float:
    """``(ours - paper) / SE`` (see :func:`standard_error`); ``nan`` where undefined."""
    if not (math.isfinite(ours) and math.isfinite(paper)):
        return math.nan
    se = standard_error(ours_std, n, paper_std, n_paper, unit)
    if not math.isfinite(se) or se <= 0.0:
        return math.nan
    return (ours - paper) / se


@dataclass
class Summary:
    """Share of scored cells with ``|z| <= limit`` and the cells beyond."""

    scored: int
    within: int
    unscored: int
    beyond: list[dict[str, Any]] = field(default_factory=list)
    limit: float = Z_LIMIT

    @property
    def share(self) -> float:
        return self.within / self.scored if self.scored else math.nan

    def line(self) -> str:
        pct = f"{100 * self.share:.0f} %" if self.scored else "n/a"
        return (
            f"{self.within} of {self.scored} scored cells ({pct}) within |z| <= {self.limit:g}; "
            f"{len(self.beyond)} beyond; {self.unscored} not scored (z undefined)"
        )

    def text(self) -> str:
        lines = [self.line()]
        if self.beyond:
            lines.append(f"cells beyond |z| = {self.limit:g} (largest first):")
            lines += ["  " + describe_cell(c) for c in self.beyond]
        return "\n".join(lines) + "\n"


def format_number(v: float) -> str:
    if not isinstance(v, int | float) or not math.isfinite(v):
        return str(v)
    return f"{v:.4g}" if (abs(v) >= 1e-3 or v == 0) else f"{v:.4e}"


def describe_cell(c: Mapping[str, Any]) -> str:
    """One line per cell, e.g. ``T4 wang-lsm a1 @ sigma2=0.001: ours -1.964 +- 0.0051 vs paper
    -1.965 +- 0.0054, z = +0.9`` (Table 1: ``na=2 tau=3``; Table 2: ``l=1``)."""
    ours = format_number(float(c["ours"]))
    if math.isfinite(float(c.get("ours_std", math.nan))):
        ours += f" +- {format_number(float(c['ours_std']))}"
    paper = format_number(float(c["paper"]))
    if math.isfinite(float(c.get("paper_std", math.nan))):
        paper += f" +- {format_number(float(c['paper_std']))}"
    table = int(c["table"])
    if table == 1:
        where = f"V na={int(c['row'])} tau={c['column']}"
    elif table == 2:
        where = f"var_dw l={int(c['row'])}"
    else:
        where = f"{c['column']} @ sigma2={float(c['row']):g}"
    return f"T{table} {c['method']} {where}: ours {ours} vs paper {paper}, z = {float(c['z']):+.1f}"


def summarise(frame: Any, limit: float = Z_LIMIT) -> Summary:
    """:class:`Summary` of a ``reproduce.csv`` frame (rows with a finite ``z`` are scored)."""
    import numpy as np

    z = frame["z"].to_numpy(dtype=float)
    finite = np.isfinite(z)
    beyond = frame[finite & (np.abs(z) > limit)].copy()
    beyond = beyond.iloc[np.argsort(-np.abs(beyond["z"].to_numpy(dtype=float)), kind="stable")]
    return Summary(
        scored=int(finite.sum()),
        within=int((finite & (np.abs(z) <= limit)).sum()),
        unscored=int((~finite).sum()),
        beyond=beyond.to_dict("records"),
        limit=limit,
    )


def _pm(mean: float, std: float, digits: int) -> str:
    if not math.isfinite(mean):
        return "inf" if mean == math.inf else "-"
    s = f"{mean:.{digits}f}"
    if math.isfinite(std):
        s += f" ± {std:.{digits}f}"
    return s


def _with_z(text: str, z: float) -> str:
    return f"{text} (z {z:+.1f})" if math.isfinite(z) else text


def display_tables(frame: Any) -> dict[str, Any]:
    """Side-by-side tables (strings) from a ``reproduce.csv`` frame: ``table1``, ``table2``,
    ``table4``, ``snr``, ``table5`` (each present when the frame has its rows)."""
    import pandas as pd

    out: dict[str, Any] = {}
    f = frame.copy()
    f["row"] = f["row"].astype(float)

    t1 = f[f["table"] == 1]
    if len(t1):
        recs = []
        for (method, na), g in t1.groupby(["method", "row"], sort=False):
            rec = {"method": method, "na": int(na)}
            for _, c in g.iterrows():
                rec[f"tau={c['column']} ours"] = _with_z(f"{c['ours'] / 1e-7:.3f}", c["z"])
                rec[f"tau={c['column']} paper"] = f"{c['paper'] / 1e-7:.3f}"
            recs.append(rec)
        out["table1"] = pd.DataFrame(recs).sort_values(["na", "method"], kind="stable")
    t2 = f[f["table"] == 2]
    if len(t2):
        out["table2"] = pd.DataFrame(
            [
                {
                    "l": int(c["row"]),
                    "ours (x1e-7)": _with_z(f"{c['ours'] / 1e-7:.4f}", c["z"]),
                    "ours std (x1e-7)": f"{c['ours_std'] / 1e-7:.4f}",
                    "paper (x1e-7)": f"{c['paper'] / 1e-7:.5g}",
                }
                for _, c in t2.iterrows()
            ]
        )
    t4 = f[(f["table"] == 4) & (f["column"] != "snr")]
    if len(t4):
        recs = []
        for (s2, method), g in t4.groupby(["row", "method"], sort=True):
            rec = {"sigma2": f"{s2:g}", "method": method}
            for _, c in g.iterrows():
                rec[f"{c['column']} ours"] = _with_z(_pm(c["ours"], c["ours_std"], 4), c["z"])
                rec[f"{c['column']} paper"] = _pm(c["paper"], c["paper_std"], 4)
            recs.append(rec)
        out["table4"] = pd.DataFrame(recs)
    snr = f[f["column"] == "snr"]
    if len(snr):
        out["snr"] = pd.DataFrame(
            [
                {
                    "sigma2": f"{c['row']:g}",
                    "SNR ours": _with_z(_pm(c["ours"], c["ours_std"], 3), c["z"]),
                    "SNR paper": _pm(c["paper"], math.nan, 4),
                    "ratio paper/ours": (
                        f"{c['paper'] / c['ours']:.3f}"
                        if math.isfinite(c["paper"]) and c["ours"]
                        else "-"
                    ),
                }
                for _, c in snr.iterrows()
            ]
        )
    t5 = f[f["table"] == 5]
    if len(t5):
        recs = []
        names = {
            ("F", "wang-lsm"): "F_LSM",
            ("F0", "oracle"): "F0_LSM",
            ("F0", "oracle-inv"): "F0_INV",
        }
        for s2, g in t5.groupby("row", sort=True):
            rec = {"sigma2": f"{s2:g}"}
            for _, c in g.iterrows():
                name = names.get((c["column"], c["method"]), f"F_INV [{c['method']}]")
                rec[f"{name} ours"] = _with_z(_pm(c["ours"], c["ours_std"], 2), c["z"])
                rec[f"{name} paper"] = _pm(c["paper"], c["paper_std"], 2)
            recs.append(rec)
        out["table5"] = pd.DataFrame(recs)
    return out


def display_notes(realisations: int | None = None) -> dict[str, str]:
    """What the ``ours`` cells of each display table hold, for the Markdown headers.

    Tables 1 and 2 show run 0 (one realisation, as the paper does) with no ``±``; Table 2 has
    the spread over the realisations in its own column, Table 1 only through ``z``. Tables 4,
    5 and the SNR column show ``mean ± std`` over the Monte Carlo runs.

    Parameters
    ----------
    realisations : int, optional
        Realisations behind the spread of Tables 1 and 2 (named when given).

    Returns
    -------
    dict of str to str
        Note per table name (``table1``, ``table2``, ``table4``, ``snr``, ``table5``).
    """
    over = f"over {realisations} realisations" if realisations else "over the realisations"
    single = "ours: run 0, one realisation as in the paper"
    mean = "ours: mean ± std over runs; z as in reproduce.csv"
    return {
        "table1": f"{single}; z uses its spread {over} (ours_std in reproduce.csv)",
        "table2": f"{single}; ours std: its spread {over}; z as in reproduce.csv",
        "table4": mean,
        "snr": mean,
        "table5": mean,
    }


def write_display_tables(frame: Any, out: Path, *, realisations: int | None = None) -> list[Path]:
    """Write each display table (:func:`display_tables`) as Markdown and LaTeX into ``out``.

    Parameters
    ----------
    frame : pandas.DataFrame
        A ``reproduce.csv`` frame.
    out : Path
        Folder to write ``table1.md``, ``table1.tex`` ... into.
    realisations : int, optional
        Realisations behind the spread of Tables 1 and 2, named in their headers.

    Returns
    -------
    list of Path
        The files written.
    """
    from hbench.tables.results import to_latex, to_markdown

    paths = []
    notes = display_notes(realisations)
    captions = {
        "table1": "Table 1: V(na, tau) x 1e-7, one realisation at sigma^2 = 1e-3",
        "table2": "Table 2: Var of Delta w(l) x 1e-7, same realisation",
        "table4": "Table 4: a1, a2, b2 mean +- std (b2 sign corrected)",
        "snr": "The SNR column ||y0|| / ||v||",
        "table5": "Table 5: fitness (%) mean +- std",
    }
    for name, table in display_tables(frame).items():
        (out / f"{name}.md").write_text(
            f"**{captions[name]}** ({notes[name]})\n\n" + to_markdown(table)
        )
        (out / f"{name}.tex").write_text(to_latex(table, caption=captions[name]))
        paths += [out / f"{name}.md", out / f"{name}.tex"]
    return paths

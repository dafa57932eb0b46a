"""The report's "Beyond the paper" section: hbench's own methods and their claims.

The section is shown when a method registered by the ``hbench_extensions`` plugin package ran
(membership from the module of the registered class, :func:`is_extension`). Its subsections
each need certain methods among the rows; without them the subsection is one line naming the
methods to add:

* **delay** (assumption A3 relaxed; needs ``wang-delay``): the hit rate of the total delay
  estimate ``tau + m p`` (fast samples) per method against the mean SNR, pooled over the delays
  of the cells ``wang-delay`` ran on (``wang-lsm`` is given m, as A3 says; ``wang-delay``
  estimates it), tau's hit rate for context, and ``wang-delay``'s hit rate per delay and level.
* **coloured noise** (needs ``wang-iv`` and ``wang-lsm-cn`` or ``wang-iv-opt``): a1's bias and
  std per cell for ``wang-lsm, wang-iv, wang-lsm-cn, wang-iv-opt`` and whether |bias| and std
  are below the IVM's (``wang-iv``'s) std. Claim: both hold at sigma^2 = 1e-2 on the paper's
  example.
* **joint refinement** (needs ``wang-lsm``, ``joint-refine``, ``oracle``): F_LSM, F_joint, F0
  and the share of the gap closed, (F_joint - F_LSM) / (F0 - F_LSM). Claim: at least half at
  sigma^2 >= 5e-3, no loss at low noise.

:func:`plan` computes the tables and the figure specs (rendered in the report's one batch,
:func:`hbench.report.figures.render_many`); :meth:`BeyondSection.html` writes the section from the
rendered PNGs. All numbers come from :func:`hbench.tables.results.aggregate` and
:func:`hbench.tables.results.structure`, keyed by cell and noise level (SNR cells apart).
"""

from __future__ import annotations

import html
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from hbench.tables import results

#: The plugin package whose methods this section is about.
EXTENSIONS_PACKAGE = "hbench_extensions"
DELAY_METHOD = "wang-delay"
IV_REFERENCE = "wang-iv"
#: The a1 comparison's methods, in the table's order (the paper's LSM and IVM first).
COLOURED_METHODS = ("wang-lsm", "wang-iv", "wang-lsm-cn", "wang-iv-opt")
JOINT_METHODS = {"F_LSM": "wang-lsm", "F_joint": "joint-refine", "F0": "oracle"}
#: What each subsection needs: groups of which at least one method must have run.
NEEDS: dict[str, tuple[tuple[str, ...], ...]] = {
    "delay": ((DELAY_METHOD,),),
    "coloured": ((IV_REFERENCE,), ("wang-lsm-cn", "wang-iv-opt")),
    "joint": tuple((m,) for m in JOINT_METHODS.values()),
}
PRESETS = {
    "delay": "hbench sweep -m experiment=delay_beyond_a3",
    "coloured": "hbench sweep -m experiment=beyond_paper",
    "joint": "hbench sweep -m experiment=beyond_paper",
}
#: Cell columns besides the method (``level``: sigma2, or -snr_target for SNR cells).
CELL = ["nonlinearity", "p", "delay", results.LEVEL]
Label = Callable[[str], str]


def is_extension(name: str) -> bool:
    """Whether the method registered as ``name`` comes from :data:`EXTENSIONS_PACKAGE`."""
    from hbench.errors import PluginNotFoundError
    from hbench.plugins import registry

    try:
        cls = registry().get("identifiers", name)
    except PluginNotFoundError:
        return False
    return str(getattr(cls, "__module__", "")).split(".")[0] == EXTENSIONS_PACKAGE


def level_label(level: float) -> str:
    """``snr=5`` for an SNR cell (negative level), ``sigma2=0.001`` for a sigma^2 cell."""
    if level is None or (isinstance(level, float) and math.isnan(level)):
        return "?"
    return f"snr={-level:g}" if level < 0 else f"sigma2={level:g}"


def missing(methods: Sequence[str], part: str) -> list[str]:
    """The requirement groups of subsection ``part`` that no method of ``methods`` meets."""
    have = set(methods)
    return [" or ".join(g) for g in NEEDS[part] if not have.intersection(g)]


def _ordered(table: pd.DataFrame) -> pd.DataFrame:
    """Rows by (nonlinearity, p), then SNR cells by rising SNR, then sigma^2 cells by rising
    sigma^2 (column ``_o``: :func:`hbench.tables.results.level_order`, as in the other tables)."""
    order = results.level_order(table[results.LEVEL])
    return table.assign(_o=order).sort_values(["nonlinearity", "p", "_o"], kind="mergesort")


# --------------------------------------------------------------------------- tables


def delay_hit_rates(structure: pd.DataFrame, is_oracle: Callable[[str], bool]) -> pd.DataFrame:
    """Hit rates of the total delay and of tau pooled over delays, per method and level.

    Parameters
    ----------
    structure : DataFrame
        :func:`hbench.tables.results.structure` with ``level=True``.
    is_oracle : callable
        ``is_oracle(method)``: oracles know the truth and are left out.

    Returns
    -------
    DataFrame
        One row per (method, nonlinearity, p, level) over the cells :data:`DELAY_METHOD` ran
        on: ``noise`` (:func:`level_label`), ``snr_mean, delays, n, delay_hit_rate,
        tau_hit_rate`` and :data:`hbench.tables.results.LEVEL`. Pooled rates and SNRs weight each
        cell by its ``n``.
    """
    cells = structure.loc[structure["method"] == DELAY_METHOD, CELL].drop_duplicates()
    s = structure.merge(cells, on=CELL)
    # a boolean mask even when s is empty (an empty object mask would not combine with &)
    s = s[~s["method"].map(is_oracle).astype(bool) & s["quantity"].isin(("delay", "tau"))]
    s = s.assign(hits=s["hit_rate"] * s["n"], snr_n=s["snr_mean"] * s["n"])
    keys = ["method", "nonlinearity", "p", results.LEVEL]
    g = (
        s.groupby([*keys, "quantity"], sort=True, dropna=False)
        .agg(
            delays=("delay", "nunique"),
            n=("n", "sum"),
            hits=("hits", "sum"),
            snr_n=("snr_n", "sum"),
        )
        .reset_index()
    )
    g["hit_rate"] = g["hits"] / g["n"].where(g["n"] > 0)
    g["snr_mean"] = g["snr_n"] / g["n"].where(g["n"] > 0)
    delay = g[g["quantity"] == "delay"].drop(columns=["quantity", "hits", "snr_n"])
    tau = g.loc[g["quantity"] == "tau", [*keys, "hit_rate"]]
    out = delay.rename(columns={"hit_rate": "delay_hit_rate"}).merge(
        tau.rename(columns={"hit_rate": "tau_hit_rate"}), on=keys, how="left"
    )
    out["noise"] = out[results.LEVEL].map(level_label)
    out = _ordered(out).sort_values(["method"], kind="mergesort")
    cols = ["method", "nonlinearity", "p", "noise", "snr_mean", "delays", "n"]
    return out[[*cols, "delay_hit_rate", "tau_hit_rate", results.LEVEL]].reset_index(drop=True)


def delay_grid(structure: pd.DataFrame, pooled: pd.DataFrame) -> pd.DataFrame:
    """:data:`DELAY_METHOD`'s hit rate of the total delay: one row per (nonlinearity, p,
    delay), one column per noise level (``snr=2``, ...; ordered by the pooled mean SNR)."""
    s = structure[(structure["method"] == DELAY_METHOD) & (structure["quantity"] == "delay")]
    if s.empty:
        return pd.DataFrame(columns=["nonlinearity", "p", "delay"])
    order = (
        pooled[pooled["method"] == DELAY_METHOD].groupby("noise")["snr_mean"].mean().sort_values()
    )
    wide = s.assign(noise=s[results.LEVEL].map(level_label)).pivot_table(
        index=["nonlinearity", "p", "delay"],
        columns="noise",
        values="hit_rate",
        aggfunc="first",
    )
    cols = [c for c in order.index if c in wide.columns]
    cols += [c for c in wide.columns if c not in cols]
    wide = wide[cols].reset_index()
    wide.columns.name = None
    return wide


def _yes_no(cond: pd.Series, known: pd.Series) -> pd.Series:
    return pd.Series(np.where(known, np.where(cond, "yes", "no"), ""), index=cond.index)


def coloured_table(fitness: pd.DataFrame, bias: pd.DataFrame) -> pd.DataFrame:
    """a1's bias and std per cell for :data:`COLOURED_METHODS`, judged against wang-iv's std.

    Parameters
    ----------
    fitness, bias : DataFrame
        :func:`hbench.tables.results.aggregate` with ``level=True``.

    Returns
    -------
    DataFrame
        One row per (cell, method) of the cells where wang-iv ran, methods in the order of
        :data:`COLOURED_METHODS`: ``a1_true, a1_bias, a1_std, iv_std, n`` and ``yes``/``no``
        in ``bias_lt_iv_std`` (|bias| < std(wang-iv)) and ``std_lt_iv_std`` (std <
        std(wang-iv); empty on wang-iv's own row).
    """
    a1 = bias[(bias["parameter"] == "a1") & bias["method"].isin(COLOURED_METHODS)]
    ref = a1.loc[a1["method"] == IV_REFERENCE, [*CELL, "std"]].rename(columns={"std": "iv_std"})
    t = a1.merge(ref, on=CELL).merge(
        fitness[["method", *CELL, "snr_mean"]], on=["method", *CELL], how="left"
    )
    known = t["iv_std"].notna() & t["std"].notna()
    t["bias_lt_iv_std"] = _yes_no(t["bias"].abs() < t["iv_std"], known & t["bias"].notna())
    t["std_lt_iv_std"] = _yes_no(t["std"] < t["iv_std"], known & (t["method"] != IV_REFERENCE))
    t["_m"] = t["method"].map(COLOURED_METHODS.index)
    t = _ordered(t).sort_values(["nonlinearity", "p", "delay", "_o", "_m"], kind="mergesort")
    t = t.rename(columns={"true": "a1_true", "bias": "a1_bias", "std": "a1_std"})
    t["noise"] = t[results.LEVEL].map(level_label)
    cols = ["nonlinearity", "p", "delay", "noise", "snr_mean", "method", "a1_true", "a1_bias"]
    cols += ["a1_std", "iv_std", "n", "bias_lt_iv_std", "std_lt_iv_std"]
    return t[cols].reset_index(drop=True)


def joint_table(fitness: pd.DataFrame) -> pd.DataFrame:
    """F_LSM, F_joint and F0 per cell and the share of the gap closed by the joint refinement.

    Parameters
    ----------
    fitness : DataFrame
        :func:`hbench.tables.results.aggregate`'s first table with ``level=True``.

    Returns
    -------
    DataFrame
        One row per cell where all three of :data:`JOINT_METHODS` ran: ``F_LSM, F_joint, F0``
        (mean fitness, %) and ``gap_closed = (F_joint - F_LSM) / (F0 - F_LSM)`` (empty when
        F0 = F_LSM); ``snr_mean`` is wang-lsm's, ``n`` joint-refine's ok runs.
    """

    def pick(column: str, extra: list[str]) -> pd.DataFrame:
        f = fitness[fitness["method"] == JOINT_METHODS[column]]
        return f[[*CELL, *extra, "fitness_mean"]].rename(columns={"fitness_mean": column})

    t = (
        pick("F_LSM", ["snr_mean"])
        .merge(pick("F_joint", ["n"]), on=CELL)
        .merge(pick("F0", []), on=CELL)
    )
    den = t["F0"] - t["F_LSM"]
    t["gap_closed"] = (t["F_joint"] - t["F_LSM"]) / den.where(den != 0)
    t = _ordered(t).sort_values(["nonlinearity", "p", "delay", "_o"], kind="mergesort")
    t["noise"] = t[results.LEVEL].map(level_label)
    cols = ["nonlinearity", "p", "delay", "noise", "snr_mean", "n", "F_LSM", "F_joint", "F0"]
    return t[[*cols, "gap_closed"]].reset_index(drop=True)


# --------------------------------------------------------------------------- the section


@dataclass
class BeyondSection:
    """The planned section: tables (written beside the report), figures to render, HTML.

    ``blocks`` are HTML fragments; an ``int`` stands for the figure of that index in
    ``figures`` (``(figure id, spec, caption)``).
    """

    tables: dict[str, pd.DataFrame] = field(default_factory=dict)
    figures: list[tuple[str, Any, str]] = field(default_factory=list)
    blocks: list[str | int] = field(default_factory=list)

    def html(self, pngs: Sequence[bytes]) -> str:
        """The section's HTML with ``pngs`` (one per entry of ``figures``) embedded."""
        from hbench.report.elements import html_figure

        out = []
        for b in self.blocks:
            if isinstance(b, int):
                fig_id, _, caption = self.figures[b]
                out.append(html_figure(fig_id, pngs[b], caption))
            else:
                out.append(b)
        return "\n".join(out)


def _esc(x: Any) -> str:
    return html.escape(str(x), quote=True)


def _missing_note(part: str, need: list[str]) -> str:
    return (
        f'<p class="note" id="beyond-{part}-missing">Not shown: add {_esc(" and ".join(need))} '
        f"to the sweep (e.g. <code>{_esc(PRESETS[part])}</code>).</p>"
    )


def _delay_blocks(
    section: BeyondSection, structure: pd.DataFrame, out: Path, series_label: Label
) -> None:
    from hbench.report.elements import html_table
    from hbench.report.style import method_info

    pooled = delay_hit_rates(structure, lambda m: method_info(m)["oracle"])
    grid = delay_grid(structure, pooled)
    blocks = section.blocks
    blocks.append(
        "<p>Assumption A3 gives every method the delay's multiple m of p; y alone fixes only "
        "the fractional delay tau in [0, p). <code>wang-delay</code> estimates m from the "
        "alignment of x with the estimated inner signal; the other methods are given it. A hit: "
        "the total delay tau + m p (fast samples) equals the plant's. Rates pooled over the "
        "delays of the cells wang-delay ran on; tau's hit rate for context.</p>"
    )
    if pooled.empty:
        blocks.append('<p class="note">No ok runs of wang-delay in these rows.</p>')
        return
    wd = pooled[(pooled["method"] == DELAY_METHOD) & pooled["delay_hit_rate"].notna()]
    if wd.empty:
        blocks.append('<p class="note">No hit rate of wang-delay (no true delay known).</p>')
        return
    hits = float((wd["delay_hit_rate"] * wd["n"]).sum())
    n = int(wd["n"].sum())
    worst = wd.loc[wd["delay_hit_rate"].idxmin()]
    blocks.append(
        f"<p><b>wang-delay found the total delay in {hits:.0f} of {n} runs "
        f"({100 * hits / max(n, 1):.1f} %) over {int(wd['delays'].max())} delays; lowest "
        f"rate {worst['delay_hit_rate']:.3g} at {_esc(worst['noise'])}.</b></p>"
    )
    multi = pooled[["nonlinearity", "p"]].drop_duplicates().shape[0] > 1
    fig = pooled.assign(
        series=pooled["method"]
        + (" | " + pooled["nonlinearity"] + ", p=" + pooled["p"].astype(str) if multi else "")
    )
    section.figures.append(
        (
            "fig-beyond-delay",
            (out / "beyond_delay_hit_rate", "hit_rate_vs_snr", (fig, series_label), {}),
            "Hit rate of the total delay tau + m p (solid) and of tau (dashed) against the "
            "mean SNR of the level, pooled over the delays, per method.",
        )
    )
    blocks.append(len(section.figures) - 1)
    shown = pooled.drop(columns=[results.LEVEL])
    blocks.append("<h4>Hit rates pooled over delays</h4>")
    blocks.append(html_table(shown, floatfmt=".3g", table_id="table-beyond-delay"))
    blocks.append("<h4>wang-delay: hit rate of the total delay per delay and level</h4>")
    blocks.append(html_table(grid, floatfmt=".3g", table_id="table-beyond-delay-grid"))
    section.tables["beyond_delay"] = shown
    section.tables["beyond_delay_grid"] = grid


def _coloured_blocks(section: BeyondSection, fitness: pd.DataFrame, bias: pd.DataFrame) -> None:
    from hbench.report.elements import html_table

    t = coloured_table(fitness, bias)
    section.blocks.append(
        "<p>a1 over the runs of each cell. Claim: at σ² = 1e-2 on the paper's example, a "
        "coloured-noise variant's |bias| is below the IVM's (wang-iv's) std while its own std "
        "stays below the IVM's. Columns <code>bias_lt_iv_std</code>: |bias| &lt; std(wang-iv); "
        "<code>std_lt_iv_std</code>: std &lt; std(wang-iv).</p>"
    )
    if t.empty:
        section.blocks.append('<p class="note">No cell where wang-iv ran: nothing to compare.</p>')
        return
    both = t[(t["bias_lt_iv_std"] == "yes") & (t["std_lt_iv_std"] == "yes")]
    multi = t[["nonlinearity", "p", "delay"]].drop_duplicates().shape[0] > 1
    where = []
    for m in ("wang-lsm-cn", "wang-iv-opt"):
        if m in set(t["method"]):
            sub = both[both["method"] == m]
            cells = [
                f"{r.noise}" + (f" (p={r.p}, delay={r.delay})" if multi else "")
                for r in sub.itertuples()
            ]
            where.append(f"{m}: {', '.join(cells) if cells else 'no cell'}")
    section.blocks.append(f"<p><b>Both hold — {_esc('; '.join(where))}.</b></p>")
    section.blocks.append(html_table(t, floatfmt=".3g", table_id="table-beyond-coloured"))
    section.tables["beyond_coloured"] = t


def _joint_blocks(section: BeyondSection, fitness: pd.DataFrame) -> None:
    from hbench.report.elements import html_table

    t = joint_table(fitness)
    section.blocks.append(
        "<p>Fitness F (%) of wang-lsm (F_LSM), joint-refine (F_joint) and the oracle bound "
        "(F0) per cell; <code>gap_closed</code> = (F_joint − F_LSM) / (F0 − F_LSM). Claim: at "
        "least half of the gap closed at σ² ≥ 5e-3, no loss (F_joint ≥ F_LSM) at low noise.</p>"
    )
    if t.empty:
        section.blocks.append('<p class="note">No cell where all three methods ran.</p>')
        return
    section.blocks.append(html_table(t, floatfmt=".4g", table_id="table-beyond-joint"))
    section.tables["beyond_joint"] = t


def plan(rows: pd.DataFrame, out: Path, series_label: Label) -> BeyondSection | None:
    """Plan the section for ``rows``.

    Parameters
    ----------
    rows : DataFrame
        Tidy rows (:data:`hbench.bench.schema.TIDY_COLUMNS`).
    out : Path
        The report folder (stems of the figures).
    series_label : callable
        Label of a figure series ``method[ | facet]``.

    Returns
    -------
    BeyondSection or None
        None when no method of :data:`EXTENSIONS_PACKAGE` is among the rows.
    """
    methods = [str(m) for m in rows["method"].unique()]  # in order of appearance
    ext = [m for m in methods if is_extension(m)]
    if not ext:
        return None
    section = BeyondSection()
    section.blocks += [
        '<section id="beyond"><h2>Beyond the paper</h2>',
        "<p>hbench's own methods (plugin package <code>hbench_extensions</code>) in these rows: "
        f"{_esc(', '.join(ext))}.</p>",
    ]
    fitness, bias = results.aggregate(rows, level=True)
    titles = {
        "delay": "Delay: assumption A3 relaxed",
        "coloured": "Coloured noise: a1 against the IVM",
        "joint": "Joint refinement: the gap to the oracle",
    }
    for part, title in titles.items():
        section.blocks.append(f'<div id="beyond-{part}"><h3>{_esc(title)}</h3>')
        need = missing(methods, part)
        if need:
            section.blocks.append(_missing_note(part, need))
        elif part == "delay":
            _delay_blocks(section, results.structure(rows, level=True), out, series_label)
        elif part == "coloured":
            _coloured_blocks(section, fitness, bias)
        else:
            _joint_blocks(section, fitness)
        section.blocks.append("</div>")
    if section.tables:
        names = ", ".join(f"{n}.md, {n}.tex" for n in section.tables)
        section.blocks.append(f"<p>Also written beside this page: {_esc(names)}.</p>")
    section.blocks.append("</section>")
    return section

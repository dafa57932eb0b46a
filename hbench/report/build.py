"""``hbench report RUN_DIR [--out DIR]``: the comparison report of a sweep or a reproduction.

Input: a folder with tidy ``rows.parquet`` (a sweep's root, a reproduction), or with none at its
root, every ``**/rows.parquet`` below it (a Hydra multirun has one per job; rows present twice are
kept once). ``provenance.json`` files (root and below) feed the provenance block; ``examples.npz``
files (written by ``hbench reproduce``; see :func:`hbench.paper.reproduce.save_examples`) the x-U
graphs; ``reproduce.csv`` (and ``investigation.csv``) the comparison with the paper.

Output (default ``RUN_DIR/report/``, or a fresh ``RUN_DIR/report-<time>/`` if that exists): a
self-contained ``report.html`` (figures embedded as base64 PNG data URIs, no external
resources), the figures as PNG (200 dpi) and PDF (TrueType fonts), and the tables. The page
opens with the headline (:func:`write_summary`: ``summary.{csv,md,tex}`` and
``summary_bias.{csv,md,tex}``, :mod:`hbench.tables.summary` and :mod:`hbench.tables.headline`):
who wins each cell, with what confidence. The other tables, as Markdown and LaTeX (booktabs),
the method's label in the ``method`` column: ``fitness``, ``bias`` (the contract's aggregation),
``structure`` (hit rates of na, nb, tau, delay), ``ranking`` (mean rank of fitness per cell
among the blind methods; oracles are bounds, not ranked), ``timing`` (seconds per run), and,
when some run is not ``ok``, ``failures`` (:func:`hbench.report.aggregate.failure_table`: per
method and cell, how many runs failed or were not identifiable, and why). On the page every
table scrolls in its own box, columns with no value are left out (said under the table), the
long tables and the provenance are folded (``<details>``), and the provenance is one block: what
every job shares, and a table of what differs. A table or figure with no data is replaced by a
one-line note (the Markdown and LaTeX files of an empty table say why it is empty); when no run
produced an estimate the page says so first. Methods whose class is a reconstruction
(``reconstruction = True``) are labelled so wherever they appear. When a method of the
``hbench_extensions`` plugin package ran, a section "Beyond the paper" follows the tables
(:mod:`hbench.report.beyond`; its tables ``beyond_*`` are written beside the others).

This module assembles the page; what it reads is :mod:`hbench.report.inputs`, the numbers it
shows :mod:`hbench.report.aggregate`, its table files :mod:`hbench.report.table_files`."""

from __future__ import annotations

import argparse
import json
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from hbench.aliases import moved
from hbench.errors import InputError
from hbench.report.aggregate import cell_stats, failure_table, run_table, status_counts
from hbench.report.elements import escape as _esc
from hbench.report.elements import html_figure, html_table
from hbench.report.inputs import load_examples, load_provenance, load_rows
from hbench.report.style import method_info
from hbench.report.table_files import markdown_cells, write_table
from hbench.system import atomic

#: Names not in the registry that reports may meet (defined by ``hbench reproduce``).
EXTRA_LABELS = {"wang-lsm-inv": "wang-lsm-inv (LSM + direct inverse)"}
FIGURE_IDS = (
    "fig-fitness-snr",
    "fig-bias-std-snr",
    "fig-xu",
    "fig-time",
    "fig-ranking",
    "fig-beyond-delay",
)


#: Names this module held that now live in the module named (read from here, they warn).
MOVED = {
    "find_rows": "hbench.report.inputs",
    "NOT_OK": "hbench.report.aggregate",
    "CELL_COLUMNS": "hbench.report.aggregate",
}


__getattr__ = moved(__name__, MOVED)


# --------------------------------------------------------------------------- labels


def method_label(name: str) -> str:
    """The name shown in reports: reconstructions and oracles say so."""
    info = method_info(name)
    label = EXTRA_LABELS.get(name, name)
    if info["reconstruction"]:
        label += " (reconstruction)"
    if info["oracle"]:
        label += " (oracle bound)"
    return label


def _series_label(series: str) -> str:
    """Label of a bias/std series: ``method[ = method2][ | facet]``."""
    methods, _, facet = series.partition(" | ")
    label = " = ".join(method_label(m) for m in methods.split(" = "))
    return label + (f" | {facet}" if facet else "")


# --------------------------------------------------------------------------- HTML


CSS = """
body{font-family:system-ui,-apple-system,Segoe UI,Helvetica,Arial,sans-serif;margin:2em auto;
max-width:1250px;color:#222;line-height:1.4;padding:0 1em}
h1{font-size:1.6em}
h2{font-size:1.25em;border-bottom:1px solid #ccc;padding-bottom:.2em;margin-top:2em}
h3{font-size:1.05em}
table{border-collapse:collapse;font-size:.82em;margin:.6em 0 1.2em}
th,td{border-top:1px solid #ddd;padding:.25em .55em;text-align:right;white-space:nowrap}
th{border-bottom:2px solid #888;border-top:2px solid #888;background:#f7f7f7}
td:first-child,th:first-child{text-align:left}
figure{margin:1em 0 2em}figure img{max-width:100%;border:1px solid #eee}
figcaption{font-size:.85em;color:#444}
pre{background:#f6f6f6;padding:.8em;overflow-x:auto;font-size:.78em;max-height:32em}
.note{background:#fff8e0;border-left:4px solid #e0b000;padding:.4em .8em}
.beyond{font-family:ui-monospace,Menlo,Consolas,monospace;font-size:.8em}
#table-failures td:last-child{white-space:normal;text-align:left;min-width:24em}
.scroll{max-width:100%;overflow-x:auto}
details{margin:.4em 0 1em}summary{cursor:pointer;color:#245}
.hidden-cols{font-size:.8em;color:#666;margin-top:-.8em}
table.headline td{vertical-align:top;line-height:1.25}
table.headline tbody th{text-align:left;background:none;border-bottom:none;
border-top:1px solid #ddd;white-space:normal;min-width:7em;max-width:11em}
table.headline td{padding:.25em .4em}
table.headline .paper{color:#666;font-size:.9em}
table.headline .diff{color:#345;font-size:.9em}
table.headline td.win{background:#eef6ee}
table.headline tr.bound th,table.headline tr.bound td{color:#777}
"""


def _fold(summary: str, inner: str, open_: bool = False) -> str:
    """``inner`` folded in a ``<details>`` element titled ``summary``."""
    return f"<details{' open' if open_ else ''}><summary>{_esc(summary)}</summary>{inner}</details>"


# --------------------------------------------------------------------------- the report


def xu_spec(out: Path, examples: Sequence[Mapping[str, Any]]) -> Any:
    """The report's x-U graphs (``out/xu``) of ``examples`` (the items of
    :func:`hbench.report.inputs.load_examples`), as a :data:`hbench.report.figures.FigureSpec`."""
    return (out / "xu", "xu_grid", (_pick_examples(examples), method_label), {})


def _pick_examples(examples: Sequence[Mapping[str, Any]]) -> list[dict[str, Any]]:
    """One example per nonlinearity (the middle one by sigma^2 when there are several)."""
    by: dict[str, list[Mapping[str, Any]]] = {}
    for ex in examples:
        by.setdefault(str(ex.get("nonlinearity", "?")), []).append(ex)
    panels = []
    for nl, exs in by.items():
        exs = sorted(exs, key=lambda e: float(e.get("sigma2") or 0.0))
        ex = exs[len(exs) // 2]
        s2 = ex.get("sigma2")
        title = f"σ² = {float(s2):g}" if s2 is not None else str(ex.get("cell", ""))
        panels.append(
            {
                "nonlinearity": nl,
                "title": title,
                "x": ex["x"],
                "U": ex["U"],
                "gain": float(ex["gain"]),
                "estimates": dict(ex["estimates"]),
            }
        )
    return panels


def _flatten(d: Any, prefix: str = "") -> dict[str, Any]:
    """A nested mapping as ``{"a.b.c": leaf}`` (lists are leaves)."""
    if not isinstance(d, Mapping):
        return {prefix: d}
    out: dict[str, Any] = {}
    for k, v in d.items():
        out.update(_flatten(v, f"{prefix}.{k}" if prefix else str(k)))
    return out


def provenance_block(prov: Sequence[tuple[Path, Mapping[str, Any]]]) -> tuple[dict, dict]:
    """``(common, differing)``: the provenance entries every file shares (flattened keys), and
    per key that differs, its value in each file (``created`` is left out: it always differs)."""
    flat = [_flatten({k: v for k, v in d.items() if k != "created"}) for _, d in prov]
    keys = list(dict.fromkeys(k for f in flat for k in f))
    common: dict[str, Any] = {}
    differing: dict[str, list[Any]] = {}
    for k in keys:
        values = [f.get(k) for f in flat]
        texts = {json.dumps(v, sort_keys=True, default=str) for v in values}
        if len(texts) == 1:
            common[k] = values[0]
        else:
            differing[k] = values
    return common, differing


def _provenance_html(prov: Sequence[tuple[Path, Mapping[str, Any]]], run_dir: Path) -> str:
    """One provenance block: what every job shares, then a table of what differs per file."""
    if not prov:
        return '<p class="note">No provenance.json found under the folder.</p>'
    import pandas as pd

    common, differing = provenance_block(prov)
    created = sorted(str(d.get("created", "?")) for _, d in prov)
    parts = [
        f"<p>{len(prov)} provenance file(s), created {_esc(created[0])}"
        + (f" to {_esc(created[-1])}" if len(created) > 1 else "")
        + ". Shared by all:</p>",
        "<details><summary>shared provenance (" + str(len(common)) + " entries)</summary>"
        f"<pre>{_esc(json.dumps(common, indent=2, default=str))}</pre></details>",
    ]
    if differing:
        table = pd.DataFrame(
            {"file": [str(p.relative_to(run_dir)) for p, _ in prov]}
            | {
                k: [json.dumps(v, default=str) if isinstance(v, list | dict) else v for v in vs]
                for k, vs in differing.items()
            }
        )
        parts.append("<p>What differs between the files:</p>")
        parts.append(
            _fold(
                f"{len(differing)} differing entries over {len(prov)} files",
                html_table(table, table_id="provenance-differs"),
                open_=len(prov) <= 12,
            )
        )
    return "\n".join(parts)


def _reproduction_html(run_dir: Path, out: Path) -> str:
    """The paper comparison when ``reproduce.csv`` is present."""
    import pandas as pd

    from hbench.tables import published as pub

    csv = run_dir / "reproduce.csv"
    if not csv.is_file():
        return ""
    frame = pd.read_csv(csv)
    summary = pub.summarise(frame)
    parts = [
        '<section id="reproduction"><h2>Reproduction of the paper (Section 6)</h2>',
        f"<p><b>{_esc(summary.line())}</b></p>",
        "<p>z = (ours − paper) / SE with SE² = s²<sub>ours</sub>/n + s²<sub>paper</sub>/"
        "n<sub>paper</sub> + u²/12 (u: the rounding unit of the printed number; "
        "s<sub>paper</sub> = s<sub>ours</sub> where the paper prints no spread; Tables 1-2 "
        "are single realisations, n = n<sub>paper</sub> = 1). Table 5: F_LSM = wang-lsm, "
        "F0_LSM = oracle, F_INV = the LSM estimates in the direct inverse, "
        "F0_INV = oracle-inv.</p>",
    ]
    summ = run_dir / "summary.txt"
    if summ.is_file():
        lines = summ.read_text().splitlines()[1:]  # the first line is the summary above
        parts.append(f'<pre class="beyond">{_esc(chr(10).join(lines))}</pre>')
    titles = {
        "table4": "Table 4: parameters (mean ± std; b2 sign corrected)",
        "snr": "SNR column",
        "table5": "Table 5: fitness (%)",
        "table1": "Table 1: V(na, τ) ×1e-7 (one realisation, σ² = 1e-3)",
        "table2": "Table 2: Var Δw(l) ×1e-7 (same realisation)",
    }
    shown = pub.display_tables(frame)
    for name in ("table4", "snr", "table5", "table1", "table2"):
        if name in shown:
            parts.append(f"<h3>{_esc(titles[name])}</h3>" + html_table(shown[name], table_id=name))
    for fig in ("figure4", "figure5"):
        png = run_dir / f"{fig}.png"
        if png.is_file():
            caption = {
                "figure4": "Figure 4: controller output x(n) vs estimated inner signal "
                "U(n) (one realisation, σ² = 1e-3)",
                "figure5": "Figure 5: x(n) vs the true inner signal U(n)",
            }[fig]
            parts.append(html_figure(fig, png.read_bytes(), caption))
    inv = run_dir / "investigation.csv"
    if inv.is_file():
        t = pd.read_csv(inv)
        # the reproduction summary's columns; the report has always left out within2_after
        cols = [c for c in pub.INVESTIGATION_COLUMNS if c in t.columns and c != "within2_after"]
        parts.append(
            "<h3>Investigation: alternatives against the defaults</h3>"
            "<p>mean |z| over Tables 4 (parameters, SNR) and 5, before (defaults) and "
            "after each single change; per-table columns after the change.</p>"
            + html_table(
                t[cols].sort_values("mean_abs_z_after"), floatfmt=".3g", table_id="investigation"
            )
        )
    parts += _cells_beyond_html(run_dir)
    parts.append("</section>")
    return "\n".join(parts)


def _cells_beyond_html(run_dir: Path) -> list[str]:
    """The investigation's cells beyond ``|z| = 2`` (``investigation_cells.csv``: per cell, the
    alternatives under which it is within) and the paper's own Table 4 rows scored on our loop
    (``published_row.csv``), where the run wrote them."""
    import pandas as pd

    parts = []
    cells = run_dir / "investigation_cells.csv"
    if cells.is_file():
        t = pd.read_csv(cells, keep_default_na=False, na_values=[""])
        t["within_by"] = t["within_by"].fillna("")
        shown = t[[c for c in t.columns if not str(c).startswith("z:")]]
        have = int((shown["within_by"] != "").sum())
        parts.append(
            "<h3>Cells beyond |z| = 2 and the alternatives that bring each within</h3>"
            f"<p>{have} of {len(shown)} cells beyond |z| = 2 under the defaults are within "
            "under at least one alternative (its z in brackets; a cell near 2 is moved within "
            "by many alternatives by chance). Each alternative's z per cell: "
            "<code>investigation_cells.csv</code>, columns <code>z:&lt;alternative&gt;</code>."
            "</p>" + html_table(shown, floatfmt=".3g", table_id="investigation-cells")
        )
    fixed = run_dir / "published_row.csv"
    if fixed.is_file():
        t = pd.read_csv(fixed)
        parts.append(
            "<h3>The paper's own Table 4 rows scored on our loop</h3>"
            "<p>Each published mean estimate (a1, a2, b2; the LSM and the IVM row of the level, "
            "the printed true values, and the simulated plant's exact ones) as a fixed model in "
            "eq. (27) (F_LSM) and in the direct inverse (F_INV), on the same realisations. "
            "Where the paper's own LSM row scores below the paper's F, no convention of "
            "scoring our estimates can close that F cell.</p>"
            + html_table(t, floatfmt=".4g", table_id="published-row")
        )
    truth = run_dir / "published_truth.csv"
    if truth.is_file():
        t = pd.read_csv(truth)
        off = t[(t["method"] == "wang-iv") & (t["z_truth"].abs() > 2.0)]
        parts.append(
            "<h3>Published IVM means off the true parameters</h3>"
            "<p>The IVM is consistent under the example's noise: its mean over 100 runs lies "
            "within about 2 of its standard errors of the truth. These published IVM cells do "
            "not (z of the published mean against the plant's true value, the paper's own "
            f"spread; all cells in <code>published_truth.csv</code>): {len(off)}.</p>"
            + (html_table(off, floatfmt=".4g", table_id="published-truth") if len(off) else "")
        )
    return parts


def write_summary(out: Path, run_dir: Path, rows: Any) -> tuple[Any, Any]:
    """Write the headline ``summary.{csv,md,tex}`` and ``summary_bias.{csv,md,tex}`` into
    ``out`` (:mod:`hbench.tables.summary`, rendered by :mod:`hbench.tables.headline`); the paper's
    values come from ``RUN_DIR/reproduce.csv`` where present. Returns the two tables."""
    import pandas as pd

    from hbench.tables import headline, summary
    from hbench.tables.results import to_markdown

    def bound(m: str) -> bool:
        return bool(method_info(m)["oracle"])

    paper_fit = paper_par = None
    csv = run_dir / "reproduce.csv"
    if csv.is_file():
        paper_fit, paper_par = summary.paper_values(pd.read_csv(csv))
    head = summary.summary(rows, bound, paper_fit)
    bias = summary.bias_summary(rows, bound, paper_par)
    head.to_csv(out / "summary.csv", index=False, float_format="%.10g")
    (out / "summary.md").write_text(headline.fitness_markdown(head, method_label))
    (out / "summary.tex").write_text(headline.fitness_latex(head, method_label))
    bias.to_csv(out / "summary_bias.csv", index=False, float_format="%.10g")
    (out / "summary_bias.md").write_text(to_markdown(markdown_cells(bias), ".4g"))
    (out / "summary_bias.tex").write_text(headline.bias_latex(bias, method_label))
    return head, bias


def _with_summary(stats: Any, table: Any, columns: dict[str, Any], by: Sequence[str] = ()) -> Any:
    """:func:`cell_stats`' ``stats`` with ``columns`` (name -> Series over ``table``) of a
    headline table, matched by method, cell (and ``by``)."""
    keys = ["method", "nonlinearity", "p", "delay", "_s2", "_st", *by]
    t = table.assign(
        _s2=table["sigma2"].astype(float).fillna(-1.0),
        _st=table["snr_target"].astype(float).fillna(-1.0),
        **columns,
    )[[*keys, *columns]]
    return stats.merge(t, on=keys, how="left")


def _headline_html(head: Any, bias: Any) -> str:
    """The section that opens the report: who wins each cell, with what confidence."""
    from hbench.tables import headline, summary

    parts = ['<section id="headline"><h2>Headline: who wins, with what confidence</h2>']
    if head.empty:
        parts.append('<p class="note">No ok run has a fitness: no headline table.</p>')
    else:
        parts += [
            f"<p>Fitness F (%): mean ± half-width of its 95 % interval. {_esc(summary.METHOD_NOTE)}"
            " Bold: the winner of the column where its lead is significant; <i>n.s.</i>: the "
            "best mean's lead is not significant; <i>tie</i>: not significantly worse than the "
            "best. Oracle bounds (grey) are not compared.</p>",
            '<div class="scroll">'
            + headline.fitness_html(head, method_label, "table-summary")
            + "</div>",
        ]
    if not bias.empty:
        parts.append(
            _fold(
                "Bias ± 95 % interval and RMSE of each parameter (blind methods)",
                '<div class="scroll">'
                + headline.bias_html(bias, method_label, "table-summary-bias")
                + "</div>",
            )
        )
    parts.append("</section>")
    return "\n".join(parts)


def _empty_reasons(none_ok: bool, status_line: str) -> dict[str, str]:
    """Why each statistics table of the report may be empty (said where the table would be)."""
    if none_ok:
        why = (
            f"No run produced an estimate (run status: {status_line}): this table is empty; "
            "why, per method and cell: the failures table."
        )
        return dict.fromkeys(("fitness", "bias", "structure", "ranking", "timing"), why)
    return {
        "fitness": "No ok run has a fitness: this table is empty.",
        "bias": "No ok run has parameter estimates (a1, a2, ..., b2, ...): this table is empty.",
        "structure": "No ok run has structure estimates (na, nb, tau, delay): this table is empty.",
        "ranking": "No blind method has a fitness in any cell: nothing to rank (oracles are "
        "bounds, not ranked).",
        "timing": "No ok run has a time: this table is empty.",
    }


def _failures_note(none_ok: bool, status_line: str) -> str:
    """The line above the failures table."""
    head = (
        f"No run produced an estimate (run status: {status_line})."
        if none_ok
        else f"Some runs produced no estimate (run status: {status_line})."
    )
    return (
        f"{head} Per method and cell: the runs that failed (the method raised) or were not "
        "identifiable, and their distinct messages (most frequent first, with their number of "
        "runs; the error column of the tidy rows holds every message whole)."
    )


def build_report(
    run_dir: Path | str,
    out: Path | str | None = None,
    *,
    rows: Any = None,
    tables: Mapping[str, Any] | None = None,
    jobs: int = 1,
    extra_figures: Sequence[Any] = (),
    spread: str = "ci",
    workers: Any = None,
    ready: Mapping[Path, Any] | None = None,
) -> Path:
    """Write the report of ``run_dir`` into ``out``; returns the path of ``report.html``.

    ``spread`` is what the fitness figure's error bars show: ``"ci"`` the 95 % interval of the
    mean, ``"std"`` one standard deviation over the runs.

    ``rows`` (already in memory) skips reading ``rows.parquet``; ``tables``, the rows'
    :func:`hbench.tables.results.aggregated_tables` when already computed (e.g. for
    :func:`hbench.tables.results.write_tables`), are not computed again; ``jobs > 1`` renders
    the figures in worker processes (:mod:`hbench.bench.parallel`); ``extra_figures``
    (:data:`hbench.report.figures.FigureSpec`) are rendered in the same batch (the
    reproduction's Figures 4 and 5); ``workers`` and ``ready`` are
    :func:`hbench.report.figures.render_many`'s: a pool already started that renders the
    workers' share, and the figures already submitted to it (the reproduction's x-U graphs,
    :func:`xu_spec`, drawn while it computes).

    The steps, in order: the output folder (:func:`_report_dir`), the statistics and the
    headline (:func:`_report_stats`), the tables written beside the page
    (:func:`_report_tables`), the figures rendered in one batch (:func:`_report_figures`), the
    page assembled (:func:`_report_page`).
    """
    from hbench.report import beyond as report_beyond
    from hbench.report import figures

    if spread not in figures.SPREADS:  # before any work
        raise InputError(f"--spread must be one of {', '.join(figures.SPREADS)}, got {spread!r}")
    run_dir = Path(run_dir)
    if rows is None:
        rows, files = load_rows(run_dir)
    else:
        files = [run_dir / "rows.parquet"]
    out = _report_dir(run_dir, out)
    stats, head, head_bias = _report_stats(out, run_dir, rows)
    shown = _report_tables(out, rows, stats, tables)
    beyond = report_beyond.plan(rows, out, _series_label)
    for name, table in (beyond.tables if beyond else {}).items():
        write_table(out, name, table)
    figs, beyond_pngs = _report_figures(
        out, run_dir, stats, shown, spread, beyond, extra_figures, jobs, workers, ready
    )
    page = [
        "<!DOCTYPE html>",
        '<html lang="en"><head><meta charset="utf-8">',
        '<meta name="viewport" content="width=device-width, initial-scale=1">',
        "<title>hbench report</title>",
        f"<style>{CSS}</style></head><body>",
        "<h1>hbench report</h1>",
        *_intro_html(run_dir, files, rows, shown),
        _headline_html(head, head_bias),
        _reproduction_html(run_dir, out),
        '<section id="figures"><h2>Figures</h2>',
        *figs,
        "</section>",
        '<section id="tables"><h2>Tables</h2>',
        "<p>Also written as Markdown and LaTeX (booktabs) files beside this page: "
        + _esc(", ".join(f"{n}.md, {n}.tex" for n in ("summary", "summary_bias", *shown.tables)))
        + ".</p>",
        *_tables_html(shown),
        "</section>",
        beyond.html(beyond_pngs) if beyond else "",
        '<section id="provenance"><h2>Provenance</h2>',
        _provenance_html(load_provenance(run_dir), run_dir),
        "</section>",
        "</body></html>",
    ]
    path = out / "report.html"
    atomic.write_text(path, "\n".join(page))
    return path


def _report_dir(run_dir: Path, out: Path | str | None) -> Path:
    """The report's folder: ``out``, or ``run_dir/report`` (a new one if that exists)."""
    from hbench.tables.results import new_output_dir

    if out is None:
        out = run_dir / "report"
        if out.exists():
            out = new_output_dir(run_dir, "report")
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    return out


def _report_stats(out: Path, run_dir: Path, rows: Any) -> tuple[dict[str, Any], Any, Any]:
    """Per-cell statistics with the headline's intervals and the paper's values beside them;
    the headline tables (written by :func:`write_summary`)."""
    stats = cell_stats(rows)
    head, head_bias = write_summary(out, run_dir, rows)
    # the interval's half-width and the paper's values for the figures
    half = (head["fitness_ci_high"] - head["fitness_ci_low"]) / 2
    stats["fitness"] = _with_summary(
        stats["fitness"], head, {"fitness_ci": half, "paper": head["paper"]}
    )
    stats["bias"] = _with_summary(
        stats["bias"],
        head_bias,
        {"paper_bias": head_bias["paper_bias"]},
        by=["parameter"],
    )
    return stats, head, head_bias


@dataclass
class _Shown:
    """The report's tables as shown (method labels in place of names) and the run status."""

    tables: dict[str, Any]
    failures: Any
    counts: dict[str, int]
    status_line: str
    none_ok: bool
    empty: dict[str, str]


def _report_tables(
    out: Path, rows: Any, stats: dict[str, Any], tables: Mapping[str, Any] | None
) -> _Shown:
    """Write the report's tables (Markdown and LaTeX) beside the page; return them as shown."""
    from hbench.tables.results import aggregated_tables

    # as the renderings show them: SNR cells told apart (column snr_target), sorted by level
    if tables is None:
        tables = aggregated_tables(rows)
    fitness_table, bias_table, structure_table = (
        tables[name].copy() for name in ("fitness", "bias", "structure")
    )
    ranking = stats["ranking"]
    timing = stats["timing"].rename(columns={"mean": "seconds_mean", "std": "seconds_std"})
    runs = run_table(rows)  # read by the failures table and the status counts
    failures = failure_table(rows, runs=runs)
    for frame in (fitness_table, bias_table, structure_table, ranking, timing, failures):
        frame["method"] = frame["method"].map(method_label)  # the label in place of the name
    counts = status_counts(rows, runs=runs)
    status_line = ", ".join(f"{k} {v}" for k, v in counts.items())
    none_ok = counts.get("ok", 0) == 0
    shown = {
        "fitness": fitness_table,
        "bias": bias_table,
        "structure": structure_table,
        "ranking": ranking,
        "timing": timing,
    }
    if len(failures):
        shown["failures"] = failures
    empty = _empty_reasons(none_ok, status_line)
    for name, table in shown.items():
        note = _failures_note(none_ok, status_line) if name == "failures" else ""
        write_table(
            out, name, table, note=note, empty=empty.get(name, ""), wrap_last=name == "failures"
        )
    return _Shown(shown, failures, counts, status_line, none_ok, empty)


def _report_figures(
    out: Path,
    run_dir: Path,
    stats: dict[str, Any],
    shown: _Shown,
    spread: str,
    beyond: Any,
    extra_figures: Sequence[Any],
    jobs: int,
    workers: Any = None,
    ready: Mapping[Path, Any] | None = None,
) -> tuple[list[str], list[bytes]]:
    """Render every figure in one batch: the page's figures as HTML in page order (a note
    where a figure has no data), and the PNGs of the beyond-the-paper section."""
    from hbench.report import figures

    none_ok = shown.none_ok
    ranking = shown.tables["ranking"]

    def missing(fig_id: str, what: str, reason: str) -> str:
        why = "No run produced an estimate" if none_ok else reason
        return f'<p class="note" id="no-{_esc(fig_id)}">{_esc(why)}: {_esc(what)}.</p>'

    # the figures in page order: (has data, figure id, spec, caption, the note shown without)
    examples = load_examples(run_dir)
    plan = [
        (
            stats["fitness"]["fitness_mean"].notna().any(),
            "fig-fitness-snr",
            (
                out / "fitness_snr",
                "fitness_vs_snr",
                (stats["fitness"], method_label),
                {"spread": spread},
            ),
            f"Fitness (mean, error bars {figures.SPREADS[spread]}) against the mean SNR of "
            "each cell, per method; the paper's values, where published, as hollow markers in "
            "the method's colour (noise-free cells, with infinite SNR, are not drawn).",
            missing("fig-fitness-snr", "no fitness against SNR to draw", "No ok run has a fitness"),
        ),
        (
            len(stats["bias"]) > 0,
            "fig-bias-std-snr",
            (out / "bias_std_snr", "bias_std_vs_snr", (stats["bias"], _series_label), {}),
            "Bias (mean − true) and standard deviation of each parameter against SNR "
            "(b1 = 1 normalisation; parameters are dimensionless).",
            missing(
                "fig-bias-std-snr",
                "no bias or std against SNR to draw",
                "No ok run of a blind method has parameter estimates (oracles know the true "
                "values)",
            ),
        ),
        (
            bool(examples),
            "fig-xu",
            xu_spec(out, examples),
            "x(n) against U(n), one realisation per nonlinearity: the true U, then each "
            "method's estimate scaled by the true gain b1 (the fitness scaling).",
            '<p class="note" id="no-examples">No examples.npz under this folder (sweeps do not '
            "save signals): the x-U graphs per method are not drawn.</p>",
        ),
        (
            len(stats["timing"]) > 0,
            "fig-time",
            (out / "time", "time_per_method", (stats["timing"], method_label), {}),
            "Identification time per run: a batch's time divided by its runs (the runs of a "
            "batch share one value), mean ± one std over the runs (so the spread between "
            "batches, cells and chunks, each weighted by its runs).",
            missing("fig-time", "no time per method to draw", "No ok run has a time"),
        ),
        (
            len(ranking) > 0,
            "fig-ranking",
            (out / "ranking", "ranking", (ranking, method_label), {}),
            "Mean rank of fitness per cell among the blind methods (1 = best; oracles are "
            "bounds and are not ranked).",
            missing(
                "fig-ranking",
                "no ranking to draw",
                "No blind method has a fitness in any cell (oracles are bounds, not ranked)",
            ),
        ),
    ]
    planned: list[tuple[str, Any, str]] = []  # rendered together below
    slots: list[int | str] = []  # in page order: an index into planned, or the note instead
    for has, fig_id, spec, caption, note in plan:
        if has:
            slots.append(len(planned))
            planned.append((fig_id, spec, caption))
        else:
            slots.append(note)
    beyond_figures = beyond.figures if beyond else []
    pngs = figures.render_many(
        [*extra_figures, *(p[1] for p in planned), *(f[1] for f in beyond_figures)],
        jobs,
        workers=workers,
        ready=ready,
    )
    pngs = pngs[len(extra_figures) :]
    figs = [
        html_figure(planned[s][0], pngs[s], planned[s][2]) if isinstance(s, int) else s
        for s in slots
    ]
    return figs, pngs[len(planned) :]


def _intro_html(run_dir: Path, files: Sequence[Path], rows: Any, shown: _Shown) -> list[str]:
    """The page's opening: the source, the run status, and notes a reader needs first."""
    counts, status_line = shown.counts, shown.status_line
    methods = [str(m) for m in rows["method"].unique()]  # in order of appearance
    recon = [m for m in methods if method_info(m)["reconstruction"]]
    n_cells = rows.drop_duplicates(["nonlinearity", "p", "delay", "sigma2", "snr_target"]).shape[0]
    intro = [
        f"<p>Source folder: <code>{_esc(run_dir)}</code> ({len(files)} rows file(s), "
        f"{len(rows)} tidy rows, {n_cells} cells, methods: "
        f"{_esc(', '.join(method_label(m) for m in methods))}).</p>",
        "<p>Run status: " + _esc(status_line) + ".</p>",
    ]
    if shown.none_ok:
        intro.append(
            '<p class="note" id="no-estimates"><b>No run produced an estimate</b>: none of the '
            f"{sum(counts.values())} runs ({_esc(status_line)}) of "
            f"{_esc(', '.join(method_label(m) for m in methods))} has a fitness or parameter "
            "estimates, so the figures and the statistics tables are empty. Why, per method "
            "and cell: the table <i>Runs without an estimate</i> below.</p>"
        )
    if recon:
        intro.append(
            '<p class="note">' + _esc(", ".join(recon)) + " is a reconstruction: "
            "its original algorithm is not available and parts of it are this project's "
            "own (see its docstring); read its numbers as those of a faithful variant."
            "</p>"
        )
    if len(shown.failures):
        intro += [
            '<section id="failures"><h2>Runs without an estimate</h2>',
            f"<p>{_esc(_failures_note(shown.none_ok, status_line))}</p>",
            html_table(shown.failures, table_id="table-failures"),
            "</section>",
        ]
    return intro


def _tables_html(shown: _Shown) -> list[str]:
    """The tables section: each table under its title, the long ones folded."""
    table_titles = {
        "ranking": "Ranking (mean rank of fitness per cell)",
        "timing": "Time per method",
        "structure": "Structure hit rate (share of runs that found the true na, nb, tau, delay)",
        "fitness": "Fitness per cell (%)",
        "bias": "Bias per parameter",
    }
    folded = {"fitness", "bias", "structure"}  # long tables: folded, the headline sums them up
    table_html = []
    for name, title in table_titles.items():
        table_html.append(f"<h3>{_esc(title)}</h3>")
        if shown.tables[name].empty:
            table_html.append(f'<p class="note" id="no-table-{name}">{_esc(shown.empty[name])}</p>')
            continue
        fmt = ".3g" if name in ("ranking", "timing", "structure") else ".4g"
        block = html_table(shown.tables[name], floatfmt=fmt, table_id=f"table-{name}")
        if name in folded:
            block = _fold(f"{len(shown.tables[name])} rows", block)
        table_html.append(block)
    return table_html


def _cmd(args: argparse.Namespace) -> int:
    from hbench.system.writable import check_output

    if args.out:  # before any work: a folder one can write in
        check_output(args.out, "--out", folder=True)
    jobs = max(1, min(2, len(os.sched_getaffinity(0))))
    path = build_report(
        Path(args.run_dir), Path(args.out) if args.out else None, jobs=jobs, spread=args.spread
    )
    print(path)
    return 0


def add_parser(subparsers: Any) -> argparse.ArgumentParser:
    """Add ``hbench report`` to the CLI."""
    p = subparsers.add_parser(
        "report",
        help="comparison report (HTML with figures, Markdown and LaTeX tables) from results",
        description="Build a self-contained HTML report (figures embedded), Markdown and LaTeX "
        "tables and PDF figures from the tidy rows under RUN_DIR (its rows.parquet, or every "
        "**/rows.parquet below it).",
    )
    p.add_argument("run_dir", metavar="RUN_DIR", help="a sweep's or a reproduction's folder")
    p.add_argument("--out", default=None, help="output folder (default RUN_DIR/report/)")
    p.add_argument(
        "--spread",
        choices=("ci", "std"),
        default="ci",
        help="error bars of the fitness figure: the 95 %% interval of the mean (default) or "
        "one std over the runs",
    )
    p.set_defaults(func=_cmd)
    return p

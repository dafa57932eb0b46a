"""The headline tables as a reader sees them: methods as rows, cells (noise levels or any swept
axis) as columns, each number with its 95 % interval, in HTML, Markdown and LaTeX.

Inputs are :func:`hbench.tables.summary.summary` (fitness) and
:func:`hbench.tables.summary.bias_summary`
(parameters). A number is printed with two significant digits of its interval's half-width and
the mean to the same decimal place (:func:`digits`); a LaTeX column uses the most decimals of its
cells, so that its numbers align on the decimal point in a right-aligned column.
"""

from __future__ import annotations

import html
import math
from collections.abc import Callable
from typing import Any

import pandas as pd

from hbench.tables.summary import CELL, METHOD_NOTE

#: LaTeX of the parameter names (``a1 -> $a_{1}$``).
PARAM_TEX = r"$\mathit{{{0}}}_{{{1}}}$"


def digits(half: float, default: int = 1, most: int = 6) -> int:
    """Decimals that show two significant digits of an interval's half-width ``half``."""
    if not (isinstance(half, float | int) and math.isfinite(half)) or half <= 0:
        return default
    return int(min(max(0, 1 - math.floor(math.log10(half))), most))


def fmt(v: float, decimals: int, sign: bool = False) -> str:
    """``v`` with ``decimals`` decimals, a real minus sign; empty for nan."""
    if not math.isfinite(v):
        return "" if math.isnan(v) else ("∞" if v > 0 else "−∞")
    if round(v, decimals) == 0:
        v = 0.0  # no "-0.00"
    text = f"{v:+.{decimals}f}" if sign else f"{v:.{decimals}f}"
    return text.replace("-", "−")


def _number(v: Any) -> str:
    """A level as printed: ``0.001``, ``1e-05`` as ``1e-05``."""
    return f"{float(v):g}"


def level_columns(table: pd.DataFrame) -> list[tuple[tuple[Any, ...], str]]:
    """The headline's columns in order: ``(cell key, label)``; the label names the noise level
    (``noise-free`` for sigma^2 = 0) and the other cell columns only where they vary."""
    if table.empty:
        return []
    keys = table[CELL].astype(object).where(table[CELL].notna(), None)
    cells = list(dict.fromkeys(map(tuple, keys.to_numpy().tolist())))
    varies = {c: keys[c].nunique(dropna=False) > 1 for c in ("nonlinearity", "p", "delay")}
    out = []
    for key in cells:
        d = dict(zip(CELL, key, strict=True))
        parts = [f"{c}={d[c]}" if c != "nonlinearity" else str(d[c]) for c in varies if varies[c]]
        if d["snr_target"] is not None:
            level = f"SNR {_number(d['snr_target'])}"
        elif d["sigma2"] is None:
            level = "σ² ?"
        elif float(d["sigma2"]) == 0:
            level = "noise-free"
        else:
            level = f"σ² = {_number(d['sigma2'])}"
        out.append((key, ", ".join([*parts, level])))
    return out


def _key(table: pd.DataFrame) -> pd.Series:
    keys = table[CELL].astype(object).where(table[CELL].notna(), None)
    return pd.Series(list(map(tuple, keys.to_numpy().tolist())), index=table.index)


def fitness_grid(summary: pd.DataFrame, label: Callable[[str], str]) -> list[dict[str, Any]]:
    """One entry per method: ``{"label", "bound", "cells": {key: cell}}``; a cell holds
    ``mean, half, paper, diff, diff_half, best, lead, tie, decimals``."""
    if summary.empty:
        return []
    s = summary.assign(_key=_key(summary))
    out = []
    for method, g in s.groupby("method", sort=False):
        cells = {}
        for _, r in g.iterrows():
            half = (r["fitness_ci_high"] - r["fitness_ci_low"]) / 2
            dhalf = (r["diff_ci_high"] - r["diff_ci_low"]) / 2
            lead = bool(r["leader"])
            cells[r["_key"]] = {
                "mean": float(r["fitness_mean"]),
                "half": float(half),
                "paper": float(r["paper"]),
                "diff": float(r["diff_to_best"]),
                "diff_half": float(dhalf),
                "best": bool(r["best"]),
                "lead": lead,
                # not significantly different from the best (the interval holds zero)
                "tie": bool(r["diff_ci_low"] <= 0 <= r["diff_ci_high"]),
                "decimals": digits(float(half), most=2),
            }
        out.append({"label": label(str(method)), "bound": bool(g["bound"].iloc[0]), "cells": cells})
    return out


# --------------------------------------------------------------------------- HTML and Markdown


def _diff_text(c: dict[str, Any]) -> str:
    if math.isnan(c["diff"]):
        return ""
    d = digits(c["diff_half"], most=2)
    word = "lead" if c["lead"] else "Δ"
    text = (
        f"{word} {fmt(c['diff'], d, sign=True)} "
        f"[{fmt(c['diff'] - c['diff_half'], d)}, {fmt(c['diff'] + c['diff_half'], d)}]"
    )
    if c["lead"] and not c["best"]:
        text += " n.s."
    elif not c["lead"] and c["tie"]:
        text += " tie"
    return text


def _main_text(c: dict[str, Any]) -> str:
    d = c["decimals"]
    text = fmt(c["mean"], d)
    return text + (f" ± {fmt(c['half'], d)}" if math.isfinite(c["half"]) else "")


def _cell_lines(c: dict[str, Any]) -> list[tuple[str, str]]:
    """A headline cell's lines as ``(kind, text)``: ``main`` (mean ± half-width), ``paper``
    (where published) and ``diff`` (the paired difference, where there is one)."""
    lines = [("main", _main_text(c))]
    if math.isfinite(c["paper"]):
        lines.append(("paper", f"paper {fmt(c['paper'], 2)}"))
    diff = _diff_text(c)
    return lines + ([("diff", diff)] if diff else [])


def _grid_rows(summary: pd.DataFrame, label: Callable[[str], str]) -> Any:
    """``(level columns, [(method row, [cell or None per column])])`` of the headline."""
    cols = level_columns(summary)
    rows = [(row, [row["cells"].get(k) for k, _ in cols]) for row in fitness_grid(summary, label)]
    return cols, rows


def fitness_html(summary: pd.DataFrame, label: Callable[[str], str], table_id: str) -> str:
    """The fitness headline as an HTML table (winner in bold, the paper's value and the paired
    difference under each number)."""
    cols, rows = _grid_rows(summary, label)
    head = "<th>method</th>" + "".join(f"<th>{html.escape(t)}</th>" for _, t in cols)
    body = []
    for row, cells in rows:
        tds = []
        for c in cells:
            if c is None:
                tds.append("<td></td>")
                continue
            lines = []
            for kind, text in _cell_lines(c):
                text = html.escape(text)
                if kind == "main":
                    lines.append(f"<b>{text}</b>" if c["best"] else text)
                else:
                    lines.append(f'<span class="{kind}">{text}</span>')
            klass = ' class="win"' if c["best"] else ""
            tds.append(f"<td{klass}>" + "<br>".join(lines) + "</td>")
        klass = ' class="bound"' if row["bound"] else ""
        body.append(f"<tr{klass}><th>{html.escape(row['label'])}</th>{''.join(tds)}</tr>")
    return (
        f'<table id="{html.escape(table_id)}" class="headline"><thead><tr>{head}</tr></thead>'
        f"<tbody>{''.join(body)}</tbody></table>"
    )


def fitness_markdown(summary: pd.DataFrame, label: Callable[[str], str]) -> str:
    """The fitness headline as a Markdown table (the same cells as the HTML one)."""
    cols, rows = _grid_rows(summary, label)
    lines = [
        "| method | " + " | ".join(t for _, t in cols) + " |",
        "|---|" + "---:|" * len(cols),
    ]
    for row, cells in rows:
        texts = []
        for c in cells:
            parts = [
                f"**{text}**" if kind == "main" and c["best"] else text
                for kind, text in (_cell_lines(c) if c is not None else [])
            ]
            texts.append("<br>".join(parts))
        lines.append(f"| {row['label']} | " + " | ".join(texts) + " |")
    return f"Fitness F (%), mean ± 95 % half-interval. {METHOD_NOTE}\n\n" + "\n".join(lines) + "\n"


# --------------------------------------------------------------------------- LaTeX


def tex_level(label: str) -> str:
    """A column label in LaTeX: ``σ² = 0.001 -> $\\sigma^2 = 10^{-3}$``, ``noise-free``."""
    from hbench.tables.results import tex_escape

    out = []
    for part in label.split(", "):
        if part.startswith("σ² = "):
            out.append(r"$\sigma^2 = " + tex_power(float(part[5:])) + "$")
        elif part.startswith("SNR "):
            out.append(r"$\mathrm{SNR} = " + part[4:] + "$")
        else:
            out.append(tex_escape(part))
    return ", ".join(out)


def tex_power(v: float) -> str:
    """``0.001 -> 10^{-3}``, ``0.005 -> 5 \\cdot 10^{-3}``, ``0.5 -> 0.5``."""
    if v == 0 or 0.1 <= abs(v) < 1000:
        return f"{v:g}"
    exp = math.floor(math.log10(abs(v)))
    mant = round(v / 10.0**exp, 6)
    return (f"{mant:g} \\cdot " if mant != 1 else "") + f"10^{{{exp}}}"


def _tex_num(v: float, decimals: int, bold: bool = False) -> str:
    if math.isnan(v):
        return ""
    if round(v, decimals) == 0:
        v = 0.0  # no "-0.00"
    text = f"{v:.{decimals}f}"
    text = "$-$" + text[1:] if text.startswith("-") else text
    return rf"\textbf{{{text}}}" if bold else text


def latex_grid(
    rows: list[tuple[str, list[tuple[float, float, bool]]]],
    columns: list[str],
    caption: str,
    label: str,
    first: str = "Method",
    note: str = "",
    most: int = 2,
) -> str:
    """A booktabs table of ``mean ± half`` numbers, levels as columns.

    Each column is two ``r``/``l`` columns joined by ``±`` (the numbers of a column share their
    decimals, so they align on the decimal point); ``rows`` are ``(text, [(mean, half, bold)
    per column])``, text already LaTeX; at most ``most`` decimals.
    """
    decimals = []
    for j in range(len(columns)):
        ds = [
            digits(cells[j][1], most=most)
            for _, cells in rows
            if j < len(cells) and not math.isnan(cells[j][0])
        ]
        decimals.append(max(ds, default=1))
    spec = "l" + r"r@{\,}l" * len(columns)
    head = f"{first} & " + " & ".join(rf"\multicolumn{{2}}{{c}}{{{c}}}" for c in columns)
    rule = "".join(rf"\cmidrule(lr){{{2 + 2 * j}-{3 + 2 * j}}}" for j in range(len(columns)))
    out = [
        r"% needs \usepackage{booktabs}",
        r"\begin{table*}[t]",
        r"\centering",
        r"\small",
        r"\setlength{\tabcolsep}{4pt}",
        r"\caption{" + caption + "}",
        r"\label{" + label + "}",
        r"\begin{tabular}{" + spec + "}",
        r"\toprule",
        head + r" \\",
        rule,
    ]
    for text, cells in rows:
        if text == r"\midrule":
            out.append(r"\midrule")
            continue
        parts = [text]
        for j, (mean, half, bold) in enumerate(cells):
            d = decimals[j]
            parts.append(_tex_num(mean, d, bold))
            parts.append(
                rf"$\pm$\,{_tex_num(half, d)}"
                if math.isfinite(half) and math.isfinite(mean)
                else ""
            )
        out.append(" & ".join(parts) + r" \\")
    out += [r"\bottomrule", r"\end{tabular}"]
    if note:
        out.append(r"\par\smallskip{\footnotesize " + note + "}")
    out.append(r"\end{table*}")
    return "\n".join(out) + "\n"


def fitness_latex(summary: pd.DataFrame, label: Callable[[str], str], name: str = "summary") -> str:
    """The fitness headline in LaTeX: per method a row of F, the paper's row where one exists
    and a row of the paired difference to the best."""
    from hbench.tables.results import tex_escape

    cols = level_columns(summary)
    rows: list[tuple[str, list[tuple[float, float, bool]]]] = []
    nan = (math.nan, math.nan, False)
    for i, row in enumerate(fitness_grid(summary, label)):
        if i:
            rows.append((r"\midrule", []))
        cells = [row["cells"].get(k) for k, _ in cols]
        rows.append(
            (
                tex_escape(row["label"]),
                [(c["mean"], c["half"], c["best"]) if c else nan for c in cells],
            )
        )
        if any(c and math.isfinite(c["paper"]) for c in cells):
            rows.append(
                (r"\quad paper", [(c["paper"], math.nan, False) if c else nan for c in cells])
            )
        if any(c and math.isfinite(c["diff"]) for c in cells):
            rows.append(
                (
                    r"\quad $\Delta F$",
                    [(c["diff"], c["diff_half"], False) if c else nan for c in cells],
                )
            )
    caption = (
        r"Fitness $F$ [\%]: mean $\pm$ half-width of the 95\,\% Student $t$ interval over the "
        r"runs. $\Delta F$: paired difference to the best blind method of the column over the "
        r"shared realisations (on the best's row: its lead over the runner-up), 95\,\% paired "
        r"$t$ interval. Bold: the best method where its lead's interval excludes zero."
    )
    return latex_grid(rows, [tex_level(t) for _, t in cols], caption, f"tab:hbench-{name}")


def bias_latex(bias: pd.DataFrame, label: Callable[[str], str], name: str = "summary_bias") -> str:
    """Bias (95 % interval) and RMSE of each parameter in LaTeX: per method and parameter a row
    of bias and a row of RMSE (and the paper's bias where published)."""
    from hbench.tables.results import tex_escape

    cols = level_columns(bias)
    keyed = bias.assign(_key=_key(bias))
    rows: list[tuple[str, list[tuple[float, float, bool]]]] = []
    nan = (math.nan, math.nan, False)
    for i, (method, g) in enumerate(keyed.groupby("method", sort=False)):
        if i:
            rows.append((r"\midrule", []))
        for par, gp in g.groupby("parameter", sort=False):
            at = {r["_key"]: r for _, r in gp.iterrows()}
            cells = [at.get(k) for k, _ in cols]
            ptex = PARAM_TEX.format(par[0], par[1:])
            head = tex_escape(label(str(method))) + ", " if par == g["parameter"].iloc[0] else ""
            rows.append(
                (
                    head + "bias " + ptex,
                    [
                        (c["bias"], (c["bias_ci_high"] - c["bias_ci_low"]) / 2, False)
                        if c is not None
                        else nan
                        for c in cells
                    ],
                )
            )
            if any(c is not None and math.isfinite(c["paper_bias"]) for c in cells):
                rows.append(
                    (
                        r"\quad paper",
                        [
                            (c["paper_bias"], math.nan, False) if c is not None else nan
                            for c in cells
                        ],
                    )
                )
            rows.append(
                (
                    r"\quad RMSE",
                    [(c["rmse"], math.nan, False) if c is not None else nan for c in cells],
                )
            )
    caption = (
        r"Bias (mean estimate $-$ true value) with the half-width of its 95\,\% Student $t$ "
        r"interval over the runs, and root mean squared error, per parameter ($b_1 = 1$ "
        r"normalisation)."
    )
    return latex_grid(rows, [tex_level(t) for _, t in cols], caption, f"tab:hbench-{name}", most=5)


def bias_html(bias: pd.DataFrame, label: Callable[[str], str], table_id: str) -> str:
    """Bias with its interval and RMSE per method and parameter, levels as columns."""
    cols = level_columns(bias)
    keyed = bias.assign(_key=_key(bias))
    head = "<th>method</th><th>parameter</th>" + "".join(
        f"<th>{html.escape(t)}</th>" for _, t in cols
    )
    body = []
    for (method, par), g in keyed.groupby(["method", "parameter"], sort=False):
        at = {r["_key"]: r for _, r in g.iterrows()}
        tds = []
        for key, _ in cols:
            c = at.get(key)
            if c is None:
                tds.append("<td></td>")
                continue
            half = (c["bias_ci_high"] - c["bias_ci_low"]) / 2
            d = digits(float(half), default=4, most=5)
            lines = [
                html.escape(
                    f"{fmt(c['bias'], d)} ± {fmt(half, d)}"
                    if math.isfinite(half)
                    else fmt(c["bias"], d)
                )
            ]
            if math.isfinite(c["paper_bias"]):
                lines.append(
                    f'<span class="paper">paper {html.escape(fmt(c["paper_bias"], d))}</span>'
                )
            lines.append(f'<span class="diff">RMSE {html.escape(fmt(c["rmse"], d))}</span>')
            tds.append("<td>" + "<br>".join(lines) + "</td>")
        body.append(
            f"<tr><th>{html.escape(label(str(method)))}</th><td>{html.escape(str(par))}</td>"
            + "".join(tds)
            + "</tr>"
        )
    return (
        f'<table id="{html.escape(table_id)}" class="headline"><thead><tr>{head}</tr></thead>'
        f"<tbody>{''.join(body)}</tbody></table>"
    )

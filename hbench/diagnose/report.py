"""Step 5 of the workflow: the human-readable diagnosis (HTML with embedded figures, and
Markdown with the same figures as PNG files beside it)."""

from __future__ import annotations

import base64
import html
import io
from pathlib import Path
from typing import Any

import numpy as np

from hbench.diagnose import core, stats
from hbench.diagnose.effects import format_p
from hbench.diagnose.validate import format_fit, half_gains, unread_halves
from hbench.system import atomic

FIGURES: tuple[tuple[str, str], ...] = (
    ("simulation", "Measured output and the simulations of the nominal and the extended model"),
    ("residual_time", "Nominal residual y - y_hat over time"),
    ("residual_spectrum", "Periodogram of the nominal residual (fit part)"),
    ("residual_acf", "Autocorrelation of the nominal model's innovations (fit part)"),
    (
        "residual_xcorr",
        "Cross-correlation of the nominal model's innovations with x (fit part, slow samples)",
    ),
    ("residual_vs_x", "Nominal residual against x"),
    ("actuator", "The actuator: x against the inner signal and the fitted nonlinearity"),
)


def has_extension(d: Any) -> bool:
    """Whether diagnosis ``d`` has an extended model to show (a cause, not ``none`` or
    ``unexplained``): the simulation figure draws it and its caption names it."""
    return d.cause not in ("none", "unexplained")


def caption(d: Any, name: str, text: str) -> str:
    """The caption of figure ``name`` (``text`` from :data:`FIGURES`) for diagnosis ``d``: the
    simulation figure shows an extended model only where there is one (:func:`has_extension`)."""
    if name == "simulation" and not has_extension(d):
        return (
            "Measured output and the nominal model's simulation (no extended model: the cause "
            f"is {d.cause})"
        )
    return text


#: The formats every figure is written in (PNG for the pages, PDF for print).
FORMATS: tuple[str, ...] = ("png", "pdf")
#: Dots per inch of the PNG figures. The page shows each at its size in inches (CSS inches,
#: 96 px), so that every figure's text has the same size on the page.
DPI = 150


def sim_fit(d: Any, which: str) -> float:
    """The ``which`` (``nominal``, ``extended``) model's simulation fit on the validation part
    (the figure's curves are the simulations, whatever the criterion)."""
    return float(d.fits.get(which, {}).get("simulation", np.nan))


def _render(fig: Any) -> dict[str, bytes]:
    """``fig`` rendered in every format of :data:`FORMATS` (PDF fonts embedded as TrueType),
    then closed."""
    import matplotlib
    import matplotlib.pyplot as plt

    out = {}
    with matplotlib.rc_context({"pdf.fonttype": 42}):
        for fmt in FORMATS:
            buf = io.BytesIO()
            fig.savefig(buf, format=fmt, dpi=DPI, bbox_inches="tight")
            out[fmt] = buf.getvalue()
    plt.close(fig)
    return out


def figures(d: Any) -> dict[str, bytes]:
    """The report's figures as PNG bytes, by name."""
    return {k: v["png"] for k, v in render_figures(d).items()}


def render_figures(d: Any) -> dict[str, dict[str, bytes]]:
    """The report's figures by name, each in every format of :data:`FORMATS`."""
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    ctx, nom = d.ctx, d.nominal
    t = np.arange(ctx.N) * ctx.h
    t_split = ctx.n_fit * ctx.h
    out: dict[str, dict[str, bytes]] = {}
    lag_unit = "fast samples" if ctx.p >= 2 else "samples"

    fig, ax = plt.subplots(figsize=(9, 3.2))
    ax.plot(t, ctx.y, color="0.55", lw=0.6, label="measured y")
    ax.plot(
        t,
        nom.yhat,
        color="C0",
        lw=0.9,
        label=f"nominal ({nom.model.cls}), validation fit {sim_fit(d, 'nominal'):.1f} %",
    )
    if has_extension(d):
        ax.plot(
            t,
            d.extended.simulate(ctx.x),
            color="C3",
            lw=0.9,
            label=f"extended ({d.cause}), validation fit {sim_fit(d, 'extended'):.1f} %",
        )
    if d.criterion != "simulation":
        from hbench.diagnose import validate

        crit = d.info.get("criterion") or validate.parse_criterion(d.criterion)
        pred = validate.criterion_output(ctx, nom.model, nom.model, crit, nom.yhat)
        v = ctx.val_idx
        fit = d.fits["nominal"][d.criterion]
        label = f"nominal, {d.criterion} ({format_fit(fit)})"
        if fit >= validate.FIT_FLOOR:
            ax.plot(t[v], pred[v], color="C2", lw=0.7, label=label)
        else:  # a diverging output would set the axis and flatten the measured y
            ax.plot([], [], color="C2", lw=0.7, label=label + ", not drawn")
    ax.axvline(t_split, color="k", ls="--", lw=0.8)
    ax.set_xlabel("t [s]")
    ax.set_ylabel("y")
    ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.2), ncol=3, fontsize=7, frameon=False)
    ax.set_title(
        f"fit part | validation part (fits in the legend: simulation; the criterion is "
        f"{d.criterion})",
        fontsize=8,
    )
    out["simulation"] = _render(fig)

    fig, ax = plt.subplots(figsize=(9, 2.6))
    ax.plot(t, nom.resid, color="C0", lw=0.6)
    ax.axvline(t_split, color="k", ls="--", lw=0.8)
    ax.set_xlabel("t [s]")
    ax.set_ylabel("y - y_hat")
    out["residual_time"] = _render(fig)

    e = nom.resid[ctx.fit_idx]
    P = stats.periodogram(e)
    f = np.arange(P.size) / (e.size * ctx.h)
    fig, ax = plt.subplots(figsize=(6, 3))
    ax.loglog(f[1:], np.maximum(P[1:], 1e-300), color="C0", lw=0.6)
    ax.set_xlabel("frequency [Hz]")
    ax.set_ylabel("periodogram")
    out["residual_spectrum"] = _render(fig)

    ei = nom.innov[ctx.fit_idx][20:]
    nl = 40
    r = stats.acf(ei, nl)
    fig, ax = plt.subplots(figsize=(6, 3))
    ax.bar(np.arange(1, nl + 1), r[1:], color="C0", width=0.7)
    band = 1.96 / np.sqrt(max(ei.size, 1))
    ax.axhline(band, color="k", ls=":", lw=0.8)
    ax.axhline(-band, color="k", ls=":", lw=0.8)
    ax.set_xlabel(f"lag [{lag_unit}]")
    ax.set_ylabel("autocorrelation")
    ax.set_title("dotted: 95 % band of white innovations", fontsize=8)
    out["residual_acf"] = _render(fig)

    # innovations against x: at the period starts, lags in slow samples (x leads for k > 0)
    es = nom.innov[:: ctx.p][: ctx.k_fit][2:]
    xs = ctx.x[: ctx.k_fit][2:]
    rx = stats.cross_correlation(xs, es, min(30, es.size // 4))
    lags = np.arange(rx.size) - rx.size // 2
    fig, ax = plt.subplots(figsize=(6, 3))
    ax.bar(lags, rx, color="C0", width=0.7)
    band = 1.96 / np.sqrt(max(es.size, 1))
    ax.axhline(band, color="k", ls=":", lw=0.8)
    ax.axhline(-band, color="k", ls=":", lw=0.8)
    ax.set_xlabel("lag k [slow samples]: correlation of the innovation at n with x at n - k")
    ax.set_ylabel("cross-correlation")
    ax.set_title("dotted: 95 % band when innovations and x are independent", fontsize=8)
    out["residual_xcorr"] = _render(fig)

    fig, ax = plt.subplots(figsize=(5, 3.6))
    slow_resid = nom.resid[:: ctx.p]
    k = ctx.k_fit
    ax.plot(ctx.x[:k], slow_resid[:k], ".", ms=2, color="C0", label="fit part")
    ax.plot(ctx.x[k:], slow_resid[k:], ".", ms=2, color="C1", label="validation part")
    ax.set_xlabel("x")
    ax.set_ylabel("y - y_hat (at the period starts)")
    ax.legend(fontsize=7)
    out["residual_vs_x"] = _render(fig)

    out["actuator"] = _actuator_figure(d, plt)
    return out


def _actuator_figure(d: Any, plt: Any) -> dict[str, bytes]:
    ctx, nom = d.ctx, d.nominal
    m = d.extended if ctx.p >= 2 else nom.model
    if ctx.p >= 2 and nom.U is not None:
        fig, ax = plt.subplots(figsize=(5, 3.8))
        k = ctx.k_fit
        x = ctx.x[:k]
        U = nom.U[:k]
        ok = np.isfinite(U)
        ax.plot(x[ok], U[ok], ".", ms=2, color="0.5", label="blind inner signal U (fit part)")
        from hbench.diagnose.classes import gain_offset

        xs = ctx.x[:k]
        if m.shift:
            xs = np.concatenate([np.full(m.shift, xs[0]), xs[: -m.shift]])
        c, off = gain_offset(m.cls, m.theta, xs, U)
        u = c * core.nl_one(m.cls, xs, m.theta) + off
        ax.plot(xs, u, "-", lw=0.6, color="C3", label=f"fitted {m.cls} (scaled)")
        ax.set_xlabel("x" + (f"(n - {m.shift})" if m.shift else "(n)"))
        ax.set_ylabel("U(n)")
        ax.legend(fontsize=7)
        return _render(fig)
    fig, axes = plt.subplots(1, 2, figsize=(9, 3.6))
    ax = axes[0]
    ax.plot(ctx.x, ctx.y, ".", ms=2, color="0.5")
    ax.set_xlabel("x (controller output)")
    ax.set_ylabel("y (process variable)")
    ax.set_title("PV-OP graph", fontsize=8)
    ax = axes[1]
    u = core.nl_one(m.cls, ctx.x, m.theta)
    ax.plot(ctx.x, u, "-", lw=0.6, color="C3")
    ax.set_xlabel("x (controller output)")
    ax.set_ylabel("fitted valve position u")
    ax.set_title(f"fitted valve characteristic: {m.cls}", fontsize=8)
    return _render(fig)


def _rows(d: Any) -> list[dict[str, str]]:
    rows = []
    for det in d.detections:
        ext = d.extensions.get(det.name)
        rows.append(
            {
                "effect": det.name,
                "statistic": _value(det.statistic, ".4g", "the statistic could not be computed"),
                "threshold": _value(det.threshold, ".4g", "no threshold"),
                "p-value": (
                    format_p(det.p_value)
                    if np.isfinite(det.p_value)
                    else _value(det.p_value, ".2g", "no test gives one")
                ),
                "verdict": "fires" if det.fired else "quiet",
                f"extended fit ({d.criterion})": (
                    ""
                    if ext is None
                    else (
                        (
                            "n/a: the extended model does not simulate"
                            if np.isnan(ext.val_fit)
                            else format_fit(ext.val_fit)
                        )
                        + "".join(f" ({n})" for n in _notes(ext.model))
                        if ext.model is not None
                        else f"failed: {ext.error}"
                    )
                ),
                f"gain: whole; 1st / 2nd half of validation ({d.criterion}, points)": (
                    _half_gains(d, ext)
                ),
                "cause": "yes" if det.name == d.cause else "",
                "evidence": det.evidence,
            }
        )
    return rows


def _half_gains(d: Any, ext: Any) -> str:
    """An extension's gain in points on the whole validation part and on its first and second
    half; the cell says where the cause rule does not read the halves
    (:func:`hbench.diagnose.validate.unread_halves`)."""
    if ext is None or ext.model is None:
        return ""
    gain = ext.val_fit - d.baseline_fit
    if not np.isfinite(gain):
        return "n/a: a fit is not finite (a diverging output, or a model that does not simulate)"
    whole = f"{gain:+.1f} whole"
    g = half_gains(ext, d.baseline_halves)
    if g is None:
        return f"{whole}; halves n/a: not measured"
    if not all(np.isfinite(g)):
        return f"{whole}; halves n/a: a half's fit is not finite (a constant half, a divergence)"
    text = f"{whole}; {g[0]:+.1f} / {g[1]:+.1f}"
    why = unread_halves(ext, d.rule)
    return f"{text} (halves not read: {why})" if why else text


def _notes(model: Any) -> list[str]:
    """An extension model's ``info["notes"]`` (a list of lines; one string is one line)."""
    notes = model.info.get("notes", ())
    return [notes] if isinstance(notes, str) else [str(n) for n in notes]


def _value(v: float, fmt: str, why: str) -> str:
    """``v`` formatted, or ``n/a: why`` where it is not a finite number."""
    try:
        v = float(v)
    except (TypeError, ValueError):
        return f"n/a: {why}"
    return format(v, fmt) if np.isfinite(v) else f"n/a: {why}"


def _summary_rows(d: Any) -> list[tuple[str, str]]:
    nl = d.nonlinearity
    scores = ", ".join(f"{k} {v:.3g}" for k, v in nl["scores"].items())
    how = (
        "blind identification (" + str(d.nominal.info.get("method", "")) + ") of G and U on "
        "the fit part; every class fitted by equation error through the dynamics from its fit "
        "to the (x, U) graph, the class chosen by BIC"
        if d.ctx.p >= 2
        else "output-error model from x to y; classes fitted through the dynamics; class decided "
        "on the whole record, parameters fitted on the fit part"
    )
    valve, cause, fits = d.findings()
    return [
        ("valve", valve.removeprefix("valve: ")),
        ("cause", cause.removeprefix("cause: ")),
        ("validation", fits.removeprefix("validation fits: ")),
        ("record", str(d.source)),
        ("p, h", f"{d.ctx.p}, {d.ctx.h:g} s"),
        (
            "samples",
            f"{d.ctx.K} slow ({d.ctx.N} fast): fit on the first {d.ctx.k_fit}, "
            f"validate on the last {d.ctx.K - d.ctx.k_fit}",
        ),
        ("nominal model", how),
        (
            "class scores",
            scores
            + (
                " (half BIC differences to linear)"
                if d.ctx.p >= 2
                else " (fit gain over linear, points of %)"
            ),
        ),
        *_shape_rows(d),
        ("why this cause", d.why),
    ]


def _shape_rows(d: Any) -> list[tuple[str, str]]:
    sh = d.nominal.info.get("shape_test")
    if not sh:
        return []
    text = (
        f"oscillation regularity {sh['regularity']:.3g} (regular above 1), period "
        f"{sh['period']:.3g} samples, triangularity of x {sh['shape_index']:.3g} (He et "
        "al.'s stiction index)"
    )
    hp = sh.get("horch_phase", float("nan"))
    if hp == hp:  # not nan
        from hbench.diagnose.nominal import HORCH_EVEN, HORCH_ODD

        text += (
            f", Horch's cross-correlation phase {hp:.3g} rad (his limits: odd, stiction, above "
            f"{HORCH_ODD:.3g}; even, not the valve, below {HORCH_EVEN:.3g}; evidence only: it "
            "also carries the controller's phase)"
        )
    if sh.get("decided"):
        text += ": the shape test decided the class"
    return [("shape test", text)]


def png_width(png: bytes) -> int:
    """The width in pixels of a PNG image (its header's first field)."""
    if png[:8] != b"\x89PNG\r\n\x1a\n":
        raise ValueError("not a PNG image")
    return int.from_bytes(png[16:20], "big")


def render_html(d: Any, figs: dict[str, bytes]) -> str:
    esc = html.escape
    parts = [
        "<!DOCTYPE html><html><head><meta charset='utf-8'>",
        f"<title>hbench diagnose: {esc(str(d.source))}</title>",
        "<style>body{font-family:sans-serif;max-width:1000px;margin:auto}"
        "table{border-collapse:collapse;font-size:13px}td,th{border:1px solid #ccc;"
        "padding:3px 6px;vertical-align:top}th{background:#eee}"
        "tr.fires td{background:#fff3e0}tr.cause td{background:#ffe0e0}"
        "figure img{max-width:100%;height:auto}</style>",
        "</head><body>",
        f"<h1>Diagnosis of {esc(Path(str(d.source)).name)}</h1>",
        "<table>",
    ]
    for k, v in _summary_rows(d):
        parts.append(f"<tr><th>{esc(k)}</th><td>{esc(v)}</td></tr>")
    parts.append("</table><h2>Evidence</h2><table><tr>")
    rows = _rows(d)
    cols = list(rows[0]) if rows else []
    parts += [f"<th>{esc(c)}</th>" for c in cols]
    parts.append("</tr>")
    for r in rows:
        cls = "cause" if r["cause"] else ("fires" if r["verdict"] == "fires" else "")
        parts.append(
            f"<tr class='{cls}'>" + "".join(f"<td>{esc(r[c])}</td>" for c in cols) + "</tr>"
        )
    parts.append("</table><h2>Figures</h2>")
    for name, text in FIGURES:
        if name in figs:
            b64 = base64.b64encode(figs[name]).decode("ascii")
            width = png_width(figs[name]) / DPI
            parts.append(
                f"<figure><img alt='{esc(name)}' style='width:{width:.2f}in' "
                f"src='data:image/png;base64,{b64}'>"
                f"<figcaption>{esc(caption(d, name, text))}</figcaption></figure>"
            )
    parts.append("</body></html>")
    return "\n".join(parts)


def _md(text: str) -> str:
    """``text`` as Markdown shows it literally on one line: HTML's ``<``, ``>``, ``&`` escaped
    (Markdown passes raw HTML through, so a record named ``<script>.csv`` stays text) and ``|``
    made ``/`` (a table cell)."""
    return html.escape(" ".join(str(text).split()), quote=False).replace("|", "/")


def render_markdown(d: Any, fig_files: dict[str, str]) -> str:
    lines = [f"# Diagnosis of {_md(Path(str(d.source)).name)}", "", "| | |", "| --- | --- |"]
    for k, v in _summary_rows(d):
        lines.append(f"| {k} | {_md(v)} |")
    lines += ["", "## Evidence", ""]
    rows = _rows(d)
    if rows:
        cols = list(rows[0])
        lines.append("| " + " | ".join(cols) + " |")
        lines.append("|" + " --- |" * len(cols))
        for r in rows:
            lines.append("| " + " | ".join(_md(r[c]) for c in cols) + " |")
    lines += ["", "## Figures", ""]
    for name, text in FIGURES:
        if name in fig_files:
            cap = caption(d, name, text)
            lines += [f"![{cap}]({fig_files[name]})", "", f"*{cap}*", ""]
    return "\n".join(lines)


def write_report(d: Any, out_dir: Path) -> tuple[Path, Path]:
    """Write ``report.html`` (self-contained) and ``report.md`` with its PNG figures to
    ``out_dir``; returns both paths."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    rendered = render_figures(d)
    figs = {k: v["png"] for k, v in rendered.items()}
    files = {}
    for name, by_fmt in rendered.items():
        for fmt, data in by_fmt.items():
            atomic.write_bytes(out_dir / f"fig_{name}.{fmt}", data)
        files[name] = f"fig_{name}.png"
    html_path = out_dir / "report.html"
    md_path = out_dir / "report.md"
    atomic.write_text(html_path, render_html(d, figs))
    atomic.write_text(md_path, render_markdown(d, files))
    return html_path, md_path

"""Figures of the reproduction and the comparison report (matplotlib, Agg backend).

One style for every figure (:data:`STYLE`); every plotting function returns a matplotlib
``Figure``; :func:`save` writes it as PNG and PDF and returns the PNG bytes (for HTML data URIs).
:func:`render_many` renders a list of figures, in forked worker processes when asked (the
reproduction's time budget). The signals of the paper's example are dimensionless (valve input
x and output u in normalised units); the axes say so. matplotlib is imported inside the functions
(start-up time of the CLI). Layouts are set by hand (no tight layout, no mathtext): both cost
more than the drawing itself.
"""

from __future__ import annotations

import io
import math
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

STYLE: dict[str, Any] = {
    "figure.dpi": 100,
    "savefig.dpi": 100,
    "font.size": 9,
    "axes.titlesize": 9,
    "axes.labelsize": 9,
    "legend.fontsize": 7.5,
    "xtick.labelsize": 8,
    "ytick.labelsize": 8,
    "axes.grid": True,
    "grid.alpha": 0.3,
    "grid.linewidth": 0.5,
    "axes.spines.top": False,
    "axes.spines.right": False,
    "lines.linewidth": 1.2,
    "lines.markersize": 4,
    "pdf.fonttype": 3,
    "pdf.compression": 6,
}
#: Label of the dimensionless signals of the example.
UNITLESS = "normalised units"
SNR_LABEL = "SNR ||y0||/||v|| (ratio of norms)"


def pyplot() -> Any:
    """``matplotlib.pyplot`` on the Agg backend with :data:`STYLE` applied."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    plt.rcParams.update(STYLE)
    return plt


def save(fig: Any, stem: Path | str | None, formats: Sequence[str] = ("png", "pdf")) -> bytes:
    """Write ``stem.png`` / ``stem.pdf`` (when ``stem`` is given); return the PNG bytes."""
    plt = pyplot()
    buf = io.BytesIO()
    fig.savefig(buf, format="png")
    png = buf.getvalue()
    if stem is not None:
        stem = Path(stem)
        for fmt in formats:
            if fmt == "png":
                stem.with_suffix(".png").write_bytes(png)
            else:
                fig.savefig(stem.with_suffix(f".{fmt}"), format=fmt)
    plt.close(fig)
    return png


#: A figure to render: ``(stem or None, name of a function of this module, args, kwargs)``.
FigureSpec = tuple[Path | None, str, tuple[Any, ...], dict[str, Any]]


def _render(spec: FigureSpec) -> bytes:
    stem, name, args, kwargs = spec
    return save(globals()[name](*args, **kwargs), stem)


def render_many(specs: Sequence[FigureSpec], processes: int = 1) -> list[bytes]:
    """Render and save every spec; PNG bytes in spec order. ``processes > 1`` forks workers."""
    if processes <= 1 or len(specs) <= 1:
        return [_render(s) for s in specs]
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    pyplot()  # import once in the parent: the forked workers inherit it
    ctx = multiprocessing.get_context("fork")
    # the costliest first, so that the workers finish together
    order = sorted(range(len(specs)), key=lambda i: -_COST.get(specs[i][1], 1))
    with ProcessPoolExecutor(max_workers=min(processes, len(specs)), mp_context=ctx) as pool:
        done = list(pool.map(_render, [specs[i] for i in order]))
    out: list[bytes] = [b""] * len(specs)
    for i, png in zip(order, done, strict=True):
        out[i] = png
    return out


#: Relative rendering cost of the figures (load balancing of :func:`render_many`).
_COST = {
    "xu_grid": 6,
    "bias_std_vs_snr": 5,
    "fitness_vs_snr": 3,
    "figure4": 2,
    "figure5": 2,
    "hit_rate_vs_snr": 2,
}


def _log(ax: Any, which: str = "x") -> None:
    """A log axis labelled 1, 2, 5, 10, ... in plain text (log tick labels default to mathtext,
    whose parser costs more than the rest of the figure)."""
    from matplotlib.ticker import FuncFormatter, LogLocator, NullFormatter

    lim = ax.dataLim
    lo, hi = (lim.x0, lim.x1) if which == "x" else (lim.y0, lim.y1)
    if not (math.isfinite(lo) and math.isfinite(hi) and min(lo, hi) > 0):
        return  # nothing positive to draw on a log axis (e.g. no spread with one run)
    axis = ax.xaxis if which == "x" else ax.yaxis
    (ax.set_xscale if which == "x" else ax.set_yscale)("log")
    axis.set_major_locator(LogLocator(base=10, subs=(1.0, 2.0, 5.0)))
    axis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:g}"))
    axis.set_minor_formatter(NullFormatter())


def _xu(ax: Any, x: Any, U: Any, color: str = "C0", lines: bool = True) -> None:
    import numpy as np

    x = np.asarray(x, float)
    U = np.asarray(U, float)
    m = np.isfinite(x) & np.isfinite(U)
    if lines:
        ax.plot(x[m], U[m], "-", color=color, lw=0.4, alpha=0.25)
    ax.plot(x[m], U[m], ".", color=color, ms=2.0)


def figure_xu(x: Any, U: Any, ylabel: str, title: str) -> Any:
    """x(n) against U(n) for one realisation (the paper's Figures 4 and 5)."""
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(5.0, 3.8))
    fig.subplots_adjust(left=0.17, right=0.97, bottom=0.13, top=0.86)
    _xu(ax, x, U)
    ax.set_xlabel(f"controller output x(n) ({UNITLESS})")
    ax.set_ylabel(ylabel)
    ax.set_title(title)
    return fig


def figure4(example: Mapping[str, Any], estimate: str = "wang-lsm") -> Any:
    """Figure 4: x(n) against the blind estimate of U(n) (b1 = 1, unscaled, as the paper)."""
    return figure_xu(
        example["x"],
        example["estimates"][estimate],
        f"estimated U(n), b1 = 1 ({UNITLESS})",
        f"Figure 4: x(n) vs estimated U(n) [{estimate}]\n{_where(example)}",
    )


def figure5(example: Mapping[str, Any]) -> Any:
    """Figure 5: x(n) against the true inner signal U(n)."""
    return figure_xu(
        example["x"],
        example["U"],
        f"true inner signal U(n) ({UNITLESS})",
        f"Figure 5: x(n) vs true U(n)\n{_where(example)}",
    )


def _where(example: Mapping[str, Any]) -> str:
    s2 = example.get("sigma2")
    return f"one realisation, σ² = {float(s2):g}" if s2 is not None else "one realisation"


def paper_figure_specs(
    example: Mapping[str, Any], out: Path, estimate: str = "wang-lsm"
) -> list[FigureSpec]:
    """Specs of ``figure4.{png,pdf}`` and ``figure5.{png,pdf}`` in ``out``."""
    ex = {k: example[k] for k in ("x", "U", "sigma2") if k in example}
    ex["estimates"] = {estimate: example["estimates"][estimate]}
    return [
        (out / "figure4", "figure4", (ex, estimate), {}),
        (out / "figure5", "figure5", (ex,), {}),
    ]


def _grid(n: int, max_cols: int = 3) -> tuple[int, int]:
    cols = min(max(n, 1), max_cols)
    return math.ceil(max(n, 1) / cols), cols


def _legend_top(fig: Any, ax: Any, top_inches: float, ncol: int = 3) -> None:
    """The axes' legend centred above the panels, which start ``top_inches`` below the top."""
    handles, labels = ax.get_legend_handles_labels()
    if handles:
        h = fig.get_figheight()
        fig.legend(
            handles,
            labels,
            loc="upper center",
            ncol=min(ncol, len(labels)),
            bbox_to_anchor=(0.5, 1.0 - 0.04 / h),
            frameon=False,
        )
        fig.subplots_adjust(top=1.0 - top_inches / h)


def _legend_rows(n: int, ncol: int = 3) -> float:
    """Height (inches) of a legend of ``n`` entries in ``ncol`` columns."""
    return 0.17 * math.ceil(n / ncol) + 0.12


def fitness_vs_snr(stats: Any, label: Callable[[str], str]) -> Any:
    """Mean fitness +- std against mean SNR, one line per method, one panel per facet.

    ``stats`` columns: ``facet, method, snr, fitness_mean, fitness_std``.
    """
    import numpy as np

    plt = pyplot()
    facets = list(dict.fromkeys(stats["facet"]))
    rows, cols = _grid(len(facets))
    methods = list(dict.fromkeys(stats["method"]))
    ncol = 2 if cols == 1 else 3
    legend_h = _legend_rows(len(methods), ncol)
    width = max(4.4 * cols + 0.4, 6.4)
    height = 3.2 * rows + legend_h + 0.3
    fig, axes = plt.subplots(rows, cols, figsize=(width, height), squeeze=False)
    fig.subplots_adjust(left=0.8 / width, right=0.98, bottom=0.5 / height, wspace=0.3, hspace=0.5)
    colors = {m: f"C{i % 10}" for i, m in enumerate(methods)}
    for ax, facet in zip(axes.flat, facets, strict=False):
        sub = stats[(stats["facet"] == facet) & np.isfinite(stats["snr"])]
        for i, m in enumerate(methods):
            s = sub[sub["method"] == m].sort_values("snr")
            if s.empty:
                continue
            dodge = 1.0 + 0.012 * (i - (len(methods) - 1) / 2)  # separate the error bars
            ax.errorbar(
                s["snr"] * dodge,
                s["fitness_mean"],
                yerr=s["fitness_std"].fillna(0.0),
                marker="o",
                capsize=2.5,
                color=colors[m],
                label=label(m),
            )
        _log(ax, "x")
        ax.set_xlabel(SNR_LABEL)
        ax.set_ylabel("fitness F (%)")
        ax.set_title(str(facet))
    for ax in list(axes.flat)[len(facets) :]:
        ax.set_visible(False)
    _legend_top(fig, axes.flat[0], legend_h + 0.3, ncol)
    return fig


def bias_std_vs_snr(stats: Any, label: Callable[[str], str]) -> Any:
    """Bias and std of each parameter against SNR (rows: parameters; columns: bias, std).

    ``stats`` columns: ``series, parameter, snr, bias, std`` (``series`` names a line: the
    method, plus its facet when there are several).
    """
    import numpy as np

    plt = pyplot()
    params = sorted(dict.fromkeys(stats["parameter"]), key=lambda p: (p[0], int(p[1:])))
    series = list(dict.fromkeys(stats["series"]))
    legend_h = _legend_rows(len(series))
    height = 2.3 * max(len(params), 1) + legend_h + 0.3
    fig, axes = plt.subplots(len(params), 2, figsize=(8.6, height), squeeze=False)
    fig.subplots_adjust(left=0.11, right=0.98, bottom=0.5 / height, wspace=0.32, hspace=0.55)
    colors = {s: f"C{i % 10}" for i, s in enumerate(series)}
    for i, par in enumerate(params):
        sub = stats[(stats["parameter"] == par) & np.isfinite(stats["snr"])]
        for s in series:
            d = sub[sub["series"] == s].sort_values("snr")
            if d.empty:
                continue
            axes[i, 0].plot(d["snr"], d["bias"], "o-", color=colors[s], label=label(s))
            std = d["std"].where(d["std"] > 0)
            axes[i, 1].plot(d["snr"], std, "o-", color=colors[s], label=label(s))
        axes[i, 0].axhline(0.0, color="0.4", lw=0.8)
        axes[i, 0].set_ylabel(f"bias of {par} (-)")
        axes[i, 1].set_ylabel(f"std of {par} (-)")
        _log(axes[i, 1], "y")
        for ax in axes[i]:
            _log(ax, "x")
            ax.set_xlabel(SNR_LABEL)
    _legend_top(fig, axes[0, 0], legend_h + 0.25)
    return fig


def xu_grid(panels: Sequence[Mapping[str, Any]], label: Callable[[str], str]) -> Any:
    """x(n) against U(n) per nonlinearity (rows) and source (columns: the true U, then each
    method's estimate scaled by the true gain b1 as in the fitness).

    ``panels``: ``{"nonlinearity", "title", "x", "U", "gain", "estimates": {method: U}}``.
    """
    plt = pyplot()
    n_est = max((len(p["estimates"]) for p in panels), default=0)
    cols = min(1 + n_est, 4)
    rows_per = math.ceil((1 + n_est) / cols)
    n_rows = rows_per * len(panels)
    height = 2.45 * n_rows + 0.3
    fig, axes = plt.subplots(n_rows, cols, figsize=(2.6 * cols + 0.4, height), squeeze=False)
    fig.subplots_adjust(
        left=0.09, right=0.98, bottom=0.45 / height, top=1 - 0.3 / height, wspace=0.08, hspace=0.35
    )
    for i, p in enumerate(panels):
        cells = [("true U", p["U"], "k")]
        cells += [
            (label(m), U / p["gain"], f"C{j % 10}")
            for j, (m, U) in enumerate(p["estimates"].items())
        ]
        block = list(axes[i * rows_per : (i + 1) * rows_per].flat)
        ylim = _common_ylim([c[1] for c in cells])
        for k, ax in enumerate(block):
            if k >= len(cells):
                ax.set_visible(False)
                continue
            title, U, color = cells[k]
            _xu(ax, p["x"], U, color, lines=False)
            if ylim is not None:
                ax.set_ylim(*ylim)
            ax.set_title(title if k else f"true U ({p['title']})", fontsize=7.5)
            if k >= len(cells) - cols:
                ax.set_xlabel(f"x(n) ({UNITLESS})", fontsize=7.5)
            if k % cols == 0:
                ax.set_ylabel(f"{p['nonlinearity']}: U(n)/b1 (-)", fontsize=7.5)
            else:
                ax.tick_params(labelleft=False)
    return fig


def _common_ylim(series: Sequence[Any]) -> tuple[float, float] | None:
    """One y range for a row of x-U panels (robust: 0.5 % .. 99.5 % quantiles, padded)."""
    import numpy as np

    vals = np.concatenate([np.asarray(s, float).ravel() for s in series])
    vals = vals[np.isfinite(vals)]
    if not vals.size:
        return None
    lo, hi = np.quantile(vals, [0.005, 0.995])
    pad = 0.08 * (hi - lo if hi > lo else 1.0)
    return float(lo - pad), float(hi + pad)


def time_per_method(stats: Any, label: Callable[[str], str]) -> Any:
    """Mean time per run (s) per method, error bars one std over its runs; log axis.

    A run's time is its batch's time divided by the runs in the batch (the runs of a chunk are
    identified together), so the runs of one batch share one value: the std over the runs
    measures the spread between batches (cells, and chunks of a cell), each weighted by its
    runs; one batch gives 0.

    Parameters
    ----------
    stats : pandas.DataFrame
        Columns ``method, mean, std`` (seconds per run over a method's rows).
    label : callable
        Display label of a method name.

    Returns
    -------
    matplotlib.figure.Figure
        The horizontal bar chart.
    """
    import numpy as np

    plt = pyplot()
    s = stats.sort_values("mean")
    height = 0.32 * len(s) + 1.1  # room for the two-line axis label
    fig, ax = plt.subplots(figsize=(6.4, height))
    fig.subplots_adjust(left=0.42, right=0.97, bottom=0.7 / height, top=1 - 0.15 / height)
    y = np.arange(len(s))
    mean = s["mean"].to_numpy(float)
    err = np.minimum(s["std"].fillna(0.0).to_numpy(float), 0.9 * mean)  # log axis: stay > 0
    ax.barh(y, mean, xerr=err, color="C0", alpha=0.8, capsize=2.5)
    ax.set_yticks(y, [label(m) for m in s["method"]])
    _log(ax, "x")
    ax.set_xlabel(
        "identification time per run (s) = batch time / runs\n"
        "error bar: one std over runs (a batch's runs share its value)"
    )
    ax.grid(axis="y", visible=False)
    return fig


def ranking(stats: Any, label: Callable[[str], str]) -> Any:
    """Mean rank of fitness per cell (1 = best), lower is better.

    ``stats`` columns: ``method, mean_rank``.
    """
    import numpy as np

    plt = pyplot()
    s = stats.sort_values("mean_rank", ascending=False)
    height = 0.32 * len(s) + 0.9
    fig, ax = plt.subplots(figsize=(6.4, height))
    fig.subplots_adjust(left=0.42, right=0.97, bottom=0.5 / height, top=1 - 0.15 / height)
    y = np.arange(len(s))
    ax.barh(y, s["mean_rank"], color="C2", alpha=0.85)
    ax.set_yticks(y, [label(m) for m in s["method"]])
    ax.set_xlabel("mean rank of fitness over cells (1 = best)")
    ax.set_xlim(0, max(float(s["mean_rank"].max()) + 0.5, 1.5))
    ax.grid(axis="y", visible=False)
    return fig


def hit_rate_vs_snr(stats: Any, label: Callable[[str], str]) -> Any:
    """Hit rate of the total delay (solid) and of tau (dashed) against mean SNR, one colour per
    series (beyond the paper: assumption A3 relaxed).

    ``stats`` columns: ``series, snr_mean, delay_hit_rate, tau_hit_rate`` (``series`` names a
    line: the method, plus its facet when there are several). Infinite SNRs are not drawn.
    """
    import numpy as np

    plt = pyplot()
    series = list(dict.fromkeys(stats["series"]))
    n_legend = len(series) + 2
    legend_h = _legend_rows(n_legend)
    height = 3.4 + legend_h + 0.3
    fig, ax = plt.subplots(figsize=(6.4, height))
    fig.subplots_adjust(left=0.12, right=0.97, bottom=0.5 / height)
    drawn = stats[np.isfinite(stats["snr_mean"])]
    for i, s in enumerate(series):
        d = drawn[drawn["series"] == s].sort_values("snr_mean")
        if d.empty:
            continue
        color = f"C{i % 10}"
        dodge = 1.0 + 0.012 * (i - (len(series) - 1) / 2)  # overlapping lines stay visible
        x = d["snr_mean"] * dodge
        ax.plot(x, d["delay_hit_rate"], "o-", color=color, label=label(s))
        ax.plot(x, d["tau_hit_rate"], "s--", color=color, alpha=0.7, mfc="none")
    ax.plot([], [], "k-", label="total delay tau + m p")
    ax.plot([], [], "k--", label="tau only")
    ax.set_ylim(-0.03, 1.03)
    _log(ax, "x")
    ax.set_xlabel(SNR_LABEL)
    ax.set_ylabel("hit rate (share of runs, -)")
    _legend_top(fig, ax, legend_h + 0.25)
    return fig

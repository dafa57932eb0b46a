"""Figures of the reproduction and the comparison report (matplotlib, Agg backend).

One style for every figure (the style file :data:`hbench.report.style.STYLE_FILE`: journal sizes,
fonts of 8 pt at print size, TrueType fonts in PDF, 200 dpi PNG) and one colour, marker and line
style per method in every figure (:func:`hbench.report.style.method_style`); figures are one column
(:data:`~hbench.report.style.COLUMN_WIDTH`) or the page (:data:`~hbench.report.style.PAGE_WIDTH`)
wide. Every plotting function returns a matplotlib ``Figure``; :func:`save` writes it as PNG and PDF
and returns the PNG bytes (for HTML data URIs). :func:`render_many` renders a list of figures, in
forked worker processes when asked (the reproduction's time budget). The signals of the paper's
example are dimensionless (valve input x and output u in normalised units); the axes say so.
matplotlib is imported inside the functions (start-up time of the CLI). Layouts are constrained
(legends above the panels); no mathtext (its parser costs more than the drawing)."""

from __future__ import annotations

import contextlib
import functools
import io
import math
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

from hbench.report.style import COLUMN_WIDTH, PAGE_WIDTH, STYLE_FILE, method_style

#: Label of the dimensionless signals of the example.
UNITLESS = "normalised units"
SNR_LABEL = "SNR ||y0||/||v|| (ratio of norms)"


def pyplot() -> Any:
    """``matplotlib.pyplot`` on the Agg backend (the style is set per figure: :func:`styled`)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def warm_up() -> None:
    """Import what rendering needs (pyplot, the PDF backend and its TrueType subsetting), so
    that it is imported once, e.g. while other work runs or before forking workers."""
    pyplot()
    import fontTools.subset  # noqa: F401
    import matplotlib.backends.backend_pdf  # noqa: F401


def styled(func: Callable[..., Any]) -> Callable[..., Any]:
    """Draw under :data:`hbench.report.style.STYLE_FILE` (a context: the caller's rcParams are left
    as they were)."""

    @functools.wraps(func)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        with pyplot().style.context(STYLE_FILE):
            return func(*args, **kwargs)

    return wrapper


def save(fig: Any, stem: Path | str | None, formats: Sequence[str] = ("png", "pdf")) -> bytes:
    """Write ``stem.png`` (200 dpi) / ``stem.pdf`` (TrueType fonts) when ``stem`` is given;
    return the PNG bytes."""
    plt = pyplot()
    buf = io.BytesIO()
    with plt.style.context(STYLE_FILE):
        fig.savefig(buf, format="png")
        png = buf.getvalue()
        fig.set_layout_engine("none")  # the layout of the PNG, kept: computed once per figure
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


def render_many(
    specs: Sequence[FigureSpec],
    processes: int = 1,
    *,
    workers: Any = None,
    ready: Mapping[Path, Any] | None = None,
) -> list[bytes]:
    """Render and save every spec; PNG bytes in spec order. ``processes > 1``: this process
    and ``processes - 1`` worker processes of :func:`hbench.bench.parallel.pool` share the
    figures (a worker forked from this process, whose caches are warm, starts without importing
    anything): each takes the costliest figure left whenever it is free (a thread of this
    process hands the workers theirs), so that all finish together.

    ``workers``, a pool of ``processes - 1`` workers of :func:`hbench.bench.parallel.pool`
    already started (after :func:`warm_up`), takes the workers' figures in place of a pool
    started here (left running); ``ready`` maps the stem of a spec already submitted to it
    (:func:`submit`) to its future: that spec is not rendered again, its PNG bytes are the
    future's, and the workers take figures of this batch once those are done.

    The hand-over by a feeder thread (:func:`_share`) is measured against the executor's own
    queue (every figure submitted at once, this process cancelling and taking back the
    cheapest still waiting) by ``benchmarks/bench_figures.py``: the queue lets a busy worker
    hold a figure this process could have drawn."""
    ready = dict(ready or {})
    todo = [i for i, s in enumerate(specs) if s[0] is None or Path(s[0]) not in ready]
    out: list[bytes] = [b""] * len(specs)
    if workers is None and (processes <= 1 or len(todo) <= 1):
        for i in todo:
            out[i] = _render(specs[i])
    elif todo:
        warm_up()  # import once in the parent: the forked workers inherit it
        todo.sort(key=lambda i: -_COST.get(specs[i][1], 1))
        with contextlib.ExitStack() as stack:
            _share(specs, todo, out, processes, workers, list(ready.values()), stack)
    for i, spec in enumerate(specs):
        if spec[0] is not None and Path(spec[0]) in ready:
            out[i] = ready[Path(spec[0])].result()
    return out


def _share(
    specs: Sequence[FigureSpec],
    todo: list[int],
    out: list[bytes],
    processes: int,
    workers: Any,
    busy: list[Any],
    stack: contextlib.ExitStack,
) -> None:
    """:func:`render_many`'s figures ``todo`` (costliest first) shared between this process and
    the workers (``busy``: the workers' futures submitted before)."""
    import concurrent.futures as cf
    import threading
    from collections import deque

    slots = max(1, min(processes, len(todo) + 1) - 1)
    left = deque(todo)
    lock = threading.Lock()
    futures: dict[int, Any] = {}

    def take() -> int | None:
        with lock:
            return left.popleft() if left else None

    if workers is None:  # started here, from this thread (a fork from a thread could copy
        from hbench.bench import parallel  # a lock that another thread holds)

        workers = stack.enter_context(parallel.pool(slots))
        for _ in range(slots):
            i = take()
            if i is not None:
                futures[i] = workers.submit(_render, specs[i])
                busy.append(futures[i])

    def feed() -> None:  # a worker's next figure as soon as it is free
        running = {f for f in busy if not f.done()}
        while True:
            while len(running) >= slots:
                done, _ = cf.wait(running, return_when=cf.FIRST_COMPLETED)
                running -= done
            i = take()
            if i is None:
                return
            try:
                futures[i] = workers.submit(_render, specs[i])
            except BaseException:  # e.g. a broken pool: this process renders what is left
                with lock:
                    left.appendleft(i)
                return
            running.add(futures[i])

    feeder = threading.Thread(target=feed, daemon=True)
    feeder.start()
    while (i := take()) is not None:
        out[i] = _render(specs[i])
    feeder.join()
    while (i := take()) is not None:  # what the feeder gave back
        out[i] = _render(specs[i])
    for i, future in futures.items():
        out[i] = future.result()


def submit(workers: Any, spec: FigureSpec) -> Any:
    """Render ``spec`` in ``workers`` (a pool of :func:`hbench.bench.parallel.pool`); its future
    (the PNG bytes), for :func:`render_many`'s ``ready``."""
    return workers.submit(_render, spec)


#: Relative rendering cost of the figures, PNG and PDF (CPU seconds of the reproduction's
#: defaults, in tenths): :func:`render_many` renders the costliest first.
_COST = {
    "xu_grid": 8,
    "bias_std_vs_snr": 8,
    "fitness_vs_snr": 3,
    "ranking": 3,
    "time_per_method": 2.5,
    "figure4": 2,
    "figure5": 2.5,
    "hit_rate_vs_snr": 2,
}


def _log(ax: Any, which: str = "x", pad: bool = False) -> None:
    """A log axis labelled 1, 2, 5, 10, ... in plain text (log tick labels default to mathtext,
    whose parser costs more than the rest of the figure); over more than two decades only the
    powers of ten are labelled, so that the labels never run together. ``pad`` widens the
    limits by a factor 1.6 each side (a single point, or points of one value)."""
    from matplotlib.ticker import FuncFormatter, LogLocator, NullFormatter

    lim = ax.dataLim
    lo, hi = (lim.x0, lim.x1) if which == "x" else (lim.y0, lim.y1)
    if not (math.isfinite(lo) and math.isfinite(hi) and min(lo, hi) > 0):
        return  # nothing positive to draw on a log axis (e.g. no spread with one run)
    axis = ax.xaxis if which == "x" else ax.yaxis
    (ax.set_xscale if which == "x" else ax.set_yscale)("log")
    if pad:
        (ax.set_xlim if which == "x" else ax.set_ylim)(lo / 1.6, hi * 1.6)
        lo, hi = lo / 1.6, hi * 1.6
    decades = math.log10(hi / lo)
    subs = (1.0, 2.0, 5.0) if decades <= 2.0 else (1.0,)
    axis.set_major_locator(LogLocator(base=10, subs=subs, numticks=8))
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


@styled
def figure_xu(x: Any, U: Any, ylabel: str, title: str, color: str = "k") -> Any:
    """x(n) against U(n) for one realisation (the paper's Figures 4 and 5)."""
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(COLUMN_WIDTH, 3.0), layout="constrained")
    _xu(ax, x, U, color)
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
        method_style(estimate)["color"],
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


def _legend_top(fig: Any, handles: Sequence[Any], labels: Sequence[str], ncol: int) -> None:
    """One legend for the figure, above its panels (constrained layout makes room)."""
    if handles:
        fig.legend(handles, labels, loc="outside upper center", ncol=max(1, min(ncol, len(labels))))


def _ncol(width: float, labels: Sequence[str] = ()) -> int:
    """Legend columns that fit a figure ``width`` inches wide: an entry takes its handle and
    about 0.065 in per character at 8 pt."""
    longest = max((len(t) for t in labels), default=12)
    return max(1, min(3, int(width // (0.065 * longest + 0.6))))


def _fits(labels: Sequence[str]) -> float:
    """The narrowest journal width whose legend holds ``labels`` in at most three rows."""
    ncol = _ncol(COLUMN_WIDTH, labels)
    return COLUMN_WIDTH if math.ceil(len(labels) / ncol) <= 3 else PAGE_WIDTH


def _paper_handle() -> Any:
    from matplotlib.lines import Line2D

    return Line2D([], [], color="k", marker="o", mfc="none", ls="none", label="paper (hollow)")


#: What the error bars of the fitness figure show: ``"ci"`` (95 % interval of the mean) or
#: ``"std"`` (one standard deviation over the runs).
SPREADS = {"ci": "95 % interval of the mean", "std": "± one std over runs"}


@styled
def fitness_vs_snr(stats: Any, label: Callable[[str], str], spread: str = "ci") -> Any:
    """Mean fitness against mean SNR with error bars, one line per method, one panel per facet;
    the paper's values (column ``paper`` where present) as hollow markers.

    ``stats`` columns: ``facet, method, snr, fitness_mean`` and ``fitness_ci`` (half-width of
    the 95 % interval) for ``spread="ci"`` or ``fitness_std`` for ``spread="std"``.
    """
    import numpy as np

    if spread not in SPREADS:
        raise ValueError(f"spread must be one of {sorted(SPREADS)}, got {spread!r}")
    plt = pyplot()
    facets = list(dict.fromkeys(stats["facet"]))
    rows, cols = _grid(len(facets))
    methods = list(dict.fromkeys(stats["method"]))
    labels = [label(m) for m in methods] + ["paper (hollow)"]
    width = _fits(labels) if cols == 1 else PAGE_WIDTH
    ncol = _ncol(width, labels)
    fig, axes = plt.subplots(
        rows,
        cols,
        figsize=(width, 2.4 * rows + 0.2 * math.ceil(len(labels) / ncol) + 0.4),
        squeeze=False,
        layout="constrained",
    )
    err_col = "fitness_ci" if spread == "ci" else "fitness_std"
    has_paper = "paper" in stats.columns and np.isfinite(stats["paper"].astype(float)).any()
    handles: dict[str, Any] = {}
    for ax, facet in zip(axes.flat, facets, strict=False):
        sub = stats[(stats["facet"] == facet) & np.isfinite(stats["snr"])]
        for i, m in enumerate(methods):
            s = sub[sub["method"] == m].sort_values("snr")
            if s.empty:
                continue
            st = method_style(m)
            dodge = 1.0 + 0.015 * (i - (len(methods) - 1) / 2)  # separate the error bars
            err = s[err_col].astype(float).fillna(0.0) if err_col in s.columns else None
            h = ax.errorbar(
                s["snr"] * dodge,
                s["fitness_mean"],
                yerr=err,
                marker=st["marker"],
                color=st["color"],
                linestyle=st["linestyle"],
                label=label(m),
            )
            handles.setdefault(label(m), h)
            paper = s["paper"].astype(float) if has_paper else None
            if paper is not None and np.isfinite(paper).any():
                at = np.isfinite(paper)
                ax.plot(
                    (s["snr"] * dodge)[at],
                    paper[at],
                    linestyle="none",
                    marker=st["marker"],
                    mfc="none",
                    markersize=7,
                    color=st["color"],
                    markeredgewidth=1.0,
                )
        _log(ax, "x")
        ax.set_xlabel(SNR_LABEL)
        ax.set_ylabel(f"fitness F (%), {SPREADS[spread]}")
        if len(facets) > 1:
            ax.set_title(str(facet))
    for ax in list(axes.flat)[len(facets) :]:
        ax.set_visible(False)
    if has_paper:
        handles["paper (hollow)"] = _paper_handle()
    _legend_top(fig, list(handles.values()), list(handles), ncol)
    return fig


@styled
def bias_std_vs_snr(stats: Any, label: Callable[[str], str]) -> Any:
    """Bias and std of each parameter against SNR (rows: parameters; columns: bias, std); the
    paper's bias (column ``paper_bias`` where present: published mean - true) as hollow markers.

    ``stats`` columns: ``series, parameter, snr, bias, std`` (``series`` names a line: the
    method, plus its facet when there are several: facets differ by line style, else the
    method's own line style marks oracles and reconstructions).
    """
    import numpy as np

    plt = pyplot()
    params = sorted(dict.fromkeys(stats["parameter"]), key=lambda p: (p[0], int(p[1:])))
    series = list(dict.fromkeys(stats["series"]))
    facets = list(dict.fromkeys(s.partition(" | ")[2] for s in series))
    dashes = ("-", "--", ":", "-.")
    ncol = _ncol(PAGE_WIDTH, [label(x) for x in series])
    height = 1.9 * max(len(params), 1) + 0.2 * math.ceil(len(series) / ncol) + 0.4
    fig, axes = plt.subplots(
        len(params), 2, figsize=(PAGE_WIDTH, height), squeeze=False, layout="constrained"
    )
    handles: dict[str, Any] = {}
    paper = False
    for i, par in enumerate(params):
        sub = stats[(stats["parameter"] == par) & np.isfinite(stats["snr"])]
        for s in series:
            d = sub[sub["series"] == s].sort_values("snr")
            if d.empty:
                continue
            st = method_style(s)
            ls = (
                st["linestyle"]
                if len(facets) == 1
                else dashes[facets.index(s.partition(" | ")[2]) % len(dashes)]
            )
            kw = {"color": st["color"], "marker": st["marker"], "linestyle": ls, "label": label(s)}
            (h,) = axes[i, 0].plot(d["snr"], d["bias"], **kw)
            if "paper_bias" in d.columns and np.isfinite(d["paper_bias"].astype(float)).any():
                axes[i, 0].plot(
                    d["snr"],
                    d["paper_bias"].astype(float),
                    linestyle="none",
                    marker=st["marker"],
                    mfc="none",
                    markersize=7,
                    color=st["color"],
                )
                paper = True
            std = d["std"].where(d["std"] > 0)
            axes[i, 1].plot(d["snr"], std, **kw)
            handles.setdefault(label(s), h)
        axes[i, 0].axhline(0.0, color="0.4", lw=0.8)
        axes[i, 0].set_ylabel(f"bias of {par} (-)")
        axes[i, 1].set_ylabel(f"std of {par} (-)")
        _log(axes[i, 1], "y")
        for ax in axes[i]:
            _log(ax, "x")
            ax.set_xlabel(SNR_LABEL)
    if paper:
        handles["paper (hollow)"] = _paper_handle()
    _legend_top(fig, list(handles.values()), list(handles), _ncol(PAGE_WIDTH, list(handles)))
    return fig


@styled
def xu_grid(panels: Sequence[Mapping[str, Any]], label: Callable[[str], str]) -> Any:
    """x(n) against U(n) per nonlinearity (rows) and source (columns: the true U, then each
    method's estimate scaled by the true gain b1 as in the fitness), each method in its colour.

    ``panels``: ``{"nonlinearity", "title", "x", "U", "gain", "estimates": {method: U}}``.
    """
    plt = pyplot()
    n_est = max((len(p["estimates"]) for p in panels), default=0)
    cols = min(1 + n_est, 4)
    rows_per = math.ceil((1 + n_est) / cols)
    n_rows = rows_per * len(panels)
    fig, axes = plt.subplots(
        n_rows,
        cols,
        figsize=(PAGE_WIDTH, 1.9 * n_rows + 0.3),
        squeeze=False,
        layout="constrained",
        sharex=True,
    )
    for i, p in enumerate(panels):
        cells = [("true U", p["U"], "k")]
        cells += [
            (label(m), U / p["gain"], method_style(m)["color"]) for m, U in p["estimates"].items()
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
            ax.set_title(title if k else f"true U ({p['title']})")
            if k >= len(cells) - cols:
                ax.set_xlabel(f"x(n) ({UNITLESS})")
            if k % cols == 0:
                ax.set_ylabel(f"{p['nonlinearity']}: U(n)/b1 (-)")
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


def _time_unit(seconds: Any) -> tuple[float, str]:
    """``(scale, unit)``: ms for times of a millisecond or more, µs below."""
    import numpy as np

    finite = np.asarray(seconds, float)
    finite = finite[np.isfinite(finite) & (finite > 0)]
    return (1e3, "ms") if finite.size and finite.min() >= 1e-3 else (1e6, "µs")


@styled
def time_per_method(stats: Any, label: Callable[[str], str]) -> Any:
    """Mean time per run per method (ms or µs), error bars one std over its runs; log axis.

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
        The horizontal dot chart, each method in its colour and marker.
    """
    import numpy as np

    plt = pyplot()
    s = stats.sort_values("mean")
    scale, unit = _time_unit(s["mean"])
    fig, ax = plt.subplots(figsize=(COLUMN_WIDTH, 0.24 * len(s) + 1.0), layout="constrained")
    y = np.arange(len(s))
    mean = s["mean"].to_numpy(float) * scale
    err = np.minimum(s["std"].fillna(0.0).to_numpy(float) * scale, 0.9 * mean)  # log: stay > 0
    for k, m in enumerate(s["method"]):
        st = method_style(m)
        ax.errorbar(
            mean[k], y[k], xerr=err[k], marker=st["marker"], color=st["color"], linestyle="none"
        )
    ax.set_yticks(y, [label(m) for m in s["method"]])
    ax.set_ylim(-0.6, len(s) - 0.4)
    _log(ax, "x", pad=True)
    fig.supxlabel(
        f"identification time per run ({unit})\n= batch time / runs; error bar: one std\n"
        "over runs (a batch's runs share its value)",
        fontsize="medium",
    )
    ax.grid(axis="y", visible=False)
    return fig


@styled
def ranking(stats: Any, label: Callable[[str], str]) -> Any:
    """Mean rank of fitness per cell (1 = best), lower is better, each method in its colour.

    ``stats`` columns: ``method, mean_rank``.
    """
    import numpy as np

    plt = pyplot()
    s = stats.sort_values("mean_rank", ascending=False)
    fig, ax = plt.subplots(figsize=(COLUMN_WIDTH, 0.24 * len(s) + 0.8), layout="constrained")
    y = np.arange(len(s))
    ax.barh(y, s["mean_rank"], color=[method_style(m)["color"] for m in s["method"]], alpha=0.85)
    ax.set_yticks(y, [label(m) for m in s["method"]])
    fig.supxlabel("mean rank of fitness over cells (1 = best)", fontsize="medium")
    ax.set_xlim(0, max(float(s["mean_rank"].max()) + 0.5, 1.5))
    ax.grid(axis="y", visible=False)
    return fig


@styled
def hit_rate_vs_snr(stats: Any, label: Callable[[str], str]) -> Any:
    """Hit rate of the total delay (solid markers) and of tau (hollow, dashed) against mean SNR,
    each method in its colour (beyond the paper: assumption A3 relaxed).

    ``stats`` columns: ``series, snr_mean, delay_hit_rate, tau_hit_rate`` (``series`` names a
    line: the method, plus its facet when there are several). Infinite SNRs are not drawn.
    """
    import numpy as np

    plt = pyplot()
    series = list(dict.fromkeys(stats["series"]))
    labels = [label(x) for x in series] + ["total delay tau + m p", "tau only"]
    width = _fits(labels)
    ncol = _ncol(width, labels)
    fig, ax = plt.subplots(
        figsize=(width, 2.6 + 0.2 * math.ceil(len(labels) / ncol)), layout="constrained"
    )
    drawn = stats[np.isfinite(stats["snr_mean"])]
    for i, s in enumerate(series):
        d = drawn[drawn["series"] == s].sort_values("snr_mean")
        if d.empty:
            continue
        st = method_style(s)
        dodge = 1.0 + 0.012 * (i - (len(series) - 1) / 2)  # overlapping lines stay visible
        x = d["snr_mean"] * dodge
        ax.plot(
            x, d["delay_hit_rate"], marker=st["marker"], ls="-", color=st["color"], label=label(s)
        )
        ax.plot(
            x,
            d["tau_hit_rate"],
            marker=st["marker"],
            ls="--",
            color=st["color"],
            alpha=0.7,
            mfc="none",
        )
    ax.plot([], [], "k-", label="total delay tau + m p")
    ax.plot([], [], "k--", label="tau only")
    ax.set_ylim(-0.03, 1.03)
    _log(ax, "x")
    ax.set_xlabel(SNR_LABEL)
    ax.set_ylabel("hit rate (share of runs, -)")
    handles, shown = ax.get_legend_handles_labels()
    _legend_top(fig, handles, shown, ncol)
    return fig

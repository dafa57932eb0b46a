"""Journal-ready output: one style per method in every figure, TrueType fonts, 200 dpi PNG, the
package's style file, and the report as a browser shows it (headless Chromium)."""

from __future__ import annotations

import json
import re
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from hbench.bench.runner import methods_from_names, run_cell
from hbench.errors import InputError
from hbench.report import aggregate, elements, figures, inputs
from hbench.report import build as report
from hbench.report.style import COLUMN_WIDTH, PAGE_WIDTH, STYLE_FILE, method_style
from hbench.sim import scenarios

METHODS = ("wang-lsm", "wang-iv", "sun-liu-sano", "oracle")


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory) -> Path:
    """Two sigma^2 cells, four methods, a few runs each (rows at the root)."""
    root = tmp_path_factory.mktemp("run")
    frames = []
    for j, s2 in enumerate((1e-4, 1e-3)):
        spec = scenarios.PAPER_SECTION6 | {"duration": 120.0}
        spec = {**spec, "noise": {**spec["noise"], "sigma2": s2}}
        res = run_cell(scenarios.build(spec), methods_from_names(METHODS), 6, 11 + j, cell=str(j))
        frames.append(res.rows)
    pd.concat(frames, ignore_index=True).to_parquet(root / "rows.parquet", index=False)
    return root


@pytest.fixture(scope="module")
def built(run_dir) -> Path:
    return report.build_report(run_dir)


def _colours(fig) -> dict[str, set[str]]:
    """Colours of the drawn lines and bars per marker (matplotlib hex)."""
    from matplotlib.colors import to_hex

    out: dict[str, set[str]] = {}
    for ax in fig.axes:
        for line in ax.lines:
            marker = str(line.get_marker())
            if marker not in ("None", "", " "):
                out.setdefault(marker, set()).add(to_hex(line.get_color()))
    return out


def _hollow(fig) -> list:
    """The lines of hollow markers only (the paper's values)."""
    return [
        ln
        for ax in fig.axes
        for ln in ax.lines
        if ln.get_markerfacecolor() == "none" and ln.get_linestyle() == "None"
    ]


def test_method_styles_are_fixed_by_name() -> None:
    assert method_style("wang-lsm") == method_style("wang-lsm | backlash, p=5, delay=3")
    assert method_style("wang-lsm")["color"] != method_style("wang-iv")["color"]
    oracle = method_style("oracle")
    assert oracle["linestyle"] == "--" and oracle["color"].startswith("0.")  # grey, dashed
    assert method_style("sun-liu-sano")["linestyle"] == ":"  # a reconstruction
    # a name no table knows: a fixed look from the name itself
    assert method_style("my-method") == method_style("my-method")


def test_every_figure_draws_a_method_in_its_colour_and_marker(run_dir) -> None:
    from matplotlib.colors import to_hex

    rows, _ = inputs.load_rows(run_dir)
    stats = aggregate.cell_stats(rows)
    stats["fitness"]["fitness_ci"] = 1.0
    blind = [m for m in METHODS if m != "oracle"]  # oracles have no bias to draw
    drawn = [
        (figures.fitness_vs_snr(stats["fitness"], str), METHODS),
        (figures.bias_std_vs_snr(stats["bias"], str), blind),
        (figures.time_per_method(stats["timing"], str), METHODS),
    ]
    try:
        for fig, names in drawn:
            colours = _colours(fig)
            for m in names:
                st = method_style(m)
                assert to_hex(st["color"]) in colours.get(st["marker"], set()), (m, colours)
    finally:
        for fig, _ in drawn:
            figures.pyplot().close(fig)


def test_figures_are_journal_sized_and_leave_rcparams_alone(run_dir) -> None:
    import matplotlib

    before = dict(matplotlib.rcParams)
    rows, _ = inputs.load_rows(run_dir)
    stats = aggregate.cell_stats(rows)
    fig = figures.time_per_method(stats["timing"], str)
    wide = figures.bias_std_vs_snr(stats["bias"], str)
    try:
        assert fig.get_figwidth() == pytest.approx(COLUMN_WIDTH)
        assert wide.get_figwidth() == pytest.approx(PAGE_WIDTH)
        sizes = [t.get_fontsize() for ax in fig.axes for t in ax.get_yticklabels()]
        assert min(sizes) >= 8
    finally:
        figures.pyplot().close(fig)
        figures.pyplot().close(wide)
    after = dict(matplotlib.rcParams)
    assert {k for k in before if before[k] != after[k]} == set()


def test_no_text_is_cut_at_the_figure_edge(run_dir) -> None:
    """Legends, labels and tick labels lie inside the figure at its journal width (the saved
    PNG and PDF show the whole figure)."""
    from matplotlib.text import Text

    rows, _ = inputs.load_rows(run_dir)
    stats = aggregate.cell_stats(rows)
    stats["fitness"]["fitness_ci"] = 1.0
    label = report.method_label  # the long labels: "... (reconstruction)", "... (oracle bound)"
    drawn = [
        figures.fitness_vs_snr(stats["fitness"], label),
        figures.bias_std_vs_snr(stats["bias"], label),
        figures.time_per_method(stats["timing"], label),
        figures.ranking(stats["ranking"], label),
    ]
    try:
        for fig in drawn:
            renderer = fig.canvas.get_renderer()
            fig.draw_without_rendering()
            box = fig.bbox
            ticks, shown = set(), []
            for ax in fig.axes:
                for axis in (ax.xaxis, ax.yaxis):
                    lo, hi = sorted(axis.get_view_interval())
                    for tick in axis.get_major_ticks() + axis.get_minor_ticks():
                        ticks.update((tick.label1, tick.label2))
                        # matplotlib draws only the ticks inside the axis' limits
                        if lo <= tick.get_loc() <= hi and tick.label1.get_visible():
                            shown.append(tick.label1)
            shown += [t for t in fig.findobj(Text) if t not in ticks and t.get_visible()]
            for text in shown:
                if not text.get_text().strip():
                    continue
                ext = text.get_window_extent(renderer)
                assert ext.x0 >= box.x0 - 1 and ext.x1 <= box.x1 + 1, text.get_text()
                assert ext.y0 >= box.y0 - 1 and ext.y1 <= box.y1 + 1, text.get_text()
    finally:
        for fig in drawn:
            figures.pyplot().close(fig)


def test_style_file_is_reusable() -> None:
    import matplotlib.pyplot as plt

    with plt.style.context(STYLE_FILE):
        import matplotlib

        rc = matplotlib.rcParams
        assert rc["pdf.fonttype"] == 42 and rc["savefig.dpi"] >= 200
        assert min(rc["font.size"], rc["legend.fontsize"], rc["xtick.labelsize"]) >= 8


def test_pdf_fonts_are_truetype_and_png_200_dpi(built) -> None:
    out = built.parent
    pdfs = sorted(out.glob("*.pdf"))
    assert len(pdfs) >= 4
    for pdf in pdfs:
        data = pdf.read_bytes()
        assert b"/Type3" not in data, pdf.name
        assert b"/CIDFontType2" in data or b"/TrueType" in data, pdf.name
    if shutil.which("pdffonts"):
        listing = subprocess.run(
            ["pdffonts", str(pdfs[0])], capture_output=True, text=True, check=True
        ).stdout
        types = [ln for ln in listing.splitlines()[2:] if ln.strip()]
        assert types and all("TrueType" in ln for ln in types), listing
    for png in out.glob("*.png"):
        assert elements.png_size(png.read_bytes())[2] >= 199.9, png.name


def test_report_opens_with_the_headline_table(built) -> None:
    page = built.read_text(encoding="utf-8")
    sections = re.findall(r'<section id="([^"]+)"', page)
    assert sections[0] == "headline"
    assert (built.parent / "summary.csv").is_file()
    head = pd.read_csv(built.parent / "summary.csv")
    assert set(head["method"]) == set(METHODS)
    assert head.loc[head["method"] == "oracle", "diff_to_best"].isna().all()


CHECK = """<script>
window.addEventListener('load', () => {
  const body = document.body.getBoundingClientRect();
  const broken = [...document.images].filter(i => !i.complete || i.naturalWidth === 0).length;
  const over = [];
  for (const el of document.body.querySelectorAll('*')) {
    if (el.closest('.scroll') || el.closest('details:not([open])')) continue;
    const r = el.getBoundingClientRect();
    if (r.width && r.right > body.right + 1) over.push(el.tagName + '#' + el.id);
  }
  const pre = document.createElement('pre');
  pre.id = 'hbench-check';
  pre.textContent = JSON.stringify({images: document.images.length, broken: broken,
    overflow: over.slice(0, 10), page: document.documentElement.scrollWidth,
    view: window.innerWidth});
  document.body.appendChild(pre);
});
</script>"""


@pytest.mark.skipif(
    shutil.which("chromium") is None,
    reason="needs headless Chromium (Debian's package chromium) to render the page",
)
def test_report_renders_in_chromium_without_overflow(built, tmp_path) -> None:
    page = built.read_text(encoding="utf-8").replace("</body>", CHECK + "</body>")
    probe = tmp_path / "probe.html"
    probe.write_text(page, encoding="utf-8")
    done = subprocess.run(
        [
            "chromium",
            "--headless",
            "--no-sandbox",
            "--disable-gpu",
            "--window-size=1400,1000",
            "--virtual-time-budget=5000",
            "--dump-dom",
            probe.as_uri(),
        ],
        capture_output=True,
        text=True,
        timeout=120,
    )
    found = re.search(r'<pre id="hbench-check">(.*?)</pre>', done.stdout, re.S)
    assert found, done.stderr[-2000:]
    result = json.loads(found.group(1).replace("&quot;", '"'))
    assert result["images"] >= 3 and result["broken"] == 0, result
    assert result["overflow"] == [] and result["page"] <= result["view"], result


def test_fitness_figure_has_paper_markers_where_published(run_dir) -> None:
    """The paper's fitness (where one is published) is a hollow marker in the method's colour."""
    from matplotlib.colors import to_hex

    rows, _ = inputs.load_rows(run_dir)
    fitness = aggregate.cell_stats(rows)["fitness"]
    published = np.where(fitness["method"] == "wang-lsm", 90.0, np.nan)
    fig = figures.fitness_vs_snr(fitness.assign(fitness_ci=1.0, paper=published), str)
    try:
        hollow = _hollow(fig)
        assert len(hollow) == 1 and np.allclose(hollow[0].get_ydata(), 90.0)
        assert to_hex(hollow[0].get_color()) == to_hex(method_style("wang-lsm")["color"])
    finally:
        figures.pyplot().close(fig)


def test_spread_option_switches_the_error_bars(run_dir, tmp_path, run_cli) -> None:
    """The fitness figure's error bars: the 95 % interval by default, one std with
    ``--spread std``; the caption says which."""
    rows, _ = inputs.load_rows(run_dir)
    fitness = aggregate.cell_stats(rows)["fitness"].assign(fitness_ci=0.123, fitness_std=4.56)

    def half_widths(spread: str) -> set[float]:
        fig = figures.fitness_vs_snr(fitness, str, spread=spread)
        try:
            out = set()
            for ax in fig.axes:
                for coll in ax.collections:  # the error bars
                    for seg in coll.get_segments():
                        out.add(round(abs(seg[1][1] - seg[0][1]) / 2, 3))
            return out
        finally:
            figures.pyplot().close(fig)

    assert half_widths("ci") == {0.123} and half_widths("std") == {4.56}
    status, _, err = run_cli(
        ["report", str(run_dir), "--out", str(tmp_path / "s"), "--spread", "std"]
    )
    assert status == 0, err
    page = (tmp_path / "s" / "report.html").read_text(encoding="utf-8")
    assert "error bars ± one std over runs" in page
    with pytest.raises(InputError, match="--spread must be one of ci, std"):
        report.build_report(run_dir, tmp_path / "bad", spread="sem")
    assert not (tmp_path / "bad").exists()  # refused before any work


def test_bias_figure_has_the_papers_bias_hollow(run_dir) -> None:
    from matplotlib.colors import to_hex

    rows, _ = inputs.load_rows(run_dir)
    bias = aggregate.cell_stats(rows)["bias"]
    published = np.where((bias["method"] == "wang-iv") & (bias["parameter"] == "a1"), 0.01, np.nan)
    fig = figures.bias_std_vs_snr(bias.assign(paper_bias=published), str)
    try:
        hollow = _hollow(fig)
        assert len(hollow) == 1 and np.allclose(hollow[0].get_ydata(), 0.01)
        assert to_hex(hollow[0].get_color()) == to_hex(method_style("wang-iv")["color"])
        assert fig.legends[0].get_texts()[-1].get_text() == "paper (hollow)"
    finally:
        figures.pyplot().close(fig)


def test_figures_shared_with_a_started_worker_are_those_of_one_process(tmp_path) -> None:
    """``render_many`` with a worker already started and a figure already submitted to it
    (the reproduction's x-U graphs, drawn early) writes and returns the PNGs of one process."""
    from hbench.bench import parallel

    x = np.linspace(-1.0, 1.0, 60)
    example = {"x": x, "U": x**3, "sigma2": 1e-3, "estimates": {"wang-lsm": x**3 + 0.01}}
    (tmp_path / "one").mkdir()
    (tmp_path / "two").mkdir()
    one = figures.render_many(figures.paper_figure_specs(example, tmp_path / "one"), 1)
    specs = figures.paper_figure_specs(example, tmp_path / "two")
    figures.warm_up()
    with parallel.pool(1) as workers:
        early = {specs[1][0]: figures.submit(workers, specs[1])}
        two = figures.render_many(specs, 2, workers=workers, ready=early)
    assert two == one
    for name in ("figure4.png", "figure5.png"):
        assert (tmp_path / "two" / name).read_bytes() == (tmp_path / "one" / name).read_bytes()

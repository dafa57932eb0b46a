"""``hbench report``: a self-contained HTML page, Markdown/LaTeX tables, PDF figures."""

from __future__ import annotations

import base64
import shutil
from html.parser import HTMLParser
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from hbench.bench.runner import methods_from_names, run_cell
from hbench.paper.reproduce import save_examples
from hbench.report import aggregate, inputs
from hbench.report import build as report
from hbench.sim import scenarios
from hbench.tables import results

METHODS = ("wang-lsm", "sun-liu-sano", "oracle")
LEVELS = (1e-4, 1e-3)


class Page(HTMLParser):
    """Tags with their attributes, the ids of enclosing elements, and the text."""

    def __init__(self) -> None:
        super().__init__()
        self.tags: list[tuple[str, dict[str, str], tuple[str, ...]]] = []
        self.stack: list[tuple[str, str]] = []
        self.text: list[str] = []
        self.section_text: dict[str, list[str]] = {}

    def handle_starttag(self, tag, attrs):
        a = {k: v or "" for k, v in attrs}
        ids = tuple(i for _, i in self.stack if i)
        self.tags.append((tag, a, ids + ((a["id"],) if a.get("id") else ())))
        if tag not in ("img", "meta", "br", "hr", "link"):
            self.stack.append((tag, a.get("id", "")))

    def handle_endtag(self, tag):
        while self.stack:
            t, _ = self.stack.pop()
            if t == tag:
                break

    def handle_data(self, data):
        self.text.append(data)
        for _, i in self.stack:
            if i:
                self.section_text.setdefault(i, []).append(data)


def parse(path: Path) -> Page:
    page = Page()
    page.feed(path.read_text(encoding="utf-8"))
    return page


@pytest.fixture(scope="module")
def sweep_dir(tmp_path_factory):
    """A Hydra-like multirun: one job folder per cell with rows.parquet + provenance.json, no
    rows at the root, and one job duplicated (rows present twice)."""
    root = tmp_path_factory.mktemp("sweep")
    methods = methods_from_names(METHODS)
    examples = []
    for j, s2 in enumerate(LEVELS):
        spec = scenarios.PAPER_SECTION6 | {"duration": 120.0}
        spec = {**spec, "noise": {**spec["noise"], "sigma2": s2}}
        res = run_cell(
            scenarios.build(spec), methods, 5, 100 + j, cell=f"s2={s2:g}", keep_example=True
        )
        job = root / str(j)
        job.mkdir()
        res.rows.to_parquet(job / "rows.parquet", index=False)
        results.write_provenance(
            job, config={"sigma2": s2, "duration": 120.0}, seeds={"cell": 100 + j}
        )
        examples.append(
            {**res.example, "cell": f"s2={s2:g}", "nonlinearity": "backlash", "sigma2": s2}
        )
    # a cell given by a target SNR (sigma2 empty in the rows)
    spec = scenarios.PAPER_SECTION6 | {"duration": 120.0}
    noise = {k: v for k, v in spec["noise"].items() if k != "sigma2"} | {"snr": 3.0}
    res = run_cell(scenarios.build({**spec, "noise": noise}), methods, 3, 7, cell="snr=3")
    (root / "snr").mkdir()
    res.rows.to_parquet(root / "snr" / "rows.parquet", index=False)
    shutil.copytree(root / "0", root / "0-copy")
    return root, examples


@pytest.fixture(scope="module")
def built(sweep_dir, tmp_path_factory):
    root, _ = sweep_dir
    import contextlib
    import io

    from hbench import cli

    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        status = cli.main(["report", str(root)])
    return status, Path(out.getvalue().strip()), err.getvalue()


def test_rows_found_below_the_root_and_deduplicated(sweep_dir):
    root, _ = sweep_dir
    rows, files = inputs.load_rows(root)
    assert len(files) == 4
    sizes = [len(pd.read_parquet(root / j / "rows.parquet")) for j in ("0", "1", "snr")]
    assert len(rows) == sum(sizes)  # the copied job counted once
    assert set(rows["sigma2"].dropna()) == set(LEVELS)
    assert set(rows["snr_target"].dropna()) == {3.0}


def test_report_html_is_self_contained(built):
    status, path, _ = built
    assert status == 0
    assert path.name == "report.html" and path.parent.name == "report"
    page = parse(path)
    for tag, attrs, _ in page.tags:
        for key in ("src", "href"):
            if key in attrs:
                assert attrs[key].startswith("data:"), (tag, key, attrs[key][:60])
        assert tag not in ("link", "script", "iframe", "object", "embed")
    imgs = [(a, ids) for t, a, ids in page.tags if t == "img"]
    by_figure = {ids[-1]: a["src"] for a, ids in imgs if ids}
    for fig in ("fig-fitness-snr", "fig-bias-std-snr", "fig-time", "fig-ranking"):
        src = by_figure[fig]
        assert src.startswith("data:image/png;base64,")
        png = base64.b64decode(src.split(",", 1)[1])
        assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 3000
    # sweeps save no signals: the x-U figure is replaced by a note that says so
    assert "fig-xu" not in by_figure
    assert "no-examples" in {a.get("id") for _, a, _ in page.tags}


def test_report_tables_provenance_and_labels(built, sweep_dir):
    _, path, _ = built
    page = parse(path)
    ids = {a.get("id") for _, a, _ in page.tags}
    assert {
        "table-ranking",
        "table-timing",
        "table-fitness",
        "table-bias",
        "table-structure",
        "table-summary",
        "provenance",
        "provenance-differs",
    } <= ids
    text = "".join(page.text)
    assert "sun-liu-sano (reconstruction)" in text
    assert "oracle (oracle bound)" in text
    prov = "".join(page.section_text["provenance"])
    assert results.git_revision() in prov
    assert "numpy" in prov
    # one block: what the jobs share once, what differs (here the level) per file
    assert prov.count('"versions.numpy"') == 1 and prov.count(results.git_revision()) == 1
    differs = "".join(page.section_text["provenance-differs"])
    assert "config.sigma2" in differs and "0.0001" in differs and "0.001" in differs
    fitness = "".join(page.section_text["table-fitness"])
    assert "wang-lsm" in fitness and "backlash" in fitness
    stats = aggregate.cell_stats(inputs.load_rows(sweep_dir[0])[0])
    assert len(stats["fitness"]) == 3 * len(METHODS)  # two sigma^2 cells and one SNR cell
    ranking = "".join(page.section_text["table-ranking"])
    assert "oracle" not in ranking  # bounds are not ranked
    # no method of the hbench_extensions package ran: no "Beyond the paper" section
    assert "beyond" not in ids and not list(path.parent.glob("beyond_*"))
    out = path.parent
    for name in ("fitness", "bias", "ranking", "timing"):
        tex = (out / f"{name}.tex").read_text()
        assert r"\toprule" in tex and r"\midrule" in tex and r"\bottomrule" in tex
        md = (out / f"{name}.md").read_text()
        # the method's label in place of its name: one column, no duplicate
        assert md.startswith("| method |") and "| label |" not in md and "|---|" in md
    for stem in ("fitness_snr", "bias_std_snr", "time", "ranking"):
        assert (out / f"{stem}.pdf").read_bytes()[:5] == b"%PDF-"
        assert (out / f"{stem}.png").stat().st_size > 3000


def test_report_with_examples_draws_xu_graphs_and_never_overwrites(sweep_dir, tmp_path):
    root, examples = sweep_dir
    run = tmp_path / "run"
    shutil.copytree(root / "1", run)
    save_examples(run / "examples.npz", examples[1:])
    first = report.build_report(run)
    second = report.build_report(run)
    assert first.parent == run / "report"
    assert second.parent != first.parent and second.parent.name.startswith("report-")
    page = parse(second)
    src = {ids[-1]: a["src"] for t, a, ids in page.tags if t == "img" and ids}
    assert src["fig-xu"].startswith("data:image/png;base64,")
    assert "no-examples" not in {a.get("id") for _, a, _ in page.tags}
    assert (second.parent / "xu.pdf").read_bytes()[:5] == b"%PDF-"
    loaded = inputs.load_examples(run)
    assert len(loaded) == 1
    assert set(loaded[0]["estimates"]) == set(METHODS)
    np.testing.assert_array_equal(loaded[0]["x"], examples[1]["x"])


def test_report_out_option(sweep_dir, tmp_path, run_cli):
    root, _ = sweep_dir
    status, out, _ = run_cli(["report", str(root / "1"), "--out", str(tmp_path / "r")])
    assert status == 0
    assert Path(out.strip()) == tmp_path / "r" / "report.html"


def test_report_bad_input(run_cli, tmp_path):
    status, _, err = run_cli(["report", str(tmp_path)])
    assert status == 2
    assert err.count("\n") == 1 and "no rows.parquet" in err and "Traceback" not in err
    status, _, err = run_cli(["report", str(tmp_path / "missing")])
    assert status == 2 and err.count("\n") == 1
    (tmp_path / "rows.parquet").write_text("not parquet")
    status, _, err = run_cli(["report", str(tmp_path)])
    assert status == 2 and err.count("\n") == 1 and "cannot read" in err


def test_method_labels():
    assert report.method_label("sun-liu-sano") == "sun-liu-sano (reconstruction)"
    assert report.method_label("oracle-inv") == "oracle-inv (oracle bound)"
    assert report.method_label("wang-lsm") == "wang-lsm"
    assert report.method_label("no-such-method") == "no-such-method"

"""``hbench report`` when runs fail or are not identifiable: the report is written and says
which method failed, in which cell, and why (never a crash, never only a status count)."""

from __future__ import annotations

import re
from html.parser import HTMLParser
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import pytest

from hbench.bench.runner import methods_from_names, run_cell
from hbench.ident.identifiers import Identifier
from hbench.report import aggregate, inputs
from hbench.report import build as report
from hbench.sim import scenarios

#: A message with every character LaTeX and Markdown tables treat specially.
NASTY = r"singular {matrix} & 50% #1 $x^2$ ~ a|b \ end"


class AlwaysFails(Identifier):
    """A method that raises on every run (not registered: the runner takes instances)."""

    name = "always-fails"

    def identify(self, record: Any, options: Any, truth: Any = None) -> Any:
        raise RuntimeError(NASTY)


class Page(HTMLParser):
    """Tags with their attributes, and the text under each element with an id."""

    def __init__(self) -> None:
        super().__init__()
        self.tags: list[tuple[str, dict[str, str]]] = []
        self.stack: list[tuple[str, str]] = []
        self.by_id: dict[str, list[str]] = {}

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        a = {k: v or "" for k, v in attrs}
        self.tags.append((tag, a))
        if tag not in ("img", "meta", "br", "hr", "link"):
            self.stack.append((tag, a.get("id", "")))

    def handle_endtag(self, tag: str) -> None:
        while self.stack:
            t, _ = self.stack.pop()
            if t == tag:
                break

    def handle_data(self, data: str) -> None:
        for _, i in self.stack:
            if i:
                self.by_id.setdefault(i, []).append(data)

    def text(self, ident: str) -> str:
        return "".join(self.by_id.get(ident, []))

    def ids(self) -> set[str]:
        return {a["id"] for _, a in self.tags if a.get("id")}


def parse(path: Path) -> Page:
    page = Page()
    page.feed(path.read_text(encoding="utf-8"))
    return page


def cell_rows(methods: dict[str, Identifier], p: int, seed: int) -> pd.DataFrame:
    spec = scenarios.PAPER_SECTION6 | {"duration": 120.0, "p": p}
    return run_cell(scenarios.build(spec), methods, 2, seed, cell=f"p={p}").rows


def check_latex(tex: str) -> None:
    """Every row of the tabular has as many unescaped ``&`` as the header (no broken cells)."""
    body = tex.split(r"\toprule", 1)[1].split(r"\bottomrule", 1)[0]
    lines = [ln for ln in body.splitlines() if ln.strip() and ln.strip() != r"\midrule"]
    counts = {len(re.findall(r"(?<!\\)&", ln)) for ln in lines if "multicolumn" not in ln}
    assert len(counts) == 1, tex
    # math (the headers' symbols, signs) comes in pairs of $; text has its $ and # escaped
    text = re.sub(r"(?<!\\)\$[^$]*?(?<!\\)\$", "", body)
    assert not re.search(r"(?<!\\)[#$]", text), tex


def check_markdown(md: str) -> None:
    """Every table line has as many unescaped ``|`` as the header."""
    lines = [ln for ln in md.splitlines() if ln.startswith("|")]
    assert lines, md
    assert len({len(re.findall(r"(?<!\\)\|", ln)) for ln in lines}) == 1, md


@pytest.fixture(scope="module")
def none_ok(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """p = 1: every run of wang-lsm is not identifiable (assumption A2)."""
    root = tmp_path_factory.mktemp("none-ok")
    cell_rows(methods_from_names(["wang-lsm"]), 1, 3).to_parquet(root / "rows.parquet")
    return root


@pytest.fixture(scope="module")
def some_fail(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Two jobs: a method that raises beside wang-lsm (p = 5), and wang-lsm at p = 1."""
    root = tmp_path_factory.mktemp("some-fail")
    methods = {
        "wang-lsm": methods_from_names(["wang-lsm"])["wang-lsm"],
        "always-fails": AlwaysFails(),
    }
    for job, (ms, p) in {"a": (methods, 5), "b": ({"wang-lsm": methods["wang-lsm"]}, 1)}.items():
        (root / job).mkdir()
        cell_rows(ms, p, 4).to_parquet(root / job / "rows.parquet")
    return root


def test_report_written_when_no_run_produced_an_estimate(none_ok, run_cli, tmp_path):
    status, out, err = run_cli(["report", str(none_ok), "--out", str(tmp_path / "r")])
    assert status == 0, err
    assert "Traceback" not in err
    path = Path(out.strip())
    assert path == tmp_path / "r" / "report.html"
    page = parse(path)
    ids = page.ids()
    note = page.text("no-estimates")
    assert "No run produced an estimate" in note
    assert "not-identifiable 2" in note
    failures = page.text("table-failures")
    assert "wang-lsm" in failures and "not identifiable: p = 1" in failures
    assert "2 runs" in failures
    # no empty figures: a one-line note per figure that needs data
    assert not [a for t, a in page.tags if t == "img"]
    for fig in ("fig-fitness-snr", "fig-bias-std-snr", "fig-time", "fig-ranking"):
        assert fig not in ids and f"no-{fig}" in ids
    for name in ("fitness", "bias", "ranking", "timing"):
        assert f"table-{name}" not in ids and f"no-table-{name}" in ids
    folder = path.parent
    md = (folder / "failures.md").read_text()
    assert "No run produced an estimate" in md and "not identifiable: p = 1" in md
    check_markdown(md)
    for name in ("fitness", "bias", "ranking", "timing"):
        assert "No run produced an estimate" in (folder / f"{name}.md").read_text()
    for tex in folder.glob("*.tex"):
        text = tex.read_text()
        check_latex(text)
        assert r"\begin{tabular}{}" not in text
    tex = (folder / "failures.tex").read_text()
    assert r"Li \& Dasgupta" in tex
    assert "No run produced an estimate" in (folder / "fitness.tex").read_text()


def test_report_names_the_failing_method_cell_and_reason(some_fail, tmp_path):
    path = report.build_report(some_fail, tmp_path / "r")
    page = parse(path)
    failures = page.text("table-failures")
    assert "always-fails" in failures and "RuntimeError: " + NASTY in failures
    assert "not identifiable: p = 1" in failures
    table = aggregate.failure_table(inputs.load_rows(some_fail)[0])
    assert list(zip(table["method"], table["p"], strict=True)) == [
        ("always-fails", 5),
        ("wang-lsm", 1),
    ]
    row = table.iloc[0]
    assert (row["runs"], row["ok"], row["failed"], row["not-identifiable"]) == (2, 0, 2, 0)
    assert row["messages"].startswith("RuntimeError: " + NASTY)
    assert row["messages"].endswith("[2 runs]")
    row = table.iloc[1]
    assert (row["runs"], row["ok"], row["failed"], row["not-identifiable"]) == (2, 0, 0, 2)
    # wang-lsm at p = 5 produced estimates: its figures are drawn, no note says otherwise
    assert "no-estimates" not in page.ids()
    assert "fig-fitness-snr" in page.ids()
    md = (path.parent / "failures.md").read_text()
    check_markdown(md)
    assert r"a\|b" in md
    tex = (path.parent / "failures.tex").read_text()
    check_latex(tex)
    for escaped in (r"\{matrix\}", r"\&", r"\%", r"\#1", r"\$x", r"\textbackslash{}"):
        assert escaped in tex, escaped


def test_failure_table_counts_and_caps_messages():
    runs = 7
    errors = ["boom 1", "boom 1", "boom 2", "boom 3", "boom 4", "x" * 500, ""]
    rows = pd.DataFrame(
        {
            "cell": "c",
            "method": "m",
            "nonlinearity": "backlash",
            "plant": "paper",
            "p": 5,
            "delay": 3,
            "sigma2": 1e-3,
            "snr_target": np.nan,
            "run": np.repeat(np.arange(runs), 2),
            "seed": "0",
            "quantity": ["fitness", "a1"] * runs,
            "value": np.nan,
            "true": np.nan,
            "snr": 3.0,
            "status": "failed",
            "error": np.repeat(errors, 2),
        }
    )
    rows.loc[rows["run"] == 6, "status"] = "ok"
    rows.loc[rows["run"] == 5, "status"] = "not-identifiable"
    table = aggregate.failure_table(rows, messages=3, width=40)
    assert len(table) == 1
    row = table.iloc[0]
    assert (row["runs"], row["ok"], row["failed"], row["not-identifiable"]) == (7, 1, 5, 1)
    parts = row["messages"].split("; ")
    assert parts[0] == "boom 1 [2 runs]"
    assert parts[1] == "boom 2 [1 run]"
    assert parts[-1] == "(+2 more distinct messages)"
    assert len(parts) == 4
    # a long message is cut, and says so
    table = aggregate.failure_table(rows[rows["run"] == 5], width=40)
    assert table.iloc[0]["messages"] == "x" * 37 + "... [1 run]"
    # every run ok: an empty table with the same columns
    empty = aggregate.failure_table(rows[rows["run"] == 6])
    assert empty.empty and "messages" in empty.columns


def test_cell_stats_without_any_ok_run(none_ok):
    stats = aggregate.cell_stats(inputs.load_rows(none_ok)[0])
    for name in ("fitness", "bias", "timing", "ranking"):
        assert stats[name].empty
        assert "method" in stats[name].columns


def test_report_when_an_extension_method_never_produced_an_estimate(tmp_path):
    cell_rows(methods_from_names(["wang-delay"]), 1, 5).to_parquet(tmp_path / "rows.parquet")
    page = parse(report.build_report(tmp_path, tmp_path / "r"))
    assert "beyond" in page.ids() and "no-estimates" in page.ids()
    assert "wang-delay" in page.text("table-failures")

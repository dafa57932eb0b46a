"""The renderings of the aggregated tables (Markdown, LaTeX, HTML), LaTeX escaping, and fresh
output folders.

The CSV files are the contract (``/work/shared/docs/contract.md``); the renderings are not: they
tell SNR cells apart (column ``snr_target``), sort rows by noise level numerically, show empty
numbers as blank cells and escape every LaTeX special character. Hand-made tidy rows keep the
tests fast.
"""

from __future__ import annotations

import html
import math
import re
import threading
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import pytest

from hbench.bench.schema import TIDY_COLUMNS
from hbench.report import build as report
from hbench.report import table_files
from hbench.tables import results
from tests.helpers import HAS_PDFLATEX, NO_PDFLATEX, compile_tex

#: Target SNRs in an order where a text sort (2, 20, 5) and the old level sort (20, 5, 2) differ
#: from the numeric one.
SNRS = (20.0, 2.0, 5.0)
SIGMA2S = (1e-2, 1e-4)
TRUE = {"a1": -1.9, "a2": 0.95, "b2": -0.7, "na": 2.0, "nb": 2.0, "tau": 3.0, "delay": 3.0}
#: Every character LaTeX treats specially in text.
SPECIALS = r"Table 1: sigma^2 = 1e-3 & R#1 {x} ~ $y$ 50% c_d \ e"
SPECIALS_TEX = (
    r"Table 1: sigma\textasciicircum{}2 = 1e-3 \& R\#1 \{x\} \textasciitilde{} \$y\$ 50\% "
    r"c\_d \textbackslash{} e"
)


def cell_rows(method: str, *, sigma2: float = math.nan, snr_target: float = math.nan) -> list:
    """Two ok runs of ``method`` on one cell; values depend on the level (cells differ)."""
    level = sigma2 if not math.isnan(sigma2) else 1.0 / snr_target
    rows = []
    for run in range(2):
        snr = snr_target if not math.isnan(snr_target) else 0.1 / math.sqrt(sigma2)
        values = {q: t + level * (run + 1) for q, t in TRUE.items() if q[0] in "ab"}
        values |= {q: t for q, t in TRUE.items() if q[0] not in "ab"}
        values |= {"fitness": 100.0 - 10 * level * (run + 1), "seconds": 0.01}
        for q, v in values.items():
            rows.append(
                {
                    "cell": f"{sigma2}-{snr_target}",
                    "method": method,
                    "nonlinearity": "backlash",
                    "plant": "paper",
                    "p": 5,
                    "delay": 3,
                    "sigma2": sigma2,
                    "snr_target": snr_target,
                    "run": run,
                    "seed": "0",
                    "quantity": q,
                    "value": v,
                    "true": TRUE.get(q, math.nan),
                    "snr": snr * (1 + 0.01 * run),
                    "status": "ok",
                    "error": "",
                }
            )
    return rows


def level_rows(snrs: tuple[float, ...] = SNRS, sigma2s: tuple[float, ...] = ()) -> pd.DataFrame:
    """wang-lsm and bai-fu on one cell at each target SNR and each sigma^2."""
    rows = []
    for method in ("wang-lsm", "bai-fu"):
        for s in snrs:
            rows += cell_rows(method, snr_target=s)
        for s2 in sigma2s:
            rows += cell_rows(method, sigma2=s2)
    return pd.DataFrame(rows, columns=list(TIDY_COLUMNS))


def read_md(path: Path) -> pd.DataFrame:
    """A Markdown table written by :func:`hbench.tables.results.to_markdown` (cells as text)."""
    lines = [ln for ln in path.read_text().splitlines() if ln.startswith("|")]
    cells = [[c.strip() for c in ln.strip().strip("|").split("|")] for ln in lines]
    return pd.DataFrame(cells[2:], columns=cells[0])


def read_tex(path: Path) -> pd.DataFrame:
    """The tabular of a table written by :func:`hbench.tables.results.to_latex` (cells as text)."""
    body = path.read_text().split(r"\toprule", 1)[1].split(r"\bottomrule", 1)[0]
    lines = [ln.strip().removesuffix(r"\\").strip() for ln in body.splitlines()]
    cells = [[c.strip() for c in ln.split(" & ")] for ln in lines if ln and ln != r"\midrule"]
    names = {tex: name for name, tex in results.TEX_HEADERS.items()}
    header = [names.get(c, c.replace(r"\_", "_")) for c in cells[0]]
    return pd.DataFrame(cells[1:], columns=header)


def read_html(path: Path, table_id: str) -> pd.DataFrame:
    """The table ``table_id`` of a report page (cells as text)."""
    page = path.read_text(encoding="utf-8")
    table = re.search(rf'<table id="{table_id}">(.*?)</table>', page, re.S)
    assert table, table_id
    rows = re.findall(r"<tr>(.*?)</tr>", table.group(1), re.S)
    cells = [[html.unescape(c) for c in re.findall(r"<t[hd]>(.*?)</t[hd]>", r)] for r in rows]
    return pd.DataFrame(cells[1:], columns=cells[0])


def check_levels_apart(shown: pd.DataFrame, by: str | None, where: str) -> None:
    """Rows of different noise levels differ in their key columns, levels sort numerically,
    empty numbers are blank."""
    keys = ["method", "nonlinearity", "p", "delay", "sigma2", "snr_target", *([by] if by else [])]
    assert set(keys) <= set(shown.columns), (where, list(shown.columns))
    assert not shown.duplicated(keys).any(), where
    assert not shown.isin(["nan", "NaN", "None", "<NA>"]).any().any(), where
    for method, g in shown.groupby("method"):
        first = g[by] == g[by].iloc[0] if by else pd.Series(True, index=g.index)
        snr = [float(v) for v in g.loc[first, "snr_target"] if v != ""]
        assert snr == sorted(SNRS), (where, method, snr)
        s2 = [float(v) for v in g.loc[first, "sigma2"] if v != ""]
        assert s2 == sorted(s2), (where, method, s2)
        # a sigma^2 cell has no target SNR and an SNR cell no sigma^2
        assert ((g["sigma2"] == "") != (g["snr_target"] == "")).all(), where


def test_tables_tell_snr_cells_apart_in_every_rendering(tmp_path: Path) -> None:
    rows = level_rows(sigma2s=SIGMA2S)
    results.write_tables(rows, tmp_path)
    out = tmp_path / "report"
    page = report.build_report(tmp_path, out, rows=rows)
    for name, by in (("fitness", None), ("bias", "parameter"), ("structure", "quantity")):
        folders = (tmp_path, out) if name != "structure" else (tmp_path,)
        for folder in folders:
            for path in (folder / f"{name}.md", folder / f"{name}.tex"):
                assert "nan" not in path.read_text(), path
                shown = read_md(path) if path.suffix == ".md" else read_tex(path)
                check_levels_apart(shown, by, str(path))
    for name, by in (("fitness", None), ("bias", "parameter")):
        check_levels_apart(read_html(page, f"table-{name}"), by, f"table-{name}")


def test_sigma2_only_tables_get_no_snr_column(tmp_path: Path) -> None:
    rows = level_rows(snrs=(), sigma2s=(1e-2, 1e-3, 2e-2))
    results.write_tables(rows, tmp_path)
    shown = read_md(tmp_path / "fitness.md")
    assert "snr_target" not in shown.columns
    assert list(shown["sigma2"]) == ["0.001", "0.01", "0.02"] * 2


def test_csv_md_and_tex_files_agree(tmp_path: Path) -> None:
    """Each table's CSV, Markdown and LaTeX files: the same columns in the same order, the same
    rows in the same order (the contract's columns, and snr_target where SNR cells exist)."""
    rows = level_rows(sigma2s=SIGMA2S)
    paths = results.write_tables(rows, tmp_path)
    fitness, bias = results.aggregate(rows, level=True)
    expected = {"fitness": fitness, "bias": bias, "structure": results.structure(rows, level=True)}
    for name, table in expected.items():
        shown = results.display_table(table)
        text = paths[f"{name}.csv"].read_text()
        assert text == shown.to_csv(index=False, float_format="%.10g"), name
        csv = pd.read_csv(paths[f"{name}.csv"])
        md, tex = read_md(tmp_path / f"{name}.md"), read_tex(tmp_path / f"{name}.tex")
        assert list(csv.columns) == list(md.columns) == list(tex.columns), name
        assert list(csv["method"]) == list(md["method"]) == list(tex["method"]), name
        key = "sigma2" if name == "fitness" else "n"
        as_text = [f"{v:.4g}" if v == v else "" for v in csv[key]]
        assert as_text == list(md[key]) == list(tex[key]), name
    cols = list(pd.read_csv(paths["fitness.csv"]).columns)
    assert [c for c in cols if c != results.SNR_TARGET] == results.FITNESS_COLUMNS
    assert cols[cols.index("sigma2") + 1] == results.SNR_TARGET
    cols = list(pd.read_csv(paths["bias.csv"]).columns)
    assert [c for c in cols if c != results.SNR_TARGET] == results.BIAS_COLUMNS
    assert pd.read_csv(paths["fitness.csv"])["sigma2"].isna().sum() == 2 * len(SNRS)


def test_sigma2_only_csv_has_exactly_the_contract_columns(tmp_path: Path) -> None:
    paths = results.write_tables(level_rows(snrs=(), sigma2s=(1e-2, 1e-3)), tmp_path)
    assert list(pd.read_csv(paths["fitness.csv"]).columns) == results.FITNESS_COLUMNS
    assert list(pd.read_csv(paths["bias.csv"]).columns) == results.BIAS_COLUMNS


def test_latex_is_journal_ready() -> None:
    """Right-aligned numbers, math headers, a label, exponents and infinite SNR in words."""
    table = pd.DataFrame(
        {
            "method": ["wang-lsm", "oracle"],
            "sigma2": [0.0, 1e-3],
            "snr_mean": [math.inf, 12.5],
            "parameter": ["a1", "b2"],
            "std": [1.102e-09, -0.25],
        }
    )
    tex = results.to_latex(table, caption="hbench bias", label="tab:x")
    assert r"\begin{tabular}{lrrlr}" in tex and r"\label{tab:x}" in tex
    assert r"Method & $\sigma^2$ & $\overline{\mathrm{SNR}}$ & Parameter & Std \\" in tex
    assert r"wang-lsm & 0 & noise-free & $a_{1}$ & $1.102 \times 10^{-9}$ \\" in tex
    assert r"oracle & 0.001 & 12.5 & $b_{2}$ & $-0.25$ \\" in tex
    assert "inf" not in tex and "e-09" not in tex


def test_display_table_orders_levels_and_keeps_parameter_order() -> None:
    _, bias = results.aggregate(level_rows(sigma2s=SIGMA2S), level=True)
    shown = results.display_table(bias)
    assert results.LEVEL not in shown.columns
    cols = list(shown.columns)
    assert cols[cols.index("sigma2") + 1] == results.SNR_TARGET
    lsm = shown[shown["method"] == "wang-lsm"]
    levels = list(zip(lsm["snr_target"], lsm["sigma2"], strict=True))[::3]
    expected = [(s, math.nan) for s in sorted(SNRS)] + [(math.nan, s) for s in sorted(SIGMA2S)]
    np.testing.assert_array_equal(np.array(levels), np.array(expected))
    assert list(lsm["parameter"]) == ["a1", "a2", "b2"] * (len(SNRS) + len(SIGMA2S))
    assert list(shown["method"]) == sorted(shown["method"])


def test_empty_numbers_are_blank_cells() -> None:
    table = pd.DataFrame({"name": ["a", None], "x": [np.nan, 1.5], "n": [1, 2]})
    md = results.to_markdown(table)
    tex = results.to_latex(table)
    for text in (md, tex):
        assert "nan" not in text and "None" not in text
    assert "| a |  | 1 |" in md and "|  | 1.5 | 2 |" in md
    assert r"a &  & 1 \\" in tex


# --------------------------------------------------------------------------- LaTeX escaping


def test_tex_escape_every_special_character() -> None:
    assert results.tex_escape(SPECIALS) == SPECIALS_TEX
    assert results.tex_escape("a\n\n  b") == "a b"  # one line (no paragraph in a cell)
    assert results.tex_escape(r"\textbackslash{}") == r"\textbackslash{}textbackslash\{\}"
    assert results.tex_escape("1.0 ± 0.1 at σ² < 2") == (
        r"1.0 \ensuremath{\pm} 0.1 at \ensuremath{\sigma}\ensuremath{^2} \textless{} 2"
    )
    # LaTeX in a cell is text like any other (callers pass plain text, such as ±)
    assert results.tex_escape(r"$\pm$") == r"\$\textbackslash{}pm\$"


def test_to_latex_escapes_caption_headers_and_cells() -> None:
    table = pd.DataFrame({"a_b": ["x^2 & #1"], "c%": [1.5], SPECIALS: ["{y}"]})
    tex = results.to_latex(table, caption=SPECIALS)
    assert r"\caption{" + SPECIALS_TEX + "}" in tex
    assert r"a\_b & c\% & " + SPECIALS_TEX + r" \\" in tex
    assert r"x\textasciicircum{}2 \& \#1 & 1.5 & \{y\} \\" in tex


def test_report_tables_escaped_once(tmp_path: Path) -> None:
    """table_files.write_table leaves the escaping to to_latex: no escape is escaped again."""
    table = pd.DataFrame({"method": ["a_b"], "messages": ["50% & {x} ^ ~"]})
    table_files.write_table(tmp_path, "t", table)
    tex = (tmp_path / "t.tex").read_text()
    assert r"a\_b & 50\% \& \{x\} \textasciicircum{} \textasciitilde{} \\" in tex
    table_files.write_table(tmp_path, "e", table.iloc[:0], empty="none_ok: 100% & ^")
    assert r"{none\_ok: 100\% \& \textasciicircum{}} \\" in (tmp_path / "e.tex").read_text()


@pytest.mark.skipif(not HAS_PDFLATEX, reason=NO_PDFLATEX)
def test_tex_files_compile(tmp_path: Path) -> None:
    rows = level_rows(sigma2s=SIGMA2S)
    results.write_tables(rows, tmp_path)
    report.build_report(tmp_path, tmp_path / "report", rows=rows)
    table = pd.DataFrame({SPECIALS: [SPECIALS, "1.0 ± 0.1 σ²"], "x": [1.0, math.nan]})
    (tmp_path / "specials.tex").write_text(results.to_latex(table, caption=SPECIALS))
    table_files.write_table(tmp_path, "empty", table.iloc[:0], note=SPECIALS, empty=SPECIALS)
    files = sorted(tmp_path.rglob("*.tex"))
    assert len(files) >= 9 and tmp_path / "report" / "summary.tex" in files
    done = compile_tex(tmp_path, files)
    assert done.returncode == 0, done.stdout[-3000:]


# --------------------------------------------------------------------------- output folders


class _Frozen(datetime):
    """``datetime.now`` at a fixed second: runs started in the same second."""

    @classmethod
    def now(cls, tz: Any = None) -> _Frozen:
        return cls(2024, 5, 6, 7, 8, 9, tzinfo=UTC)


STAMP = "20240506T070809Z"


def test_new_output_dir_skips_existing_folders(tmp_path: Path, monkeypatch) -> None:
    monkeypatch.setattr(results, "datetime", _Frozen)
    (tmp_path / f"run-{STAMP}").mkdir()
    (tmp_path / f"run-{STAMP}-2").write_text("a file takes the name too")
    assert results.new_output_dir(tmp_path, "run") == tmp_path / f"run-{STAMP}-3"
    assert results.new_output_dir(tmp_path / "new" / "base", "run").is_dir()


def test_new_output_dir_when_another_run_takes_the_name_first(tmp_path: Path, monkeypatch):
    """Another run makes the folder between a check for it and the ``mkdir``: no crash, and
    each run gets a folder of its own."""
    monkeypatch.setattr(results, "datetime", _Frozen)
    real_exists = Path.exists
    taken: list[Path] = []

    def exists_then_taken(self: Path, *args: Any, **kwargs: Any) -> bool:
        found = real_exists(self, *args, **kwargs)
        if not found and self.parent == tmp_path:
            self.mkdir()  # the other run, just after the check
            taken.append(self)
        return found

    monkeypatch.setattr(Path, "exists", exists_then_taken)
    path = results.new_output_dir(tmp_path, "run")
    assert path.is_dir() and path not in taken
    assert path.name.startswith(f"run-{STAMP}")


def test_new_output_dir_concurrent_runs(tmp_path: Path, monkeypatch) -> None:
    monkeypatch.setattr(results, "datetime", _Frozen)
    n = 16
    barrier = threading.Barrier(n)
    made: list[Path] = []
    errors: list[BaseException] = []

    def run() -> None:
        barrier.wait()
        try:
            made.append(results.new_output_dir(tmp_path, "run"))
        except BaseException as exc:  # reported by the assertion below
            errors.append(exc)

    threads = [threading.Thread(target=run) for _ in range(n)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert not errors
    assert len(set(made)) == n and all(p.is_dir() for p in made)


def test_tables_computed_once_write_and_show_the_same(tmp_path: Path) -> None:
    """``aggregated_tables`` passed to ``write_tables`` and ``build_report`` (as the reproduction
    does, computing them once) give the same files as each computing them itself, and neither
    changes the tables it was given (the report shows the oracle's label, not its name)."""
    rows = level_rows(sigma2s=SIGMA2S)
    rows["method"] = rows["method"].replace("bai-fu", "oracle")
    tables = results.aggregated_tables(rows)
    kept = {name: table.copy() for name, table in tables.items()}
    own, given = tmp_path / "own", tmp_path / "given"
    results.write_tables(rows, own)
    results.write_tables(rows, given, tables=tables)
    report.build_report(own, own / "report", rows=rows)
    report.build_report(given, given / "report", rows=rows, tables=tables)
    stems = ("fitness", "bias", "structure")
    names = [f"{n}.{ext}" for n in stems for ext in ("csv", "md", "tex")]
    names += [f"report/{n}.{ext}" for n in stems for ext in ("md", "tex")]
    for name in names:
        assert (own / name).read_bytes() == (given / name).read_bytes(), name
    for name, table in tables.items():
        pd.testing.assert_frame_equal(table, kept[name])

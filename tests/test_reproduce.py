"""``hbench reproduce``: published tables, z-scores, summary, the output folder end to end."""

from __future__ import annotations

import json
import math
import tomllib
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from hbench import cli
from hbench.bench.runner import TIDY_COLUMNS
from hbench.paper import compare as pc
from hbench.paper import investigate as pi
from hbench.paper import levels as pl
from hbench.paper import reproduce as rp
from hbench.tables import published as pub
from tests.helpers import BIAS_COLUMNS, FITNESS_COLUMNS, HAS_PDFLATEX, NO_PDFLATEX, compile_tex

ROOT = Path(__file__).resolve().parents[1]
CONTRACT_COLUMNS = [
    "table",
    "row",
    "column",
    "method",
    "paper",
    "paper_std",
    "ours",
    "ours_std",
    "z",
]
# Tables 1 (2 methods x 5 na x 5 tau), 2 (5 phases), 4 (6 levels x (SNR + 2 methods x 3
# parameters)), 5 (6 levels x 4 columns)
N_CELLS = {1: 50, 2: 5, 4: 42, 5: 24}


# --------------------------------------------------------------------------- published numbers


def test_package_data_is_declared():
    conf = tomllib.loads((ROOT / "pyproject.toml").read_text())
    assert "data/*" in conf["tool"]["setuptools"]["package-data"]["hbench"]
    assert (ROOT / "hbench" / "data" / "paper_tables.json").is_file()


def test_paper_cells_typed_with_the_notes_corrections():
    cells = pub.paper_cells()
    counts = {t: sum(c.table == t for c in cells) for t in N_CELLS}
    assert counts == N_CELLS
    t4 = {(c.row, c.column, c.method): c for c in cells if c.table == 4}
    # b2's sign corrected (printed +0.7244), rows as plain sigma^2 (printed "x 10^-2")
    assert t4[(0.0, "b2", "wang-lsm")].value == -0.7244
    assert t4[(1e-3, "b2", "wang-iv")].value == -0.7171
    assert {c.row for c in cells if c.table in (4, 5)} == set(pl.LEVELS)
    assert t4[(1e-4, "a1", "wang-lsm")].std == 0.0018
    assert t4[(1e-2, "snr", "scenario")].value == 1.8889
    assert math.isinf(t4[(0.0, "snr", "scenario")].value)
    # Tables 1 and 2 in units of 1e-7, printed precision kept
    t1 = {(c.row, c.column, c.method): c for c in cells if c.table == 1}
    assert t1[(2, "3", "wang-lsm")].value == pytest.approx(1.073e-7)
    assert t1[(3, "4", "wang-lsm")].unit == pytest.approx(1e-2 * 1e-7)  # "152.37"
    t5 = {(c.row, c.column, c.method): c for c in cells if c.table == 5}
    assert t5[(1e-3, "F", "wang-lsm")].value == 85.052
    assert t5[(1e-3, "F", "wang-lsm")].std == 5.249
    assert math.isnan(t5[(1e-3, "F0", "oracle")].std)  # not published


@pytest.mark.parametrize(
    ("text", "value", "unit"),
    [
        ("0.9623", 0.9623, 1e-4),
        ("-1.9620", -1.962, 1e-4),
        ("100", 100.0, 1.0),
        ("152.37", 152.37, 1e-2),
        ("1e-3", 1e-3, 1e-3),
        ("inf", math.inf, 0.0),
    ],
)
def test_parse_printed(text, value, unit):
    v, u = pub.parse_printed(text)
    assert v == value
    assert u == pytest.approx(unit)


# --------------------------------------------------------------------------- z and summary


def test_z_score_known_values():
    # SE = sqrt(0.2^2/100 + 0.2^2/100) = 0.028284; (1.1 - 1.0) / SE = 3.5355
    assert pub.z_score(1.1, 0.2, 100, 1.0, 0.2, 100) == pytest.approx(3.5355339, rel=1e-6)
    # no published std: the paper's spread is taken to be ours
    assert pub.z_score(1.1, 0.2, 100, 1.0, math.nan, 100) == pytest.approx(3.5355339, rel=1e-6)
    # different spreads and counts: SE = sqrt(0.3^2/25 + 0.1^2/100) = 0.0608276
    assert pub.z_score(0.9, 0.3, 25, 1.0, 0.1, 100) == pytest.approx(-0.1 / 0.0608276, rel=1e-6)
    # single realisations (Tables 1, 2): SE = sqrt(2) s
    assert pub.z_score(3.0, 1.0, 1, 1.0, math.nan, 1) == pytest.approx(2 / math.sqrt(2))
    # rounding of the printed number: SE = u / sqrt(12) when nothing else varies
    assert pub.z_score(1.0001, 0.0, 10, 1.0, 0.0, 1, unit=1e-4) == pytest.approx(
        1e-4 / (1e-4 / math.sqrt(12))
    )
    assert math.isnan(pub.z_score(math.inf, 0.0, 10, math.inf, 0.0, 1))
    assert math.isnan(pub.z_score(1.0, 0.0, 10, 1.0, 0.0, 1, unit=0.0))  # SE = 0: undefined
    assert math.isnan(pub.z_score(1.0, math.nan, 1, 2.0, math.nan, 1, unit=0.0))
    # one run of ours (no spread): the published spread stands for both
    assert pub.z_score(1.1, math.nan, 1, 1.0, 0.1, 100) == pytest.approx(0.1 / math.sqrt(0.0101))


def _frame(zs):
    return pd.DataFrame(
        [
            {
                "table": 4,
                "row": 1e-3,
                "column": f"q{i}",
                "method": "m",
                "paper": 1.0,
                "paper_std": 0.1,
                "ours": 1.0 + z / 10,
                "ours_std": 0.1,
                "z": z,
            }
            for i, z in enumerate(zs)
        ],
        columns=CONTRACT_COLUMNS,
    )


def test_summary_share_and_beyond_cells():
    s = pub.summarise(_frame([0.5, -1.9, 2.0, 2.1, -3.0, math.nan]))
    assert (s.scored, s.within, s.unscored) == (5, 3, 1)
    assert s.share == pytest.approx(0.6)
    assert [c["z"] for c in s.beyond] == [-3.0, 2.1]  # largest |z| first, exactly the cells
    assert s.line().startswith("3 of 5 scored cells (60 %) within |z| <= 2; 2 beyond")
    text = s.text()
    assert "q4 @ sigma2=0.001" in text and "z = -3.0" in text and "z = +2.1" in text
    assert "q2" not in text  # |z| = 2 is within


def test_summary_with_nothing_beyond():
    s = pub.summarise(_frame([0.1, -0.2]))
    assert s.beyond == [] and s.within == 2
    assert "beyond |z|" not in s.text()


def _tidy(level, method, quantity, values, snr):
    return pd.DataFrame(
        {
            "cell": "c",
            "method": method,
            "sigma2": level,
            "run": np.arange(len(values)),
            "quantity": quantity,
            "value": values,
            "snr": snr,
            "status": "ok",
        }
    )


def test_compare_tables45_on_hand_made_rows():
    a1 = np.array([-1.96, -1.97, -1.95, -1.962])
    fit = np.array([80.0, 90.0, 85.0, 85.0])
    snr = np.array([5.0, 5.2, 4.8, 5.0])
    rows = pd.concat(
        [
            _tidy(1e-3, "wang-lsm", "a1", a1, snr),
            _tidy(1e-3, "wang-lsm", "fitness", fit, snr),
            _tidy(1e-3, "bai-fu", "fitness", fit - 20.0, snr),
            _tidy(1e-3, "wang-lsm-inv", "fitness", fit - 5.0, snr),
        ],
        ignore_index=True,
    )
    out = pc.compare_tables45(rows).set_index(["table", "row", "column", "method"])
    cell = out.loc[(4, 1e-3, "a1", "wang-lsm")]
    assert cell["ours"] == pytest.approx(a1.mean())
    assert cell["ours_std"] == pytest.approx(a1.std(ddof=1))
    se = math.sqrt(a1.std(ddof=1) ** 2 / 4 + 0.0054**2 / 100 + 1e-8 / 12)
    assert cell["z"] == pytest.approx((a1.mean() + 1.9651) / se)
    s = out.loc[(4, 1e-3, "snr", "scenario")]
    assert s["ours"] == pytest.approx(5.0) and s["paper"] == 5.1003
    assert out.loc[(5, 1e-3, "F", "wang-lsm-inv"), "ours"] == pytest.approx(80.0)
    # cells without rows are empty, not invented
    assert math.isnan(out.loc[(4, 1e-4, "a1", "wang-lsm"), "ours"])
    # F_INV mapped to bai-fu and the power SNR by configuration
    alt = pc.compare_tables45(rows, pl.Config(f_inv="bai-fu", snr="power"))
    alt = alt.set_index(["table", "row", "column", "method"])
    assert alt.loc[(5, 1e-3, "F", "bai-fu"), "ours"] == pytest.approx(65.0)
    assert alt.loc[(4, 1e-3, "snr", "scenario"), "ours"] == pytest.approx(np.mean(snr**2))


def test_lsm_rows_from_the_paper_steps():
    """Config.lsm puts another method in Table 4's LSM rows and F_LSM; the investigation
    matches those cells with the defaults' (slot), and steps_comparison scores ``wang``."""
    a1 = np.array([-1.96, -1.97, -1.95, -1.962])
    snr = np.full(4, 5.0)
    rows = pd.concat(
        [
            _tidy(5e-3, "wang-lsm", "a1", a1, snr),
            _tidy(5e-3, "wang", "a1", a1 - 0.01, snr),
            _tidy(5e-3, "wang-lsm", "fitness", np.full(4, 50.0), snr),
            _tidy(5e-3, "wang", "fitness", np.full(4, 60.0), snr),
            _tidy(5e-3, "wang-lsm-inv", "fitness", np.full(4, 40.0), snr),
        ],
        ignore_index=True,
    )
    before = pc.compare_tables45(rows)
    after = pc.compare_tables45(rows, pl.Config(lsm="wang"))
    cells = after.set_index(["table", "row", "column", "method"])
    assert cells.loc[(4, 5e-3, "a1", "wang"), "ours"] == pytest.approx(a1.mean() - 0.01)
    assert cells.loc[(5, 5e-3, "F", "wang"), "ours"] == pytest.approx(60.0)
    assert cells.loc[(5, 5e-3, "F", "wang-lsm-inv"), "ours"] == pytest.approx(40.0)
    assert not (after["method"] == "wang-lsm").any()
    row = pi.investigation_row(pl.Config(label="steps", lsm="wang"), before, after)
    assert row["cells"] == int(np.isfinite(before["z"]).sum())  # every cell matched
    steps, text = pc.steps_comparison(rows, before)
    assert set(steps["method"]) == {"wang"} and len(steps) == len(
        before[before["method"] == "wang-lsm"]
    )
    assert "a1 @ sigma2=0.005: paper -1.972; wang -1.97" in text
    assert "F @ sigma2=0.005: paper 62.17; wang 60 " in text


def test_table2_read_swapped():
    """Config.table2 = "swapped" compares the paper's l = 1 with our l = 2 and back."""
    var = np.array([[9.0, 5.0, 1.0, 1.0, 1.0], [8.0, 4.0, 1.1, 0.9, 1.0]]) * 1e-7
    tab = {
        "na_values": np.array([1]),
        "V": {m: np.ones((2, 1, 5)) * 1e-6 for m in ("wang-lsm", "wang-iv")},
        "var_dw": var,
    }

    def t2(config):
        f = pc.compare_tables12(tab, config)
        return f[f["table"] == 2].set_index("row")["ours"]

    printed, swapped = t2(pl.Config()), t2(pl.Config(table2="swapped"))
    assert printed[1] == var[0, 0] and printed[2] == var[0, 1]
    assert swapped[1] == var[0, 1] and swapped[2] == var[0, 0]
    assert (swapped[[3, 4, 5]] == printed[[3, 4, 5]]).all()


def _header_and_body(md: str) -> tuple[str, str]:
    """The bold header line of a display table's Markdown, and the table below it."""
    header, _, body = md.partition("\n\n")
    return header, body


def test_display_table_headers_agree_with_their_cells(tmp_path):
    """Table 1's header said "(ours: mean ± std over runs ...)" over cells with no std: the
    cells are run 0 (one realisation, as the paper's), their spread only behind z."""
    nan = math.nan
    cell = dict.fromkeys(CONTRACT_COLUMNS, nan)
    frame = pd.DataFrame(
        [
            {**cell, "table": 1, "row": 2, "column": "3", "method": "wang-lsm"}
            | {"paper": 1.2e-7, "ours": 1.3e-7, "ours_std": 0.2e-7, "z": 0.5},
            {**cell, "table": 1, "row": 2, "column": "4", "method": "wang-lsm"}
            | {"paper": 1.1e-7, "ours": 1.0e-7, "ours_std": 0.1e-7, "z": -1.0},
            {**cell, "table": 2, "row": 1, "column": "var_dw", "method": "wang-lsm"}
            | {"paper": 2.0e-7, "ours": 2.1e-7, "ours_std": 0.3e-7, "z": 0.3},
            {**cell, "table": 4, "row": 1e-3, "column": "a1", "method": "wang-lsm"}
            | {"paper": -1.9651, "paper_std": 0.0054, "ours": -1.964, "ours_std": 0.005}
            | {"z": 0.9},
        ],
        columns=CONTRACT_COLUMNS,
    )
    pub.write_display_tables(frame, tmp_path, realisations=20)
    for name in ("table1", "table2", "table4"):
        header, body = _header_and_body((tmp_path / f"{name}.md").read_text())
        assert ("mean ± std" in header) == ("±" in body), (name, header)
    header, body = _header_and_body((tmp_path / "table1.md").read_text())
    assert "run 0, one realisation" in header and "over 20 realisations" in header
    assert "1.300 (z +0.5)" in body  # the cells themselves are unchanged
    header, body = _header_and_body((tmp_path / "table2.md").read_text())
    assert "ours std" in header and "ours std" in body
    header, body = _header_and_body((tmp_path / "table4.md").read_text())
    assert "mean ± std over runs" in header and "-1.9640 ± 0.0050" in body


def test_investigation_row_counts_moved_cells():
    before = _frame([10.0, 0.5, -4.0, math.nan])
    after = _frame([1.0, 0.5, -6.0, math.nan])
    row = pi.investigation_row(pl.Config(label="alt"), before, after)
    assert row["alternative"] == "alt"
    assert (row["cells"], row["cells_closer"], row["cells_further"]) == (3, 1, 1)
    assert row["mean_abs_z_before"] == pytest.approx((10 + 0.5 + 4) / 3)
    assert row["mean_abs_z_after"] == pytest.approx((1 + 0.5 + 6) / 3)
    assert row["moved_most"].startswith("T4 m q0@0.001: +10.0->+1.0")


def test_investigation_row_matches_cells_by_slot():
    """Table 1 holds two methods per (row, column); F_INV's method changes with the mapping."""

    def frame(z_iv, f_inv_method, z_inv):
        recs = [
            {"table": 1, "row": 2, "column": "0", "method": "wang-lsm", "z": 1.0},
            {"table": 1, "row": 2, "column": "0", "method": "wang-iv", "z": z_iv},
            {"table": 5, "row": 1e-3, "column": "F", "method": "wang-lsm", "z": 0.5},
            {"table": 5, "row": 1e-3, "column": "F", "method": f_inv_method, "z": z_inv},
        ]
        return pd.DataFrame(recs).assign(paper=1.0, paper_std=0.1, ours=1.0, ours_std=0.1)

    row = pi.investigation_row(
        pl.Config(label="f"), frame(-8.0, "wang-lsm-inv", -3.0), frame(-8.0, "bai-fu", -9.0)
    )
    assert (row["cells"], row["cells_closer"], row["cells_further"]) == (4, 0, 1)
    assert row["moved_most"] == "T5 bai-fu F@0.001: -3.0->-9.0"
    assert row["T5_before"] == pytest.approx(1.75) and row["T5_after"] == pytest.approx(4.75)
    assert row["T1_after"] == pytest.approx(4.5)


def test_explained_cells_name_the_alternatives_within():
    before = _frame([10.0, 0.5, -4.0, math.nan])
    comps = {"a": _frame([1.0, 0.5, -6.0, math.nan]), "b": _frame([-1.5, 3.0, 1.9, 0.0])}
    out = pi.explained_cells(before, comps)
    assert list(out["z"]) == [10.0, -4.0]
    assert list(out["within_by"]) == ["a (+1.0); b (-1.5)", "b (+1.9)"]
    assert pi.explained_cells(before, {"c": before})["within_by"].tolist() == ["", ""]


def test_spread_ratio_is_a_geometric_mean():
    f = pd.DataFrame({"ours_std": [2.0, 0.5, math.nan, 3.0], "paper_std": [1.0, 1.0, 1.0, 0.0]})
    assert pi.spread_ratio(f) == pytest.approx(1.0)
    f = pd.DataFrame({"ours_std": [2.0, 8.0], "paper_std": [1.0, 1.0]})
    assert pi.spread_ratio(f) == pytest.approx(4.0)
    assert math.isnan(pi.spread_ratio(f.iloc[:0]))


def test_best_alternative_per_group():
    t = pd.DataFrame(
        {
            "alternative": ["a", "b", "c", "d"],
            "group": ["g", "g", "h", "k"],
            "mean_abs_z_before": [5.0, 5.0, 5.0, 5.0],
            "mean_abs_z_after": [4.0, 2.0, 6.0, 4.9],
            "T1_before": 1.0,
            "T1_after": [1.0, 3.0, 1.0, 1.0],
            "T2_before": 2.0,
            "T2_after": 2.0,
            "std_ratio_T4-params_after": [1.0, 1.1, 2.0, 1.0],
            "std_ratio_T5_after": [1.0, 1.2, 3.0, 1.0],
        }
    )
    lines = pi._best_per_group(t)
    assert lines[0] == (
        "- g: b 5.00 -> 2.00 (closer; T1 1.00 -> 3.00, T2 2.00 -> 2.00; spreads 1.10, 1.20)"
    )
    assert lines[1].startswith("- h: c 5.00 -> 6.00 (further;")
    assert lines[2].startswith("- k: d 5.00 -> 4.90 (no change;")


def test_alternatives_are_distinct_single_changes():
    alts = pi.alternatives()
    labels = [a.label for a in alts]
    assert len(labels) == len(set(labels))
    assert pi.POST_PROCESSED <= set(labels)
    for a in alts:  # each builds a valid scenario
        pl.scenario_spec(a, 1e-3)


# --------------------------------------------------------------------------- end to end


@pytest.fixture(scope="module")
def reproduced(tmp_path_factory):
    base = tmp_path_factory.mktemp("reproduce")
    import contextlib
    import io

    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        status = cli.main(["reproduce", "--runs", "5", "--out", str(base)])
    folders = list(base.glob("reproduce-*"))
    return status, folders, out.getvalue(), err.getvalue()


def test_reproduce_writes_a_new_folder(reproduced):
    status, folders, out, err = reproduced
    assert status == 0
    assert len(folders) == 1
    assert f"results: {folders[0]}" in out
    assert "sigma^2 = 0.001: 5 runs" in err and "reproduce [" in err  # progress on stderr
    assert "report: " in out


def test_reproduce_csv_is_the_contract(reproduced):
    d = reproduced[1][0]
    frame = pd.read_csv(d / "reproduce.csv")
    assert list(frame.columns) == CONTRACT_COLUMNS
    counts = frame["table"].value_counts().to_dict()
    assert counts == N_CELLS
    t45 = frame[frame["table"].isin([4, 5])]
    assert set(t45["row"].astype(float)) == set(pl.LEVELS)
    assert set(frame.loc[frame["table"] == 4, "column"]) == {"a1", "a2", "b2", "snr"}
    assert set(frame.loc[frame["table"] == 5, "column"]) == {"F", "F0"}
    assert set(frame.loc[frame["table"] == 1, "column"].astype(str)) == {"0", "1", "2", "3", "4"}
    assert set(frame.loc[frame["table"] == 1, "row"]) == {1, 2, 3, 4, 5}
    assert set(frame.loc[frame["table"] == 2, "row"]) == {1, 2, 3, 4, 5}
    assert set(frame.loc[frame["table"] == 5, "method"]) == {
        "wang-lsm",
        "oracle",
        "wang-lsm-inv",
        "oracle-inv",
    }
    # z is finite wherever it is defined: everywhere but the SNR at sigma^2 = 0 (inf vs inf)
    undefined = frame[~np.isfinite(frame["z"])]
    assert len(undefined) == 1
    assert undefined.iloc[0]["column"] == "snr" and undefined.iloc[0]["row"] == 0
    assert np.isfinite(frame["ours"].drop(undefined.index)).all()
    # the noise-free level is exact: the published true values within rounding
    exact = frame[(frame["table"] == 4) & (frame["row"] == 0) & (frame["column"] != "snr")]
    assert (exact["z"].abs() < 2).all()


def test_summary_line_printed_and_saved(reproduced):
    d = reproduced[1][0]
    frame = pd.read_csv(d / "reproduce.csv")
    s = pub.summarise(frame)
    saved = (d / "summary.txt").read_text()
    assert saved.splitlines()[0] == s.line()
    assert s.line() in reproduced[2]
    z = frame["z"].to_numpy(float)
    beyond = int(np.sum(np.abs(z[np.isfinite(z)]) > 2))
    assert len(s.beyond) == beyond
    assert saved.count(", z = ") == beyond  # every cell beyond is listed
    assert "wang-lsm na=" in saved
    assert "steps (ii) and (iv)" in saved and "steps (ii) and (iv)" in reproduced[2]
    steps = pd.read_csv(d / "steps.csv")
    assert list(steps.columns) == CONTRACT_COLUMNS and set(steps["method"]) == {"wang"}
    assert len(steps) == int((frame["method"].eq("wang-lsm") & frame["table"].isin([4, 5])).sum())


def test_tables_figures_and_provenance(reproduced):
    d = reproduced[1][0]
    for name in ("table1", "table2", "table4", "snr", "table5"):
        md = (d / f"{name}.md").read_text()
        assert md.count("\n|") >= 5, name
        tex = (d / f"{name}.tex").read_text()
        assert r"\toprule" in tex and r"\midrule" in tex and r"\bottomrule" in tex
    t4 = (d / "table4.md").read_text()
    assert "±" in t4 and "-1.9651 ± 0.0054" in t4  # the paper's cell beside ours
    for name in ("table1", "table2", "table4", "snr", "table5"):  # a header says what it shows
        header, body = _header_and_body((d / f"{name}.md").read_text())
        assert ("mean ± std" in header) == ("±" in body), (name, header)
    for stem in ("figure4", "figure5"):
        png = (d / f"{stem}.png").read_bytes()
        assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 5000
        pdf = (d / f"{stem}.pdf").read_bytes()
        assert pdf[:5] == b"%PDF-" and len(pdf) > 2000
    rows = pd.read_parquet(d / "rows.parquet")
    assert list(rows.columns) == list(TIDY_COLUMNS)
    assert set(rows["method"]) == set(pl.ALL_METHODS)
    assert set(rows["sigma2"]) == set(pl.LEVELS)
    assert list(pd.read_csv(d / "fitness.csv").columns) == FITNESS_COLUMNS
    assert list(pd.read_csv(d / "bias.csv").columns) == BIAS_COLUMNS
    for name in ("fitness", "bias"):
        assert r"\toprule" in (d / f"{name}.tex").read_text()
        assert (d / f"{name}.md").read_text().startswith("| method")
    prov = json.loads((d / "provenance.json").read_text())
    assert prov["config"]["runs"] == 5
    assert prov["config"]["table5_columns"]["F_INV"] == "wang-lsm-inv"
    assert prov["config"]["reproduction"]["fitness_runs"] == "all"
    assert prov["config"]["reproduction"]["f_lsm"] is None  # F_LSM from the LSM rows' method
    assert prov["seeds"]["base"] == pl.DEFAULT_SEED
    assert {"git_revision", "versions", "created"} <= set(prov)
    with np.load(d / "examples.npz") as ex:
        assert ex["c0__x"].shape == ex["c0__U"].shape == ex["c0__est__wang-lsm"].shape
    tab = json.loads((d / "tables12.json").read_text())
    # the realisation selects the paper's structure (na = 2, tau = 3, nb = 2)
    assert {k: tab["selection"]["wang-lsm"][k] for k in ("na", "tau", "nb")} == {
        "na": 2,
        "tau": 3,
        "nb": 2,
    }
    assert (d / "report" / "report.html").is_file()


def test_reproduce_bad_input(run_cli, tmp_path):
    status, _, err = run_cli(["reproduce", "--runs", "0", "--out", str(tmp_path)])
    assert status == 2
    assert err.count("\n") == 1 and "--runs" in err and "Traceback" not in err
    assert not list(tmp_path.iterdir())  # nothing written
    status, _, err = run_cli(
        ["reproduce", "--runs", "2", "--out", str(tmp_path), "--set", "noise.sigma2=1"]
    )
    assert status == 2 and err.count("\n") == 1
    status, _, err = run_cli(
        ["reproduce", "--runs", "2", "--out", str(tmp_path), "--set", "reference.band=[0,2]"]
    )
    assert status == 2 and err.count("\n") == 1


@pytest.mark.slow
def test_reproduce_defaults_match_most_published_cells(tmp_path):
    """100 runs per level (the paper's): Tables 4 and 5 parameter cells mostly within 3 SE."""
    d = rp.reproduce(out=tmp_path, report=False)
    frame = pd.read_csv(d / "reproduce.csv")
    params = frame[(frame["table"] == 4) & (frame["column"] != "snr") & (frame["row"] > 0)]
    assert (params["z"].abs() <= 3).mean() >= 0.75
    # the noise-free level is exact and the consistent IVM stays within 3 SE of the truth
    iv = params[params["method"] == "wang-iv"]
    assert (
        iv["ours"] - iv["column"].map({"a1": -1.962, "a2": 0.9623, "b2": -0.7244})
    ).abs().max() < 0.01


@pytest.mark.slow
def test_investigate_writes_one_row_per_alternative(tmp_path):
    d = rp.reproduce(runs=3, out=tmp_path, investigate_=True, report=False)
    inv = pd.read_csv(d / "investigation.csv")
    assert list(inv["alternative"]) == [a.label for a in pi.alternatives()]
    assert {"mean_abs_z_before", "mean_abs_z_after", "T5_after", "cells_closer"} <= set(inv)
    assert (d / "investigation.md").read_text().startswith("# Investigation")


@pytest.mark.skipif(not HAS_PDFLATEX, reason=NO_PDFLATEX)
def test_every_latex_table_of_the_reproduction_compiles(reproduced):
    """Tables 1, 2, 4, 5, the aggregated tables and the report's (the headline summary too)."""
    _, folders, _, _ = reproduced
    files = sorted(folders[0].rglob("*.tex"))
    assert {"table5.tex", "summary.tex", "summary_bias.tex"} <= {f.name for f in files}
    done = compile_tex(folders[0], files)
    assert done.returncode == 0, done.stdout[-3000:]


def test_the_alternatives_are_data_each_one_change_from_the_defaults():
    """``hbench/data/paper_alternatives.json``: unique labels, every alternative differs from the
    defaults, and each builds a scenario (its keys are the scenario's)."""
    from hbench.sim import scenarios

    data = json.loads((ROOT / "hbench" / "data" / "paper_alternatives.json").read_text())
    entries = data["alternatives"]
    alternatives = pi.alternatives()
    assert [a.label for a in alternatives] == [e["label"] for e in entries]
    assert len({a.label for a in alternatives}) == len(alternatives)
    assert all(a.describe() != pl.Config().describe() | {"label": a.label} for a in alternatives)
    for a in alternatives:
        scenarios.build(pl.scenario_spec(a, pl.TYPICAL_LEVEL))


def test_levels_in_parts_give_the_rows_of_one_process(monkeypatch):
    """With workers the levels are cut into parts of runs (``PART_RUNS``): the rows, the example
    and the task order are those of one process computing each level whole (but for the timed
    quantity ``seconds``)."""
    from hbench.bench import runner

    monkeypatch.setattr(pl, "PART_RUNS", 2)
    tasks = pl.level_tasks(pl.Config(), 5, 7, (2, 3, 2), ("wang-lsm", "oracle"))[:2]
    assert [len(pl._level_parts(t)) for t in tasks] == [1, 1]  # chunks of 200 runs: whole
    pieces = runner._pieces  # the runner's chunks of 2 runs (its rows are in chunk order)
    monkeypatch.setattr(runner, "_pieces", lambda runs, chunk, jobs: pieces(runs, 2, jobs))
    assert [len(pl._level_parts(t)) for t in tasks] == [3, 3]
    one = pl.run_levels(tasks, 1)
    parts = pl.run_levels(tasks, 2)
    for (rows1, ex1, _), (rows2, ex2, _) in zip(one, parts, strict=True):
        keep = rows1["quantity"] != "seconds"
        pd.testing.assert_frame_equal(
            rows1[keep].reset_index(drop=True), rows2[keep].reset_index(drop=True)
        )
        assert ex1.keys() == ex2.keys()
        for key in ("x", "U"):
            np.testing.assert_array_equal(ex1.get(key), ex2.get(key))

"""The "beyond the paper" outputs: ``structure.csv`` and the report's section ``beyond``.

Hand-made tidy rows give known hit rates, biases, spreads and fitness values, so the tables are
checked exactly (floating-point means of a few numbers: ``rel=1e-12``); one tiny real sweep runs
the delay preset end to end through ``hbench sweep`` and ``hbench report``.
"""

from __future__ import annotations

import contextlib
import io
import math
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

import pandas as pd
import pytest

from hbench import cli
from hbench.bench.schema import TIDY_COLUMNS
from hbench.report import beyond as report_beyond
from hbench.report import build as report
from hbench.sweep import config
from hbench.tables import results
from tests.test_report import parse

pytestmark = pytest.mark.filterwarnings(f"ignore:{config.SCHEMA_NOTE}:UserWarning")

#: structure.csv's columns (spelled out, not imported).
STRUCTURE_COLUMNS = [
    "method",
    "nonlinearity",
    "p",
    "delay",
    "sigma2",
    "snr_mean",
    "quantity",
    "true",
    "hit_rate",
    "n",
]
A1 = -1.9  # a made-up true a1


def tidy(
    method: str,
    values: Mapping[str, Sequence[float]],
    true: Mapping[str, float] | None = None,
    *,
    sigma2: float = math.nan,
    snr_target: float = math.nan,
    delay: int = 8,
    p: int = 5,
    snr: Sequence[float] | None = None,
    status: Sequence[str] | None = None,
) -> list[dict[str, Any]]:
    """Tidy rows of one method on one cell: ``values[quantity][run]``, ``true[quantity]``."""
    runs = len(next(iter(values.values())))
    snr = snr if snr is not None else [10.0] * runs
    status = status if status is not None else ["ok"] * runs
    cell = f"d{delay}-s{sigma2}-t{snr_target}"
    rows = []
    for q, vals in values.items():
        for run, v in enumerate(vals):
            rows.append(
                {
                    "cell": cell,
                    "method": method,
                    "nonlinearity": "backlash",
                    "plant": "paper",
                    "p": p,
                    "delay": delay,
                    "sigma2": sigma2,
                    "snr_target": snr_target,
                    "run": run,
                    "seed": "0",
                    "quantity": q,
                    "value": float(v),
                    "true": (true or {}).get(q, math.nan),
                    "snr": snr[run],
                    "status": status[run],
                    "error": "" if status[run] == "ok" else "made up",
                }
            )
    return rows


def frame(*parts: Iterable[dict[str, Any]]) -> pd.DataFrame:
    return pd.DataFrame([r for part in parts for r in part], columns=list(TIDY_COLUMNS))


STRUCT_TRUE = {"na": 2.0, "nb": 2.0, "tau": 3.0, "delay": 8.0}


def structure_rows() -> pd.DataFrame:
    """Four runs per cell; run 3 of the sigma2 cell is not identifiable, run 2 failed."""
    s2 = tidy(
        "wang-delay",
        {
            "na": [2, 2, 1, 2],
            "nb": [2, 1, 2, 2],
            "tau": [3, 3, 3, 3],
            "delay": [8, 3, 8, 13],
            "fitness": [90, 80, 70, 60],
        },
        STRUCT_TRUE,
        sigma2=1e-3,
        snr=[4.0, 6.0, 100.0, 100.0],
        status=["ok", "ok", "failed", "not-identifiable"],
    )
    snr_a = tidy(
        "wang-delay",
        {"na": [2, 2], "nb": [2, 2], "tau": [3, 4], "delay": [8, 9], "fitness": [1, 2]},
        STRUCT_TRUE,
        snr_target=2.0,
        snr=[2.0, 2.0],
    )
    snr_b = tidy(
        "wang-delay",
        {"na": [2, 2], "nb": [2, 2], "tau": [3, 3], "delay": [8, 8], "fitness": [1, 2]},
        STRUCT_TRUE,
        snr_target=20.0,
        snr=[20.0, 20.0],
    )
    # wang-lsm on the same SNR cell: given the multiple (A3), a NaN estimate is not counted
    lsm = tidy(
        "wang-lsm",
        {"na": [2, math.nan], "nb": [2, 2], "tau": [3, 4], "delay": [8, 9], "fitness": [1, 2]},
        STRUCT_TRUE,
        snr_target=2.0,
        snr=[2.0, 2.0],
    )
    return frame(s2, snr_a, snr_b, lsm)


def test_structure_table_hit_rates_exact_and_snr_cells_apart() -> None:
    table = results.structure(structure_rows())
    assert list(table.columns) == STRUCTURE_COLUMNS
    assert set(table["quantity"]) == {"na", "nb", "tau", "delay"}
    assert len(table) == 4 * 4  # 3 wang-delay cells + 1 wang-lsm cell, 4 quantities each
    got = {
        (r.method, "snr" if math.isnan(r.sigma2) else "s2", round(r.snr_mean), r.quantity): (
            r.hit_rate,
            r.n,
            r.true,
        )
        for r in table.itertuples()
    }
    # the sigma2 cell: runs 0 and 1 are ok (run 2 failed, run 3 not identifiable)
    assert got["wang-delay", "s2", 5, "na"] == (1.0, 2, 2.0)
    assert got["wang-delay", "s2", 5, "nb"] == (0.5, 2, 2.0)
    assert got["wang-delay", "s2", 5, "tau"] == (1.0, 2, 3.0)
    assert got["wang-delay", "s2", 5, "delay"] == (0.5, 2, 8.0)
    # two SNR cells at the same (p, delay): two rows each, sigma2 empty, kept apart by snr_mean
    assert got["wang-delay", "snr", 2, "tau"] == (0.5, 2, 3.0)
    assert got["wang-delay", "snr", 2, "delay"] == (0.5, 2, 8.0)
    assert got["wang-delay", "snr", 20, "tau"] == (1.0, 2, 3.0)
    assert got["wang-delay", "snr", 20, "delay"] == (1.0, 2, 8.0)
    # a NaN estimate counts neither as a hit nor in n
    assert got["wang-lsm", "snr", 2, "na"] == (1.0, 1, 2.0)
    assert got["wang-lsm", "snr", 2, "delay"] == (0.5, 2, 8.0)
    s2 = table[table["sigma2"].notna()]
    assert set(s2["sigma2"]) == {1e-3} and (s2["snr_mean"] == 5.0).all()  # ok runs' SNR only
    # the level key keeps what sigma2 leaves empty
    levels = results.structure(structure_rows(), level=True)[results.LEVEL]
    assert set(levels) == {1e-3, -2.0, -20.0}


def test_write_tables_adds_structure_and_keeps_fitness_bias(tmp_path: Path) -> None:
    rows = structure_rows()
    paths = results.write_tables(rows, tmp_path)
    assert set(paths) == {"fitness.csv", "bias.csv", "structure.csv"}
    for ext in ("csv", "md", "tex"):
        assert (tmp_path / f"structure.{ext}").stat().st_size > 0
    back = pd.read_csv(tmp_path / "structure.csv")
    # SNR cells: snr_target after sigma2, as in structure.md and .tex
    assert [c for c in back.columns if c != "snr_target"] == STRUCTURE_COLUMNS and len(back) == 16
    fitness = pd.read_csv(tmp_path / "fitness.csv")
    assert len(fitness) == 4 and fitness["sigma2"].isna().sum() == 3  # three SNR cells
    assert "level" not in fitness.columns  # the contract's columns only


# --------------------------------------------------------------------------------------------
# coloured noise and joint refinement, from hand-made rows
# --------------------------------------------------------------------------------------------

#: a1 offsets from the truth per method: (bias, +- spread) -> std = spread * sqrt(2)
A1_RUNS = {
    "wang-lsm": (0.01, 0.3),  # |bias| < std(IV), std > std(IV)
    "wang-iv": (0.0, 0.1),  # the reference: std = 0.1 sqrt(2)
    "wang-lsm-cn": (0.2, 0.01),  # |bias| > std(IV), std < std(IV)
    "wang-iv-opt": (-0.05, 0.01),  # both below
}
FITNESS = {  # level -> method -> two runs' fitness
    1e-4: {"wang-lsm": [89, 91], "joint-refine": [88, 90], "oracle": [94, 96]},
    1e-2: {"wang-lsm": [60, 62], "joint-refine": [70, 72], "oracle": [80, 82]},
}


def claims_rows(methods: Iterable[str]) -> pd.DataFrame:
    parts = []
    for level, fits in FITNESS.items():
        for m in methods:
            bias, spread = A1_RUNS.get(m, (0.0, 0.0))
            values = {
                "a1": [A1 + bias - spread, A1 + bias + spread],
                "fitness": fits.get(m, [50.0, 50.0]),
                "seconds": [0.1, 0.1],
            }
            parts.append(tidy(m, values, {"a1": A1}, sigma2=level, delay=3))
    # an SNR cell where only the coloured-noise methods ran (kept apart from the sigma2 cells)
    for m in A1_RUNS:
        if m in methods:
            bias, spread = A1_RUNS[m]
            values = {"a1": [A1 + bias - spread, A1 + bias + spread], "fitness": [1.0, 3.0]}
            parts.append(tidy(m, values, {"a1": A1}, snr_target=3.0, delay=3, snr=[3.0, 3.0]))
    return frame(*parts)


ALL = (*A1_RUNS, "joint-refine", "oracle")


def test_coloured_table_from_known_bias_and_std() -> None:
    fitness, bias = results.aggregate(claims_rows(ALL), level=True)
    t = report_beyond.coloured_table(fitness, bias)
    assert len(t) == 3 * 4  # two sigma2 levels and one SNR level, four methods each
    assert list(t["method"][:4]) == list(report_beyond.COLOURED_METHODS)
    assert list(dict.fromkeys(t["noise"])) == ["snr=3", "sigma2=0.0001", "sigma2=0.01"]
    iv_std = 0.1 * math.sqrt(2)
    for r in t.itertuples():
        b, spread = A1_RUNS[r.method]
        assert r.a1_bias == pytest.approx(b, rel=1e-12, abs=1e-12)
        assert r.a1_std == pytest.approx(spread * math.sqrt(2), rel=1e-12)
        assert r.iv_std == pytest.approx(iv_std, rel=1e-12)
        assert r.n == 2
    verdict = {
        m: (g["bias_lt_iv_std"].unique().tolist(), g["std_lt_iv_std"].unique().tolist())
        for m, g in t.groupby("method")
    }
    assert verdict == {
        "wang-lsm": (["yes"], ["no"]),
        "wang-iv": (["yes"], [""]),  # its own std is the reference
        "wang-lsm-cn": (["no"], ["yes"]),
        "wang-iv-opt": (["yes"], ["yes"]),
    }


def test_joint_table_gap_closed() -> None:
    fitness, _ = results.aggregate(claims_rows(ALL), level=True)
    t = report_beyond.joint_table(fitness)
    assert list(t["noise"]) == ["sigma2=0.0001", "sigma2=0.01"]  # the SNR cell lacks joint-refine
    low, high = t.iloc[0], t.iloc[1]
    assert (low["F_LSM"], low["F_joint"], low["F0"]) == (90.0, 89.0, 95.0)
    assert low["gap_closed"] == pytest.approx(-0.2, rel=1e-12)  # (89 - 90) / (95 - 90)
    assert (high["F_LSM"], high["F_joint"], high["F0"]) == (61.0, 71.0, 81.0)
    assert high["gap_closed"] == pytest.approx(0.5, rel=1e-12)
    assert (t["n"] == 2).all()


def test_report_section_from_hand_made_rows(tmp_path: Path) -> None:
    rows = claims_rows(ALL)
    path = report.build_report(tmp_path, tmp_path / "rep", rows=rows)
    page = parse(path)
    ids = {a.get("id") for _, a, _ in page.tags}
    assert {"beyond", "beyond-coloured", "beyond-joint", "beyond-delay"} <= ids
    assert {"table-beyond-coloured", "table-beyond-joint", "beyond-delay-missing"} <= ids
    assert "table-beyond-delay" not in ids and "fig-beyond-delay" not in ids
    missing = "".join(page.section_text["beyond-delay-missing"])
    assert "wang-delay" in missing
    joint = "".join(page.section_text["table-beyond-joint"])
    assert "0.5" in joint and "-0.2" in joint
    both = "".join(page.section_text["beyond-coloured"])
    assert "wang-iv-opt: snr=3, sigma2=0.0001, sigma2=0.01" in both
    assert "wang-lsm-cn: no cell" in both
    for name, n_rows in (("beyond_coloured", 12), ("beyond_joint", 2)):
        assert r"\toprule" in (path.parent / f"{name}.tex").read_text()
        md = (path.parent / f"{name}.md").read_text().splitlines()
        assert md[0].startswith("| nonlinearity |") and len(md) == 2 + n_rows
    assert not (path.parent / "beyond_delay.md").exists()


def test_missing_methods_are_named() -> None:
    rows = claims_rows(("wang-lsm", "wang-lsm-cn"))
    section = report_beyond.plan(rows, Path("."), report._series_label)
    assert section is not None and not section.figures and not section.tables
    html = section.html([])
    assert 'id="beyond-coloured-missing"' in html and "add wang-iv to the sweep" in html
    assert 'id="beyond-joint-missing"' in html and "add joint-refine and oracle" in html
    assert 'id="beyond-delay-missing"' in html and "add wang-delay" in html
    assert report_beyond.missing(["wang-iv", "wang-iv-opt"], "coloured") == []
    assert report_beyond.missing(["wang-iv"], "coloured") == ["wang-lsm-cn or wang-iv-opt"]


def test_section_absent_without_extension_methods(tmp_path: Path) -> None:
    rows = claims_rows(("wang-lsm", "wang-iv", "oracle"))
    assert report_beyond.plan(rows, tmp_path, report._series_label) is None
    path = report.build_report(tmp_path, tmp_path / "rep", rows=rows)
    ids = {a.get("id") for _, a, _ in parse(path).tags}
    assert "beyond" not in ids and "tables" in ids
    assert not list(path.parent.glob("beyond_*"))


def test_membership_from_the_registered_class_module() -> None:
    for name in ("wang-delay", "wang-lsm-cn", "wang-iv-opt", "joint-refine"):
        assert report_beyond.is_extension(name), name
    for name in ("wang-lsm", "wang-iv", "oracle", "no-such-method"):
        assert not report_beyond.is_extension(name), name


# --------------------------------------------------------------------------------------------
# a tiny real sweep of the delay preset
# --------------------------------------------------------------------------------------------

DELAYS = (3, 8)


@pytest.fixture(scope="module")
def delay_sweep(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """experiment=delay_beyond_a3 cut down: delays 3, 8 (m = 0, 1), SNR 5, 3 runs of 120 s."""
    out = tmp_path_factory.mktemp("delay")
    err = io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        status = cli.main(
            [
                "sweep",
                "-m",
                "experiment=delay_beyond_a3",
                f"plant.delay={','.join(map(str, DELAYS))}",
                "noise.snr=5",
                "runs=3",
                "scenario.duration=120",
                f"out={out}",
            ]
        )
    assert status == 0, err.getvalue()
    return out


def test_delay_sweep_structure_csv(delay_sweep: Path) -> None:
    table = pd.read_csv(delay_sweep / "structure.csv")
    assert [c for c in table.columns if c != "snr_target"] == STRUCTURE_COLUMNS  # SNR cells
    assert len(table) == 2 * len(DELAYS) * 4  # methods x delays x quantities
    assert set(table["method"]) == {"wang-lsm", "wang-delay"}
    assert table["sigma2"].isna().all() and (table["n"] == 3).all()
    delay = table[table["quantity"] == "delay"]
    assert (delay["true"] == delay["delay"]).all()  # the plant's delay in fast samples
    tau = table[table["quantity"] == "tau"].set_index(["method", "delay"])["true"]
    assert tau.to_dict() == {(m, d): d % 5 for m in ("wang-delay", "wang-lsm") for d in DELAYS}
    # hit rates recomputed from the tidy rows
    rows = pd.read_parquet(delay_sweep / "rows.parquet")
    ok = rows[(rows["status"] == "ok") & rows["quantity"].isin(["na", "nb", "tau", "delay"])]
    hits = (ok["value"] == ok["true"]).groupby([ok["method"], ok["delay"], ok["quantity"]]).mean()
    got = table.set_index(["method", "delay", "quantity"])["hit_rate"]
    assert set(got.index) == set(hits.index)
    for key, rate in hits.items():  # the CSV keeps 10 significant digits
        assert got[key] == pytest.approx(rate, rel=1e-9), key
    # wang-lsm is given the multiple of p (A3): its total delay is right exactly when tau is
    lsm = table[table["method"] == "wang-lsm"].pivot(
        index="delay", columns="quantity", values="hit_rate"
    )
    assert (lsm["delay"] == lsm["tau"]).all()


def test_delay_sweep_report_has_the_delay_subsection(delay_sweep: Path) -> None:
    path = report.build_report(delay_sweep)
    page = parse(path)
    ids = {a.get("id") for _, a, _ in page.tags}
    assert {"beyond", "beyond-delay", "table-beyond-delay", "table-beyond-delay-grid"} <= ids
    assert {"beyond-coloured-missing", "beyond-joint-missing"} <= ids
    imgs = {i[-1]: (a["src"], i) for t, a, i in page.tags if t == "img" and i}
    src, where = imgs["fig-beyond-delay"]
    assert src.startswith("data:image/png;base64,")
    assert "beyond-delay" in where and "figures" not in where  # in its subsection
    assert "fig-fitness-snr" in imgs and "beyond" not in imgs["fig-fitness-snr"][1]
    pooled = pd.read_csv(io.StringIO(_md_to_csv(path.parent / "beyond_delay.md")))
    assert set(pooled["method"]) == {"wang-lsm", "wang-delay"}
    assert (pooled["delays"] == len(DELAYS)).all() and (pooled["n"] == 3 * len(DELAYS)).all()
    structure = pd.read_csv(delay_sweep / "structure.csv")
    for m in ("wang-lsm", "wang-delay"):
        expected = structure[(structure["method"] == m) & (structure["quantity"] == "delay")]
        row = pooled[pooled["method"] == m].iloc[0]
        # equal n per delay: the pooled rate is the mean of the delays' (4 digits in the .md)
        assert row["delay_hit_rate"] == pytest.approx(expected["hit_rate"].mean(), abs=1e-3)
    assert (path.parent / "beyond_delay_hit_rate.pdf").read_bytes()[:5] == b"%PDF-"
    grid = (path.parent / "beyond_delay_grid.md").read_text()
    assert grid.startswith("| nonlinearity | p | delay | snr=5 |")


def _md_to_csv(path: Path) -> str:
    """A Markdown table written by :func:`hbench.tables.results.to_markdown` as CSV text."""
    lines = [ln for ln in path.read_text().splitlines() if ln and not ln.startswith("|---")]
    return "\n".join(",".join(c.strip() for c in ln.strip("|").split("|")) for ln in lines)


def test_level_key_and_labels() -> None:
    assert set(results.level_key(structure_rows())) == {1e-3, -2.0, -20.0}
    assert report_beyond.level_label(-5.0) == "snr=5"
    assert report_beyond.level_label(1e-3) == "sigma2=0.001"
    assert report_beyond.level_label(float("nan")) == "?"


def test_presets_validate_to_their_job_counts() -> None:
    from hbench.sweep.app import validate

    assert validate(["experiment=delay_beyond_a3"], multirun=True) == 15 * 3  # delays x SNRs
    assert validate(["experiment=beyond_paper"], multirun=True) == 4  # noise levels

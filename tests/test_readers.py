"""Record readers: fast-rate tables, plant logs, validation messages and the CLI's exit status."""

from __future__ import annotations

import csv
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from hbench.cli import main
from hbench.errors import RecordError
from hbench.io.readers import (
    READERS,
    PlantLogReader,
    TableReader,
    read_record,
    record_from_fast,
    write_record,
)
from hbench.sim.records import Record

SHARED = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "stictiongpt"


# ------------------------------------------------------------------------------------- helpers


def slow_record(p: int, K: int = 60, h: float = 0.1, seed: int = 0, with_r: bool = True) -> Record:
    """A one-run record with x changing at every slow period."""
    rng = np.random.default_rng(seed)
    return Record(
        y=rng.standard_normal((1, K * p)),
        x=rng.standard_normal((1, K)),
        r=rng.standard_normal((1, K)) if with_r else None,
        p=p,
        h=h,
    )


def fast_arrays(
    p: int, K: int = 60, lead: int = 0, trail: int = 0, h: float = 0.1, seed: int = 1
) -> dict[str, np.ndarray]:
    """Fast t, x, y, r for K whole periods plus a partial period before and after."""
    rng = np.random.default_rng(seed)

    def held(values: np.ndarray) -> np.ndarray:
        return np.concatenate(
            [np.full(lead, values[0]), np.repeat(values[1:-1], p), np.full(trail, values[-1])]
        )

    x, r = held(rng.standard_normal(K + 2)), held(rng.standard_normal(K + 2))
    n = x.size
    return {"t": np.arange(n) * h, "x": x, "y": rng.standard_normal(n), "r": r}


def write_csv(path: Path, cols: dict[str, object]) -> Path:
    """Write columns to CSV with full float precision."""
    pd.DataFrame(cols).to_csv(path, index=False, float_format=lambda v: repr(float(v)))
    return path


def assert_same(a: Record, b: Record) -> None:
    assert a.p == b.p
    assert a.h == b.h
    np.testing.assert_array_equal(a.y, b.y)
    np.testing.assert_array_equal(a.x, b.x)
    if a.r is None:
        assert b.r is None
    else:
        np.testing.assert_array_equal(a.r, b.r)


def cli_error(path: Path, capsys: pytest.CaptureFixture[str], *extra: str) -> str:
    """Run ``hbench inspect``; check exit 2 and a one-line error; return the line."""
    capsys.readouterr()
    rc = main(["inspect", str(path), *extra])
    err = capsys.readouterr().err
    assert rc == 2
    assert "Traceback" not in err
    assert err.endswith("\n") and err.count("\n") == 1, err
    assert err.startswith("hbench inspect: error:")
    return err


# ---------------------------------------------------------------------------------- round trip


@pytest.mark.parametrize("suffix", [".csv", ".parquet", ".tsv", ".pq"])
@pytest.mark.parametrize("p", [1, 3, 5])
def test_round_trip(tmp_path: Path, suffix: str, p: int) -> None:
    rec = slow_record(p, seed=p)
    path = write_record(rec, tmp_path / f"rec{suffix}")
    back = read_record(path)
    assert_same(rec, back)
    assert back.source == str(path)
    assert back.meta["p_inferred"] is True
    assert back.meta["trimmed"] == (0, 0)
    notices = back.meta["notices"]
    if p == 1:
        assert notices == ["x changes at every sample: treated as p = 1, no fast sampling"]
    else:
        assert notices == []


@pytest.mark.parametrize("h", [1 / 3, 0.37 / 7, 1e-4, 60.0])
@pytest.mark.parametrize("suffix", [".csv", ".parquet"])
def test_round_trip_odd_h_and_no_r(tmp_path: Path, h: float, suffix: str) -> None:
    rec = slow_record(4, K=200, h=h, with_r=False)
    back = read_record(write_record(rec, tmp_path / f"rec{suffix}"))
    assert_same(rec, back)
    assert back.r is None


def test_round_trip_given_p(tmp_path: Path) -> None:
    rec = slow_record(5)
    back = read_record(write_record(rec, tmp_path / "rec.csv"), p=5)
    assert_same(rec, back)
    assert back.meta["p_inferred"] is False


def test_write_record_refuses(tmp_path: Path) -> None:
    rec = slow_record(2)
    two = Record(y=np.vstack([rec.y, rec.y]), x=np.vstack([rec.x, rec.x]), r=None, p=2, h=0.1)
    with pytest.raises(RecordError, match="one run"):
        write_record(two, tmp_path / "a.csv")
    with pytest.raises(RecordError, match="cannot write"):
        write_record(rec, tmp_path / "a.xlsx")
    with pytest.raises(RecordError, match="needs x"):
        write_record(rec.withhold(set()), tmp_path / "a.csv")


# ------------------------------------------------------------------------------- p inference


def test_leading_partial_period_is_trimmed(tmp_path: Path) -> None:
    f = fast_arrays(p=4, K=60, lead=3, trail=2)
    rec = read_record(write_csv(tmp_path / "a.csv", f))
    assert rec.p == 4
    assert rec.n_slow == 60
    assert rec.meta["trimmed"] == (3, 2)
    assert rec.meta["t0"] == f["t"][3]
    np.testing.assert_array_equal(rec.y[0], f["y"][3 : 3 + 240])
    np.testing.assert_array_equal(rec.x[0], f["x"][3 : 3 + 240 : 4])
    np.testing.assert_array_equal(rec.r[0], f["r"][3 : 3 + 240 : 4])
    (notice,) = rec.meta["notices"]
    assert "trimmed 3 leading" in notice and "2 trailing" in notice


def test_given_p_uses_the_same_phase(tmp_path: Path) -> None:
    f = fast_arrays(p=4, K=60, lead=3, trail=2)
    path = write_csv(tmp_path / "a.csv", f)
    assert_same(read_record(path), read_record(path, p=4))
    # p = 2 divides the true p: x is held over it too (two slow samples per true period)
    rec2 = read_record(path, p=2)
    assert rec2.p == 2 and rec2.meta["trimmed"] == (1, 0)


def test_constant_stretch_longer_than_p() -> None:
    rng = np.random.default_rng(3)
    xs = rng.standard_normal(80)
    xs[10:25] = xs[10]  # held for 15 periods
    xs[40:43] = xs[40]
    p = 6
    x = np.repeat(xs, p)
    rec = record_from_fast(np.arange(x.size) * 0.5, x, rng.standard_normal(x.size))
    assert rec.p == 6 and rec.n_slow == 80
    np.testing.assert_array_equal(rec.x[0], xs)
    assert rec.r is None


def test_x_changing_at_every_sample_is_p1() -> None:
    rng = np.random.default_rng(4)
    n = 100
    rec = record_from_fast(np.arange(n), rng.standard_normal(n), rng.standard_normal(n))
    assert rec.p == 1 and rec.n_slow == n
    assert rec.meta["notices"] == ["x changes at every sample: treated as p = 1, no fast sampling"]


def test_x_with_irregular_holds_is_p1() -> None:
    rng = np.random.default_rng(5)
    gaps = rng.choice([1, 2, 3], size=200)
    x = np.repeat(rng.standard_normal(200), gaps)
    rec = record_from_fast(np.arange(x.size), x, np.zeros(x.size) + rng.standard_normal(x.size))
    assert rec.p == 1
    assert "not held over any p > 1" in rec.meta["notices"][0]


def test_r_is_taken_at_the_period_start() -> None:
    f = fast_arrays(p=3, K=60)
    r = np.arange(f["x"].size, dtype=float)  # a ramp: not held
    rec = record_from_fast(f["t"], f["x"], f["y"], r)
    np.testing.assert_array_equal(rec.r[0], r[::3])
    assert any("varies inside slow periods" in s for s in rec.meta["notices"])


def test_a_few_stray_changes_do_not_give_a_small_p() -> None:
    f = fast_arrays(p=6, K=60)
    x = f["x"].copy()
    x[62] += 0.5  # one change inside a hold, at a row 3 off the grid (gcd would drop to 1)
    with pytest.raises(RecordError, match=r"looks held over p = 6.*row 62.*--p"):
        record_from_fast(f["t"], x, f["y"])
    with pytest.raises(RecordError, match=r"not held over p = 6: it changes at row 62"):
        record_from_fast(f["t"], x, f["y"], p=6)
    assert record_from_fast(f["t"], x, f["y"], p=1).p == 1


def test_float_jitter_in_x_is_refused_with_a_hint() -> None:
    f = fast_arrays(p=5, K=60)
    x = f["x"].copy()
    x[[7, 33, 101]] += 1e-13
    with pytest.raises(RecordError, match="float jitter"):
        record_from_fast(f["t"], x, f["y"])
    with pytest.raises(RecordError, match="float jitter"):
        record_from_fast(f["t"], x, f["y"], p=5)


def test_record_from_fast_argument_checks() -> None:
    t = np.arange(100.0)
    x = np.repeat(np.arange(50.0), 2)
    with pytest.raises(RecordError, match="p must be a positive integer"):
        record_from_fast(t, x, t, p=0)
    with pytest.raises(RecordError, match="p must be a positive integer"):
        record_from_fast(t, x, t, p=2.5)  # type: ignore[arg-type]
    with pytest.raises(RecordError, match="'y' has 99 samples"):
        record_from_fast(t, x, t[:-1])
    with pytest.raises(RecordError, match="1-D"):
        record_from_fast(t, x, np.vstack([t, t]))
    with pytest.raises(RecordError, match="does not increase"):
        record_from_fast(t[::-1], x, t)
    with pytest.raises(RecordError, match=r"changes only once.*--p"):
        record_from_fast(t, np.r_[np.zeros(50), np.ones(50)], t)
    assert record_from_fast(t, x, t, p=2).n_slow == 50
    rec = record_from_fast(t, np.zeros(100), t, p=2)
    assert any("constant" in s for s in rec.meta["notices"])


# ------------------------------------------------------------------------------- bad inputs


def _good(n: int = 120, p: int = 2) -> dict[str, list[object]]:
    f = fast_arrays(p=p, K=n // p)
    return {k: list(v) for k, v in f.items()}


def _missing_column(tmp: Path) -> Path:
    cols = _good()
    del cols["y"]
    cols["Y_meas"] = cols.pop("r")
    return write_csv(tmp / "a.csv", cols)


def _non_numeric(tmp: Path) -> Path:
    cols = _good()
    cols["y"][7] = "abc"
    return write_csv(tmp / "a.csv", cols)


def _nan(tmp: Path) -> Path:
    cols = _good()
    cols["y"][10] = None
    return write_csv(tmp / "a.csv", cols)


def _inf(tmp: Path) -> Path:
    cols = _good()
    cols["x"][12] = np.inf
    path = tmp / "a.parquet"
    pd.DataFrame(cols).to_parquet(path, index=False)
    return path


def _held_over_3(tmp: Path) -> Path:
    return write_csv(tmp / "a.csv", _good(n=150, p=3))


def _non_uniform_t(tmp: Path) -> Path:
    cols = _good()
    cols["t"] = [v + (0.05 if i > 20 else 0.0) for i, v in enumerate(cols["t"])]
    return write_csv(tmp / "a.csv", cols)


def _short(tmp: Path) -> Path:
    return write_csv(tmp / "a.csv", _good(n=60, p=2))  # 30 slow samples


def _constant_x(tmp: Path) -> Path:
    cols = _good()
    cols["x"] = [1.5] * len(cols["x"])
    return write_csv(tmp / "a.csv", cols)


def _one_row(tmp: Path) -> Path:
    (tmp / "a.csv").write_text("t,x,y\n0,1,2\n")
    return tmp / "a.csv"


def _empty(tmp: Path) -> Path:
    (tmp / "a.csv").write_text("")
    return tmp / "a.csv"


def _bad_parquet(tmp: Path) -> Path:
    (tmp / "a.parquet").write_text("t,x,y\n")
    return tmp / "a.parquet"


def _unsupported(tmp: Path) -> Path:
    (tmp / "a.xlsx").write_bytes(b"PK\x03\x04")
    return tmp / "a.xlsx"


def _text_not_a_log(tmp: Path) -> Path:
    (tmp / "a.txt").write_text("t,x,y\n0,1,2\n")
    return tmp / "a.txt"


def _directory(tmp: Path) -> Path:
    (tmp / "dir.csv").mkdir()
    return tmp / "dir.csv"


BAD: dict[str, tuple[Callable[[Path], Path], tuple[str, ...], list[str]]] = {
    # case: (make file, fragments of the message, extra CLI arguments)
    "missing column": (_missing_column, ("missing column 'y'", "columns found: 't', 'x'"), []),
    "non-numeric": (_non_numeric, ("column 'y' has a non-numeric value 'abc' at row 7",), []),
    "NaN": (_nan, ("column 'y' is NaN (missing) at row 10",), []),
    "inf": (_inf, ("column 'x' is infinite (inf) at row 12",), []),
    "non-uniform t": (_non_uniform_t, ("'t' is not uniform", "row 20 to row 21", "+0.05"), []),
    "not held over p": (_held_over_3, ("'x' is not held over p = 2", "slow period"), ["--p", "2"]),
    "fewer than 50 slow": (_short, ("only 30 slow samples", "at least 50 are needed"), []),
    "p not inferable": (_constant_x, ("'x' never changes", "pass --p"), []),
    "one sample": (_one_row, ("1 sample(s); at least 2 are needed",), []),
    "empty file": (_empty, ("empty",), []),
    "bad parquet": (_bad_parquet, ("cannot read it as PARQUET",), []),
    "unsupported": (_unsupported, ("unsupported record format", "plant-log", "table"), []),
    "txt not a log": (_text_not_a_log, ("unsupported record format",), []),
    "directory": (_directory, ("is a directory",), []),
    "p zero": (_held_over_3, ("p must be a positive integer, got 0",), ["--p", "0"]),
}


@pytest.mark.parametrize("case", list(BAD))
def test_bad_input(tmp_path: Path, capsys: pytest.CaptureFixture[str], case: str) -> None:
    make, fragments, extra = BAD[case]
    path = make(tmp_path)
    p = int(extra[1]) if extra else None
    with pytest.raises(RecordError) as info:
        read_record(path, p=p)
    for fragment in fragments:
        assert fragment in str(info.value)
    err = cli_error(path, capsys, *extra)
    for fragment in fragments:
        assert fragment in err


def test_missing_file(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(FileNotFoundError):
        read_record(tmp_path / "nope.csv")
    assert "no such file" in cli_error(tmp_path / "nope.csv", capsys)


def test_cli_inspect_prints_notices(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = write_csv(tmp_path / "a.csv", fast_arrays(p=4, K=60, lead=3))
    assert main(["inspect", str(path)]) == 0
    out, err = capsys.readouterr()
    assert '"p": 4' in out and '"n_slow": 60' in out
    assert err.startswith("notice: trimmed 3 leading")


def test_readers_argument(tmp_path: Path) -> None:
    rec = slow_record(2)

    class Fake:
        name = "fake"

        def can_read(self, path: Path) -> bool:
            return path.suffix == ".fake"

        def read(self, path: Path, p: int | None = None) -> Record:
            return rec

    (tmp_path / "a.fake").write_text("")
    assert read_record(tmp_path / "a.fake", readers=[Fake()]) is rec
    with pytest.raises(RecordError, match="unsupported record format; supported: plant-log"):
        read_record(tmp_path / "a.fake")
    (tmp_path / "a.other").write_text("")
    with pytest.raises(RecordError, match=r"unsupported record format; supported: fake$"):
        read_record(tmp_path / "a.other", readers=[Fake()])
    assert [r.name for r in READERS] == ["plant-log", "table"]


# ------------------------------------------------------------------------------------ plant logs


def write_plant_log(
    path: Path,
    n: int = 80,
    Ts: float = 10.0,
    *,
    encoding: str = "utf-8",
    tag: str = "2#CDU.7040-311_FIC31102",
    mv: list[str] | None = None,
    flags_at: tuple[int, ...] = (),
    stamps: list[str] | None = None,
    declared: int | None = None,
) -> dict[str, np.ndarray]:
    """A plant log in the stictiongpt layout (CRLF, Chinese descriptions, flag columns)."""
    rng = np.random.default_rng(7)
    MV = rng.uniform(20, 80, n).round(6)
    PV = rng.uniform(90, 110, n).round(7)
    SV = np.where(np.arange(n) < n // 2, 100.0, 102.5)
    mv_text = mv if mv is not None else [repr(float(v)) for v in MV]
    lines = [
        f"PROCESSDATA\t{tag} Data\tyyyy-MM-dd HH:mm:ss",
        f"8\t{Ts:g}\t2024-06-27 21:55:00\t{n if declared is None else declared}",
        f"tagname\t{tag}.MV\t{tag}.PV\t{tag}.SV\t{tag}.MODE\tbOpOFL\tbPvOFL\tbSpOFL\tbAutOFL",
        "desc\t汽包给水流量控制_OP\t汽包给水流量控制_PV\t汽包给水流量控制_SP\tAut"
        "\tbOpOFL\tbPvOFL\tbSpOFL\tbAutOFL",
        "fsMax=1.63\tfsMin=0\tfsGridNum=10\tfdMax=1.63tfdMin=0\tfdGridNum=10\tv0GridNum=10\tL=24",
    ]
    t0 = pd.Timestamp("2024-06-27 21:55:00")
    for k in range(n):
        stamp = stamps[k] if stamps else str(t0 + pd.Timedelta(seconds=k * Ts))
        flag = "1\t1\t1\t1" if k in flags_at else "0\t0\t0\t0"
        lines.append(f"{stamp}\t{mv_text[k]}\t{float(PV[k])!r}\t{SV[k]:g}\t1\t{flag}")
    path.write_bytes(("\r\n".join(lines) + "\r\n").encode(encoding))
    return {"MV": MV, "PV": PV, "SV": SV}


@pytest.mark.parametrize("encoding", ["utf-8", "utf-8-sig", "gb18030", "utf-16"])
def test_synthetic_plant_log(tmp_path: Path, encoding: str) -> None:
    path = tmp_path / "loop.txt"
    sig = write_plant_log(path, n=80, Ts=10.0, encoding=encoding, flags_at=(0, 30))
    assert PlantLogReader().can_read(path)
    assert not TableReader().can_read(path)
    rec = read_record(path)
    assert rec.p == 1 and rec.h == 10.0 and rec.y.shape == (1, 80)
    np.testing.assert_array_equal(rec.x[0], sig["MV"])
    np.testing.assert_array_equal(rec.y[0], sig["PV"])
    np.testing.assert_array_equal(rec.r[0], sig["SV"])
    m = rec.meta
    assert m["format"] == "plant-log"
    assert m["tag"] == "2#CDU.7040-311_FIC31102"
    assert m["Ts"] == 10.0 and m["start"] == "2024-06-27 21:55:00" and m["n_declared"] == 80
    assert m["mode"] == {"1": 80}
    assert m["flags"] == {"bOpOFL": 2, "bPvOFL": 2, "bSpOFL": 2, "bAutOFL": 2}
    assert m["parameters"]["fdMax"] == "1.63" and m["parameters"]["fdMin"] == "0"
    assert m["descriptions"]["MV"] == "汽包给水流量控制_OP"
    assert m["notices"] == [
        "2 rows carry a set flag (bOpOFL 2, bPvOFL 2, bSpOFL 2, bAutOFL 2); "
        "their values are kept as logged"
    ]


def test_plant_log_odd_stamps_and_count(tmp_path: Path) -> None:
    t0 = pd.Timestamp("2024-06-27 21:55:00")
    stamps = [str(t0 + pd.Timedelta(seconds=60 * k)) for k in range(60)]
    stamps[30] = stamps[29]  # a repeated stamp, then a 2 Ts step, as in two real logs
    path = tmp_path / "loop.txt"
    write_plant_log(path, n=60, Ts=60.0, stamps=stamps, declared=61)
    rec = read_record(path)
    assert rec.h == 60.0 and rec.n_fast == 60
    notices = " | ".join(rec.meta["notices"])
    assert "the header announces 61 samples; the file has 60 rows" in notices
    assert "timestamps are irregular at 2 step(s) (1 of 0 s, 1 of 120 s" in notices
    assert "t is built from Ts = 60 s" in notices


def test_plant_log_given_p(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "loop.txt"
    held = [repr(float(v)) for v in np.repeat(np.arange(60.0), 2)]
    write_plant_log(path, n=120, mv=held)
    rec = read_record(path, p=2)
    assert rec.p == 2 and rec.n_slow == 60 and rec.h == 10.0
    with pytest.raises(RecordError, match=r"'MV' is not held over p = 3"):
        read_record(path, p=3)


def _set_field(lines: list[str], line: int, field: int, value: str) -> None:
    fields = lines[line - 1].split("\t")
    fields[field] = value
    lines[line - 1] = "\t".join(fields)


BAD_LOGS: dict[str, tuple[Callable[[list[str]], None], str]] = {
    # case: (edit the lines of a good 80-row log, fragment of the message)
    "Ts": (lambda ls: _set_field(ls, 2, 1, "0"), "sampling period Ts > 0 in seconds, got '0'"),
    "no MV": (lambda ls: _set_field(ls, 3, 1, "TAG.OP"), "line 3 has no MV column"),
    "bad value": (
        lambda ls: _set_field(ls, 13, 1, "Bad"),
        "column 'MV' has a non-numeric value 'Bad' at row 7 (line 13)",
    ),
    "missing value": (lambda ls: _set_field(ls, 14, 2, ""), "'PV' is NaN (missing) at row 8"),
    "short row": (lambda ls: ls.__setitem__(9, "2024-06-27 21:55:40"), "line 10 has 1 field(s)"),
    "short record": (lambda ls: ls.__delitem__(slice(40, None)), "only 35 slow samples"),
    "header only": (lambda ls: ls.__delitem__(slice(3, None)), "needs a 3-line header and data"),
}


@pytest.mark.parametrize("case", list(BAD_LOGS))
def test_bad_plant_log(tmp_path: Path, capsys: pytest.CaptureFixture[str], case: str) -> None:
    edit, fragment = BAD_LOGS[case]
    path = tmp_path / "loop.txt"
    write_plant_log(path, n=80)
    lines = path.read_text(encoding="utf-8").splitlines()
    edit(lines)
    path.write_text("\r\n".join(lines), encoding="utf-8")
    with pytest.raises(RecordError) as info:
        read_record(path)
    assert fragment in str(info.value)
    assert fragment in cli_error(path, capsys)


@pytest.mark.shared
def test_every_stictiongpt_log_reads() -> None:
    if not SHARED.is_dir():
        pytest.skip("../shared/data/stictiongpt not found (a user's clone has no ../shared)")
    with (SHARED / "INDEX.csv").open(encoding="utf-8", newline="") as fh:
        index = list(csv.DictReader(fh))
    assert len(index) == 80
    for row in index:
        rec = read_record(SHARED / row["file"])
        n, Ts = int(row["n_samples"]), float(row["Ts_s"])
        assert rec.p == 1, row["file"]
        assert rec.h == Ts, row["file"]
        assert rec.y.shape == (1, n) and rec.x.shape == (1, n) and rec.r.shape == (1, n)
        assert rec.meta["Ts"] == Ts and rec.meta["start"] == row["start"]
        assert np.isfinite(rec.y).all() and np.isfinite(rec.x).all()

"""Faults end to end, as a user meets them: nothing lost, nothing silently wrong, bounded memory.

Each test drives the command line (in this process, or in a child process where the fault is
a process's: a closed pipe, SIGKILL, a dead launcher) and checks the outcome a user relies on:
the tables of an interrupted or faulty sweep equal an uninterrupted run's byte for byte, a
misbehaving method fails its own rows only, and what cannot be done is refused at once with one
line on stderr.
"""

from __future__ import annotations

import errno
import importlib.util
import json
import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import pytest
from omegaconf import OmegaConf

from hbench.bench.runner import methods_from_names, run_cell
from hbench.errors import InputError, OutputError
from hbench.ident.identifiers import NON_FINITE, Identifier
from hbench.plugins import registry
from hbench.sim.scenarios import build
from hbench.sweep import config
from hbench.sweep.jobs import DONE, ROWS
from hbench.system import atomic
from tests.helpers import paper_spec, registered_methods

pytestmark = pytest.mark.filterwarnings(f"ignore:{config.SCHEMA_NOTE}:UserWarning")

RunCli = Callable[[Sequence[str]], tuple[int, str, str]]
REPO = Path(__file__).resolve().parents[1]
#: Small and fast: 3 runs of 120 s records.
SMALL = ("runs=3", "scenario.duration=120")
TABLES = ("fitness.csv", "bias.csv", "structure.csv")


# --------------------------------------------------------------------------------------------
# misbehaving methods
# --------------------------------------------------------------------------------------------


def _lsm(record: Any, options: Any) -> Any:
    return registry().get("identifiers", "wang-lsm")().identify(record, options, None)


class Mutates(Identifier):
    """Writes into the record it was given, then returns wang-lsm's estimate."""

    name = "test-mutates"

    def identify(self, record: Any, options: Any, truth: Any = None) -> Any:
        record.y[:] = 0.0
        return _lsm(record, options)


class MutatesShared(Identifier):
    """Writes into what the record's methods share (the quiet-phase differences of y)."""

    name = "test-mutates-shared"

    def identify(self, record: Any, options: Any, truth: Any = None) -> Any:
        from hbench.ident.identifiers import largest_order, shared_moments

        dy, _ = shared_moments(record.y, record.p, largest_order(options), record.cache)
        dy *= 0.0
        return _lsm(record, options)


class Exits(Identifier):
    name = "test-exits"

    def identify(self, record: Any, options: Any, truth: Any = None) -> Any:
        sys.exit(3)


class Hangs(Identifier):
    """Never returns (a Python loop, as a method stuck in its own iteration)."""

    name = "test-hangs"

    def identify(self, record: Any, options: Any, truth: Any = None) -> Any:
        while True:
            try:
                time.sleep(0.05)
            except Exception:  # swallows what it can: the time limit must still stop it
                pass


class Infinite(Identifier):
    """wang-lsm's estimate with an infinite a1 in run 0."""

    name = "test-infinite"

    def identify(self, record: Any, options: Any, truth: Any = None) -> Any:
        est = _lsm(record, options)
        a = est.a.copy()
        a[0, 0] = np.inf
        return replace(est, a=a)


FAULTY = (Mutates, Exits, Hangs, Infinite)


@pytest.fixture
def faulty() -> Iterator[None]:
    with registered_methods("faults-test", *FAULTY):
        yield


def sweep(run_cli: RunCli, out: Path, *overrides: str) -> tuple[int, str, str]:
    return run_cli(["sweep", "-m", *overrides, f"out={out}"])


def tables(root: Path) -> dict[str, bytes]:
    return {name: (root / name).read_bytes() for name in TABLES}


def statuses(root: Path) -> list[str]:
    return sorted(json.loads(m.read_text())["status"] for m in root.rglob(DONE))


def one_line_error(stderr: str, command: str) -> str:
    assert "Traceback" not in stderr, stderr
    lines = stderr.strip().splitlines()
    assert len(lines) == 1, stderr
    assert lines[0].startswith(f"hbench {command}: error: "), stderr
    return lines[0]


def child(argv: Sequence[str], **kwargs: Any) -> subprocess.Popen:
    """``hbench ARGV`` in a child process."""
    env = {**os.environ, "MPLBACKEND": "Agg", "PYTHONPATH": str(REPO)}
    return subprocess.Popen(
        [sys.executable, "-m", "hbench.cli", *argv], cwd=REPO, env=env, **kwargs
    )


GRID = ("noise.snr=5,20", "method=wang-lsm,bai-fu", *SMALL)


@pytest.fixture(scope="module")
def reference(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The uninterrupted sweep of :data:`GRID` (4 jobs)."""
    from hbench import cli

    out = tmp_path_factory.mktemp("reference")
    assert cli.main(["sweep", "-m", *GRID, f"out={out}"]) == 0
    return out


# --------------------------------------------------------------------------------------------
# interrupted and faulty sweeps resume to the same tables
# --------------------------------------------------------------------------------------------


def test_a_closed_stderr_loses_nothing(tmp_path: Path, reference: Path) -> None:
    """``hbench sweep ... 2>&1 | head -3``: every job completes (a progress line on a closed
    pipe is not a failure of the cell) and the tables are the uninterrupted run's."""
    proc = child(
        ["sweep", "-m", *GRID, f"out={tmp_path}"], stdout=subprocess.PIPE, stderr=subprocess.STDOUT
    )
    assert proc.stdout is not None
    for _ in range(3):
        proc.stdout.readline()
    proc.stdout.close()
    proc.wait(timeout=300)
    assert statuses(tmp_path) == ["ok"] * 4
    assert tables(tmp_path) == tables(reference)


def test_a_failed_cell_is_computed_again_on_resume(
    run_cli: RunCli, tmp_path: Path, reference: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A cell that fails as a whole (here MemoryError) is stored with its failed rows but is not
    done: resuming computes it again."""
    from hbench.bench import runner

    real = runner.run_cell
    calls = []

    def once_out_of_memory(*args: Any, **kwargs: Any) -> Any:
        calls.append(1)
        if len(calls) == 2:
            raise MemoryError("no room")
        return real(*args, **kwargs)

    monkeypatch.setattr(runner, "run_cell", once_out_of_memory)
    status, _, err = sweep(run_cli, tmp_path, *GRID)
    assert status == 0, err
    assert "cell FAILED: MemoryError: no room" in err
    assert statuses(tmp_path) == ["cell-failed"] + ["ok"] * 3
    monkeypatch.setattr(runner, "run_cell", real)
    status, _, err = sweep(run_cli, tmp_path, *GRID)
    assert status == 0, err
    assert err.count("skipped") == 3 and err.count("done in") == 1
    assert statuses(tmp_path) == ["ok"] * 4
    assert tables(tmp_path) == tables(reference)


def test_sigkill_mid_sweep_then_resume(run_cli: RunCli, tmp_path: Path, reference: Path) -> None:
    proc = child(
        ["sweep", "-m", *GRID, f"out={tmp_path}"],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    deadline = time.monotonic() + 120
    while not list(tmp_path.rglob(DONE)) and time.monotonic() < deadline:
        assert proc.poll() is None, "the sweep ended before it was killed"
        time.sleep(0.02)
    proc.send_signal(signal.SIGKILL)
    proc.wait(timeout=30)
    assert 1 <= len(statuses(tmp_path)) < 4
    status, _, err = sweep(run_cli, tmp_path, *GRID)
    assert status == 0, err
    assert tables(tmp_path) == tables(reference)


def test_truncated_job_rows_are_named_and_computed_again(
    run_cli: RunCli, tmp_path: Path, reference: Path
) -> None:
    status, _, err = sweep(run_cli, tmp_path, *GRID)
    assert status == 0, err
    before = tables(tmp_path)
    victim = sorted(tmp_path.rglob(ROWS))[0]  # a job's rows (the sweep's own sort after them)
    assert victim.parent != tmp_path
    victim.write_bytes(victim.read_bytes()[: victim.stat().st_size // 2])
    # aggregation alone: one line naming the job, exit 1, the tables left as they were
    status, _, err = run_cli(["sweep", "--aggregate", str(tmp_path)])
    assert status == 1
    line = one_line_error(err, "sweep")
    assert str(victim.parent) in line and "cannot be read" in line
    assert tables(tmp_path) == before
    # resuming: the job is not done (unreadable rows), so it runs again
    status, _, err = sweep(run_cli, tmp_path, *GRID)
    assert status == 0, err
    assert err.count("skipped") == 3 and err.count("done in") == 1
    assert tables(tmp_path) == tables(reference)


def test_an_unreadable_job_fails_the_sweeps_aggregation(run_cli: RunCli, tmp_path: Path) -> None:
    """Inside Hydra (the callback), too: exit 1 and one line, never a warning and status 0."""
    from hbench.sweep.callbacks import AggregateTables

    status, _, err = sweep(run_cli, tmp_path, "noise.snr=5", "method=wang-lsm", *SMALL)
    assert status == 0, err
    rows = next(p for p in tmp_path.rglob(ROWS) if p.parent != tmp_path)
    rows.write_bytes(b"PAR1 not a table")
    cfg = OmegaConf.create({"hydra": {"sweep": {"dir": str(tmp_path)}}})
    with pytest.raises(SystemExit) as info:
        AggregateTables().on_multirun_end(cfg)
    assert info.value.code == 1


# --------------------------------------------------------------------------------------------
# misbehaving methods fail their own rows
# --------------------------------------------------------------------------------------------


def _cell(methods: dict[str, Identifier], runs: int = 3, **kwargs: Any) -> pd.DataFrame:
    scenario = build(paper_spec(duration=120.0))
    return run_cell(scenario, methods, runs, 5, **kwargs).rows


def _values(rows: pd.DataFrame, method: str) -> np.ndarray:
    mine = rows[(rows["method"] == method) & (rows["quantity"] != "seconds")]
    return mine["value"].to_numpy()


@pytest.mark.parametrize("bad", [Mutates, MutatesShared])
def test_a_method_writing_into_the_record_fails_alone(bad: type[Identifier]) -> None:
    lsm = methods_from_names(["wang-lsm"])
    rows = _cell({bad.name: bad(), **lsm})  # the mutating method runs first
    alone = _cell(lsm)
    np.testing.assert_array_equal(_values(rows, "wang-lsm"), _values(alone, "wang-lsm"))
    assert (rows[rows["method"] == "wang-lsm"]["status"] == "ok").all()
    mine = rows[rows["method"] == bad.name]
    assert (mine["status"] == "failed").all()
    assert mine["error"].str.contains("read-only").all()


def test_a_method_calling_sys_exit_fails_alone(
    run_cli: RunCli, tmp_path: Path, faulty: None
) -> None:
    status, _, err = sweep(
        run_cli, tmp_path, "noise.snr=5,20", "methods=[test-exits,wang-lsm]", *SMALL
    )
    assert status == 0, err
    rows = pd.read_parquet(tmp_path / ROWS)
    bad = rows[rows["method"] == "test-exits"]
    assert len(bad) and (bad["status"] == "failed").all()
    assert bad["error"].str.startswith("SystemExit: 3").all()
    assert (rows[rows["method"] == "wang-lsm"]["status"] == "ok").all()
    fitness = pd.read_csv(tmp_path / "fitness.csv")
    assert list(fitness["method"]) == ["wang-lsm", "wang-lsm"]


def test_a_hanging_method_times_out(run_cli: RunCli, tmp_path: Path, faulty: None) -> None:
    status, _, err = sweep(
        run_cli,
        tmp_path,
        "noise.snr=5",
        "methods=[test-hangs,wang-lsm]",
        "method_timeout=0.5",
        *SMALL,
    )
    assert status == 0, err
    rows = pd.read_parquet(tmp_path / ROWS)
    bad = rows[rows["method"] == "test-hangs"]
    assert len(bad) and (bad["status"] == "failed").all()
    assert (bad["error"] == "timed out after 0.5 s (method_timeout)").all()
    assert (rows[rows["method"] == "wang-lsm"]["status"] == "ok").all()
    # the timer is gone once the cell is over
    assert signal.getitimer(signal.ITIMER_REAL) == (0.0, 0.0)
    assert signal.getsignal(signal.SIGALRM) in (signal.SIG_DFL, signal.default_int_handler, None)
    status, _, err = run_cli(["sweep", "method_timeout=-1", "runs=2"])
    assert status == 2 and "method_timeout: must be > 0" in one_line_error(err, "sweep")


def test_the_time_limit_does_not_change_the_job_id_when_unset() -> None:
    base = {"runs": 3, "method_timeout": None}
    assert config.run_id(base) == config.run_id({"runs": 3})
    assert config.run_id({**base, "method_timeout": 5.0}) != config.run_id(base)


def test_infinite_parameters_are_a_failed_run() -> None:
    rows = _cell({"test-infinite": Infinite()})
    a1 = rows[rows["quantity"] == "a1"].set_index("run")
    assert a1.loc[0, "status"] == "failed" and a1.loc[0, "error"] == NON_FINITE
    assert (a1.loc[1:, "status"] == "ok").all()
    from hbench.tables.results import aggregate

    _, bias = aggregate(rows)
    assert np.isfinite(bias["mean"]).all()


# --------------------------------------------------------------------------------------------
# orphaned workers
# --------------------------------------------------------------------------------------------


def _children(pid: int) -> list[int]:
    out = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if int(fields[1]) == pid:
            out.append(int(stat.parent.name))
    return out


def _alive(pids: list[int]) -> list[int]:
    live = []
    for pid in pids:
        try:
            state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
        except OSError:
            continue
        if state != "Z":
            live.append(pid)
    return live


@pytest.mark.skipif(
    importlib.util.find_spec("hydra_plugins.hydra_joblib_launcher") is None
    or not Path("/proc/self/stat").exists(),
    reason="needs the joblib extra and /proc",
)
def test_joblib_workers_exit_when_the_sweep_is_killed(tmp_path: Path) -> None:
    """Each worker computes a long job; killing ``hbench sweep`` ends them within seconds."""
    proc = child(
        [
            "sweep",
            "-m",
            "hydra/launcher=joblib",
            "hydra.launcher.n_jobs=2",
            "noise.snr=5,20",
            "method=wang-lsm",
            "runs=100000",
            "scenario.duration=120",
            f"out={tmp_path}",
        ],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    deadline = time.monotonic() + 120
    while len([d for d in tmp_path.iterdir() if d.is_dir()]) < 2:
        assert time.monotonic() < deadline and proc.poll() is None
        time.sleep(0.05)
    time.sleep(1.0)  # both workers inside their job
    workers = _children(proc.pid)
    assert workers
    proc.send_signal(signal.SIGKILL)
    proc.wait(timeout=30)
    deadline = time.monotonic() + 20
    while _alive(workers) and time.monotonic() < deadline:
        time.sleep(0.1)
    left = _alive(workers)
    for pid in left:  # do not leave them behind whatever the outcome
        os.kill(pid, signal.SIGKILL)
    assert not left
    assert not list(tmp_path.rglob(DONE))  # no job finished for nobody


# --------------------------------------------------------------------------------------------
# full disks and unwritable outputs
# --------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def record(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from hbench import cli

    path = tmp_path_factory.mktemp("rec") / "rec.csv"
    assert cli.main(["simulate", "--out", str(path), "--set", "duration=120"]) == 0
    return path


def _disk_full(monkeypatch: pytest.MonkeyPatch) -> None:
    def full(fd: int) -> None:
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(atomic.os, "fsync", full)


def test_diagnose_to_a_full_disk(
    run_cli: RunCli, record: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    status, _, err = run_cli(["diagnose", str(record), "--json", "/dev/full"])
    assert status == 2
    assert "cannot write /dev/full: No space left on device" in one_line_error(err, "diagnose")
    assert Path("/dev/full").is_char_device()  # written in place, never replaced
    _disk_full(monkeypatch)
    status, _, err = run_cli(["diagnose", str(record), "--out", str(tmp_path / "rep")])
    assert status == 2
    assert "No space left on device" in one_line_error(err, "diagnose")
    assert list((tmp_path / "rep").iterdir()) == []  # no truncated report, no temporary file


def test_a_failed_write_keeps_the_old_file(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    path = atomic.write_text(tmp_path / "table.csv", "old\n")
    with pytest.raises(RuntimeError), atomic.replacing(path) as tmp:
        tmp.write_text("new, partly")
        raise RuntimeError("killed")
    _disk_full(monkeypatch)
    with pytest.raises(OutputError, match=r"cannot write .*table\.csv: No space left"):
        atomic.write_text(path, "new\n")
    assert path.read_text() == "old\n"
    assert [p.name for p in tmp_path.iterdir()] == ["table.csv"]


def test_simulate_to_a_full_disk(
    run_cli: RunCli, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    _disk_full(monkeypatch)
    out = tmp_path / "rec.parquet"
    status, _, err = run_cli(["simulate", "--out", str(out), "--set", "duration=60"])
    assert status == 2 and "No space left" in one_line_error(err, "simulate")
    assert list(tmp_path.iterdir()) == []


# --------------------------------------------------------------------------------------------
# sizes refused before work
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("argv", "words"),
    [
        (["simulate", "--out", "{tmp}/r.csv", "--set", "duration=1e9"], "would need about"),
        (["simulate", "--out", "{tmp}/r.csv", "--set", "plant.delay=100000"], "100002 states"),
        (["sweep", "runs=10000000", "out={tmp}/s"], "a job of 10000000 runs x 6 methods"),
        (["sweep", "runs=1000000000", "out={tmp}/s"], "would need about"),
        (["sweep", "plant.delay=10000", "out={tmp}/s"], "10002 states"),
    ],
)
def test_huge_sizes_are_refused_before_work(
    run_cli: RunCli, tmp_path: Path, argv: list[str], words: str
) -> None:
    argv = [a.replace("{tmp}", str(tmp_path)) for a in argv]
    status, _, err = run_cli(argv)
    assert status == 2
    assert words in one_line_error(err, argv[0])
    assert not (tmp_path / "s").exists() and not (tmp_path / "r.csv").exists()


def test_the_memory_budget_is_the_users(
    run_cli: RunCli, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from hbench.system import limits

    monkeypatch.setenv(limits.BUDGET_ENV, "1M")
    status, _, err = run_cli(["sweep", "runs=100", f"out={tmp_path}/s"])
    assert status == 2 and "more than the budget of 1 MB" in one_line_error(err, "sweep")
    monkeypatch.setenv(limits.BUDGET_ENV, "lots")
    with pytest.raises(InputError, match="HBENCH_MEMORY_BUDGET='lots'"):
        limits.budget()
    monkeypatch.delenv(limits.BUDGET_ENV)
    assert limits.budget() == limits.physical_memory() // 2


def test_diagnose_refuses_a_long_record_at_once(run_cli: RunCli, tmp_path: Path) -> None:
    from hbench.diagnose.cli import MAX_SAMPLES

    n = (MAX_SAMPLES // 5 + 1) * 5
    rng = np.random.default_rng(0)
    x = np.repeat(rng.standard_normal(n // 5), 5)
    path = tmp_path / "long.csv"
    pd.DataFrame({"t": np.arange(n) * 0.1, "x": x, "y": rng.standard_normal(n)}).to_csv(
        path, index=False
    )
    status, _, err = run_cli(["diagnose", str(path)])
    assert status == 2
    assert f"{n} fast samples, more than the {MAX_SAMPLES}" in one_line_error(err, "diagnose")


# --------------------------------------------------------------------------------------------
# bad input: one line
# --------------------------------------------------------------------------------------------


def test_simulate_refuses_a_negative_seed_and_two_noise_levels(
    run_cli: RunCli, tmp_path: Path
) -> None:
    out = str(tmp_path / "r.csv")
    status, _, err = run_cli(["simulate", "--out", out, "--seed", "-1"])
    assert status == 2 and "--seed must be >= 0" in one_line_error(err, "simulate")
    argv = ["simulate", "--out", out, "--set", "noise.snr=5", "--set", "noise.sigma2=0.01"]
    status, _, err = run_cli(argv)
    assert status == 2 and "both given" in one_line_error(err, "simulate")
    # one level alone replaces the preset's
    status, _, err = run_cli(["simulate", "--out", out, "--set", "noise.snr=5"])
    assert status == 0, err


def test_an_output_under_proc_is_refused_before_work(run_cli: RunCli, record: Path) -> None:
    status, _, err = run_cli(["diagnose", str(record), "--json", "/proc/out.json"])
    assert status == 2
    line = one_line_error(err, "diagnose")
    assert "cannot create files in /proc" in line and "no such file" not in line


def test_a_truncated_plant_log_names_the_columns_it_needs(tmp_path: Path) -> None:
    from hbench.io.readers import read_record

    src = sorted((REPO.parent / "shared/data/stictiongpt/stiction").glob("*.txt"))
    if not src:
        pytest.skip("the plant logs of ../shared are not here")
    path = tmp_path / "cut.txt"
    path.write_bytes(src[0].read_bytes()[:3000])
    with pytest.raises(InputError) as info:
        read_record(path)
    text = str(info.value)
    assert "the first 5 of the 9 columns are needed" in text and "truncated?" in text
    assert text.count(",") == 4  # the five columns named, not nine


def test_a_refused_record_gets_one_line_and_no_warning(run_cli: RunCli, tmp_path: Path) -> None:
    rng = np.random.default_rng(1)
    n = 1000
    path = tmp_path / "huge.csv"
    pd.DataFrame(
        {
            "t": np.arange(n) * 0.1,
            "x": np.repeat(rng.standard_normal(n // 5), 5),
            "y": rng.standard_normal(n) * 1e300,
        }
    ).to_csv(path, index=False)
    status, _, err = run_cli(["diagnose", str(path)])
    assert status == 2
    one_line_error(err, "diagnose")


def test_report_md_escapes_the_record_name(record: Path, tmp_path: Path) -> None:
    from hbench import cli

    named = tmp_path / "<script>alert(1)<script>.csv"
    named.write_bytes(record.read_bytes())
    assert cli.main(["diagnose", str(named), "--out", str(tmp_path / "rep")]) == 0
    md = (tmp_path / "rep" / "report.md").read_text()
    assert "<script>" not in md and "&lt;script&gt;alert(1)" in md


@pytest.mark.parametrize("name", ["a/b", "<b>", "..", "x..y", "", "a b", 7])
def test_plugin_names_are_checked(name: Any) -> None:
    class Odd(Identifier):
        def identify(self, record: Any, options: Any, truth: Any = None) -> Any:
            return None

    Odd.name = name
    with registered_methods("odd-names-test", Odd):
        with pytest.raises(InputError, match="is not a valid name"):
            registry().names("identifiers")


# --------------------------------------------------------------------------------------------
# time columns
# --------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def frame(record: Path) -> pd.DataFrame:
    return pd.read_csv(record)


def test_a_datetime_t_is_read_in_seconds(frame: pd.DataFrame, tmp_path: Path) -> None:
    from hbench.io.readers import read_record

    base = read_record_frame(frame, tmp_path / "plain.parquet")
    stamped = frame.assign(
        t=pd.Timestamp("2024-06-27 21:55", tz="UTC") + pd.to_timedelta(frame["t"], unit="s")
    )
    stamped.to_parquet(tmp_path / "dt.parquet", index=False)
    rec = read_record(tmp_path / "dt.parquet")
    assert rec.h == pytest.approx(base.h, rel=1e-12) and rec.p == base.p
    assert any("date-time" in n for n in rec.meta["notices"])
    np.testing.assert_array_equal(rec.y, base.y)


def test_a_unix_epoch_t_is_uniform(frame: pd.DataFrame, tmp_path: Path) -> None:
    from hbench.io.readers import read_record

    base = read_record_frame(frame, tmp_path / "plain.csv")
    epoch = frame.assign(t=1.7e9 + frame["t"])
    epoch.to_csv(tmp_path / "epoch.csv", index=False)
    rec = read_record(tmp_path / "epoch.csv")
    assert rec.h == pytest.approx(base.h, rel=1e-8) and rec.p == base.p
    # a real jump is still refused
    jump = epoch.copy()
    jump.loc[100:, "t"] += 0.01
    jump.to_csv(tmp_path / "jump.csv", index=False)
    with pytest.raises(InputError, match="is not uniform"):
        read_record(tmp_path / "jump.csv")


def read_record_frame(frame: pd.DataFrame, path: Path) -> Any:
    from hbench.io.readers import read_record

    if path.suffix == ".parquet":
        frame.to_parquet(path, index=False)
    else:
        frame.to_csv(path, index=False)
    return read_record(path)


@pytest.mark.parametrize("writer", ["hbench", "hydra"])
def test_a_sweep_on_a_full_disk_stops_with_one_line(
    run_cli: RunCli, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, writer: str
) -> None:
    """Whether hbench's files or Hydra's own (a job's .hydra/) meet the full disk."""
    if writer == "hbench":
        _disk_full(monkeypatch)
    else:
        from hydra.core import utils as hydra_core

        def full(*args: Any, **kwargs: Any) -> None:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

        monkeypatch.setattr(hydra_core, "_save_config", full)
    status, _, err = sweep(run_cli, tmp_path, "noise.snr=5,20", "method=wang-lsm", *SMALL)
    assert status == 2, err
    assert "Traceback" not in err
    errors = [line for line in err.splitlines() if "error" in line]
    assert len(errors) == 1 and "No space left on device" in errors[0]
    assert not list(tmp_path.rglob(DONE))  # nothing counts as done
    assert not list(tmp_path.rglob("*.tmp"))

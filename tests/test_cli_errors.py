"""The command line's error contract: exit 2 and one line on stderr for bad input; clean stdout.

Bad ``--set`` values (``p=2.5``, ``p=abc``, ``plant.delay=abc`` ...), bad output paths (a folder
for a file, a path under a file) and argparse's own errors each give one line
``hbench CMD: error: ...``; ``diagnose --json -`` writes nothing but the JSON on stdout.
"""

from __future__ import annotations

import copy
import json
import os
import re
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from hbench import cli
from hbench.errors import InputError
from hbench.io.readers import read_record
from hbench.sim import scenarios

RunCli = Callable[[list[str]], tuple[int, str, str]]


def _one_line_error(stderr: str, command: str) -> str:
    assert "Traceback" not in stderr
    lines = stderr.splitlines()
    assert len(lines) == 1, stderr
    assert lines[0].startswith(f"hbench {command}: error: "), stderr
    return lines[0]


@pytest.fixture(scope="module")
def record(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A short simulated record that ``diagnose`` accepts (200 slow samples)."""
    path = tmp_path_factory.mktemp("rec") / "rec.csv"
    assert cli.main(["simulate", "--out", str(path), "--set", "duration=120"]) == 0
    return path


@pytest.fixture
def no_diagnosis(monkeypatch: pytest.MonkeyPatch) -> None:
    """Fail the test if ``diagnose`` starts the work (output paths are checked before it)."""
    from hbench.diagnose import validate

    def refuse(*args: object, **kwargs: object) -> None:
        raise AssertionError("the diagnosis ran before the output path was checked")

    monkeypatch.setattr(validate, "diagnose", refuse)


# --------------------------------------------------------------------------- diagnose --json -


def test_diagnose_json_to_stdout_is_only_json(run_cli: RunCli, record: Path) -> None:
    status, stdout, stderr = run_cli(["diagnose", str(record), "--json", "-"])
    assert status == 0, stderr
    assert json.loads(stdout)["record"] == str(record)  # the whole of stdout is the JSON
    assert "cause:" in stderr and "validation fit" in stderr  # the summary went to stderr


# --------------------------------------------------------------------------- output paths


@pytest.mark.parametrize(
    ("option", "target", "words"),
    [
        pytest.param("--json", "folder", ["--json", "is a folder"], id="json-is-a-folder"),
        pytest.param("--json", "file/d.json", ["--json", "not a folder"], id="json-under-a-file"),
        pytest.param("--out", "file", ["--out", "is a file"], id="out-is-a-file"),
        pytest.param("--out", "file/rep", ["--out", "not a folder"], id="out-under-a-file"),
    ],
)
def test_diagnose_bad_output_path_is_refused_before_the_work(
    run_cli: RunCli,
    record: Path,
    tmp_path: Path,
    no_diagnosis: None,
    option: str,
    target: str,
    words: list[str],
) -> None:
    (tmp_path / "folder").mkdir()
    (tmp_path / "file").write_text("")
    status, stdout, stderr = run_cli(["diagnose", str(record), option, str(tmp_path / target)])
    assert status == 2
    assert stdout == ""
    line = _one_line_error(stderr, "diagnose")
    for word in words:
        assert word in line


@pytest.mark.skipif(os.geteuid() == 0, reason="root writes anywhere")
def test_diagnose_unwritable_folder_is_refused(
    run_cli: RunCli, record: Path, tmp_path: Path, no_diagnosis: None
) -> None:
    locked = tmp_path / "locked"
    locked.mkdir(mode=0o500)
    try:
        status, _, stderr = run_cli(["diagnose", str(record), "--json", str(locked / "d.json")])
    finally:
        locked.chmod(0o700)
    assert status == 2
    assert "permission denied" in _one_line_error(stderr, "diagnose")


def test_simulate_creates_missing_parent_folders(run_cli: RunCli, tmp_path: Path) -> None:
    """Like ``reproduce --out`` and ``report --out``, missing folders are created."""
    out = tmp_path / "a" / "b" / "s.csv"
    status, _, stderr = run_cli(["simulate", "--out", str(out), "--set", "duration=30"])
    assert status == 0, stderr
    assert read_record(out).p == 5


@pytest.mark.parametrize(
    ("target", "words"),
    [
        pytest.param("folder", ["is a folder"], id="a-folder"),
        pytest.param("file/s.csv", ["not a folder"], id="under-a-file"),
    ],
)
def test_simulate_bad_output_path(
    run_cli: RunCli, tmp_path: Path, target: str, words: list[str]
) -> None:
    (tmp_path / "folder").mkdir()
    (tmp_path / "file").write_text("")
    status, stdout, stderr = run_cli(["simulate", "--out", str(tmp_path / target)])
    assert status == 2
    assert stdout == ""
    line = _one_line_error(stderr, "simulate")
    for word in ["--out", *words]:
        assert word in line


def test_simulate_unwritable_suffix_is_refused_before_simulating(
    run_cli: RunCli, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """``--out x.txt`` is refused before any simulation work (it was refused only after it)."""
    import hbench.sim.simulate

    def no_simulation(*args: object, **kwargs: object) -> None:
        raise AssertionError("simulate() ran before the output suffix was checked")

    monkeypatch.setattr(hbench.sim.simulate, "simulate", no_simulation)
    status, stdout, stderr = run_cli(["simulate", "--out", str(tmp_path / "x.txt")])
    assert status == 2
    assert stdout == ""
    line = _one_line_error(stderr, "simulate")
    assert "'.txt'" in line and ".csv" in line
    assert not (tmp_path / "x.txt").exists()


def test_path_errors_of_a_command_are_one_line(
    run_cli: RunCli, monkeypatch: pytest.MonkeyPatch
) -> None:
    """An OS error about a named path (a command's output folder) is bad input, not a crash."""

    def denied(args: object) -> int:
        raise PermissionError(13, "Permission denied", "/somewhere/out")

    monkeypatch.setattr(cli, "_cmd_plugins", denied)
    status, _, stderr = run_cli(["plugins"])
    assert status == 2
    assert "/somewhere/out: Permission denied" in _one_line_error(stderr, "plugins")


# --------------------------------------------------------------------------- --set values

BAD_SETTINGS = [
    pytest.param("p=2.5", "p", "2.5", id="p-fraction"),
    pytest.param("p=abc", "p", "'abc'", id="p-text"),
    pytest.param("p=true", "p", "True", id="p-boolean"),
    pytest.param("plant.delay=2.5", "plant.delay", "2.5", id="delay-fraction"),
    pytest.param("plant.delay=abc", "plant.delay", "'abc'", id="delay-text"),
    pytest.param("controller.delay=abc", "controller.delay", "'abc'", id="controller-delay"),
    pytest.param("reference.order=2.5", "reference.order", "2.5", id="order-fraction"),
    pytest.param("reference.burn_in=abc", "reference.burn_in", "'abc'", id="burn-in-text"),
    pytest.param("reference.per_run=abc", "reference.per_run", "'abc'", id="flag-text"),
    pytest.param("controller.kp=abc", "controller.kp", "'abc'", id="gain-text"),
    pytest.param("T=abc", "T", "'abc'", id="period-text"),
    pytest.param("duration=abc", "duration", "'abc'", id="duration-text"),
    pytest.param("noise.sigma2=true", "noise.sigma2", "True", id="sigma2-boolean"),
    pytest.param("reference.band=abc", "reference.band", "'abc'", id="band-text"),
    pytest.param("reference.band=[0,a]", "reference.band", "'a'", id="band-entry-text"),
]


@pytest.mark.parametrize(("setting", "key", "value"), BAD_SETTINGS)
def test_simulate_bad_set_value(
    run_cli: RunCli, tmp_path: Path, setting: str, key: str, value: str
) -> None:
    out = tmp_path / "s.csv"
    argv = ["simulate", "--out", str(out), "--set", "duration=30", "--set", setting]
    status, stdout, stderr = run_cli(argv)
    assert status == 2
    assert stdout == ""
    line = _one_line_error(stderr, "simulate")
    assert f" {key} must be" in line and value in line
    assert not out.exists()


STUCK_VALVE = ["--set", "nonlinearity.name=stiction", "--set", "nonlinearity.S=0.2"]


def test_simulate_snr_of_an_actuator_that_never_moves_is_one_line(tmp_path: Path) -> None:
    """The review's repro, as a user runs it (a subprocess, so a leaked numpy warning shows):
    exit 2, one line naming the cause, no RuntimeWarning, no "choose a larger SNR"."""
    out = tmp_path / "s.csv"
    argv = ["simulate", "--out", str(out), *STUCK_VALVE, "--set", "noise.snr=50"]
    proc = subprocess.run(
        [sys.executable, "-m", "hbench.cli", *argv], capture_output=True, text=True, timeout=120
    )
    assert proc.returncode == 2, proc.stderr
    assert proc.stdout == ""
    line = _one_line_error(proc.stderr, "simulate")
    assert "RuntimeWarning" not in line and "choose a larger SNR" not in line
    assert "noise-free output is zero in 1 of run 0:" in line
    assert "actuator never moves" in line and "stiction S=0.2" in line
    assert "an SNR cannot be set" in line
    assert not out.exists()


def test_simulate_sigma2_of_an_actuator_that_never_moves_warns(
    run_cli: RunCli, tmp_path: Path
) -> None:
    """With sigma2 the noise-only record is written (legal data), with a one-line warning
    saying why its SNR is 0 (it printed "SNR = 0" and nothing else)."""
    out = tmp_path / "s.csv"
    argv = ["simulate", "--out", str(out), *STUCK_VALVE, "--set", "nonlinearity.S=0.5"]
    status, _, stderr = run_cli([*argv, "--set", "noise.sigma2=0.001"])
    assert status == 0, stderr
    warning, wrote = stderr.strip().splitlines()
    assert warning.startswith("hbench simulate: warning: scenario ")
    assert re.search(
        r"actuator never moves .*noise only \(SNR = 0\) \(ZeroOutputWarning\)$", warning
    )
    assert wrote.startswith("wrote ") and wrote.endswith("SNR = 0)")
    assert out.exists()


@pytest.mark.parametrize("setting", ["p=5.0", "plant.delay=4.0", "reference.band=[0,1e-1]"])
def test_simulate_integer_valued_floats_are_taken(
    run_cli: RunCli, tmp_path: Path, setting: str
) -> None:
    out = tmp_path / "s.csv"
    status, _, stderr = run_cli(
        ["simulate", "--out", str(out), "--set", "duration=30", "--set", setting]
    )
    assert status == 0, stderr
    assert read_record(out).p == 5


@pytest.mark.parametrize("setting", ["p=2.5", "p=abc", "plant.delay=abc"])
def test_reproduce_bad_set_value_before_any_work(
    run_cli: RunCli, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, setting: str
) -> None:
    from hbench.tables import results

    def refuse(*args: object, **kwargs: object) -> None:
        raise AssertionError("the reproduction started")

    monkeypatch.setattr(results, "new_output_dir", refuse)
    argv = ["reproduce", "--runs", "2", "--out", str(tmp_path / "r"), "--set", setting]
    status, _, stderr = run_cli(argv)
    assert status == 2
    key, value = setting.split("=")
    line = _one_line_error(stderr, "reproduce")
    assert f" {key} must be an integer" in line and value in line


@pytest.mark.parametrize(
    ("value", "expected"),
    [(5, 5), (5.0, 5), ("5", 5), ("5.0", 5), (2.5, None), ("abc", None), (True, None)],
)
def test_check_value_integers(value: object, expected: int | None) -> None:
    if expected is None:
        with pytest.raises(InputError, match=r"^x must be an integer, got "):
            scenarios.check_value("x", "int", value)
    else:
        result = scenarios.check_value("x", "int", value)
        assert result == expected and type(result) is int


def test_build_names_the_bad_key(make_spec: Callable[..., dict]) -> None:
    with pytest.raises(InputError, match=r"^p must be an integer, got 2\.5$"):
        scenarios.build(make_spec(p=2.5))
    with pytest.raises(InputError, match=r"^plant\.delay must be an integer, got 'x'$"):
        scenarios.build(make_spec({"plant.delay": "x"}))
    # the paper plant's delay may be None (``int | None``: delay_s seconds then)
    assert scenarios.build(make_spec({"plant.delay": None})).plant.delay is None


# --------------------------------------------------------------------------- argparse


@pytest.mark.parametrize(
    ("argv", "command", "words"),
    [
        pytest.param(["reproduce", "--runs", "abc"], "reproduce", ["--runs", "'abc'"], id="type"),
        pytest.param(["diagnose"], "diagnose", ["record"], id="missing-argument"),
        pytest.param(
            ["simulate", "--out", "x.csv", "--bogus"], "simulate", ["--bogus"], id="extra"
        ),
        pytest.param(["inspect", "r.csv", "--p", "2.5"], "inspect", ["--p", "'2.5'"], id="int-p"),
    ],
)
def test_argparse_errors_are_one_line(
    capsys: pytest.CaptureFixture[str], argv: list[str], command: str, words: list[str]
) -> None:
    with pytest.raises(SystemExit) as info:
        cli.main(argv)
    assert info.value.code == 2
    out, err = capsys.readouterr()
    assert out == ""
    line = _one_line_error(err, command)
    for word in [*words, f"'hbench {command} --help'"]:
        assert word in line


def test_argparse_error_without_command_is_one_line(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as info:
        cli.main(["nope"])
    assert info.value.code == 2
    lines = capsys.readouterr().err.splitlines()
    assert len(lines) == 1 and lines[0].startswith("hbench: error: ") and "'nope'" in lines[0]


def test_help_still_prints_usage_and_options(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as info:
        cli.main(["reproduce", "--help"])
    assert info.value.code == 0
    out = capsys.readouterr().out
    assert out.startswith("usage: hbench reproduce")
    assert "--runs RUNS" in out and "options:" in out


def test_a_closed_pipe_ends_quietly(monkeypatch: pytest.MonkeyPatch) -> None:
    """``hbench plugins | head -1``: once the reader has gone, the command stops without a
    BrokenPipeError traceback (status 141, as a command killed by SIGPIPE)."""
    import io
    import os

    from hbench import cli

    read, write = os.pipe()
    os.close(read)  # the reader is gone: every write fails with EPIPE
    stream = io.TextIOWrapper(io.FileIO(write, "w"), write_through=True)
    monkeypatch.setattr("sys.stdout", stream)
    try:
        assert cli.main(["plugins"]) == 141
    finally:
        monkeypatch.undo()
        try:
            stream.close()
        except OSError:
            pass


@pytest.mark.parametrize("command", ["reproduce", "report"])
def test_reproduce_and_report_check_out_before_any_work(
    run_cli, tmp_path: Path, command: str
) -> None:
    afile = tmp_path / "afile"
    afile.write_text("x")
    argv = ["reproduce", "--runs", "2"] if command == "reproduce" else ["report", str(tmp_path)]
    for out, said in ((afile, "is a file, not a folder"), (afile / "sub", "is not a folder")):
        status, _, err = run_cli([*argv, "--out", str(out)])
        assert status == 2 and said in err and len(err.strip().splitlines()) == 1, err


@pytest.mark.parametrize(
    ("key", "value"),
    [
        ("p", np.int64(5)),
        ("T", np.float64(0.6)),
        ("T", 1),  # an int for a float
        ("reference.per_run", 1),  # YAML's 0/1 flags
        ("reference.per_run", np.bool_(True)),
        ("reference.band", np.array([0.0, 0.3])),
        ("plant.delay", None),  # optional: delay_s then
    ],
)
def test_valid_values_of_every_kind_are_still_taken(key: str, value: object) -> None:
    """The type checks refuse bad values only: numpy scalars, ints for floats, 0/1 flags,
    arrays for number lists and None where a parameter is optional are taken as before."""
    spec = copy.deepcopy(scenarios.PAPER_SECTION6)
    scenarios.set_dotted(spec, key, value)
    scenarios.build(spec)


def test_the_scenarios_periods_are_floats_whatever_number_gave_them() -> None:
    """``T`` and ``duration`` are floats in the scenario, as before the checks (``T=1``)."""
    spec = copy.deepcopy(scenarios.PAPER_SECTION6)
    spec.update(T=1, duration=np.int64(60))
    sc = scenarios.build(spec)
    assert type(sc.T) is float and type(sc.duration) is float and type(sc.p) is int


def test_one_line_warnings_keeps_filters_added_inside() -> None:
    """Only ``showwarning`` is swapped: a filter a module adds inside (at its import) outlives
    the block (``catch_warnings`` threw it away, so a second in-process call warned again)."""
    import warnings

    from hbench.errors import one_line_warnings

    before = warnings.showwarning
    with warnings.catch_warnings():  # this test's own sandbox for the filters
        with one_line_warnings("x"):
            warnings.filterwarnings("ignore", message="added inside")
        assert warnings.showwarning is before
        assert any(f[1] is not None and f[1].pattern == "added inside" for f in warnings.filters)


def test_one_line_warnings_format(capsys: pytest.CaptureFixture[str]) -> None:
    import warnings

    from hbench.errors import one_line_warnings

    with warnings.catch_warnings(), one_line_warnings("simulate"):
        warnings.simplefilter("always")
        warnings.warn("two\n lines", UserWarning, stacklevel=1)
    assert capsys.readouterr().err == "hbench simulate: warning: two lines (UserWarning)\n"

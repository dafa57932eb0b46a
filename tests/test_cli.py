"""Tests of the ``hbench`` command line (:mod:`hbench.cli`).

Most tests call :func:`hbench.cli.main` in-process (its return value is the exit status); one
runs the real interpreter to check the status and stderr a user sees.
"""

from __future__ import annotations

import json
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from hbench import cli
from hbench.io.readers import read_record

RunCli = Callable[[list[str]], tuple[int, str, str]]


def _simulate(run_cli: RunCli, out: Path, *settings: str) -> tuple[int, str, str]:
    """``hbench simulate --out OUT --set S1 --set S2 ...``."""
    argv = ["simulate", "--out", str(out)]
    for item in settings:
        argv += ["--set", item]
    return run_cli(argv)


def test_simulate_then_inspect(run_cli: RunCli, tmp_path: Path) -> None:
    out = tmp_path / "F.csv"
    status, stdout, stderr = run_cli(["simulate", "--out", str(out)])
    assert status == 0
    assert out.is_file()
    assert stderr.startswith("wrote ") and "p = 5" in stderr

    status, stdout, _ = run_cli(["inspect", str(out)])
    assert status == 0
    info = json.loads(stdout)
    assert info["p"] == 5
    assert info["n_slow"] == 833  # floor(500 s / 0.6 s)
    assert info["n_fast"] == 833 * 5
    assert info["runs"] == 1
    assert info["has_r"] is True
    assert info["h"] == pytest.approx(0.12, rel=1e-12)  # h read back from a printed time column


def test_simulate_seed_is_reproducible(run_cli: RunCli, tmp_path: Path) -> None:
    paths = [tmp_path / f"{name}.csv" for name in ("a", "b", "c")]
    for path, seed in zip(paths, ("7", "7", "8"), strict=True):
        assert run_cli(["simulate", "--out", str(path), "--seed", seed])[0] == 0
    a, b, c = (read_record(p) for p in paths)
    assert np.array_equal(a.y, b.y) and np.array_equal(a.x, b.x)
    assert not np.array_equal(a.y, c.y)


def test_simulate_set_changes_the_scenario(run_cli: RunCli, tmp_path: Path) -> None:
    out = tmp_path / "p4.csv"
    status, _, _ = _simulate(
        run_cli, out, "p=4", "duration=60", "nonlinearity.name=stiction", "nonlinearity.S=0.2"
    )
    assert status == 0
    rec = read_record(out)
    assert rec.p == 4 and rec.n_slow == 100


BAD_INPUT = [
    pytest.param(
        ["--set", "plant.name=nope"], ["unknown plant 'nope'", "paper"], id="unknown-plugin"
    ),
    pytest.param(
        ["--set", "plant.name=discrete", "--set", "plant.a=[1,-2.5,1.2]"],
        ["plant", "unstable"],
        id="unstable-plant",
    ),
    pytest.param(["--set", "controller.kp=5"], ["closed loop", "unstable"], id="unstable-loop"),
    pytest.param(["--set", "nonlinearity.wdith=3"], ["'wdith'"], id="unknown-parameter"),
    pytest.param(["--set", "p5"], ["KEY=VALUE", "'p5'"], id="malformed-set"),
]


def _assert_one_line_error(stderr: str, command: str = "simulate") -> str:
    assert "Traceback" not in stderr
    lines = stderr.splitlines()
    assert len(lines) == 1, stderr
    assert lines[0].startswith(f"hbench {command}: error:")
    return lines[0]


@pytest.mark.parametrize(("args", "words"), BAD_INPUT)
def test_simulate_bad_input(
    run_cli: RunCli, tmp_path: Path, args: list[str], words: list[str]
) -> None:
    out = tmp_path / "bad.csv"
    status, stdout, stderr = run_cli(["simulate", "--out", str(out), *args])
    assert status == 2
    assert stdout == ""
    line = _assert_one_line_error(stderr)
    for word in words:
        assert word in line
    assert not out.exists()


def test_bad_input_exit_status_from_the_interpreter(tmp_path: Path) -> None:
    argv = ["simulate", "--out", str(tmp_path / "x.csv"), "--set", "plant.name=nope"]
    proc = subprocess.run(
        [sys.executable, "-m", "hbench.cli", *argv], capture_output=True, text=True, timeout=120
    )
    assert proc.returncode == 2
    _assert_one_line_error(proc.stderr)


def test_inspect_missing_file(run_cli: RunCli, tmp_path: Path) -> None:
    status, _, stderr = run_cli(["inspect", str(tmp_path / "missing.csv")])
    assert status == 2
    assert "missing.csv" in _assert_one_line_error(stderr, "inspect")


def test_help_lists_commands(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as info:
        cli.main(["--help"])
    assert info.value.code == 0
    out = capsys.readouterr().out
    for command in ("plugins", "inspect", "simulate"):
        assert command in out


def test_no_command_prints_help(run_cli: RunCli) -> None:
    status, out, _ = run_cli([])
    assert status == 0
    assert "simulate" in out


# --------------------------------------------------------------------------- noise level


def test_simulate_sigma2_in_exponent_notation(run_cli: RunCli, tmp_path: Path) -> None:
    """'1e-3' is a string to YAML 1.1 (no dot); the paper's own noise level must still work."""
    status, _, stderr = _simulate(run_cli, tmp_path / "s.csv", "noise.sigma2=1e-3")
    assert status == 0, stderr


def test_simulate_non_numeric_sigma2_is_bad_input(run_cli: RunCli, tmp_path: Path) -> None:
    status, _, stderr = _simulate(run_cli, tmp_path / "s.csv", "noise.sigma2=abc")
    assert status == 2
    line = _assert_one_line_error(stderr)
    assert "sigma2" in line and "'abc'" in line


def test_simulate_changing_noise_model_keeps_noise(run_cli: RunCli, tmp_path: Path) -> None:
    """--set noise.name=white keeps the noise level (it is not a parameter of the old model)."""
    white, quiet = tmp_path / "white.csv", tmp_path / "quiet.csv"
    assert _simulate(run_cli, white, "noise.name=white")[0] == 0
    assert _simulate(run_cli, quiet, "noise.name=white", "noise.sigma2=0")[0] == 0
    assert not np.array_equal(read_record(white).y, read_record(quiet).y)


def test_a_command_module_that_cannot_be_imported_is_an_error(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """A missing command module fails loudly instead of the command silently vanishing."""
    monkeypatch.setattr(cli, "COMMAND_MODULES", (*cli.COMMAND_MODULES, "hbench.no_such_command"))
    with pytest.raises(ModuleNotFoundError, match=r"hbench\.no_such_command"):
        cli.build_parser()

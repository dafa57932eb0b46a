"""``hbench sweep``: the Hydra app end to end (small runs, short records).

Sweeps run in-process through :func:`hbench.cli.main` with the basic launcher unless a test says
otherwise; each writes into its own ``tmp_path`` folder (``out=...``).
"""

from __future__ import annotations

import contextlib
import importlib.util
import io
import json
import os
import subprocess
import sys
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import pytest

from hbench.errors import InputError
from hbench.ident.identifiers import Identifier
from hbench.plugins import registry
from hbench.sweep import config
from hbench.sweep.app import EXAMPLE, validate
from hbench.sweep.callbacks import aggregate_dir
from hbench.sweep.jobs import DONE, ROW_COLUMNS, ROWS
from hbench.tables import results
from tests.helpers import BIAS_COLUMNS, FITNESS_COLUMNS, registered_methods

pytestmark = pytest.mark.filterwarnings(f"ignore:{config.SCHEMA_NOTE}:UserWarning")

RunCli = Callable[[Sequence[str]], tuple[int, str, str]]
#: Small and fast: 5 runs of 120 s records.
SMALL = ("runs=5", "scenario.duration=120")


def sweep(
    run_cli: RunCli, out: Path, *overrides: str, multirun: bool = True
) -> tuple[int, str, str]:
    argv = ["sweep", *(["-m"] if multirun else []), *overrides, f"out={out}"]
    return run_cli(argv)


def markers(root: Path) -> dict[str, int]:
    """run id -> mtime (ns) of its DONE marker."""
    return {json.loads(m.read_text())["run_id"]: m.stat().st_mtime_ns for m in root.rglob(DONE)}


# --------------------------------------------------------------------------------------------
# a 3 x 2 x 2 multirun
# --------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def grid(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[Path, str, str]]:
    """noise.snr = 2, 5, 20 x scenario.p = 4, 5 x method = wang-lsm, bai-fu (12 jobs)."""
    from hbench import cli

    out = tmp_path_factory.mktemp("grid")
    err, std = io.StringIO(), io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(std):
        status = cli.main(
            [
                "sweep",
                "-m",
                "noise.snr=2,5,20",
                "scenario.p=4,5",
                "method=wang-lsm,bai-fu",
                *SMALL,
                f"out={out}",
            ]
        )
    assert status == 0, err.getvalue()
    yield out, std.getvalue(), err.getvalue()


def test_grid_writes_the_contracts_tables(grid: tuple[Path, str, str]) -> None:
    out, stdout, _ = grid
    fitness = pd.read_csv(out / "fitness.csv")
    bias = pd.read_csv(out / "bias.csv")
    # the contract's columns, and the target SNR of these SNR cells after sigma2 (as in the
    # Markdown and LaTeX files)
    assert list(fitness.columns) == [*FITNESS_COLUMNS[:5], "snr_target", *FITNESS_COLUMNS[5:]]
    assert list(bias.columns) == [*BIAS_COLUMNS[:5], "snr_target", *BIAS_COLUMNS[5:]]
    assert len(fitness) == 3 * 2 * 2  # one row per (method, p, snr) cell
    assert set(fitness["method"]) == {"wang-lsm", "bai-fu"} and set(fitness["p"]) == {4, 5}
    assert fitness["sigma2"].isna().all()  # SNR cells: the level varies by run
    assert sorted(np.round(fitness["snr_mean"]).unique()) == [2, 5, 20]
    # the paper plant has a1, a2, b2 (b1 = 1): three bias rows per cell
    assert len(bias) == 3 * len(fitness)
    assert set(bias["parameter"]) == {"a1", "a2", "b2"}
    for name in ("fitness", "bias"):
        for ext in ("md", "tex"):
            assert (out / f"{name}.{ext}").stat().st_size > 0
    assert str(out / "fitness.csv") in stdout  # where the tables are


def test_grid_n_counts_the_ok_runs(grid: tuple[Path, str, str]) -> None:
    out, _, _ = grid
    rows = pd.read_parquet(out / ROWS)
    assert list(rows.columns) == list(ROW_COLUMNS)
    fit = rows[rows["quantity"] == "fitness"]
    per_cell = fit.groupby(["method", "p", "snr_target"])["run"].apply(sorted)
    assert len(per_cell) == 12 and all(r == [0, 1, 2, 3, 4] for r in per_cell)
    ok = fit[fit["status"] == "ok"].groupby(["method", "p", "snr_target"]).size()
    fitness = pd.read_csv(out / "fitness.csv")
    fitness["snr_target"] = np.round(fitness["snr_mean"]).astype(float)
    n = fitness.set_index(["method", "p", "snr_target"])["n"]
    assert n.to_dict() == ok.reindex(n.index, fill_value=0).to_dict()
    assert not rows.duplicated(["cell", "method", "run", "quantity"]).any()


def test_grid_job_folders(grid: tuple[Path, str, str]) -> None:
    out, _, stderr = grid
    jobs = sorted(m.parent for m in out.rglob(DONE))
    assert len(jobs) == 12
    for job in jobs:
        assert {"rows.parquet", "config.yaml", "provenance.json", DONE} <= {
            p.name for p in job.iterdir()
        }
        run_id = json.loads((job / DONE).read_text())["run_id"]
        assert job.name == run_id  # folders named by the run id
        prov = json.loads((job / "provenance.json").read_text())
        assert prov["seeds"]["run_id"] == run_id and prov["config"]["runs"] == 5
    assert "12/12 jobs finished" in stderr and "5/5 runs" in stderr  # progress


def test_every_method_of_a_cell_sees_the_same_data(grid: tuple[Path, str, str]) -> None:
    rows = pd.read_parquet(grid[0] / ROWS)
    by = rows.groupby(["p", "snr_target"])
    assert (by["cell"].nunique() == 1).all() and (by["seed"].nunique() == 1).all()
    snr = rows[rows["quantity"] == "fitness"].pivot_table(
        index=["p", "snr_target", "run"], columns="method", values="snr"
    )
    assert (snr["wang-lsm"] == snr["bai-fu"]).all()  # the realised SNR: the same records


def test_readme_example_validates_to_54_jobs() -> None:
    assert validate(EXAMPLE.split()[3:], multirun=True) == 54
    assert validate(["experiment=snr_p_delay"], multirun=True) == 54


# --------------------------------------------------------------------------------------------
# reliability (1): a method that raises, a cell that fails as a whole
# --------------------------------------------------------------------------------------------


class Boom(Identifier):
    """Raises at p = 4; elsewhere it is wang-lsm."""

    name = "boom"

    def identify(self, record: Any, options: Any, truth: Any = None) -> Any:
        if record.p == 4:
            raise RuntimeError("boom at p = 4")
        return registry().get("identifiers", "wang-lsm")().identify(record, options, truth)


@pytest.fixture
def boom() -> Iterator[str]:
    with registered_methods("boom-test", Boom):
        yield Boom.name


def test_a_raising_method_gives_failed_rows_and_the_sweep_goes_on(
    run_cli: RunCli, tmp_path: Path, boom: str
) -> None:
    # basic launcher: the throwaway plugin lives in this process only
    status, out, err = sweep(
        run_cli, tmp_path, "scenario.p=4,5", f"methods=[wang-lsm,{boom}]", *SMALL
    )
    assert status == 0, err
    rows = pd.read_parquet(tmp_path / ROWS)
    bad = rows[(rows["method"] == boom) & (rows["p"] == 4)]
    assert len(bad) and (bad["status"] == "failed").all()
    assert bad["error"].str.contains("RuntimeError: boom at p = 4").all()
    assert (rows[rows["method"] == "wang-lsm"]["status"] != "failed").all()
    assert (rows[(rows["method"] == boom) & (rows["p"] == 5)]["status"] != "failed").all()
    fitness = pd.read_csv(tmp_path / "fitness.csv")
    cells = set(zip(fitness["method"], fitness["p"], strict=True))
    assert cells == {("wang-lsm", 4), ("wang-lsm", 5), (boom, 5)}
    assert "1 method x cell pairs failed" in out
    # the job says which method gave no estimate at all, and why
    assert f"WARNING {boom}: no estimate in 5 runs (failed 5): RuntimeError: boom at p = 4" in err
    assert "WARNING wang-lsm" not in err


def test_a_failing_cell_gives_failed_rows_for_every_method(run_cli: RunCli, tmp_path: Path) -> None:
    # kp = 5 makes the closed loop unstable: the whole cell raises inside the job
    status, out, err = sweep(
        run_cli, tmp_path, "controller.kp=0.1,5", "methods=[wang-lsm,bai-fu]", *SMALL
    )
    assert status == 0, err
    assert "cell FAILED: UnstableError" in err and "failed" in out
    rows = pd.read_parquet(tmp_path / ROWS)
    failed = rows[rows["status"] == "failed"]
    assert set(failed["method"]) == {"wang-lsm", "bai-fu"}
    assert failed["error"].str.contains("closed loop .* is unstable").all()
    assert set(failed["run"]) == set(range(5))
    assert len(markers(tmp_path)) == 2
    fitness = pd.read_csv(tmp_path / "fitness.csv")
    assert len(fitness) == 2 and (fitness["n"] > 0).all()  # the stable cell, both methods


# --------------------------------------------------------------------------------------------
# reliability (2): resume
# --------------------------------------------------------------------------------------------


def test_rerun_skips_finished_jobs_without_duplication(run_cli: RunCli, tmp_path: Path) -> None:
    common = ("method=wang-lsm", *SMALL)
    status, _, err = sweep(run_cli, tmp_path, "plant.delay=0,2", *common)
    assert status == 0, err
    first = markers(tmp_path)
    tables = {n: (tmp_path / n).read_bytes() for n in ("fitness.csv", "bias.csv")}
    assert len(first) == 2

    # the same sweep again: nothing runs, the tables are unchanged
    status, _, err = sweep(run_cli, tmp_path, "plant.delay=0,2", *common)
    assert status == 0, err
    assert err.count("skipped") == 2 and "done in" not in err
    assert markers(tmp_path) == first
    assert {n: (tmp_path / n).read_bytes() for n in tables} == tables

    # an interrupted job (no DONE marker) and a wider sweep in another order: only the
    # interrupted and the new job run; job numbers change, run ids do not
    victim = next(iter(first))
    (tmp_path / victim / DONE).unlink()
    status, _, err = sweep(run_cli, tmp_path, "plant.delay=7,2,0", *common)
    assert status == 0, err
    assert err.count("skipped") == 1 and err.count("done in") == 2
    now = markers(tmp_path)
    assert len(now) == 3 and all(now[k] == first[k] for k in first if k != victim)
    rows = pd.read_parquet(tmp_path / ROWS)
    assert not rows.duplicated(["cell", "method", "run", "quantity"]).any()
    fitness = pd.read_csv(tmp_path / "fitness.csv")
    assert sorted(fitness["delay"]) == [0, 2, 7] and (fitness["n"] <= 5).all()
    old = pd.read_csv(io.BytesIO(tables["fitness.csv"]))
    new = fitness[fitness["delay"].isin([0, 2])].reset_index(drop=True)
    pd.testing.assert_frame_equal(old, new)  # recomputed job: the same numbers


def test_aggregation_counts_a_run_once_when_two_jobs_computed_it(
    run_cli: RunCli, tmp_path: Path
) -> None:
    # runs=3 and runs=5 of the same cell: runs 0-2 are the same measurement
    status, _, err = sweep(
        run_cli, tmp_path, "runs=3,5", "method=wang-lsm", "scenario.duration=120"
    )
    assert status == 0, err
    fitness = pd.read_csv(tmp_path / "fitness.csv")
    rows = pd.read_parquet(tmp_path / ROWS)
    assert len(fitness) == 1 and sorted(rows["run"].unique()) == [0, 1, 2, 3, 4]
    ok = rows[(rows["quantity"] == "fitness") & (rows["status"] == "ok")]
    assert fitness["n"].item() == len(ok) <= 5


# --------------------------------------------------------------------------------------------
# reliability (3): bit-identical tables
# --------------------------------------------------------------------------------------------


@pytest.mark.skipif(
    importlib.util.find_spec("hydra_plugins.hydra_joblib_launcher") is None,
    reason="needs the joblib extra",
)
def test_same_seed_same_bits_under_basic_and_joblib(run_cli: RunCli, tmp_path: Path) -> None:
    ov = ("noise.snr=5,20", "method=wang-lsm", "seed=7", *SMALL)
    status, _, err = sweep(run_cli, tmp_path / "basic", *ov)
    assert status == 0, err
    status, _, err = sweep(
        run_cli, tmp_path / "joblib", *ov, "hydra/launcher=joblib", "hydra.launcher.n_jobs=2"
    )
    assert status == 0, err
    for name in ("fitness.csv", "bias.csv"):
        assert (tmp_path / "basic" / name).read_bytes() == (tmp_path / "joblib" / name).read_bytes()
    # a cell's numbers do not depend on which other cells ran: {5, 20} vs {20} alone
    status, _, err = sweep(
        run_cli, tmp_path / "alone", "noise.snr=20", "method=wang-lsm", "seed=7", *SMALL
    )
    assert status == 0, err
    for name in ("fitness.csv", "bias.csv"):
        both = (tmp_path / "basic" / name).read_text().splitlines()
        alone = (tmp_path / "alone" / name).read_text().splitlines()
        assert len(alone) > 1 and set(alone) <= set(both)
        assert len(both) > len(alone)
    # and the seed matters
    status, _, err = sweep(
        run_cli, tmp_path / "seed8", "noise.snr=20", "method=wang-lsm", "seed=8", *SMALL
    )
    assert status == 0, err
    assert (tmp_path / "seed8" / "fitness.csv").read_bytes() != (
        tmp_path / "alone" / "fitness.csv"
    ).read_bytes()


# --------------------------------------------------------------------------------------------
# reliability (4): typos exit 2 with one line naming the key
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("overrides", "named"),
    [
        (["plant.delya=7"], "plant.delya"),
        (["runs=abc"], "runs"),
        (["rnus=5"], "rnus"),
        (["+foo=1"], "foo"),
        (["nonlinearity=bakclash"], "bakclash"),
        (["nonlinearity.name=bakclash"], "bakclash"),
        (["method=wang-lmx"], "wang-lmx"),
        (["methods=[wang-lmx]"], "wang-lmx"),
        (["+plant.foo=1"], "foo"),
        (["noise.snr=abc"], "noise.snr"),
        (["noise.snr=2,5"], "noise.snr"),
        (["scenario.p=0"], "scenario.p"),
        (["+method_options.wang-lsm.poold=true"], "poold"),
        (["-m", "nonlinearity=backlash,stiction", "nonlinearity.d=0.2"], "nonlinearity.d"),
        (["hydra/launcher=slurm"], "slurm"),
        (["method=[wang-lsm,bai-fu]"], "methods=[a,b]"),
    ],
)
def test_typo_exits_2_naming_the_key(
    run_cli: RunCli, tmp_path: Path, overrides: list[str], named: str
) -> None:
    status, _, err = run_cli(["sweep", *overrides, f"out={tmp_path / 'x'}"])
    assert status == 2
    lines = err.strip().splitlines()
    assert len(lines) == 1 and named in lines[0], err
    assert "Traceback" not in err and not (tmp_path / "x").exists()  # nothing launched


def test_typo_exits_2_from_the_console(tmp_path: Path) -> None:
    proc = subprocess.run(
        [sys.executable, "-m", "hbench.cli", "sweep", "-m", "scenario.p=3,5", "plant.delya=7"],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=120,
        env={**os.environ, "HYDRA_FULL_ERROR": "1"},
    )
    assert proc.returncode == 2
    assert proc.stderr.count("\n") == 1 and "'plant.delya'" in proc.stderr
    assert "did you mean plant.delay" in proc.stderr and "Traceback" not in proc.stderr
    assert not (tmp_path / "results").exists()


def test_both_noise_levels_is_an_input_error() -> None:
    with pytest.raises(InputError, match=r"noise\.sigma2 \(0\.1\) and noise\.snr \(5.*both set"):
        validate(["noise.snr=5", "noise.sigma2=0.1"])
    # a preset that fixes sigma2: the message says how to switch to the SNR
    with pytest.raises(InputError, match=r"noise\.sigma2=null"):
        validate(["experiment=paper_section6", "noise.snr=5"])
    validate(["experiment=paper_section6", "noise.snr=5", "noise.sigma2=null"])


def test_a_list_inside_a_sweep_of_a_group_is_refused_too() -> None:
    with pytest.raises(InputError, match="would merge"):
        validate(["method=[wang-lsm,bai-fu],wang-iv"], multirun=True)


def test_cfg_with_m_and_an_empty_out_exit_2(run_cli: RunCli, tmp_path: Path) -> None:
    status, _, err = run_cli(["sweep", "-m", "--cfg", "job", "scenario.p=3,5"])
    assert status == 2 and "drop -m" in err and len(err.strip().splitlines()) == 1, err
    status, _, err = run_cli(["sweep", "out=", "runs=2"])
    assert status == 2 and "out= is empty" in err and len(err.strip().splitlines()) == 1, err


@pytest.mark.parametrize("group", ["method", "nonlinearity"])
def test_a_list_for_a_config_group_is_refused_not_merged(group: str) -> None:
    """``method=[a,b]`` would merge the two options (only b's methods would run)."""
    value = {"method": "[wang-lsm,bai-fu]", "nonlinearity": "[backlash,deadband]"}[group]
    with pytest.raises(InputError, match=rf"-m {group}=a,b") as info:
        validate([f"{group}={value}"])
    assert ("methods=[a,b]" in str(info.value)) == (group == "method")
    with pytest.raises(InputError, match=r"methods=\[a,b\]"):  # the sweep hint for 'method'
        validate(["method=wang-lsm,bai-fu"])


@pytest.mark.parametrize("multirun", [False, True])
def test_an_out_that_is_a_file_exits_2(run_cli: RunCli, tmp_path: Path, multirun: bool) -> None:
    afile = tmp_path / "afile"
    afile.write_text("not a folder")
    for out, said in ((afile, "is a file, not a folder"), (afile / "sub", "is not a folder")):
        status, _, err = sweep(run_cli, out, "method=wang-lsm", *SMALL, multirun=multirun)
        assert status == 2 and said in err and len(err.strip().splitlines()) == 1, err
    # Hydra's own folder keys are held to the same rule
    key = "hydra.sweep.dir" if multirun else "hydra.run.dir"
    status, _, err = run_cli(["sweep", *(["-m"] if multirun else []), "runs=2", f"{key}={afile}"])
    assert status == 2 and "is a file, not a folder" in err, err
    assert afile.read_text() == "not a folder"


def test_a_single_run_never_overwrites_another_configs_results(
    run_cli: RunCli, tmp_path: Path
) -> None:
    status, _, err = sweep(run_cli, tmp_path, "method=bai-fu", *SMALL, multirun=False)
    assert status == 0, err
    before = {p.name: p.read_bytes() for p in tmp_path.iterdir() if p.is_file()}
    status, _, err = sweep(run_cli, tmp_path, "method=wang-lsm", *SMALL, multirun=False)
    assert status == 2 and len(err.strip().splitlines()) == 1, err
    assert "holds the finished run of another config" in err and "bai-fu" in err
    assert {p.name: p.read_bytes() for p in tmp_path.iterdir() if p.is_file()} == before
    status, _, err = sweep(run_cli, tmp_path, "method=bai-fu", *SMALL, multirun=False)
    assert status == 0 and "already done" in err  # the same config: skipped, as in a sweep
    # Hydra's own run folder is held to the same rule, and --cfg (nothing runs) is not refused
    argv = ["sweep", "method=wang-lsm", *SMALL, f"hydra.run.dir={tmp_path}"]
    status, _, err = run_cli(argv)
    assert status == 2 and "holds the finished run of another config" in err, err
    assert {p.name: p.read_bytes() for p in tmp_path.iterdir() if p.is_file()} == before
    status, out, err = run_cli(["sweep", "--cfg", "job", "method=wang-lsm", f"out={tmp_path}"])
    assert status == 0 and "wang-lsm" in out, err


# --------------------------------------------------------------------------------------------
# a single run, Ray
# --------------------------------------------------------------------------------------------


def test_single_run_aggregates_into_its_folder(run_cli: RunCli, tmp_path: Path) -> None:
    status, _, err = sweep(
        run_cli,
        tmp_path,
        "method=bai-fu",
        "plant.delay=7",
        "runs=3",
        "scenario.duration=120",
        multirun=False,
    )
    assert status == 0, err
    assert {"rows.parquet", "config.yaml", "provenance.json", DONE, "fitness.csv", "bias.csv"} <= {
        p.name for p in tmp_path.iterdir()
    }
    fitness = pd.read_csv(tmp_path / "fitness.csv")
    assert fitness[["method", "p", "delay"]].values.tolist() == [["bai-fu", 5, 7]]
    assert fitness["sigma2"].item() == 0.001
    # the tables are exactly what results.write_tables makes of the rows
    again = results.aggregate(pd.read_parquet(tmp_path / ROWS))[0]
    pd.testing.assert_frame_equal(again, fitness, check_dtype=False, atol=1e-9)
    assert aggregate_dir(tmp_path, quiet=True)  # re-aggregating is harmless


def test_ray_launcher_two_jobs(run_cli: RunCli, tmp_path: Path) -> None:
    pytest.importorskip("ray", reason="the ray extra lives in its own environment")
    pytest.importorskip("hydra_plugins.hydra_ray_launcher", reason="hydra-ray-launcher")
    status, _, err = sweep(
        run_cli,
        tmp_path,
        "noise.snr=5,20",
        "method=wang-lsm",
        *SMALL,
        "hydra/launcher=ray",
        "+hydra.launcher.ray.init.num_cpus=2",
    )
    assert status == 0, err
    assert len(markers(tmp_path)) == 2
    assert len(pd.read_csv(tmp_path / "fitness.csv")) == 2


def test_worker_processes_kept_for_the_sweep_give_the_same_bits(
    run_cli: RunCli, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Two cells with ``jobs=2`` under the basic launcher share the workers kept for the sweep
    (:func:`hbench.bench.parallel.kept_workers`): the tables are those of ``jobs=1``."""
    from hbench.bench import parallel

    ov = ("noise.snr=5,20", "method=wang-lsm", "seed=7", *SMALL, "chunk=2")
    status, _, err = sweep(run_cli, tmp_path / "one", *ov)
    assert status == 0, err

    started: list[tuple[object, ...]] = []
    pool = parallel.pool

    def counted(workers: int, *args: object) -> object:
        started.append((workers, *args))
        return pool(workers, *args)

    monkeypatch.setattr(parallel, "pool", counted)
    status, _, err = sweep(run_cli, tmp_path / "two", *ov, "jobs=2")
    assert status == 0, err
    for name in ("fitness.csv", "bias.csv"):
        one, two = (tmp_path / d / name for d in ("one", "two"))
        assert len(one.read_text().splitlines()) > 1
        assert one.read_bytes() == two.read_bytes()
    assert started == [(1,)]  # one pool of one worker for both cells, none per cell

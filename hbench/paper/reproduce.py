"""``hbench reproduce``: the paper's Section 6 example beside its published Tables 1, 2, 4 and 5.

What runs (the defaults, and why):

* The scenario is :data:`hbench.sim.scenarios.PAPER_SECTION6` (``--set KEY=VALUE`` overrides a
  key) at the noise levels of Tables 4 and 5, sigma^2 = 0, 1e-4, 5e-4, 1e-3, 5e-3, 1e-2,
  ``--runs`` Monte Carlo runs each (100 by default, as in the paper; the noise-free level needs at
  most 10: every estimate is exact there).
* Tables 1 and 2 come from one realisation at sigma^2 = 1e-3: run 0 of that level's Monte Carlo
  batch (the same realisation as Figures 4 and 5). ``V`` is the bias-compensated LSM's table of
  eq. (19) (``wang-lsm``) and the IVM's own table (``wang-iv`` with ``structure="iv"``);
  Table 2 is the LSM's ``Var{Delta w^(l)}``. The structure they select (na, tau, nb) is printed.
* The structure is then FIXED to that selection for every Monte Carlo run, as the paper does
  (it illustrates the selection once and reports a1, a2, b2 only in Table 4); ``--structure
  selected`` selects it per run instead.
* Methods: ``wang-lsm`` and ``wang-iv`` with ``pooled=True`` (the denominator from every quiet
  phase nb+1..p: the paper's step (iii) re-estimates A "by taking nb in place of n0_b"; with
  phase p alone the parameter spread is about twice the published one), ``bai-fu``,
  ``sun-liu-sano`` (a reconstruction), ``oracle``, ``oracle-inv``, ``wang`` (the paper's steps
  (ii) and (iv): per run, A from the LSM or the IVM by the integrated AIC and each b_l by V_EIV;
  scored beside the LSM rows in ``steps.csv`` and ``summary.txt``) and ``wang-lsm-inv`` -- the
  LSM's estimates put in the direct inverse A(q)/B(q) y, defined here. Table 5's columns are
  F_LSM = ``wang-lsm``, F0_LSM = ``oracle``, F_INV = ``wang-lsm-inv``, F0_INV = ``oracle-inv``:
  the paper's text compares eq. (27) with the direct inverse for the same estimated G(q)
  ("Eq. (27) reduces the noise effect ..."), and ``bai-fu``'s ordinary least squares is biased
  under noise (its fitness is reported beside, not as F_INV; ``--investigate`` tests that mapping).
* Fitness is the paper's: the blind estimate scaled by the true gain b1 ("the gain of G(q) is
  assumed to be known").

The comparison (``reproduce.csv``, the contract's columns) gives, per published cell,
``z = (ours - paper) / SE`` with ``SE^2 = s_ours^2 / n + s_paper^2 / n_paper + u^2 / 12``: ``s``
the standard deviations over runs, ``n`` and ``n_paper`` the runs behind each mean (100 in the
paper), ``u`` the rounding unit of the printed number (its last digit). A spread that is not
known is taken equal to the other side's (the null hypothesis of one common distribution):
``s_paper = s_ours`` where the paper prints none (SNR, F0_LSM, F0_INV, Tables 1 and 2),
``s_ours = s_paper`` after a single run. Tables 1 and 2 are single realisations: ``n = n_paper =
1`` and ``s_ours`` is the standard deviation over the first realisations of the level (up to 20),
so ``SE^2 = 2 s^2 + u^2/12``. z is undefined (empty) where a value is infinite (the SNR at
sigma^2 = 0) or no spread is known. The summary gives the share of scored cells with
``|z| <= 2`` and lists every cell beyond.

``--investigate`` re-runs Tables 4 and 5 (and Tables 1 and 2) under alternative conventions and
writes ``investigation.csv``: which alternative moves which cells toward the paper, and by how
much (mean |z| per table before and after, and the ratio of our spreads to the published ones);
``investigation_cells.csv`` lists, per cell beyond ``|z| = 2`` under the defaults, the
alternatives under which it is within (a cell near 2 is moved within by many of them by chance;
a cell far beyond by one, and only one, names its likely cause), and one column ``z:<label>`` per
alternative with the cell's z under it. ``published_row.csv``
(:mod:`hbench.paper.published_row`) scores the paper's own Table 4 rows, as fixed models, on the
same realisations: what the published estimates achieve in F_LSM and F_INV on our loop.

What ``--investigate`` finds under the defaults (100 runs, seed 20070601), and the command that
produces it: ``docs/experiments/reproduce-investigation.md``.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import time
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

from hbench.errors import InputError
from hbench.paper.compare import LevelValues, compare_tables12, compare_tables45, steps_comparison
from hbench.paper.investigate import investigate
from hbench.paper.levels import (
    ALL_METHODS,
    DEFAULT_RUNS,
    DEFAULT_SEED,
    LEVELS,
    NOISE_FREE_RUNS,
    TABLE12_RUNS,
    TYPICAL_LEVEL,
    Config,
    LevelTask,
    cell_name,
    level_seed,
    level_tasks,
    log,
    run_levels,
    run_tables12,
    scenario_spec,
)
from hbench.tables.published import (
    TABLE5_COLUMNS,
    summarise,
    write_display_tables,
)

# --------------------------------------------------------------------------- published tables


# --------------------------------------------------------------------------- z and summary


# --------------------------------------------------------------------------- configuration


# --------------------------------------------------------------------------- simulation tasks


# --------------------------------------------------------------------------- comparison


# --------------------------------------------------------------------------- display tables


# --------------------------------------------------------------------------- investigation


# --------------------------------------------------------------------------- orchestration


def save_examples(path: Path, examples: Sequence[Mapping[str, Any]]) -> Path:
    """``examples.npz``: per example ``c{i}__x``, ``c{i}__U``, ``c{i}__gain``, ``c{i}__meta``
    (JSON: cell, nonlinearity, sigma2) and ``c{i}__est__{method}``."""
    import numpy as np

    arrays: dict[str, Any] = {}
    for i, ex in enumerate(examples):
        arrays[f"c{i}__x"] = np.asarray(ex["x"])
        arrays[f"c{i}__U"] = np.asarray(ex["U"])
        arrays[f"c{i}__gain"] = np.asarray(ex["gain"], dtype=float)
        meta = {k: ex.get(k) for k in ("cell", "nonlinearity", "sigma2", "snr_target")}
        arrays[f"c{i}__meta"] = np.asarray(json.dumps(meta, default=str))
        for name, U in ex.get("estimates", {}).items():
            arrays[f"c{i}__est__{name}"] = np.asarray(U)
    np.savez_compressed(path, **arrays)
    return path


def reproduce(
    runs: int = DEFAULT_RUNS,
    out: Path | str = "results",
    seed: int = DEFAULT_SEED,
    investigate_: bool = False,
    jobs: int | None = None,
    overrides: Iterable[tuple[str, Any]] = (),
    structure_mode: str = "fixed",
    report: bool = True,
) -> Path:
    """The whole reproduction; returns the new output folder."""
    t_start = time.perf_counter()
    if isinstance(runs, bool) or int(runs) != runs or runs < 1:
        raise InputError(f"--runs must be a positive integer, got {runs}")
    if jobs is None:
        cpus = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
        jobs = max(1, min(2, cpus or 1))
    if jobs < 1:
        raise InputError(f"--jobs must be >= 1, got {jobs}")
    if structure_mode not in ("fixed", "selected"):
        raise InputError(f"--structure must be 'fixed' or 'selected', got {structure_mode!r}")
    config = replace(Config(), overrides=tuple(overrides), structure=structure_mode)
    from hbench.sim import scenarios

    scenarios.build(scenario_spec(config, TYPICAL_LEVEL))  # bad overrides fail before any work

    from hbench.tables import results as res

    out_dir = res.new_output_dir(Path(out), "reproduce")
    log(f"writing to {out_dir}")

    tab = run_tables12(config, min(runs, TABLE12_RUNS), seed)
    sel = tab["selection"]["wang-lsm"]
    sel_iv = tab["selection"]["wang-iv"]
    structure = (sel["na"], sel["tau"], sel["nb"])
    log(
        f"Tables 1-2 ({tab['runs']} realisations at sigma^2 = 1e-3, run 0 shown): LSM selects "
        f"na = {sel['na']}, tau = {sel['tau']}, nb = {sel['nb']}; the IV's own table na = "
        f"{sel_iv['na']}, tau = {sel_iv['tau']}, nb = {sel_iv['nb']} ({tab['seconds']:.1f} s)"
    )

    def progress(task: LevelTask, seconds: float) -> None:
        log(
            f"sigma^2 = {task.sigma2:g}: {task.runs} runs x {len(task.methods)} methods "
            f"({seconds:.1f} s)"
        )

    def warm_up() -> None:  # the figures need matplotlib: import it while the workers compute
        from hbench.report import figures

        figures.warm_up()

    drawn: list[float] = []  # the level whose example Figures 4 and 5 show
    pending: list[Any] = []  # with jobs > 1, their futures
    early: dict[Path, Any] = {}  # the report's figures submitted early: stem -> future
    with contextlib.ExitStack() as stack:
        figure_workers: list[Any] = []  # a worker that draws while this process goes on

        def draw_example(task: LevelTask, result: tuple[Any, dict[str, Any], float]) -> None:
            # Figures 4 and 5 (and the report's x-U graphs) need one level's example: drawn as
            # soon as it is in, while the workers compute the other levels, instead of with
            # the report's figures at the end; with jobs > 1 by a worker forked now (matplotlib
            # imported), so that this process goes on with the tables meanwhile
            if not result[1] or drawn:
                return
            from hbench.report import figures

            drawn.append(task.sigma2)
            specs = figures.paper_figure_specs(result[1], out_dir, estimate="wang-lsm")
            if jobs <= 1:
                figures.render_many(specs, 1)
                return
            from hbench.bench import parallel

            figures.warm_up()
            workers = stack.enter_context(parallel.pool(1))
            figure_workers.append(workers)
            pending.extend(figures.submit(workers, spec) for spec in specs)
            if report:
                from hbench.report.build import xu_spec

                (out_dir / "report").mkdir()
                spec = xu_spec(out_dir / "report", [result[1]])
                early[spec[0]] = figures.submit(workers, spec)

        tasks = level_tasks(config, runs, seed, structure, ALL_METHODS)
        results = run_levels(
            tasks,
            jobs,
            progress,
            while_waiting=warm_up if report else None,
            on_result=draw_example,
        )
        _tables_and_report(
            out_dir,
            results,
            tab,
            config,
            runs,
            seed,
            structure,
            structure_mode,
            investigate_,
            jobs,
            report,
            figure_workers[0] if figure_workers else None,
            early,
        )
        for future in pending:  # Figures 4 and 5 written (or their error raised)
            future.result()
    log(f"done in {time.perf_counter() - t_start:.1f} s")
    return out_dir


def _tables_and_report(
    out_dir: Path,
    results: Sequence[tuple[Any, dict[str, Any], float]],
    tab: dict[str, Any],
    config: Config,
    runs: int,
    seed: int,
    structure: tuple[int, int, int],
    structure_mode: str,
    investigate_: bool,
    jobs: int,
    report: bool,
    workers: Any,
    early: dict[Path, Any],
) -> Path | None:
    """The comparison, the tables, the report and the rows of the levels' ``results``; the
    report's path (None without one). ``workers`` and ``early``: the worker drawing figures
    and the report's figures it was given (:func:`hbench.report.build.build_report`)."""
    import pandas as pd

    from hbench.tables import results as res

    sel = tab["selection"]["wang-lsm"]
    sel_iv = tab["selection"]["wang-iv"]
    rows = pd.concat([r[0] for r in results], ignore_index=True)
    examples = [r[1] for r in results if r[1]]
    values = LevelValues.of(rows)  # read by every comparison of these rows
    comparison = pd.concat(
        [compare_tables12(tab, config), compare_tables45(values, config)], ignore_index=True
    )
    summary = summarise(comparison)
    steps, steps_text = steps_comparison(values, comparison, config)

    tables = res.aggregated_tables(rows)  # written here, shown by the report
    res.write_tables(rows, out_dir, tables=tables)
    comparison.to_csv(out_dir / "reproduce.csv", index=False, float_format="%.10g")
    write_display_tables(comparison, out_dir, realisations=int(tab["runs"]))
    selection_text = (
        f"structure from Tables 1-2 (run 0 at sigma^2 = 1e-3): wang-lsm na={sel['na']} "
        f"tau={sel['tau']} nb={sel['nb']} (the same in {100 * sel['share_of_runs']:.0f} % of "
        f"the first {tab['runs']} realisations); wang-iv's own table na={sel_iv['na']} "
        f"tau={sel_iv['tau']} nb={sel_iv['nb']}; the paper: na=2 tau=3 nb=2. Monte Carlo "
        f"structure: {structure_mode}."
    )
    steps.to_csv(out_dir / "steps.csv", index=False, float_format="%.10g")
    (out_dir / "summary.txt").write_text(summary.text() + selection_text + "\n" + steps_text)
    for name in ("table1", "table2"):
        with (out_dir / f"{name}.md").open("a") as fh:
            fh.write(f"\nSelection implied: {selection_text}\n")
    (out_dir / "tables12.json").write_text(
        json.dumps(
            {
                "selection": tab["selection"],
                "runs": tab["runs"],
                "snr_run0": tab["snr"],
                "na_values": tab["na_values"].tolist(),
                "V_run0": {k: v[0].tolist() for k, v in tab["V"].items()},
                "var_dw_run0": tab["var_dw"][0].tolist(),
            },
            indent=2,
        )
    )
    if examples:
        save_examples(out_dir / "examples.npz", examples)
    config_desc = {
        "scenario": scenario_spec(config, TYPICAL_LEVEL),
        "levels": list(LEVELS),
        "runs": runs,
        "noise_free_runs": min(runs, NOISE_FREE_RUNS),
        "methods": list(ALL_METHODS),
        "structure": list(structure),
        "reproduction": config.describe(),
        "table5_columns": {k: v[1] for k, v in TABLE5_COLUMNS.items()},
        "z": "z = (ours - paper) / sqrt(s_o^2/n + s_p^2/n_p + u^2/12); s_p = s_o where the "
        "paper prints none; Tables 1-2: n = n_p = 1",
    }
    seeds = {"base": seed, **{cell_name(s2): str(level_seed(seed, s2).entropy) for s2 in LEVELS}}
    res.write_provenance(out_dir, config=config_desc, seeds=seeds)
    if investigate_:
        (out_dir / "investigation").mkdir()
        investigate(
            {"values": values, "tables12": tab, "comparison": comparison},
            runs,
            seed,
            structure,
            jobs,
            out_dir,
        )
    log("tables written; rendering the figures and the report")
    path = None
    if report:
        from hbench.report import build as rep

        if len(examples) != 1:  # the x-U graphs drawn early are not the report's: drawn again
            for future in early.values():
                future.result()
            early = {}
        path = rep.build_report(
            out_dir,
            out_dir / "report",
            rows=rows,
            tables=tables,
            jobs=jobs,
            workers=workers,
            ready=early,
        )
    rows.to_parquet(out_dir / "rows.parquet", index=False)  # last: no fork after pyarrow
    print(summary.text() + selection_text + "\n" + steps_text, end="")
    if report:
        print(f"report: {path}")
    print(f"results: {out_dir}")
    return path


def _cmd(args: argparse.Namespace) -> int:
    from hbench.sim.scenarios import parse_value
    from hbench.system.runtime import collector_paused
    from hbench.system.writable import check_output

    if args.out is not None:  # before any work: a folder one can write in
        check_output(args.out, "--out", folder=True)
    overrides = []
    for item in args.set or []:
        if "=" not in item:
            raise InputError(f"--set takes KEY=VALUE, got {item!r}")
        key, value = item.split("=", 1)
        overrides.append((key, parse_value(value)))
    with collector_paused():  # a few seconds of work: hbench.system.runtime
        reproduce(
            runs=args.runs,
            out=args.out,
            seed=args.seed,
            investigate_=args.investigate,
            jobs=args.jobs,
            overrides=overrides,
            structure_mode=args.structure,
        )
    return 0


def add_parser(subparsers: Any) -> argparse.ArgumentParser:
    """Add ``hbench reproduce`` to the CLI."""
    p = subparsers.add_parser(
        "reproduce",
        help="the paper's Section 6 example beside Tables 1, 2, 4, 5 and Figures 4, 5",
        description="Run the paper's Section 6 example at every noise level of Tables 4 and 5 "
        "with every method, compare with the published numbers (reproduce.csv: z per cell), draw "
        "Figures 4 and 5 and write the comparison report, all into a new folder under --out.",
    )
    p.add_argument(
        "--runs",
        type=int,
        default=DEFAULT_RUNS,
        help=f"Monte Carlo runs per noise level (default {DEFAULT_RUNS}, the paper's)",
    )
    p.add_argument("--out", default="results", help="base folder (default results/)")
    p.add_argument(
        "--seed", type=int, default=DEFAULT_SEED, help=f"base seed (default {DEFAULT_SEED})"
    )
    p.add_argument(
        "--investigate",
        action="store_true",
        help="also re-run under alternative conventions (investigation.csv)",
    )
    p.add_argument(
        "--jobs",
        type=int,
        default=None,
        help="worker processes (default: up to 2, the CPUs available)",
    )
    p.add_argument(
        "--structure",
        choices=("fixed", "selected"),
        default="fixed",
        help="fix (na, tau, nb) to Tables 1-2's selection (default) or select per run",
    )
    p.add_argument(
        "--set",
        action="append",
        metavar="KEY=VALUE",
        help="override a scenario key (dotted), e.g. reference.band=[0,0.25]",
    )
    p.set_defaults(func=_cmd)
    return p

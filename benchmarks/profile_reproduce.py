"""Where ``hbench reproduce`` spends its time: shares of one process's profile by phase.

Runs ``hbench reproduce --jobs 1`` under cProfile (one process, so that every phase is in the
profile) and prints each phase's cumulative seconds and its share of the command's total::

    MPLBACKEND=Agg .venv/bin/python benchmarks/profile_reproduce.py --runs 1000

cProfile slows pure-Python code (matplotlib, pandas' Python layers) more than compiled code
(numpy, BLAS, the kernels), so the shares of the figures and tables are upper bounds; the wall
and CPU times of the command itself are ``bench_reproduce.py``'s. Phases nest as printed
("of which" lines are inside the line above them); imports are counted wherever they happen.
"""

from __future__ import annotations

import argparse
import cProfile
import pstats
import tempfile

#: (label, file suffix, function name) of each phase; "  " marks a part of the line above.
PHASES = (
    ("the levels (simulation, 8 methods, Figures 4-5)", "hbench/paper/levels.py", "run_levels"),
    ("  of which the simulation", "hbench/sim/simulate.py", "simulate"),
    ("  of which the eight methods", "hbench/ident/invoke.py", "identify"),
    ("  of which Figures 4 and 5", "hbench/paper/reproduce.py", "draw_example"),
    ("  of which matplotlib's import", "hbench/paper/reproduce.py", "warm_up"),
    ("Tables 1-2", "hbench/paper/levels.py", "run_tables12"),
    ("the comparison with Tables 4-5", "hbench/paper/compare.py", "compare_tables45"),
    ("the aggregated tables", "hbench/tables/results.py", "aggregated_tables"),
    ("the report", "hbench/report/build.py", "build_report"),
    ("  of which its figures (PNG and PDF)", "hbench/report/figures.py", "render_many"),
    ("  of which PDF font subsetting", "backends/_backend_pdf_ps.py", "get_glyphs_subset"),
    ("  of which the headline tables", "hbench/report/build.py", "write_summary"),
    ("  of which the cell statistics", "hbench/report/aggregate.py", "cell_stats"),
    ("rows.parquet", "pandas/core/frame.py", "to_parquet"),
)


def cumulative(stats: pstats.Stats, suffix: str, name: str) -> float:
    """Cumulative seconds of the functions ``name`` defined in a file ending in ``suffix``.

    Parameters
    ----------
    stats : pstats.Stats
        The profile.
    suffix : str
        The end of the defining file's path (e.g. ``"hbench/report/build.py"``).
    name : str
        The function's name.

    Returns
    -------
    float
        The sum of their cumulative times (a recursive function counted once per outer call).
    """
    return sum(
        row[3]
        for (path, _, func), row in stats.stats.items()  # type: ignore[attr-defined]
        if func == name and path.endswith(suffix)
    )


def main() -> None:
    """Profile one ``hbench reproduce --jobs 1`` and print the phases' shares."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=100)
    args = parser.parse_args()
    from hbench.cli import main as cli

    with tempfile.TemporaryDirectory() as out:
        profile = cProfile.Profile()
        profile.runcall(cli, ["reproduce", "--runs", str(args.runs), "--jobs", "1", "--out", out])
    stats = pstats.Stats(profile)
    total = cumulative(stats, "hbench/cli.py", "main")
    figures_4_5 = cumulative(stats, "hbench/paper/reproduce.py", "draw_example")
    imports = sum(row[3] for key, row in stats.stats.items() if key[2] == "_find_and_load")  # type: ignore[attr-defined]
    print(f"hbench reproduce --runs {args.runs} --jobs 1 under cProfile: {total:.2f} s")
    for label, suffix, name in PHASES:
        seconds = cumulative(stats, suffix, name)
        if name == "render_many":  # Figures 4 and 5 go through it too, inside the levels
            seconds -= figures_4_5
        print(f"{label:52s} {seconds:7.2f} s {100 * seconds / total:5.1f} %")
    print(f"{'imports (wherever they happen)':52s} {imports:7.2f} s {100 * imports / total:5.1f} %")


if __name__ == "__main__":
    main()

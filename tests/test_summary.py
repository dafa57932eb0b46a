"""The headline summary: intervals, paired differences, the winner only where significant."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest
from scipy import stats

from hbench.bench.schema import TIDY_COLUMNS
from hbench.tables import headline, summary


def fitness_rows(values: dict[str, np.ndarray], sigma2: float = 1e-3) -> pd.DataFrame:
    """Tidy fitness rows of one cell: ``values[method][run]``."""
    runs = [(m, run, float(f)) for m, v in values.items() for run, f in enumerate(v)]
    frame = pd.DataFrame(runs, columns=["method", "run", "value"]).assign(
        cell="c", nonlinearity="backlash", plant="paper", p=5, delay=3, sigma2=sigma2,
        snr_target=math.nan, seed="s", quantity="fitness", true=math.nan, snr=10.0,
        status="ok", error=None,
    )  # fmt: skip
    return frame[list(TIDY_COLUMNS)]


def test_t_interval_is_students() -> None:
    v = np.random.default_rng(1).normal(3.0, 2.0, 12)
    mean, low, high = summary.t_interval(v)
    expected = stats.t.interval(0.95, len(v) - 1, loc=v.mean(), scale=stats.sem(v))
    assert mean == pytest.approx(v.mean())
    assert (low, high) == pytest.approx(expected)
    assert math.isnan(summary.t_interval([1.0])[1])


def test_paired_difference_finds_a_winner_that_separate_intervals_miss() -> None:
    """The realisations dominate the spread; the methods differ by 1 on every run: their own
    intervals overlap, the paired one excludes zero."""
    rng = np.random.default_rng(7)
    common = rng.normal(80.0, 10.0, 30)
    b = common + rng.normal(0.0, 0.3, 30)
    table = summary.summary(fitness_rows({"a": b + 1.0, "b": b}))
    a_row, b_row = (table[table["method"] == m].iloc[0] for m in ("a", "b"))
    assert a_row["fitness_ci_low"] < b_row["fitness_ci_high"]  # the intervals overlap
    assert a_row["best"] and a_row["leader"] and not b_row["best"]
    assert b_row["diff_to_best"] == pytest.approx(-1.0)
    assert b_row["diff_ci_high"] < 0 and b_row["n_pairs"] == 30
    assert a_row["diff_to_best"] == pytest.approx(1.0)  # the best's lead over the runner-up
    assert a_row["diff_ci_low"] > 0


def test_no_winner_where_the_lead_is_noise() -> None:
    rng = np.random.default_rng(3)
    a, b = rng.normal(80.0, 5.0, (2, 20))
    table = summary.summary(fitness_rows({"a": a, "b": b}))
    assert not table["best"].any()
    leader = table[table["leader"]].iloc[0]
    assert leader["diff_ci_low"] < 0 < leader["diff_ci_high"]


def test_exact_ties_are_no_win_and_bounds_are_not_compared() -> None:
    same = np.full(10, 100.0)
    table = summary.summary(
        fitness_rows({"a": same, "b": same + 1e-12, "oracle": same + 5}),
        bound=lambda m: m == "oracle",
    )
    assert not table["best"].any()  # a lead of 1e-12 % is rounding, not a win
    oracle = table[table["method"] == "oracle"].iloc[0]
    assert oracle["bound"] and not oracle["leader"] and math.isnan(oracle["diff_to_best"])


def test_pairs_only_shared_runs_and_keeps_contract_columns() -> None:
    rows = fitness_rows({"a": np.arange(10.0) + 2, "b": np.arange(10.0)})
    rows = rows[~((rows["method"] == "b") & (rows["run"] >= 6))]  # b lost 4 runs
    table = summary.summary(rows)
    b = table[table["method"] == "b"].iloc[0]
    assert b["n"] == 6 and b["n_pairs"] == 6 and b["diff_to_best"] == pytest.approx(-2.0)
    contract = "fitness_mean fitness_ci_low fitness_ci_high diff_to_best diff_ci_low diff_ci_high"
    assert set(contract.split()) | {"best", "paper"} <= set(table.columns)


def test_paper_values_from_reproduce_csv() -> None:
    frame = pd.DataFrame(
        {
            "table": [5, 5, 4, 4],
            "row": [0.001, 0.001, 0.001, 0.001],
            "column": ["F", "F0", "a1", "snr"],
            "method": ["a", "oracle", "a", "scenario"],
            "paper": [85.05, 91.36, -1.965, 10.0],
        }
    )
    fit, par = summary.paper_values(frame)
    assert set(fit["method"]) == {"a", "oracle"} and list(par["parameter"]) == ["a1"]
    table = summary.summary(fitness_rows({"a": np.full(5, 85.0), "b": np.full(5, 80.0)}), paper=fit)
    assert table.set_index("method").loc["a", "paper"] == 85.05
    assert math.isnan(table.set_index("method").loc["b", "paper"])


def test_headline_columns_name_levels_and_digits_follow_the_interval() -> None:
    rows = pd.concat(
        [
            fitness_rows({"a": np.full(3, 100.0)}, sigma2=0.0),
            fitness_rows({"a": np.array([80.0, 81.0, 82.0])}, sigma2=1e-3),
        ]
    )
    table = summary.summary(rows)
    assert [label for _, label in headline.level_columns(table)] == ["noise-free", "σ² = 0.001"]
    assert headline.digits(2.48) == 1 and headline.digits(0.0123) == 3 and headline.digits(25) == 0
    md = headline.fitness_markdown(table, str)
    assert "81.0 ± 2.5" in md  # half-width 2.48 -> two significant digits, mean to match
    tex = headline.fitness_latex(table, str)
    assert r"\multicolumn{2}{c}{noise-free}" in tex and r"$\sigma^2 = 10^{-3}$" in tex
    assert r"\label{tab:hbench-summary}" in tex and r"\caption{" in tex

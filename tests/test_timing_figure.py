"""The time-per-method figure says what its error bars are.

A run's time is its batch's time divided by the runs in the batch, so the runs of a batch share
one value: the std over runs is the spread between batches (its docstring and the report's
caption did not say so)."""

from __future__ import annotations

import pandas as pd

from hbench.report import figures


def test_time_figure_says_runs_share_their_batchs_time() -> None:
    stats = pd.DataFrame(
        {"method": ["wang-lsm", "bai-fu"], "mean": [0.002, 0.05], "std": [0.0005, 0.01]}
    )
    fig = figures.time_per_method(stats, str)
    try:
        label = fig.get_supxlabel()
        assert "time per run (ms)" in label  # times of milliseconds: in ms
        assert "batch time / runs" in label and "a batch's runs share its value" in label
        assert fig.axes[0].get_xscale() == "log"
    finally:
        figures.pyplot().close(fig)


def test_time_figure_is_logarithmic_in_microseconds_for_fast_methods() -> None:
    """Times of microseconds: a log axis in µs whose limits hold every point (not flat at 0)."""
    stats = pd.DataFrame(
        {"method": ["wang-lsm", "oracle"], "mean": [2e-5, 4e-6], "std": [0.0, 1e-6]}
    )
    fig = figures.time_per_method(stats, str)
    try:
        ax = fig.axes[0]
        assert "(µs)" in fig.get_supxlabel() and ax.get_xscale() == "log"
        lo, hi = ax.get_xlim()
        assert 0 < lo < 4.0 and hi > 20.0
    finally:
        figures.pyplot().close(fig)

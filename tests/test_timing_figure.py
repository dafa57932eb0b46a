"""The time-per-method figure says what its error bars are.

A run's time is its batch's time divided by the runs in the batch, so the runs of a batch share
one value: the std over runs is the spread between batches (its docstring and the report's
caption did not say so)."""

from __future__ import annotations

import pandas as pd

from hbench import figures


def test_time_figure_says_runs_share_their_batchs_time() -> None:
    stats = pd.DataFrame(
        {"method": ["wang-lsm", "bai-fu"], "mean": [0.002, 0.05], "std": [0.0005, 0.01]}
    )
    fig = figures.time_per_method(stats, str)
    try:
        label = fig.axes[0].get_xlabel()
        assert "time per run (s)" in label
        assert "batch time / runs" in label and "a batch's runs share its value" in label
    finally:
        figures.pyplot().close(fig)

"""The paper's Section 6 example with its continuous-filter noise: Table 4, LSM and IVM rows.

100 runs per noise level (about 2 s in all). Compared cell by cell with the published mean +- std,
read from the packaged ``hbench/data/paper_tables.json`` (b2's sign corrected; rows sigma^2 =
1e-4, 5e-4, 1e-3 as ``shared/paper/NOTES.md`` reads the noise column): |ours - paper| <= 3 SE with
SE = sqrt(s_ours^2 + s_paper^2) / sqrt(100), both means being averages of 100 runs. Where a
published mean is itself more than 3 of its own SE from the true value (the paper's IVM b2 at
sigma^2 = 1e-3: -0.7171 +- 0.0188, 3.9 SE from -0.7244, against the paper's own consistency
theorem), the cell is checked against the truth instead and listed in PUBLISHED_OFF_TRUTH. Only
the IVM is consistent under this coloured noise; the LSM's published bias is real and is compared
as published.
"""

from __future__ import annotations

import numpy as np
import pytest

from hbench.tables.published import paper_data
from tests.helpers import TRUE_STRUCTURE, run_method, sim

PAPER = paper_data()
TRUE = {key: float(value) for key, value in PAPER["true"].items()}
LEVELS = (1e-4, 5e-4, 1e-3)
#: (method, sigma2) -> parameter -> (mean, std), from the packaged Table 4 (b2's sign corrected)
TABLE4 = {
    (method, row["sigma2"]): {
        key: (float(mean), float(std)) for key, (mean, std) in row[method].items()
    }
    for row in PAPER["table4"]["rows"]
    if row["sigma2"] in LEVELS
    for method in ("wang-lsm", "wang-iv")
}
RUNS = 100


def _published_off_truth() -> set[tuple[str, float, str]]:
    out = set()
    for (method, s2), cells in TABLE4.items():
        if method != "wang-iv":  # the LSM is not consistent under coloured noise
            continue
        for key, (mean, std) in cells.items():
            if abs(mean - TRUE[key]) > 3 * std / np.sqrt(RUNS):
                out.add((method, s2, key))
    return out


PUBLISHED_OFF_TRUTH = _published_off_truth()


def test_published_cells_off_truth_are_few():
    """Only the IVM b2 cell at 1e-3 contradicts the truth (and so the consistency theorem)."""
    assert PUBLISHED_OFF_TRUTH == {("wang-iv", 1e-3, "b2")}


def test_the_table_read_is_the_published_one():
    assert len(TABLE4) == 6
    assert TABLE4[("wang-iv", 1e-3)]["b2"] == (-0.7171, 0.0188)
    assert TRUE == {"a1": -1.9620, "a2": 0.9623, "b2": -0.7244}


@pytest.mark.parametrize("sigma2", LEVELS)
@pytest.mark.parametrize("method", ["wang-lsm", "wang-iv"])
def test_table4_cells(method, sigma2):
    record, _ = sim(runs=RUNS, seed=20070601, noise__sigma2=sigma2)
    params = run_method(method, record, options=TRUE_STRUCTURE).params()
    for key, (p_mean, p_std) in TABLE4[(method, sigma2)].items():
        vals = params[key]
        o_mean, o_std = float(np.mean(vals)), float(np.std(vals, ddof=1))
        if (method, sigma2, key) in PUBLISHED_OFF_TRUTH:
            se = o_std / np.sqrt(RUNS)
            assert abs(o_mean - TRUE[key]) <= 3 * se, (key, o_mean, TRUE[key], se)
            continue
        se = np.hypot(o_std, p_std) / np.sqrt(RUNS)
        assert abs(o_mean - p_mean) <= 3 * se, (key, o_mean, p_mean, se)

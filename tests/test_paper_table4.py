"""The paper's Section 6 example with its continuous-filter noise: Table 4, LSM and IVM rows.

100 runs per noise level (about 2 s in all). Compared cell by cell with the published mean +- std
(b2's sign corrected, rows sigma^2 = 1e-4, 5e-4, 1e-3 per NOTES.md): |ours - paper| <= 3 SE with SE
= sqrt(s_ours^2 + s_paper^2) / sqrt(100), both means being averages of 100 runs. Where a published
mean is itself more than 3 of its own SE from the true value (the paper's IVM b2 at sigma^2 = 1e-3:
-0.7171 +- 0.0188, 3.9 SE from -0.7244, against the paper's own consistency theorem), the cell is
checked against the truth instead and listed in PUBLISHED_OFF_TRUTH. Only the IVM is consistent
under this coloured noise; the LSM's published bias is real and is compared as published.
"""

from __future__ import annotations

import numpy as np
import pytest

from tests.helpers import TRUE_STRUCTURE, run_method, sim

TRUE = {"a1": -1.9620, "a2": 0.9623, "b2": -0.7244}
# (method, sigma2) -> parameter -> (mean, std); b2 sign flipped (Table 4 prints +0.7244)
TABLE4 = {
    ("wang-lsm", 1e-4): {"a1": (-1.9623, 0.0018), "a2": (0.9626, 0.0019), "b2": (-0.7240, 0.0027)},
    ("wang-iv", 1e-4): {"a1": (-1.9619, 0.0022), "a2": (0.9622, 0.0023), "b2": (-0.7243, 0.0064)},
    ("wang-lsm", 5e-4): {"a1": (-1.9634, 0.0038), "a2": (0.9638, 0.0038), "b2": (-0.7242, 0.0053)},
    ("wang-iv", 5e-4): {"a1": (-1.9627, 0.0045), "a2": (0.9630, 0.0045), "b2": (-0.7216, 0.0151)},
    ("wang-lsm", 1e-3): {"a1": (-1.9651, 0.0054), "a2": (0.9656, 0.0055), "b2": (-0.7247, 0.0085)},
    ("wang-iv", 1e-3): {"a1": (-1.9633, 0.0063), "a2": (0.9636, 0.0063), "b2": (-0.7171, 0.0188)},
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


@pytest.mark.parametrize("sigma2", [1e-4, 5e-4, 1e-3])
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

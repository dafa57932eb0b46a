"""The published classical stiction detectors, with their published limits, as baselines.

Each detector gives one of three verdicts on a control loop from its controller output ``x``
(OP) and process output ``y`` (PV): ``stiction``, ``no-stiction`` or ``undetermined`` (the
statistic falls between the published limits or cannot be read). Both are tests for
oscillating loops, so both sit behind the same oscillation gate:

* **Oscillation gate** (Thornhill, Huang & Zhang 2003): the regularity ``r`` of the
  oscillation in ``x`` (:func:`hbench.diagnose.stats.regularity`) must exceed
  :data:`REGULARITY` (1). A loop that does not oscillate regularly is ``no-stiction`` for both
  baselines: neither test is defined there, and a sticking valve that causes no regular
  oscillation is what they cannot see.
* **Horch** (A. Horch, "A simple method for detection of stiction in control valves", Control
  Engineering Practice 7 (1999) 1221-1231): the cross-correlation of ``x`` and ``y``; an odd
  correlation is stiction, an even one is not. Its phase ``|dphi|``
  (:func:`hbench.diagnose.stats.horch_phase`) above :data:`HORCH_ODD` (2 pi / 3) is stiction,
  below :data:`HORCH_EVEN` (pi / 3) no stiction, between (or with no zero crossing on both sides
  of lag 0) undetermined. Horch states the test for self-regulating loops with integral control;
  here it runs on every loop.
* **He et al.** (Q. P. He, J. Wang, M. Pottmann, S. J. Qin, "A curve fitting method for detecting
  valve stiction in oscillating control loops", Ind. Eng. Chem. Res. 46 (2007) 4549-4560): a
  triangle and a sinusoid fitted to every half period of ``x``; the index ``MSE_sin / (MSE_sin +
  MSE_tri)`` (:func:`hbench.diagnose.stats.stiction_index`) above :data:`HE_STICTION` (0.6) is
  stiction, below :data:`HE_NO_STICTION` (0.4) no stiction, between undetermined. He et al. fit
  the PV instead of the OP on integrating (level) loops; here the OP is fitted on every loop.

No limit here was chosen on data: all are the publications' values.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hbench.diagnose import stats

#: The verdicts: the two labels of a scored record, and the third answer of a test.
STICTION, NO_STICTION, UNDETERMINED = "stiction", "no-stiction", "undetermined"
#: Thornhill et al.: an oscillation is regular when its regularity exceeds this.
REGULARITY = 1.0
#: Horch: a cross-correlation phase ``|dphi|`` above this (an odd correlation) is stiction ...
HORCH_ODD = 2 * np.pi / 3
#: ... and below this (an even correlation) no stiction.
HORCH_EVEN = np.pi / 3
#: He et al.: a stiction index above this (a triangular OP) is stiction ...
HE_STICTION = 0.6
#: ... and below this (a sinusoidal OP) no stiction.
HE_NO_STICTION = 0.4
#: The baselines by name, in the order they are reported.
DETECTORS = ("horch", "he")


@dataclass(frozen=True)
class Verdict:
    """One detector's answer: ``verdict`` (:data:`STICTION`, :data:`NO_STICTION` or
    :data:`UNDETERMINED`), the ``statistic`` it read (nan where it read none) and ``why`` in
    words."""

    verdict: str
    statistic: float
    why: str


def three_way(value: float, stiction_above: float, none_below: float, name: str) -> Verdict:
    """The verdict of a statistic with two published limits: above ``stiction_above`` stiction,
    below ``none_below`` no stiction, between (or nan) undetermined."""
    if not np.isfinite(value):
        return Verdict(UNDETERMINED, float(value), f"{name} cannot be read")
    if value > stiction_above:
        return Verdict(STICTION, float(value), f"{name} {value:.3g} > {stiction_above:.3g}")
    if value < none_below:
        return Verdict(NO_STICTION, float(value), f"{name} {value:.3g} < {none_below:.3g}")
    between = f"{name} {value:.3g} in [{none_below:.3g}, {stiction_above:.3g}]"
    return Verdict(UNDETERMINED, float(value), between)


def oscillation(x: np.ndarray) -> tuple[bool, float]:
    """The oscillation gate: ``(regular, r)`` with Thornhill's regularity ``r`` of ``x`` and
    ``regular = r > REGULARITY``."""
    r, _ = stats.regularity(x)
    return bool(r > REGULARITY), float(r)


def gated(x: np.ndarray) -> Verdict | None:
    """:data:`NO_STICTION` for a loop that does not oscillate regularly; ``None`` for one that
    does (the test then decides)."""
    regular, r = oscillation(x)
    if regular:
        return None
    return Verdict(NO_STICTION, float("nan"), f"no regular oscillation: r = {r:.2f} <= 1")


def horch(x: np.ndarray, y: np.ndarray) -> Verdict:
    """Horch's cross-correlation test on a loop (controller output ``x``, process output ``y``)
    behind the oscillation gate; the statistic is the phase ``|dphi|`` in radians."""
    x, y = stats.paired(x, y)
    return gated(x) or three_way(stats.horch_phase(x, y), HORCH_ODD, HORCH_EVEN, "|dphi|")


def he(x: np.ndarray) -> Verdict:
    """He et al.'s curve-fitting test on a loop's controller output ``x`` behind the oscillation
    gate; the statistic is the stiction index."""
    x = np.asarray(x, float)
    return gated(x) or three_way(stats.stiction_index(x), HE_STICTION, HE_NO_STICTION, "index")


def verdicts(x: np.ndarray, y: np.ndarray) -> dict[str, Verdict]:
    """Every baseline's verdict on a loop, by name (:data:`DETECTORS`)."""
    return {"horch": horch(x, y), "he": he(x)}

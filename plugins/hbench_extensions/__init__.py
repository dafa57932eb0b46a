"""Methods beyond the paper, each derived in its class docstring.

* ``wang-lsm-cn``: the bias-compensated LSM generalised to coloured equation noise, with the
  noise correlation estimated from the quiet phases.
* ``joint-refine``: (A, B, U) refined jointly over the SIMO model of eq. (26) by variable
  projection, started from ``wang-lsm-cn``.
* ``wang-delay``: assumption A3 relaxed, the delay's multiple of p estimated from the alignment
  of the measured x with the estimated inner signal.
"""

from __future__ import annotations

from hbench.hookspecs import Register, hookimpl

from .coloured import ColoredNoiseLSM, noise_bias, quiet_autocovariance
from .delay import DelayEstimating, delay_multiple_from_alignment
from .joint import JointRefinement, joint_refine
from .optiv import OptimalIV, gmm_iv

__all__ = [
    "ColoredNoiseLSM",
    "DelayEstimating",
    "JointRefinement",
    "OptimalIV",
    "delay_multiple_from_alignment",
    "gmm_iv",
    "joint_refine",
    "noise_bias",
    "quiet_autocovariance",
]


@hookimpl
def register_identifiers(register: Register) -> None:
    for cls in (ColoredNoiseLSM, JointRefinement, DelayEstimating, OptimalIV):
        register(cls.name, cls)

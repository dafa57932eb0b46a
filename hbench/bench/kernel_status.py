"""Which computations run compiled on this machine, in one line for people.

The kernels (:mod:`hbench.numerics.kernels`) give the numpy path's numbers where this machine's
libraries compute as they do; the checks of that live beside the numpy path each kernel stands
for (:func:`hbench.ident.polyphase.lapack_is_reference`,
:func:`hbench.numerics.kernels.lfilter_is_scipys`, :func:`hbench.bench.metrics.sums_are_numpys`).
"""

from __future__ import annotations

from hbench.bench import metrics
from hbench.ident import polyphase
from hbench.numerics import kernels


def status() -> str:
    """Which path runs and why (``hbench plugins`` and every run's provenance print it).

    Returns
    -------
    str
        :func:`hbench.numerics.kernels.status` with the computations that keep to numpy or
        scipy although the kernels run.
    """
    if kernels.backend() != "c":
        return kernels.status()
    own_route = [
        what
        for what, same in (
            ("eq. (27) (this LAPACK's dptsv)", polyphase.lapack_is_reference()),
            ("lfilter (this scipy's)", kernels.lfilter_is_scipys()),
            ("the fitness (this numpy's sums)", metrics.sums_are_numpys()),
        )
        if not same
    ]
    return kernels.status(own_route)

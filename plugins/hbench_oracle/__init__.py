"""Oracle bounds: the true A, B and delay used in the inner-signal estimate.

The one declared exception to "methods never see the truth" (``needs = {"truth"}``). ``oracle``
puts the true parameters in eq. (27) (Table 5's F0_LSM); ``oracle-inv`` in the direct inverse
(F0_INV, with the Bezout combiner for a non-minimum-phase B).
"""

from __future__ import annotations

from typing import ClassVar

import numpy as np

from hbench.hookspecs import Register, hookimpl
from hbench.ident import polyphase as pp
from hbench.ident.identifiers import (
    Estimate,
    Identifier,
    IdentifyOptions,
    check_identifiable,
    empty_estimate,
    inner_ls,
    inverse_inner,
)
from hbench.sim.records import Record, Truth


class Oracle(Identifier):
    """True A, B (b1 = 1) and tau in eq. (27): the upper bound F0_LSM of Table 5."""

    name: ClassVar[str] = "oracle"
    needs: ClassVar[frozenset[str]] = frozenset({"truth"})
    summary: ClassVar[str] = "Oracle: true A, B in eq. (27) (F0_LSM)"

    def _inner(self):
        return inner_ls

    def identify(
        self, record: Record, options: IdentifyOptions, truth: Truth | None = None
    ) -> Estimate:
        assert truth is not None
        plant, p, R, K = truth.plant, record.p, record.runs, record.n_slow
        why = check_identifiable(p, options) if plant.nb >= p else ""
        if why:
            return empty_estimate(self.name, record, why)
        tau, m = plant.tau(p), plant.delay_multiple(p)
        a = np.broadcast_to(plant.a, (R, plant.a.size)).copy()
        b = np.broadcast_to(plant.b_normalised, (R, plant.nb)).copy()
        w = pp.filtered_output(record.y, a)
        Ut, n_first, label = self._inner()(record.y, w, a, b, p, tau, plant.na)
        return Estimate(
            method=self.name,
            a=a[:, 1:],
            b=b,
            na=np.full(R, plant.na),
            nb=np.full(R, plant.nb),
            tau=np.full(R, tau),
            sigma2=truth.sigma2.copy(),
            U=pp.align(Ut, n_first, m, K),
            identifiable=np.ones(R, bool),
            reason=[""] * R,
            info={"inverse": {label: R}, "oracle": True},
        )


class OracleInverse(Oracle):
    """True A, B in the direct inverse A(q)/B(q) y (F0_INV of Table 5)."""

    name: ClassVar[str] = "oracle-inv"
    summary: ClassVar[str] = "Oracle: true A, B in the direct inverse (F0_INV)"

    def _inner(self):
        return inverse_inner("auto")


@hookimpl
def register_identifiers(register: Register) -> None:
    register(Oracle.name, Oracle)
    register(OracleInverse.name, OracleInverse)

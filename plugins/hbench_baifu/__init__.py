"""Bai & Fu (2002), "A blind approach to Hammerstein model identification", IEEE Trans. Signal
Processing 50(7): the noise-free design, as this suite implements it.

From the source (as summarised in Wang et al. 2007 and ``shared/docs/methods-and-models.md``): A
from the quiet-phase equations by ordinary least squares (no noise compensation, their setting is
noise-free); B from the active phases; the inner signal by the direct inverse ``A(q)/B(q) y``
down-sampled by p (Table 5's F_INV), or a Bezout-identity inverse when B is not minimum phase.
Reconstructed here: B as the least-squares ratio of ``Delta w(kp + l)`` to ``Delta w(kp + 1)``; the
Bezout inverse as the minimum-norm degree-0 combiner of the polyphase channels (exact because every
channel of eq. 25 has order one); the structure selection of
:func:`hbench.ident.identifiers.select_structure` with the OLS denominator (Bai & Fu assume the
orders)."""

from __future__ import annotations

from typing import Any, ClassVar

from hbench.errors import InputError
from hbench.hookspecs import Register, hookimpl
from hbench.ident import polyphase as pp
from hbench.ident.identifiers import (
    INVERSES,
    Estimate,
    Identifier,
    IdentifyOptions,
    SelectionRule,
    blind_fit,
    inverse_inner,
    ols_fit,
)
from hbench.sim.records import Record, Truth


class BaiFu(Identifier):
    """Bai & Fu (2002) direct-inverse baseline (OLS A, ratio B, direct or Bezout inverse)."""

    name: ClassVar[str] = "bai-fu"
    summary: ClassVar[str] = "Bai & Fu 2002: OLS on quiet phases, direct inverse A/B (F_INV)"

    def __init__(self, inverse: str = "auto", pooled: bool = True) -> None:
        if inverse not in INVERSES:
            raise InputError(
                f"bai-fu inverse must be one of {', '.join(INVERSES)}, got {inverse!r}"
            )
        self.inverse, self.pooled = inverse, bool(pooled)

    def options(self) -> dict[str, Any]:
        return {"inverse": self.inverse, "pooled": self.pooled}

    def identify(
        self, record: Record, options: IdentifyOptions, truth: Truth | None = None
    ) -> Estimate:
        def numerator(dw, tau, nb, sigma2, idx):
            return pp.b_ols(dw, record.p, tau, nb, t_min=pp.first_valid(dw))

        return blind_fit(
            self.name,
            record,
            options,
            denominator=ols_fit,
            numerator=numerator,
            inner=inverse_inner(self.inverse),
            pooled=self.pooled,
            rule=SelectionRule(),
            info=self.options(),
        )


@hookimpl
def register_identifiers(register: Register) -> None:
    register(BaiFu.name, BaiFu)

"""The identifier interface in one place: what a method plugin imports.

A method is an :class:`Identifier` whose ``identify(record, options, truth=None)`` returns an
:class:`Estimate`; :func:`identify` runs it, showing it only what it declared it needs. Blind
methods build on the shared structure selection (:func:`select_structure`) and blind route
(:func:`blind_fit`). The names live in four modules, one job each:

* :mod:`hbench.ident.estimate`: what a method is given and returns (:class:`IdentifyOptions`,
  :class:`Estimate`, :class:`Identifier`, the checks of assumption A2 and of the record's length);
* :mod:`hbench.ident.selection`: the structure selection, Section 6 steps (i)-(iii);
* :mod:`hbench.ident.blind`: the blind route and its inner-signal steps (eq. 27, the inverses);
* :mod:`hbench.ident.invoke`: how a method is run and its estimate checked.

Every name those modules export is a name of this module too (the stable path plugins use, as
is :mod:`hbench.identifiers`).
"""

from __future__ import annotations

from hbench.ident.blind import (
    INVERSES,
    REFUSALS,
    InnerSignal,
    NumeratorFit,
    blind_fit,
    check_a4,
    inner_ls,
    inverse_inner,
)
from hbench.ident.estimate import (
    PARAMETERS,
    Estimate,
    Identifier,
    IdentifyOptions,
    check_identifiable,
    check_length,
    empty_estimate,
    largest_order,
    pad,
)
from hbench.ident.invoke import NO_ESTIMATE, NON_FINITE, check_estimate, identify, run_status
from hbench.ident.selection import (
    DenominatorFit,
    SelectionRule,
    Structure,
    bias_compensated_fit,
    groups,
    kept_in,
    ols_fit,
    runs_of,
    select_structure,
    shared_moments,
)

__all__ = [
    "INVERSES",
    "NON_FINITE",
    "NO_ESTIMATE",
    "PARAMETERS",
    "REFUSALS",
    "DenominatorFit",
    "Estimate",
    "Identifier",
    "IdentifyOptions",
    "InnerSignal",
    "NumeratorFit",
    "SelectionRule",
    "Structure",
    "bias_compensated_fit",
    "blind_fit",
    "check_a4",
    "check_estimate",
    "check_identifiable",
    "check_length",
    "empty_estimate",
    "groups",
    "identify",
    "inner_ls",
    "inverse_inner",
    "kept_in",
    "largest_order",
    "ols_fit",
    "pad",
    "run_status",
    "runs_of",
    "select_structure",
    "shared_moments",
]

"""The blind route the methods share: structure, A, B, the A4 check, the inner signal.

:func:`blind_fit` runs a method's denominator, numerator and inner-signal steps on every group
of runs that selected the same structure, batched. The inner-signal steps: eq. (27) solved in
O(K) (:func:`inner_ls`), and the direct inverse or the Bezout combiner (:func:`inverse_inner`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace
from typing import Any

import numpy as np

from hbench.docparams import parameters
from hbench.errors import InputError
from hbench.ident import polyphase as pp
from hbench.ident.estimate import (
    PARAMETERS,
    Estimate,
    IdentifyOptions,
    check_identifiable,
    check_length,
    empty_estimate,
    largest_order,
)
from hbench.ident.selection import (
    DenominatorFit,
    SelectionRule,
    groups,
    kept_in,
    runs_of,
    select_structure,
    shared_moments,
)
from hbench.sim.records import Record


@parameters(
    PARAMETERS,
    b=("ndarray", "Numerator coefficients, ``(runs, nb)``."),
    tol=("float, optional", "``|B(1)|`` at or below this counts as zero."),
)
def check_a4(b: np.ndarray, tol: float = 1e-6) -> np.ndarray:
    """True where ``B(1) = sum b`` is (numerically) zero: assumption A4 fails."""
    return np.abs(b.sum(axis=1)) <= tol * np.abs(b).sum(axis=1)


def _reads_the_regression_only(fit: Callable[..., Any]) -> bool:
    """A module-level function, no closure: what it computes depends on its arguments alone."""
    return getattr(fit, "__closure__", True) is None and "<locals>" not in getattr(
        fit, "__qualname__", "<locals>"
    )


#: ``numerator(dw, tau, nb, sigma2, idx) -> b`` of shape ``(len(idx), nb)`` with ``b1 = 1``.
NumeratorFit = Callable[[np.ndarray, int, int, np.ndarray, np.ndarray], np.ndarray]
#: ``inner(y, w, a, b, p, tau, t_min) -> (U~, n_first, label)``: the inner signal on the shifted
#: grid, from the group's outputs ``y``, ``w = A(q) y``, ``A`` and ``B``. Its arrays are inputs
#: only (``y`` may be a read-only view of the record's).
InnerSignal = Callable[..., tuple[np.ndarray, int, str]]


#: Why an ``inner`` step returned no estimate, by its label.
REFUSALS = {
    "refused-nmp": "B(q) is not minimum phase: the direct inverse A(q)/B(q) is unstable and was "
    "refused (choose inverse='bezout' or 'auto')",
}


@parameters(
    PARAMETERS,
    y=("ndarray", "The group's fast-rate outputs, ``(runs, N)``."),
    w=("ndarray", "``A(q) y``, ``(runs, N)``."),
    a=("ndarray", "Denominators with the leading 1, ``(runs, na + 1)``."),
    b=("ndarray", "Numerators with ``b1 = 1``, ``(runs, nb)``."),
    tau=("int", "Delay within a period."),
    t_min=("int", "First fast sample where ``w`` is defined."),
)
def inner_ls(
    y: np.ndarray, w: np.ndarray, a: np.ndarray, b: np.ndarray, p: int, tau: int, t_min: int
) -> tuple[np.ndarray, int, str]:
    """The paper's inner-signal estimate, eq. (27), solved in O(K) (tridiagonal)."""
    sys = pp.simo_system(w, p, tau, t_min)
    h0, h1 = pp.simo_channels(b, p)
    return pp.inner_signal_ls(sys, h0, h1), sys.n0 - 1, "ls27"


#: ``inverse`` choices of :func:`inverse_inner`.
INVERSES = ("auto", "direct", "bezout", "refuse")


def inverse_inner(choice: str) -> InnerSignal:
    """An ``inner`` step for :func:`blind_fit`: the direct inverse or the Bezout combiner.

    The direct inverse is ``A(q)/B(q) y`` down-sampled by p (Table 5's F_INV); the Bezout
    combiner is the minimum-norm degree-0 combination of the polyphase channels, for a B that
    is not minimum phase.

    Parameters
    ----------
    choice : str
        One of :data:`INVERSES`. ``auto`` uses the direct inverse when every zero of B is inside
        the unit circle and the Bezout combiner otherwise; ``direct`` and ``bezout`` use one of
        them for every run; ``refuse`` marks non-minimum-phase runs with nan (no estimate, the
        reason in :data:`REFUSALS`).

    Returns
    -------
    InnerSignal
        ``inner(y, w, a, b, p, tau, t_min) -> (U~, n_first, label)``.
    """
    if choice not in INVERSES:
        raise InputError(f"inverse must be one of {', '.join(INVERSES)}, got {choice!r}")

    def inner(y, w, a, b, p, tau, t_min):
        n0, periods = pp.simo_periods(w.shape[1], p, tau, t_min)
        n_first = n0 - 1
        M = periods + 1
        nmp = pp.max_root_modulus(b) >= 1.0
        use_direct = (
            (~nmp) if choice in ("auto", "refuse") else np.full(b.shape[0], choice == "direct")
        )
        if use_direct.all():  # every run (the usual case): no copies of the batch
            return pp.inner_signal_direct(y, a, b, p, tau, n_first, M), n_first, "direct"
        # from here on some runs are not minimum phase (or the Bezout combiner was chosen)
        U = np.full((b.shape[0], M), np.nan)
        if use_direct.any():
            U[use_direct] = pp.inner_signal_direct(
                y[use_direct], a[use_direct], b[use_direct], p, tau, n_first, M
            )
        if choice == "refuse":
            return U, n_first, "refused-nmp"  # runs without an estimate get its reason
        rest = ~use_direct
        h0, h1 = pp.simo_channels(b[rest], p)
        sys_rest = pp.simo_system(w[rest], p, tau, t_min)
        U[rest] = pp.inner_signal_bezout(sys_rest, h0, h1)[:, :M]
        return U, n_first, "direct+bezout" if use_direct.any() else "bezout"

    return inner


@parameters(
    PARAMETERS,
    record=("Record", "The record (``y`` is read; ``record.cache`` holds shared tables)."),
    denominator=("DenominatorFit", "``(reg, idx) -> (theta, sigma2)``: A and the noise variance."),
    numerator=("NumeratorFit", "``(dw, tau, nb, sigma2, idx) -> b`` with ``b1 = 1``."),
    inner=("InnerSignal, optional", "The inner-signal step (default: eq. (27), :func:`inner_ls`)."),
    pooled=("bool, optional", "The denominator from all quiet phases instead of phase p alone."),
    rule=("SelectionRule, optional", "How the selection tables are read."),
    info=("dict, optional", "Entries of ``Estimate.info`` (the method's options)."),
    selector=("DenominatorFit, optional", "The denominator estimate of the structure selection."),
    refine=(
        "callable, optional",
        "``(reg, idx, tau, nb) -> (theta, sigma2)`` for the final estimate.",
    ),
)
def blind_fit(
    method: str,
    record: Record,
    options: IdentifyOptions,
    *,
    denominator: DenominatorFit,
    numerator: NumeratorFit,
    inner: InnerSignal = inner_ls,
    pooled: bool = False,
    rule: SelectionRule = SelectionRule(),
    info: dict[str, Any] | None = None,
    selector: DenominatorFit | None = None,
    refine: Callable[..., tuple[np.ndarray, np.ndarray]] | None = None,
) -> Estimate:
    """The blind route shared by the methods: structure, A, B, A4 check, U, alignment with x.

    Runs that select the same (na, tau, nb) are processed together, batched. ``pooled`` takes
    the denominator from all quiet phases ``nb + 1 .. p`` instead of phase ``p`` alone.
    ``selector`` is the denominator estimate used for the structure selection (default: the
    method's own ``denominator``). ``refine(reg, idx, tau, nb) -> (theta, sigma2)``, when given,
    replaces ``denominator`` for the final estimate once the structure is known.
    Methods whose selection estimate is the same module-level function (e.g.
    :func:`~hbench.ident.selection.bias_compensated_fit`,
    :func:`~hbench.ident.selection.ols_fit`), with the same rule and options, share the
    selected structure on one record (kept in ``record.cache``) instead of computing the same
    tables again: such a function sees the regression (built from ``y``) and nothing else. A
    closure may read more (the reference, say) and is never shared.
    """
    p, R, K = record.p, record.runs, record.n_slow
    why = check_identifiable(p, options) or check_length(K, p, options)
    if why:
        return empty_estimate(method, record, why, **(info or {}))
    y = record.y
    fit = selector or denominator
    # the selection reads y alone: what the method knows of the delay's multiple plays no part
    key = (
        ("structure", fit, rule, pooled, replace(options, delay_multiple=0))
        if _reads_the_regression_only(fit)
        else None
    )
    st = kept_in(
        record.cache, key, lambda: select_structure(y, p, options, fit, rule, pooled, record.cache)
    )
    dy_all, lm = shared_moments(y, p, largest_order(options), record.cache)
    na_max, nb_max = int(st.na.max()), int(st.nb.max())
    a = np.zeros((R, na_max))
    b = np.zeros((R, nb_max))
    sigma2 = np.full(R, np.nan)
    U = np.full((R, K), np.nan)
    ok = np.ones(R, bool)
    reason = [""] * R
    inverse: dict[str, int] = {}
    for (na, tau, nb), idx in groups(st.na, st.tau, st.nb):
        phases = tuple(range(nb + 1, p + 1)) if pooled else (p,)
        y_idx = runs_of(y, idx)
        reg = pp.quiet_regression(runs_of(dy_all, idx), p, na, phases, tau, moments=lm.take(idx))
        theta, s2 = refine(reg, idx, tau, nb) if refine is not None else denominator(reg, idx)
        a[idx, :na] = theta
        sigma2[idx] = s2
        den = np.concatenate([np.ones((idx.size, 1)), theta], axis=1)
        w, dw = pp.filtered_output_and_delta(y_idx, den)
        bb = numerator(dw, tau, nb, s2, idx)
        b[idx, :nb] = bb
        bad = check_a4(bb)
        for j in idx[bad]:
            ok[j] = False
            reason[j] = (
                "not identifiable: estimated B(1) = 0 (assumption A4): the inner signal "
                "is not unique"
            )
        good = idx[~bad]
        if good.size:
            if bad.any():
                sel = ~bad
                y_idx, w, den, bb = runs_of(y, good), w[sel], den[sel], bb[sel]
            Ut, n_first, label = inner(y_idx, w, den, bb, p, tau, na)
            U[good] = pp.align(Ut, n_first, options.delay_multiple, K)
            inverse[label] = inverse.get(label, 0) + good.size
            for j in good[np.all(np.isnan(U[good]), axis=1)]:
                reason[j] = REFUSALS.get(label, f"no inner-signal estimate ({label})")
    out_info = dict(info or {})
    out_info["inverse"] = inverse
    out_info["pooled"] = pooled
    return Estimate(
        method=method,
        a=a,
        b=b,
        na=st.na.copy(),
        nb=st.nb.copy(),
        tau=st.tau.copy(),
        sigma2=sigma2,
        U=U,
        identifiable=ok,
        reason=reason,
        criteria={"V": st.V, "var_dw": st.var_dw, "na_values": st.na_values},
        info=out_info,
    )

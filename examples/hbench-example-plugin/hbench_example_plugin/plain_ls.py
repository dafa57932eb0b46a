"""``plain-ls``: a blind method in one function, the recipe to copy for a new method.

Plain least squares on the paper's polyphase equations, with no noise compensation (Wang, Sano,
Shook, Chen & Huang, *A blind approach to closed-loop identification of Hammerstein systems*,
IJC 2007, Sections 3-4; the quiet/active phase idea is Bai & Fu 2002):

1. A(q) by ordinary least squares of ``Delta y`` on its own past at the *quiet* phases
   ``nb + 1 .. p`` of every slow period, where ``Delta A(q) y`` holds noise only (eq. 13;
   ``wang-lsm`` adds the bias compensation of eqs. 14-15 to this step).
2. B(q) with ``b1 = 1`` as the least-squares ratio of the *active* phases of
   ``Delta w = Delta A(q) y``: ``b_l = sum dw_1 dw_l / sum dw_1^2`` (eq. 18 without its
   ``sigma^2`` terms).
3. The inner signal U by the least-squares solution of the SIMO equations (26), eq. (27), then
   placed on the record's slow grid so that ``U[:, n]`` belongs with ``x[:, n]``.

The structure (na, tau, nb) comes from hbench's shared selection (Section 6, steps (i)-(iii))
with the OLS denominator. Under noise the OLS of step 1 is biased (the regressor
``Delta y(t - 1)`` holds ``e(t - 1)``, which is also in the target's ``Delta e(t)``), so this
method is a baseline for what the paper's compensation buys, not a competitor.

:func:`hbench.ident.identifiers.blind_fit` packages this same route (plus sharing the selection
between methods run on one record) for methods that only replace a step; it is spelled out here so
that each field of the :class:`~hbench.ident.identifiers.Estimate` can be seen being filled."""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np

from hbench.ident import polyphase as pp
from hbench.ident.identifiers import (
    Estimate,
    Identifier,
    IdentifyOptions,
    check_a4,
    check_identifiable,
    check_length,
    empty_estimate,
    groups,
    ols_fit,
    select_structure,
)
from hbench.sim.records import Record, Truth


class PlainLS(Identifier):
    """Uncompensated least squares: OLS A on the quiet phases, LS-ratio B, eq. (27) for U.

    Sees ``y`` only (``needs`` is empty), so ``record.x`` and ``record.r`` are None here and
    ``truth`` is always None.
    """

    name: ClassVar[str] = "plain-ls"
    summary: ClassVar[str] = "OLS on quiet phases (no compensation), LS-ratio B, eq. (27) U"
    needs: ClassVar[frozenset[str]] = frozenset()  # add "x" and/or "r" to be shown them

    def identify(
        self, record: Record, options: IdentifyOptions, truth: Truth | None = None
    ) -> Estimate:
        """Estimate A, B, the structure and U for every run of ``record``.

        Parameters
        ----------
        record : hbench.sim.records.Record
            A batch of runs: ``y`` of shape ``(runs, K p)``, ``p``; ``x`` and ``r`` withheld.
        options : hbench.ident.identifiers.IdentifyOptions
            Prior knowledge: ``nb_max`` (n0_b), the ``na`` range, the delay's multiple of p.
        truth : None
            Always None for a method that does not declare ``"truth"``.

        Returns
        -------
        hbench.ident.identifiers.Estimate
            One row per run. Runs where an assumption fails are flagged
            (``identifiable`` False, ``reason`` says why), never raised.
        """
        p, R, K = record.p, record.runs, record.n_slow
        # A2 (p >= n0_b + 1) fails, or the record is too short: every run flagged, all nan
        why = check_identifiable(p, options) or check_length(K, p, options)
        if why:
            return empty_estimate(self.name, record, why)

        # structure (na, tau, nb) per run, Section 6 (i)-(iii); record.cache lets methods run
        # on the same record share the quiet-phase moments (computed from y alone)
        st = select_structure(record.y, p, options, ols_fit, pooled=True, cache=record.cache)

        # the Estimate's arrays: one row per run, a and b zero-padded to the largest order
        a = np.zeros((R, int(st.na.max())))
        b = np.zeros((R, int(st.nb.max())))
        sigma2 = np.full(R, np.nan)
        U = np.full((R, K), np.nan)  # nan where the record does not determine U
        identifiable = np.ones(R, bool)
        reason = [""] * R

        dy = pp.delta(record.y)
        # the polyphase helpers work on runs that share one structure: group them
        for (na, tau, nb), idx in groups(st.na, st.tau, st.nb):
            # 1. A: OLS of eq. (13) on the quiet phases nb+1 .. p under the shift tau
            reg = pp.quiet_regression(dy[idx], p, na, tuple(range(nb + 1, p + 1)), tau)
            theta, ms, _ = pp.ols(reg)
            a[idx, :na] = theta
            sigma2[idx] = ms / 2.0  # Delta e has variance 2 sigma^2 (biased under noise)

            # 2. B: LS ratio of the active phases of Delta w, w = A(q) y (nan for t < na)
            den = np.concatenate([np.ones((idx.size, 1)), theta], axis=1)
            w = pp.filtered_output(record.y[idx], den)
            dw = pp.delta(w)
            bb = pp.b_ols(dw, p, tau, nb, t_min=pp.first_valid(dw))
            b[idx, :nb] = bb

            # A4: B(1) = 0 leaves U undetermined: flag those runs, keep their U nan
            bad = check_a4(bb)
            for j in idx[bad]:
                identifiable[j] = False
                reason[j] = "not identifiable: estimated B(1) = 0 (assumption A4)"
            good = ~bad
            if not good.any():
                continue

            # 3. U: eq. (27), least squares over the SIMO blocks (26) of w, solved in O(K)
            simo = pp.simo_system(w[good], p, tau, t_min=na)
            h0, h1 = pp.simo_channels(bb[good], p)
            U_tilde = pp.inner_signal_ls(simo, h0, h1)  # U~(n0 - 1 ..)
            # on the record's slow grid, shifted by the delay's known multiple of p (A3)
            U[idx[good]] = pp.align(U_tilde, simo.n0 - 1, options.delay_multiple, K)

        return Estimate(
            method=self.name,
            a=a,
            b=b,
            na=st.na.copy(),
            nb=st.nb.copy(),
            tau=st.tau.copy(),
            sigma2=sigma2,
            U=U,
            identifiable=identifiable,
            reason=reason,
            # optional: the selection tables, and notes for provenance
            criteria={"V": st.V, "var_dw": st.var_dw, "na_values": st.na_values},
            info={"pooled": True},
        )

    def options(self) -> dict[str, Any]:
        """No options of its own (a method with some takes them as keyword arguments)."""
        return {}

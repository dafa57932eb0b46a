"""Wang, Sano, Shook, Chen & Huang (2007), "A blind approach to closed-loop identification of
Hammerstein systems", Int. J. Control: the bias-compensated LSM and the IVM.

Both follow the paper's Section 6 algorithm: (i) na and tau from ``V^(p)(na)`` of eq. (19) over
shifts, (ii) A with nb = n0_b, (iii) nb from ``Var{Delta w^(l)}``, (iv) B, (v) U from eq. (27). The
selection in (i) and (iii) is made automatic by :class:`hbench.ident.identifiers.SelectionRule`; the
tables it decided from are kept in ``Estimate.criteria``. ``wang-lsm`` and ``wang-iv`` keep the
LSM's and the IVM's estimates apart so that both can be compared; ``wang`` makes the paper's
choices between them, step (ii) for A by the integrated AIC and step (iv) for b by V_EIV.
"""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np

from hbench.errors import InputError
from hbench.hookspecs import Register, hookimpl
from hbench.ident import polyphase as pp
from hbench.ident.identifiers import (
    INVERSES,
    Estimate,
    Identifier,
    IdentifyOptions,
    SelectionRule,
    bias_compensated_fit,
    blind_fit,
    inner_ls,
    inverse_inner,
    largest_order,
)
from hbench.sim.records import Record, Truth


def _check_instruments(method: str, m: int, lag0: int) -> None:
    """Eq. (20)'s instruments need ``m >= 1`` lags from ``lag0 >= 1`` on."""
    if int(m) < 1 or int(lag0) < 1:
        raise InputError(f"{method} needs m >= 1 and lag0 >= 1 (got m={m}, lag0={lag0})")


class _Wang(Identifier):
    """What the three methods share: the selection rule, ``pooled`` and ``inverse``.

    ``inverse``: ``None`` (default) for eq. (27); one of :data:`hbench.ident.identifiers.INVERSES`
    for the direct inverse ``A(q)/B(q) y`` down-sampled by p instead (Bezout combiner where B is
    not minimum phase, with ``auto``): the method's estimates in the direct inverse, as Table 5's
    F_INV (:func:`hbench.ident.identifiers.inverse_inner`). A and B are the same either way.
    """

    def __init__(
        self,
        pooled: bool = True,
        selection: str = "common-a",
        tol_na: float = 0.10,
        tol_tau: float = 0.25,
        tol_nb: float = 0.5,
        inverse: str | None = None,
    ) -> None:
        if inverse is not None and inverse not in INVERSES:
            raise InputError(
                f"{self.name} inverse must be one of {', '.join(INVERSES)}, got {inverse!r}"
            )
        self.pooled = bool(pooled)
        self.rule = SelectionRule(
            method=selection, tol_na=float(tol_na), tol_tau=float(tol_tau), tol_nb=float(tol_nb)
        )
        self.inverse = inverse

    def options(self) -> dict[str, Any]:
        out = {
            "pooled": self.pooled,
            "selection": self.rule.method,
            "tol_na": self.rule.tol_na,
            "tol_tau": self.rule.tol_tau,
            "tol_nb": self.rule.tol_nb,
        }
        if self.inverse is not None:  # eq. (27) by default, as the paper's
            out["inverse"] = self.inverse
        return out

    def _blind_fit(
        self,
        record: Record,
        options: IdentifyOptions,
        denominator,
        numerator,
        selector=None,
    ) -> Estimate:
        """:func:`hbench.ident.identifiers.blind_fit` with this method's name, options, rule and
        inner-signal step (eq. (27), or the direct inverse when ``inverse`` is set)."""
        return blind_fit(
            self.name,
            record,
            options,
            denominator=denominator,
            numerator=numerator,
            inner=inner_ls if self.inverse is None else inverse_inner(self.inverse),
            pooled=self.pooled,
            rule=self.rule,
            info=self.options(),
            selector=selector,
        )


def _compensated_real(reg: pp.QuietRegression, idx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Eqs. (14)-(15) with the complex roots' real part where (15) has no real root."""
    return pp.bias_compensated(reg, "real")


def _compensated_modulus(reg: pp.QuietRegression, idx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Eqs. (14)-(15) with the complex roots' modulus where (15) has no real root."""
    return pp.bias_compensated(reg, "modulus")


def _compensated_zero(reg: pp.QuietRegression, idx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Eqs. (14)-(15) with no compensation where (15) has no real root."""
    return pp.bias_compensated(reg, "zero")


#: ``wang-lsm``'s ``eq15`` option -> its denominator fit (module-level functions, so that the
#: selection tables are shared on a record as for :func:`bias_compensated_fit`)
EQ15_FITS = {
    "clip": bias_compensated_fit,
    "real": _compensated_real,
    "modulus": _compensated_modulus,
    "zero": _compensated_zero,
}


class WangLSM(_Wang):
    """Bias-compensated least squares (eqs. 13-15 for A, 18 for B, 27 for U).

    * A: ``theta = R^-1 (f - [sigma^2, 0, ..])`` on the quiet-phase equations (13), eq. (14) with
      the sign the extraction lost; sigma^2 from eq. (15) corrected to the root of
      ``g11 x^2 - 2x + s2 = 0`` (the OLS residual tends to ``2 sigma^2 - g11 sigma^4``).
    * B: eq. (18) with ``- 2 sigma^2`` in the first factor and ``+ sigma^2`` for l = 2.
    * U: eq. (27) through its tridiagonal normal equations.
    * ``pooled=True`` (default): A re-estimated from every quiet phase ``nb + 1 .. p`` once nb is
      known, the paper's step (iii) ("taking nb in place of n0_b"); ``pooled=False``: A from
      phase p alone (Section 3.2's ``l = p``). Pooling brings the spreads of Table 4 to the
      paper's (measured: 1.0-1.1x the published std, against 2-4x from phase p alone).
    * ``eq15``: what eq. (15) gives where it has no real root (``clip``, default; ``real``,
      ``modulus``, ``zero``: :func:`hbench.ident.polyphase.noise_variance`).
      It happens in the selection tables, on active phases (wrong shifts: Table 1's tau = 4
      column) and at over-fitted orders; the fit at the paper's structure has a real root.
    * ``inverse``: U by the direct inverse ``A(q)/B(q) y`` instead of eq. (27) (``auto``: Bezout
      combiner where B is not minimum phase): the LSM's estimates as Table 5's F_INV; the same
      option as ``wang-iv``'s and ``wang``'s (:func:`hbench.ident.identifiers.inverse_inner`).

    Consistent for ARX noise ``e / A(q)``; biased for coloured equation noise (Table 4's LSM rows).
    """

    name: ClassVar[str] = "wang-lsm"
    summary: ClassVar[str] = "Wang et al. 2007: bias-compensated LSM (eqs. 14, 15, 18, 27)"

    def __init__(self, eq15: str = "clip", **kwargs: Any) -> None:
        super().__init__(**kwargs)
        if eq15 not in EQ15_FITS:
            raise InputError(f"wang-lsm eq15 must be one of {', '.join(EQ15_FITS)}, got {eq15!r}")
        self.eq15 = eq15

    def options(self) -> dict[str, Any]:
        return {**super().options(), "eq15": self.eq15}

    def identify(
        self, record: Record, options: IdentifyOptions, truth: Truth | None = None
    ) -> Estimate:
        def numerator(dw, tau, nb, sigma2, idx):
            return pp.b_lsm(dw, record.p, tau, nb, sigma2, t_min=pp.first_valid(dw))

        return self._blind_fit(record, options, EQ15_FITS[self.eq15], numerator)


class WangIV(_Wang):
    """Instrumental variables (eqs. 20 for A, 21 for B, 27 for U), instruments from past r.

    The structure (na, tau, nb) is decided once, as in the paper's steps (i)-(iii), from the
    bias-compensated LSM's table (``structure="lsm"``, default: the paper reads both tables and
    cross-checks; the IV's table is noisier and its over-fitted orders win by chance) or from the
    IV's own table (``structure="iv"``); the IV then estimates A and B with that structure.
    ``zeta(k) = [r(k - lag0), ..., r(k - lag0 - m + 1)]`` with the paper's ``lag0 = 1``; the
    extended IV solution uses the Moore-Penrose pseudo-inverse when ``m > na``. Consistent under
    coloured noise as long as r is independent of it (A1); larger variance than the LSM. The noise
    variance reported is half the mean square of the quiet-phase residual. ``inverse``: U by the
    direct inverse instead of eq. (27), as ``wang-lsm``'s.
    """

    name: ClassVar[str] = "wang-iv"
    needs: ClassVar[frozenset[str]] = frozenset({"r"})
    summary: ClassVar[str] = (
        "Wang et al. 2007: instrumental variables from past r (eqs. 20, 21, 27)"
    )

    def __init__(self, m: int = 6, lag0: int = 1, structure: str = "lsm", **kwargs: Any) -> None:
        super().__init__(**kwargs)
        _check_instruments(self.name, m, lag0)
        if structure not in ("lsm", "iv"):
            raise InputError(f"wang-iv structure must be 'lsm' or 'iv', got {structure!r}")
        self.m, self.lag0, self.structure = int(m), int(lag0), structure

    def options(self) -> dict[str, Any]:
        return {**super().options(), "m": self.m, "lag0": self.lag0, "structure": self.structure}

    def identify(
        self, record: Record, options: IdentifyOptions, truth: Truth | None = None
    ) -> Estimate:
        r = record.r
        m = max(self.m, largest_order(options))

        def denominator(reg: pp.QuietRegression, idx: np.ndarray):
            theta = pp.iv(reg, r[idx], m, self.lag0)
            return theta, reg.residual_ms(theta) / 2.0

        def numerator(dw, tau, nb, sigma2, idx):
            t_min = pp.first_valid(dw)
            return pp.b_iv(dw, r[idx], record.p, tau, nb, self.m, t_min, self.lag0)

        selector = bias_compensated_fit if self.structure == "lsm" else None
        return self._blind_fit(record, options, denominator, numerator, selector)


#: ``select_a`` / ``select_b`` values: the paper's criterion, or one estimator throughout
A_CHOICES = ("aic", "lsm", "iv")
B_CHOICES = ("v-eiv", "lsm", "iv")


def _use_iv(choice: str, crit_lsm: np.ndarray, crit_iv: np.ndarray) -> np.ndarray:
    """Where the IVM's estimate is taken: everywhere (``iv``), nowhere (``lsm``), or where its
    criterion is strictly smaller than the LSM's (a tie keeps the LSM's)."""
    if choice == "iv":
        return np.ones(crit_lsm.shape, bool)
    if choice == "lsm":
        return np.zeros(crit_lsm.shape, bool)
    return crit_iv < crit_lsm


class WangPaper(_Wang):
    """The paper's Section 6 algorithm with its choices between the LSM and the IVM.

    * Steps (i), (iii): the structure from the bias-compensated LSM's tables (as ``wang-lsm``).
    * Step (ii): A from the LSM (eq. 14) and from the IVM (eq. 20) on the same quiet-phase rows;
      per run, the one with the smaller integrated AIC, eq. (19) summed over the phases the
      estimate is fitted on (with ``pooled=True`` the phases ``nb + 1 .. p``: the residual mean
      square over their stacked rows, times ``1 + 2 na / K``; the penalty is the same for both).
    * Step (iv): each ``b_l`` (l = 2 .. nb) from the LSM (eq. 18) and from the IVM (eq. 21),
      both on ``w = A(q) y`` with the A chosen in step (ii); per run and per l, the one with the
      smaller generalised prediction error ``V_EIV(l)`` (:func:`hbench.ident.polyphase.v_eiv`).
    * sigma^2 is eq. (15)'s (the LSM's) whichever A is kept; it enters eq. (18) only.

    ``select_a="aic"`` / ``select_b="v-eiv"`` are the paper's steps; ``"lsm"`` or ``"iv"`` take
    one estimator throughout (``select_a="lsm", select_b="lsm"`` gives ``wang-lsm``'s numbers).
    What was chosen is kept per run in ``Estimate.criteria``: ``a_from_iv`` (runs,),
    ``aic`` (runs, 2: LSM, IVM), ``b_from_iv`` and ``v_eiv_lsm``, ``v_eiv_iv`` (runs, nb_max).
    Instruments as ``wang-iv``'s (``m``, ``lag0``); ``inverse``: U from the chosen estimates by the
    direct inverse instead of eq. (27), as ``wang-lsm``'s.
    """

    name: ClassVar[str] = "wang"
    needs: ClassVar[frozenset[str]] = frozenset({"r"})
    summary: ClassVar[str] = (
        "Wang et al. 2007, Section 6: A by integrated AIC and b by V_EIV between LSM and IVM"
    )

    def __init__(
        self,
        select_a: str = "aic",
        select_b: str = "v-eiv",
        m: int = 6,
        lag0: int = 1,
        **kwargs: Any,
    ) -> None:
        super().__init__(**kwargs)
        if select_a not in A_CHOICES:
            raise InputError(
                f"wang select_a must be one of {', '.join(A_CHOICES)}, got {select_a!r}"
            )
        if select_b not in B_CHOICES:
            raise InputError(
                f"wang select_b must be one of {', '.join(B_CHOICES)}, got {select_b!r}"
            )
        _check_instruments(self.name, m, lag0)
        self.select_a, self.select_b = select_a, select_b
        self.m, self.lag0 = int(m), int(lag0)

    def options(self) -> dict[str, Any]:
        return {
            **super().options(),
            "select_a": self.select_a,
            "select_b": self.select_b,
            "m": self.m,
            "lag0": self.lag0,
        }

    def identify(
        self, record: Record, options: IdentifyOptions, truth: Truth | None = None
    ) -> Estimate:
        r, R, p = record.r, record.runs, record.p
        m = max(self.m, largest_order(options))
        width = max(options.nb_max, options.nb or 0)
        a_from_iv = np.zeros(R, bool)
        aic = np.full((R, 2), np.nan)
        b_from_iv = np.zeros((R, width), bool)
        veiv = np.full((2, R, width), np.nan)

        def denominator(reg: pp.QuietRegression, idx: np.ndarray):
            theta_lsm, sigma2 = pp.bias_compensated(reg)
            theta_iv = pp.iv(reg, r[idx], m, self.lag0)
            crit = [pp.aic(reg.residual_ms(t), reg.na, reg.n) for t in (theta_lsm, theta_iv)]
            use = _use_iv(self.select_a, *crit)
            a_from_iv[idx], aic[idx, 0], aic[idx, 1] = use, crit[0], crit[1]
            return np.where(use[:, None], theta_iv, theta_lsm), sigma2

        def numerator(dw, tau, nb, sigma2, idx):
            t_min = pp.first_valid(dw)
            b_lsm = pp.b_lsm(dw, p, tau, nb, sigma2, t_min=t_min)
            b_iv = pp.b_iv(dw, r[idx], p, tau, nb, self.m, t_min, self.lag0)
            crit = [pp.v_eiv(dw, p, tau, b, t_min) for b in (b_lsm, b_iv)]
            use = _use_iv(self.select_b, *crit)
            use[:, 0] = False  # b1 = 1 either way
            b_from_iv[idx, :nb] = use
            veiv[0, idx, :nb], veiv[1, idx, :nb] = crit
            return np.where(use, b_iv, b_lsm)

        est = self._blind_fit(record, options, denominator, numerator, bias_compensated_fit)
        est.criteria.update(
            a_from_iv=a_from_iv, aic=aic, b_from_iv=b_from_iv, v_eiv_lsm=veiv[0], v_eiv_iv=veiv[1]
        )
        est.info["a_from_iv_runs"] = int(a_from_iv.sum())
        est.info["b_from_iv_runs"] = int(b_from_iv.any(axis=1).sum())
        return est


@hookimpl
def register_identifiers(register: Register) -> None:
    register(WangLSM.name, WangLSM)
    register(WangIV.name, WangIV)
    register(WangPaper.name, WangPaper)

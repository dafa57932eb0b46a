"""The structure selection every blind method shares (Section 6, steps (i)-(iii)).

:func:`select_structure` tabulates the criterion of eq. (19) over the candidate orders and
shifts, reads ``na`` and ``tau`` from it by a :class:`SelectionRule`, and ``nb`` from Table 2's
phase variances. The tables and the moments they are computed from are kept in a record's cache
(:func:`kept_in`), so that several methods run on one record compute them once.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from hbench.docparams import parameters
from hbench.errors import InputError
from hbench.ident import polyphase as pp
from hbench.ident.estimate import PARAMETERS, IdentifyOptions, largest_order


@dataclass(frozen=True)
class SelectionRule:
    """The stated, automatic version of the paper's visual selection (Section 3.4, Section 6).

    For every candidate order ``na`` and shift ``s`` the denominator is estimated at phase p under
    shift s (eq. 13-15 or 20), and its criterion ``C(na, s, s')`` of eq. (19) is evaluated at every
    shift ``s'``; ``V(na, s) = C(na, s, s)`` is the paper's table (Table 1).

    ``method="common-a"`` (default): a shift is quiet for a candidate ``(na, s)`` when its ``C`` is
    within ``1 + tol_tau`` of the candidate's smallest; the candidate's block is the cyclic run of
    quiet shifts containing ``s`` (``s`` itself must be quiet). A block's support is the number of
    shifts in it whose own estimate yields the same block. Each order keeps its best-supported
    block (ties: the lowest level, the mean ``C`` over the block); among the orders whose block is
    corroborated (support >= 2, when any order's is; an order whose level is below half the best
    corroborated level is admitted too, for p = nb + 1 where the truth has one quiet phase), ``na``
    is the smallest whose level is
    within ``1 + tol_na`` of the best (parsimony with a tolerance); tau is the last shift of its
    block. Rationale: the true A
    annihilates every quiet phase (eq. 10), so the estimates from all ``p - nb`` quiet shifts
    agree on one block ending at tau (Section 3.4); a regression that fits one active phase (at
    the b2 phase an AR(na + 1) absorbs ``b2/b1 Delta w(t-1)``), or a poor one that inflates every
    shift alike, is supported by itself only; an under-fitted order loses on level.

    ``method="row-min"``: the paper's table read row by row: ``na`` the smallest order whose best
    ``V`` is within ``1 + tol_na`` of the best overall; shifts within ``1 + tol_tau`` of that row's
    minimum are quiet; tau the last shift of the longest cyclic run (Table 3's remark: a run
    4, 0, 1 ends at 1).

    ``nb`` (both methods): phases whose ``Var{Delta w^(l)}`` exceeds ``1 + tol_nb`` times the quiet
    level (the mean of the ``p - n0_b`` smallest) are active; nb is the last active phase within
    ``n0_b`` (Table 2). ``floor`` guards noise-free data: differences below ``floor`` times the
    mean square of ``Delta y`` count as equal (the tables are evaluated from moments, exact up to
    rounding of order 1e-16 of that mean square; any real noise is many decades above 1e-12).
    """

    method: str = "common-a"
    tol_na: float = 0.10
    tol_tau: float = 0.25
    tol_nb: float = 0.5
    floor: float = 1e-12

    def __post_init__(self) -> None:
        if self.method not in ("common-a", "row-min"):
            raise InputError(
                f"selection method must be 'common-a' or 'row-min', got {self.method!r}"
            )
        for name in ("tol_na", "tol_tau", "tol_nb"):
            if not getattr(self, name) >= 0:
                raise InputError(f"selection {name} must be >= 0")


@dataclass(frozen=True)
class Structure:
    """Per-run selected structure and the tables it was decided from."""

    na: np.ndarray
    tau: np.ndarray
    nb: np.ndarray
    V: np.ndarray  # (R, n_na, p): the paper's V(na, shift)
    C: np.ndarray  # (R, n_na, p, p): criterion of the estimate at shift s evaluated at shift s'
    var_dw: np.ndarray  # (R, p)
    na_values: np.ndarray


def _cyclic_run(q: np.ndarray, s: int) -> tuple[int, int]:
    """Length and last element of the cyclic run of True in ``q`` that contains ``s``."""
    p = q.size
    if q.all():
        return p, p - 1
    end = s
    while q[(end + 1) % p]:
        end = (end + 1) % p
    length = 0
    while length < p and q[(end - length) % p]:
        length += 1
    return length, end


def _longest_run(q: np.ndarray) -> tuple[int, int]:
    """Length and last element of the longest cyclic run of True in ``q`` (ties: first found)."""
    best = (0, 0)
    for s in np.flatnonzero(q):
        cand = _cyclic_run(q, int(s))
        if cand[0] > best[0]:
            best = cand
    return best


def _select_row_min(
    V: np.ndarray, na_values: np.ndarray, rule: SelectionRule, floor: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    R = V.shape[0]
    best_per_na = V.min(axis=2)  # (R, n_na)
    best = best_per_na.min(axis=1, keepdims=True)
    ok = best_per_na <= (1 + rule.tol_na) * best + floor[:, None]
    ia = np.argmax(ok, axis=1)
    Vna = V[np.arange(R), ia]
    quiet = Vna <= (1 + rule.tol_tau) * Vna.min(axis=1, keepdims=True) + floor[:, None]
    tau = np.array([_longest_run(quiet[r])[1] for r in range(R)], dtype=int)
    return na_values[ia], tau


def _blocks(q: np.ndarray) -> np.ndarray:
    """Bit mask of the cyclic run of True containing each position: ``q`` (..., p) -> (..., p).

    Positions that are False get mask 0.
    """
    p = q.shape[-1]
    weights = 1 << np.arange(p)
    mask = np.where(q, weights, 0)
    out = mask.copy()
    for direction in (1, -1):  # grow each run p - 1 steps both ways
        reach = q.copy()
        for step in range(1, p):
            nxt = np.roll(q, -direction * step, axis=-1)
            reach = reach & nxt
            out = out | np.where(reach, np.roll(weights, -direction * step), 0)
    return np.where(q, out, 0)


def _last_of_block(mask: np.ndarray, p: int) -> np.ndarray:
    """The last shift of a cyclic block given as a bit mask (the one whose successor is out)."""
    bits = (mask[..., None] >> np.arange(p)) & 1  # (..., p)
    succ = np.roll(bits, -1, axis=-1)
    last = (bits == 1) & (succ == 0)
    full = bits.all(axis=-1)
    return np.where(full, p - 1, np.argmax(last, axis=-1))


#: Largest p whose cyclic blocks are read from tables of every bit pattern (2**p rows).
_TABLE_P = 12


@functools.cache
def _block_tables(p: int) -> tuple[np.ndarray, np.ndarray]:
    """For every pattern of ``p`` bits ``m`` (row ``m``): :func:`_blocks` of the pattern
    ``(2**p, p)`` and :func:`_last_of_block` of the mask ``m`` ``(2**p,)``. Built by those
    functions, so a lookup gives their values exactly; read-only (shared by every call)."""
    patterns = ((np.arange(2**p)[:, None] >> np.arange(p)) & 1).astype(bool)
    blocks, last = _blocks(patterns), _last_of_block(np.arange(2**p), p)
    blocks.flags.writeable = last.flags.writeable = False
    return blocks, last


def _last_shift(mask: np.ndarray, p: int) -> np.ndarray:
    """:func:`_last_of_block`, read from its table where there is one (p <= 12)."""
    return _block_tables(p)[1][mask] if p <= _TABLE_P else _last_of_block(mask, p)


def _own_blocks(q: np.ndarray, own: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(block, last)``: for each row ``s`` of ``q`` (..., p, p) where ``own``, the mask of the
    cyclic run of True containing position ``s`` (else 0), and the last shift of that mask."""
    p = q.shape[-1]
    if p > _TABLE_P:
        diag = np.arange(p)[None, None, :, None]
        block = np.where(own, np.take_along_axis(_blocks(q), diag, axis=3)[..., 0], 0)
    else:
        pattern = np.where(q, 1 << np.arange(p), 0).sum(axis=-1)
        block = np.where(own, _block_tables(p)[0][pattern, np.arange(p)], 0)
    return block, _last_shift(block, p)


def _select_common_a(
    C: np.ndarray,
    na_values: np.ndarray,
    rule: SelectionRule,
    floor: np.ndarray,
    allowed: np.ndarray,
    min_quiet: int = 2,
) -> tuple[np.ndarray, np.ndarray]:
    R, _n_na, p, _ = C.shape
    fl = floor[:, None, None, None]
    q = C <= (1 + rule.tol_tau) * C.min(axis=3, keepdims=True) + fl  # (R, n_na, s, s')
    own = np.einsum("rass->ras", q)  # the estimate from s explains s
    block, last = _own_blocks(q, own)  # (R, n_na, s)
    valid = own & allowed[last]
    # support: shifts of the same order whose own block is the same
    same = (block[..., :, None] == block[..., None, :]) & valid[..., None, :]
    support = np.where(valid, same.sum(axis=3), 0)
    bits = ((block[..., None] >> np.arange(p)) & 1).astype(bool)  # (R, n_na, s, s')
    level_s = np.where(bits, C, 0.0).sum(axis=3) / np.maximum(bits.sum(axis=3), 1)
    # a block's level: mean over the shifts that support it
    level = np.where(same, level_s[..., None, :], 0.0).sum(axis=3) / np.maximum(support, 1)
    # per order: max support, then min level
    key = np.where(valid, support - level / (np.abs(level).max() + 1.0) * 0.5, -np.inf)
    best_s = np.argmax(key, axis=2)  # (R, n_na)

    def take(a):
        return np.take_along_axis(a, best_s[..., None], axis=2)[..., 0]

    sup_o, lev_o, blk_o = take(support), take(level), take(block)
    has = np.isfinite(take(key))
    need = np.minimum(2, np.where(has, sup_o, 0).max(axis=1, keepdims=True))
    eligible = has & (sup_o >= need)
    # with one quiet phase (p = nb + 1) the true block cannot be corroborated: an order whose
    # level is below half the best corroborated one is admitted (an under-fitted order inflates
    # every shift alike, so it can look corroborated at a far higher level)
    best_corr = np.where(eligible, lev_o, np.inf).min(axis=1, keepdims=True)
    eligible |= has & (lev_o <= 0.5 * best_corr)
    best = np.where(eligible, lev_o, np.inf).min(axis=1, keepdims=True)
    ok = eligible & (lev_o <= (1 + rule.tol_na) * best + floor[:, None])
    ia = np.argmax(ok, axis=1)
    na = na_values[ia]
    tau = _last_shift(blk_o[np.arange(R), ia], p)
    none = ~ok.any(axis=1)
    if none.any():  # nothing explains itself: fall back to the paper's table
        V = np.einsum("rass->ras", C[none])
        na_f, tau_f = _select_row_min(
            np.where(allowed[None, None, :], V, np.inf), na_values, rule, floor[none]
        )
        na[none], tau[none] = na_f, tau_f
    return na, tau


def _select_nb(
    var_dw: np.ndarray, nb_max: int, rule: SelectionRule, scale: np.ndarray
) -> np.ndarray:
    _R, p = var_dw.shape
    n_quiet = max(p - nb_max, 1)
    level = np.sort(var_dw, axis=1)[:, :n_quiet].mean(axis=1, keepdims=True)
    active = var_dw > (1 + rule.tol_nb) * level + (rule.floor * scale)[:, None]
    active[:, nb_max:] = False
    last = np.where(active.any(axis=1), p - 1 - np.argmax(active[:, ::-1], axis=1), 0)
    return np.maximum(last + 1, 1)


#: ``fit(reg, idx) -> (theta, sigma2)``: a denominator estimate on the runs ``idx`` of the batch.
DenominatorFit = Callable[[pp.QuietRegression, np.ndarray], tuple[np.ndarray, np.ndarray]]


@parameters(PARAMETERS)
def bias_compensated_fit(reg: pp.QuietRegression, idx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Eqs. (14)-(15) as a :data:`DenominatorFit` (the LSM's estimate and selection)."""
    return pp.bias_compensated(reg)


@parameters(PARAMETERS)
def ols_fit(reg: pp.QuietRegression, idx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Ordinary LS of eq. (13) as a :data:`DenominatorFit`; sigma^2 as half the residual mean
    square (Bai & Fu's estimate and selection).
    """
    theta, s2, _ = pp.ols(reg)
    return theta, s2 / 2.0


@parameters(
    PARAMETERS,
    cache=("dict or None", "A record's cache (``record.cache``); None computes afresh."),
    key=("hashable or None", "What the value is kept under; None computes afresh."),
    make=("callable", "``make()`` computes the value."),
)
def kept_in(cache: dict[Any, Any] | None, key: Any, make: Callable[[], Any]) -> Any:
    """``make()``, kept in ``cache`` (a record's) under ``key`` and taken from there next time.

    Computed afresh when there is no cache (or no key). Kept arrays (``make()`` itself, or the
    arrays of a tuple) are made read-only, as the record's are."""
    if cache is None or key is None:
        return make()
    if key not in cache:
        value = make()
        for arr in value if isinstance(value, tuple) else (value,):
            if isinstance(arr, np.ndarray):  # shared by the methods: none may change it
                arr.flags.writeable = False
        cache[key] = value
    return cache[key]


@parameters(
    PARAMETERS,
    L=("int", "Largest lag (regression order) the moments must cover."),
    cache=("dict, optional", "A record's cache (``record.cache``); None computes afresh."),
)
def shared_moments(
    y: np.ndarray, p: int, L: int, cache: dict[str, Any] | None = None
) -> tuple[np.ndarray, pp.LagMoments]:
    """``(Delta y, its quiet-phase moments up to lag L)``, kept in ``cache`` (a record's) so that
    every method run on one record computes them once.
    """

    def make() -> tuple[np.ndarray, pp.LagMoments]:
        dy = pp.delta(y)
        return dy, pp.LagMoments(dy, p, L)

    return kept_in(cache, f"quiet-moments/p={p}/L={L}", make)


def _mean_square(dy: np.ndarray, cache: dict[str, Any] | None = None) -> np.ndarray:
    """``nanmean(dy**2, axis=1)`` (the same sums: nan squares zeroed, then ``np.sum``), kept in
    ``cache`` so that the selections of several methods on one record compute it once."""

    def make() -> np.ndarray:
        sq = np.square(dy)
        bad = np.isnan(sq)
        sq[bad] = 0.0
        return np.sum(sq, axis=1) / np.sum(~bad, axis=1, dtype=np.intp)

    return kept_in(cache, "mean-square-delta-y", make)


@parameters(
    PARAMETERS,
    options=("IdentifyOptions", "Orders and delay given a priori (those given are not selected)."),
    fit=("DenominatorFit", "The denominator estimate whose criterion is tabulated."),
    rule=("SelectionRule, optional", "How the tables are read (default: ``SelectionRule()``)."),
    pooled=(
        "bool, optional",
        "Re-estimate A from every quiet phase ``nb + 1 .. p`` for step (iii).",
    ),
    cache=("dict, optional", "A record's cache, for moments shared between methods."),
)
def select_structure(
    y: np.ndarray,
    p: int,
    options: IdentifyOptions,
    fit: DenominatorFit,
    rule: SelectionRule = SelectionRule(),
    pooled: bool = False,
    cache: dict[str, Any] | None = None,
) -> Structure:
    """Steps (i)-(iii) of Section 6 for a batch of runs.

    (i) ``V^(p)(na, shift)`` of eq. (19) with ``theta`` from ``fit`` (bias-compensated LSM or IV)
    at phase ``l = p`` under each shift; ``na`` and ``tau`` by :class:`SelectionRule`.
    (ii)-(iii) ``A`` with ``nb = n0_b``, ``w = A(q) y``, ``Var{Delta w^(l)}``, ``nb``.
    With ``na``, ``tau`` and ``nb`` all given nothing is selected and the tables are nan.
    """
    R = y.shape[0]
    if options.na is not None and options.tau is not None and options.nb is not None:
        if not 0 <= options.tau < p:
            raise InputError(f"tau must lie within [0, p) = [0, {p}), got {options.tau}")
        return Structure(
            na=np.full(R, int(options.na)),
            tau=np.full(R, int(options.tau)),
            nb=np.full(R, int(options.nb)),
            V=np.full((R, 1, p), np.nan),
            C=np.full((R, 1, p, p), np.nan),
            var_dw=np.full((R, p), np.nan),
            na_values=np.array([options.na]),
        )
    dy, lm = shared_moments(y, p, largest_order(options), cache)
    scale = _mean_square(dy, cache)
    na_lo, na_hi = options.na_range
    na_values = np.arange(na_lo, na_hi + 1) if options.na is None else np.array([options.na])
    shifts = list(range(p))
    if options.tau_range is not None:
        lo, hi = options.tau_range
        if not 0 <= lo <= hi < p:
            raise InputError(
                f"tau_range must lie within [0, p) = [0, {p}), got {options.tau_range}"
            )
    all_runs = np.arange(R)
    n_na = na_values.size
    # one regression per shift with the largest order; every order uses its first columns and
    # the same rows (those valid for the largest order), so V is compared on equal data
    na_max = int(na_values.max())
    # kept in the record's cache: another method's selection on the same record (the LSM's
    # and the OLS's tables) reuses the regressions and what they computed (Rm^+)
    full = kept_in(
        cache,
        f"selection-regressions/p={p}/na={na_max}/L={lm.L}",
        lambda: [
            pp.quiet_regression(dy, p, na_max, (p,), s, moments=lm, fast=True) for s in shifts
        ],
    )
    C = np.empty((R, n_na, p, p))
    for i, na in enumerate(na_values):
        regs = [reg.truncate(int(na)) for reg in full]
        pp.QuietRegression.invert_together(regs)
        # eq. (19) for the estimate of every shift s on the rows of every shift s2, from the
        # moments: the residual mean square is v' M v with v = [1, -theta]
        v = np.ones((R, p, int(na) + 1))
        v[:, :, 1:] = -np.stack([fit(reg, all_runs)[0] for reg in regs], axis=1)
        M = np.stack([reg.all_moments() for reg in regs], axis=1)  # (R, s2, na+1, na+1)
        # two plain einsums, not an optimised path: that one contracts one run differently
        # from many, and a run's numbers must not depend on the runs it is batched with
        ms = np.einsum("rsa,rsta->rst", v, np.einsum("rtab,rsb->rsta", M, v))
        C[:, i] = pp.aic(ms, int(na), regs[0].n)
    V = np.einsum("rass->ras", C)
    allowed = np.ones(p, bool)
    if options.tau_range is not None:
        lo, hi = options.tau_range
        allowed[:] = False
        allowed[lo : hi + 1] = True
    floor = rule.floor * scale
    if rule.method == "row-min":
        na, tau = _select_row_min(
            np.where(allowed[None, None, :], V, np.inf), na_values, rule, floor
        )
    else:
        na, tau = _select_common_a(C, na_values, rule, floor, allowed)
    if options.tau is not None:
        tau = np.full(R, int(options.tau))
    # (ii)-(iii): A with nb = n0_b, then Var of Delta w per phase
    var_dw = np.empty((R, p))
    for key in set(zip(na.tolist(), tau.tolist(), strict=True)):
        idx = np.flatnonzero((na == key[0]) & (tau == key[1]))
        phases = tuple(range(options.nb_max + 1, p + 1)) if pooled else (p,)
        reg = pp.quiet_regression(runs_of(dy, idx), p, key[0], phases, key[1], moments=lm.take(idx))
        a = np.concatenate([np.ones((idx.size, 1)), fit(reg, idx)[0]], axis=1)
        var_dw[idx] = pp.filtered_phase_variances(runs_of(y, idx), a, p, key[1], t_min=key[0] + 1)
    nb = (
        _select_nb(var_dw, options.nb_max, rule, scale)
        if options.nb is None
        else np.full(R, int(options.nb))
    )
    return Structure(na=na, tau=tau, nb=nb, V=V, C=C, var_dw=var_dw, na_values=na_values)


@parameters(
    PARAMETERS,
    a=("ndarray", "An array over runs, ``(runs, ...)``."),
    idx=("ndarray of int", "Sorted distinct run indices (as :func:`groups` gives)."),
)
def runs_of(a: np.ndarray, idx: np.ndarray) -> np.ndarray:
    """``a[idx]``, read-only.

    When ``idx`` is every run of a C-ordered ``a``, a view of it instead of a copy (the same
    values in the same layout, hence the same numbers, without copying the batch). Read-only
    either way, so a step that writes to its input fails whatever the batch."""
    out = a.view() if idx.size == a.shape[0] and a.flags.c_contiguous else a[idx]
    out.flags.writeable = False
    return out


@parameters(
    PARAMETERS, keys=("ndarray", "Per-run keys of equal length (e.g. ``na``, ``tau``, ``nb``).")
)
def groups(*keys: np.ndarray) -> list[tuple[tuple[int, ...], np.ndarray]]:
    """Runs grouped by equal keys: ``[((k1, k2, ..), indices), ...]``."""
    stacked = np.stack(keys, axis=1)
    uniq, inv = np.unique(stacked, axis=0, return_inverse=True)
    return [
        (tuple(int(v) for v in u), np.flatnonzero(inv.ravel() == i)) for i, u in enumerate(uniq)
    ]

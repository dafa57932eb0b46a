"""The identifier interface and the structure selection every blind method shares.

An identifier receives a :class:`~hbench.sim.records.Record` (``y`` always; ``x`` and ``r`` only if
it declares it needs them) and :class:`IdentifyOptions` (what the user knows a priori: p from the
record, the bound ``n0_b``, the ``na`` range, the fractional-delay range and the known multiple of p
in the delay, assumption A3). It returns an :class:`Estimate`. It never sees the truth; the oracle
is the one declared exception (``needs = {"truth"}``).

The structure selection (Section 6, steps (i)-(iii)) is shared: :func:`select_structure`.
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from typing import Any, ClassVar

import numpy as np

from hbench.docparams import parameters
from hbench.errors import InputError, MethodError
from hbench.ident import polyphase as pp
from hbench.sim.records import Record, Truth


@dataclass(frozen=True)
class IdentifyOptions:
    """Prior knowledge given to every method (the paper's assumptions A2, A3).

    Parameters
    ----------
    nb_max : int
        Upper bound ``n0_b`` of the numerator order (A2 requires ``p >= n0_b + 1``).
    na_range : tuple of int
        Candidate denominator orders (inclusive range ``(lo, hi)``).
    tau_range : tuple of int or None
        Candidate fractional delays ``(lo, hi)`` inclusive, within ``[0, p)``; None for all.
    delay_multiple : int
        The delay's integer multiple of p, known a priori (A3); aligns U with x.
    na : int or None
        Fix ``na`` instead of selecting it.
    tau : int or None
        Fix the fractional delay instead of selecting it.
    nb : int or None
        Fix ``nb`` instead of selecting it.
    """

    nb_max: int = 4
    na_range: tuple[int, int] = (1, 5)
    tau_range: tuple[int, int] | None = None
    delay_multiple: int = 0
    na: int | None = None
    tau: int | None = None
    nb: int | None = None

    def __post_init__(self) -> None:
        # tuples (a list from Python or a config would make the options unhashable)
        object.__setattr__(self, "na_range", tuple(int(v) for v in self.na_range))
        if self.tau_range is not None:
            object.__setattr__(self, "tau_range", tuple(int(v) for v in self.tau_range))
        lo, hi = self.na_range
        if not 1 <= lo <= hi:
            raise InputError(f"na_range must satisfy 1 <= lo <= hi, got {self.na_range}")
        if self.nb_max < 1:
            raise InputError(f"nb_max (n0_b) must be >= 1, got {self.nb_max}")
        if self.delay_multiple < 0:
            raise InputError(f"delay_multiple must be >= 0, got {self.delay_multiple}")


@dataclass
class Estimate:
    """A method's estimate for a batch of runs.

    Attributes
    ----------
    method : str
        Registered name of the method.
    a : ndarray, shape (runs, na_max)
        ``a1 .. a_na`` per run, zero-padded to the largest selected order.
    b : ndarray, shape (runs, nb_max)
        ``b1 .. b_nb`` per run with ``b1 = 1`` (the paper's normalisation), zero-padded.
    na, nb, tau : ndarray of int, shape (runs,)
        Selected orders and fractional delay.
    sigma2 : ndarray, shape (runs,)
        Noise-variance estimate (``nan`` where the method has none).
    U : ndarray, shape (runs, K)
        Slow-rate inner signal aligned with ``x`` (``U[:, n]`` belongs with ``x[:, n]``), up to the
        gain ambiguity (b1 = 1); ``nan`` where the record does not determine it.
    identifiable : ndarray of bool, shape (runs,)
        False where an assumption fails (A2, A4); ``reason`` says which.
    reason : list of str
        Per run: empty, or why the run is not identifiable / failed.
    criteria : dict of ndarray
        Selection tables: ``V_lsm``/``V_iv`` (runs, n_na, p) of eq. (19) over (na, shift),
        ``var_dw`` (runs, p) (Table 2), ...
    info : dict
        Method options and notes (e.g. which inverse was used).
    delay_multiple : ndarray of int or None
        The delay's multiple of p where the method estimates it (relaxing A3); None where it
        takes the known value of :class:`IdentifyOptions`.
    """

    method: str
    a: np.ndarray
    b: np.ndarray
    na: np.ndarray
    nb: np.ndarray
    tau: np.ndarray
    sigma2: np.ndarray
    U: np.ndarray
    identifiable: np.ndarray
    reason: list[str]
    criteria: dict[str, np.ndarray] = field(default_factory=dict)
    info: dict[str, Any] = field(default_factory=dict)
    delay_multiple: np.ndarray | None = None

    @property
    def runs(self) -> int:
        return self.U.shape[0]

    def params(self) -> dict[str, np.ndarray]:
        """``a1, a2, ..., b2, b3, ...`` as arrays over runs (``nan`` beyond a run's order)."""
        out: dict[str, np.ndarray] = {}
        for i in range(self.a.shape[1]):
            out[f"a{i + 1}"] = np.where(self.na > i, self.a[:, i], np.nan)
        for j in range(1, self.b.shape[1]):
            out[f"b{j + 1}"] = np.where(self.nb > j, self.b[:, j], np.nan)
        return out

    @property
    def den(self) -> np.ndarray:
        """``[1, a1, ...]`` per run (scipy.signal convention)."""
        return np.concatenate([np.ones((self.runs, 1)), self.a], axis=1)


class Identifier:
    """Base class of blind identification methods (one plugin each).

    Subclasses set ``name``, ``needs`` (subset of ``{"x", "r", "truth"}``), ``summary``,
    ``reconstruction`` (True where the algorithm is this project's reconstruction of a method
    whose source is not available: reports say so), and ``test_options`` (tiny options for the
    conformance suite), and implement :meth:`identify`.
    """

    name: ClassVar[str] = ""
    needs: ClassVar[frozenset[str]] = frozenset()
    summary: ClassVar[str] = ""
    reconstruction: ClassVar[bool] = False
    test_options: ClassVar[dict[str, Any]] = {}

    def __init__(self, **options: Any) -> None:
        if options:
            raise InputError(f"method {self.name!r} takes no options, got {sorted(options)}")

    def identify(
        self, record: Record, options: IdentifyOptions, truth: Truth | None = None
    ) -> Estimate:
        """Estimate A, B, the structure and the inner signal from ``record``."""
        raise NotImplementedError

    def options(self) -> dict[str, Any]:
        """The method's own options (for provenance)."""
        return {}


# --- structure selection (Section 6, steps (i)-(iii)) -------------------------------------------


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


#: numpydoc descriptions of the parameters shared here (:func:`hbench.docparams.parameters`)
_PARAMS: dict[str, tuple[str, str]] = {
    "p": ("int", "Fast-sampling ratio."),
    "reg": ("QuietRegression", "The quiet-phase equations (13) of a group of runs."),
    "idx": (
        "ndarray of int",
        "The group's runs in the record (unused: the fit reads ``reg`` only).",
    ),
    "y": ("ndarray", "Fast-rate outputs, ``(runs, N)``."),
    "method": ("str", "The method's name (``Estimate.method``)."),
    "options": ("IdentifyOptions", "What is known a priori."),
}


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


@parameters(
    _PARAMS,
    p=("int", "Fast-sampling ratio of the record."),
    options=("IdentifyOptions", "What the method knows a priori (``nb_max`` is n0_b)."),
)
def check_identifiable(p: int, options: IdentifyOptions) -> str:
    """Empty string, or why assumption A2 fails for this p."""
    if p < options.nb_max + 1:
        return (
            f"not identifiable: p = {p} < n0_b + 1 = {options.nb_max + 1} "
            "(assumption A2; Bai, Li & Dasgupta 2002)"
        )
    return ""


@parameters(
    _PARAMS,
    K=("int", "Slow periods (controller samples) of the record."),
    options=("IdentifyOptions", "The orders the regressions may take (:func:`largest_order`)."),
)
def check_length(K: int, p: int, options: IdentifyOptions) -> str:
    """Empty string, or why a record of K slow periods is too short for the quiet regressions."""
    L = largest_order(options)
    need = -(-(L + 1) // p) + 3  # the periods before the first full lag window, then 3 rows
    if K < need:
        return (
            f"record too short: {K} controller periods, the regressions of order up to {L} "
            f"at p = {p} need at least {need}"
        )
    return ""


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


@parameters(_PARAMS)
def bias_compensated_fit(reg: pp.QuietRegression, idx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Eqs. (14)-(15) as a :data:`DenominatorFit` (the LSM's estimate and selection)."""
    return pp.bias_compensated(reg)


@parameters(_PARAMS)
def ols_fit(reg: pp.QuietRegression, idx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Ordinary LS of eq. (13) as a :data:`DenominatorFit`; sigma^2 as half the residual mean
    square (Bai & Fu's estimate and selection).
    """
    theta, s2, _ = pp.ols(reg)
    return theta, s2 / 2.0


def _reads_the_regression_only(fit: Callable[..., Any]) -> bool:
    """A module-level function, no closure: what it computes depends on its arguments alone."""
    return getattr(fit, "__closure__", True) is None and "<locals>" not in getattr(
        fit, "__qualname__", "<locals>"
    )


@parameters(_PARAMS, options=("IdentifyOptions", "The given orders, or the ranges searched."))
def largest_order(options: IdentifyOptions) -> int:
    """The largest denominator order a method may fit under ``options``."""
    return int(options.na) if options.na is not None else int(options.na_range[1])


def _kept(cache: dict[Any, Any] | None, key: Any, make: Callable[[], Any]) -> Any:
    """``make()``, kept in ``cache`` (a record's) under ``key`` and taken from there next time;
    computed afresh when there is no cache (or no key). Kept arrays (``make()`` itself, or the
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
    _PARAMS,
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

    return _kept(cache, f"quiet-moments/p={p}/L={L}", make)


def _mean_square(dy: np.ndarray, cache: dict[str, Any] | None = None) -> np.ndarray:
    """``nanmean(dy**2, axis=1)`` (the same sums: nan squares zeroed, then ``np.sum``), kept in
    ``cache`` so that the selections of several methods on one record compute it once."""

    def make() -> np.ndarray:
        sq = np.square(dy)
        bad = np.isnan(sq)
        sq[bad] = 0.0
        return np.sum(sq, axis=1) / np.sum(~bad, axis=1, dtype=np.intp)

    return _kept(cache, "mean-square-delta-y", make)


@parameters(
    _PARAMS,
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
    full = _kept(
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
        reg = pp.quiet_regression(_runs(dy, idx), p, key[0], phases, key[1], moments=lm.take(idx))
        a = np.concatenate([np.ones((idx.size, 1)), fit(reg, idx)[0]], axis=1)
        var_dw[idx] = pp.filtered_phase_variances(_runs(y, idx), a, p, key[1], t_min=key[0] + 1)
    nb = (
        _select_nb(var_dw, options.nb_max, rule, scale)
        if options.nb is None
        else np.full(R, int(options.nb))
    )
    return Structure(na=na, tau=tau, nb=nb, V=V, C=C, var_dw=var_dw, na_values=na_values)


def _runs(a: np.ndarray, idx: np.ndarray) -> np.ndarray:
    """``a[idx]``, read-only, for sorted distinct run indices ``idx`` (as :func:`groups` gives);
    when they are every run of a C-ordered ``a``, a view of it instead of a copy (the same values
    in the same layout, hence the same numbers, without copying the batch). Read-only either way,
    so a step that writes to its input fails whatever the batch."""
    out = a.view() if idx.size == a.shape[0] and a.flags.c_contiguous else a[idx]
    out.flags.writeable = False
    return out


@parameters(
    _PARAMS, keys=("ndarray", "Per-run keys of equal length (e.g. ``na``, ``tau``, ``nb``).")
)
def groups(*keys: np.ndarray) -> list[tuple[tuple[int, ...], np.ndarray]]:
    """Runs grouped by equal keys: ``[((k1, k2, ..), indices), ...]``."""
    stacked = np.stack(keys, axis=1)
    uniq, inv = np.unique(stacked, axis=0, return_inverse=True)
    return [
        (tuple(int(v) for v in u), np.flatnonzero(inv.ravel() == i)) for i, u in enumerate(uniq)
    ]


@parameters(
    _PARAMS,
    b=("ndarray", "Numerator coefficients, ``(runs, nb)``."),
    tol=("float, optional", "``|B(1)|`` at or below this counts as zero."),
)
def check_a4(b: np.ndarray, tol: float = 1e-6) -> np.ndarray:
    """True where ``B(1) = sum b`` is (numerically) zero: assumption A4 fails."""
    return np.abs(b.sum(axis=1)) <= tol * np.abs(b).sum(axis=1)


@parameters(
    _PARAMS,
    record=("Record", "The record the estimate is for (its runs and slow samples)."),
    reason=("str", "Why there is no estimate, kept for every run."),
    info=("Any", "Entries of ``Estimate.info``."),
)
def empty_estimate(method: str, record: Record, reason: str, **info: Any) -> Estimate:
    """An all-nan estimate flagged not identifiable (never an exception that stops a sweep)."""
    R, K = record.runs, record.n_slow
    return Estimate(
        method=method,
        a=np.full((R, 1), np.nan),
        b=np.full((R, 1), np.nan),
        na=np.zeros(R, int),
        nb=np.zeros(R, int),
        tau=np.zeros(R, int),
        sigma2=np.full(R, np.nan),
        U=np.full((R, K), np.nan),
        identifiable=np.zeros(R, bool),
        reason=[reason] * R,
        info=dict(info),
    )


@parameters(
    _PARAMS,
    parts=("sequence of ndarray", "2-D arrays with equal row counts."),
    width=("int", "Columns of the result (at least each part's)."),
)
def pad(parts: Sequence[np.ndarray], width: int) -> np.ndarray:
    """Zero-pad 2-D arrays on the right to ``width`` columns."""
    return np.stack([np.pad(p, (0, width - p.size)) for p in parts])


@parameters(
    _PARAMS,
    method=("Identifier", "The method instance."),
    record=("Record", "The record; ``x`` and ``r`` reach the method only if it needs them."),
    truth=("Truth, optional", "The simulation's truth; passed only to a method that needs it."),
)
def identify(
    method: Identifier, record: Record, options: IdentifyOptions, truth: Truth | None = None
) -> Estimate:
    """Run ``method`` on ``record`` showing it only what it declared it needs."""
    rec = record.withhold(method.needs)
    missing = [s for s in ("x", "r") if s in method.needs and getattr(rec, s) is None]
    if missing:
        raise InputError(
            f"method {method.name!r} needs {', '.join(missing)}, absent from the record"
        )
    if "truth" in method.needs and truth is None:
        raise InputError(f"method {method.name!r} (an oracle) needs the simulation's truth")
    est = method.identify(rec, options, truth if "truth" in method.needs else None)
    check_estimate(est, record, method.name)
    return est


@parameters(
    _PARAMS,
    est=("Any", "What the method returned."),
    record=("Record", "The record it was given."),
    name=("str", "The method's name, for the message."),
)
def check_estimate(est: Any, record: Record, name: str) -> None:
    """Raise :class:`~hbench.errors.MethodError` unless ``est`` is an :class:`Estimate` of the
    shapes :class:`Estimate` documents for ``record`` (``R`` runs, ``K`` slow samples).

    :func:`identify` checks every method's return value with it, so that a plugin returning a
    malformed estimate fails with a message naming it, instead of an error further down (in the
    metrics, or in another method's rows). Values are not judged here: ``nan`` is how an
    estimate says the record does not determine something.
    """
    if not isinstance(est, Estimate):
        raise MethodError(
            f"method {name!r} returned {type(est).__name__}, "
            "not an hbench.ident.identifiers.Estimate"
        )
    R, K = record.runs, record.n_slow
    wanted: dict[str, tuple[int | None, ...]] = {
        "U": (R, K),
        "a": (R, None),
        "b": (R, None),
        "na": (R,),
        "nb": (R,),
        "tau": (R,),
        "sigma2": (R,),
        "identifiable": (R,),
    }
    if est.delay_multiple is not None:
        wanted["delay_multiple"] = (R,)
    problems = []
    for field_name, shape in wanted.items():
        got = np.shape(getattr(est, field_name))
        fits = len(got) == len(shape) and all(
            w is None or g == w for g, w in zip(got, shape, strict=True)
        )
        if not fits:
            want = tuple("any" if w is None else w for w in shape)
            problems.append(f"{field_name} of shape {got}, expected {want}".replace("'", ""))
    if np.shape(est.b)[1:] == (0,):
        problems.append("b without b1 (shape (R, 0))")
    for field_name in ("na", "nb", "tau", "delay_multiple"):
        v = getattr(est, field_name)
        if field_name in wanted and np.size(v) and not _whole(v):
            problems.append(f"{field_name} holds values that are not whole numbers")
    if not _shape_failed(problems):
        a_cols, b_cols = np.shape(est.a)[1], np.shape(est.b)[1]
        if _whole(est.na) and np.size(est.na) and int(np.max(est.na)) > a_cols:
            problems.append(f"na up to {int(np.max(est.na))} with only {a_cols} columns of a")
        if _whole(est.nb) and np.size(est.nb) and int(np.max(est.nb)) > b_cols:
            problems.append(f"nb up to {int(np.max(est.nb))} with only {b_cols} columns of b")
    reason = est.reason
    if isinstance(reason, (str, bytes)) or not hasattr(reason, "__len__") or len(reason) != R:
        what = type(reason).__name__
        if hasattr(reason, "__len__") and not isinstance(reason, (str, bytes)):
            what = f"a {what} of {len(reason)}"
        problems.append(f"reason is {what}, expected one string per run ({R})")
    if problems:
        runs = "1 run" if R == 1 else f"{R} runs"
        raise MethodError(
            f"method {name!r} returned an invalid estimate for a record of {runs} and {K} slow "
            f"samples: {'; '.join(problems)}"
        )


#: Why a run the method called identifiable is counted as failed.
NO_ESTIMATE = "the method returned no finite inner-signal estimate U for this run"


#: The reason of a run whose method called it identifiable but returned an infinite parameter.
NON_FINITE = "non-finite parameters (an infinite a or b)"


@parameters(_PARAMS, est=("Estimate", "A checked estimate (:func:`check_estimate`)."))
def run_status(est: Estimate) -> tuple[np.ndarray, list[str]]:
    """Each run's status and reason: ``ok`` (with the method's note, if any), ``not-identifiable``
    (the method's flag and its reason), or ``failed`` where the method called the run
    identifiable but returned neither a finite sample of ``U`` nor a reason (a result without
    an estimate or an explanation: a failure of the method, reason :data:`NO_ESTIMATE`), or
    an infinite parameter (reason :data:`NON_FINITE`: an overflow is never an estimate).

    A run without ``U`` whose method says why (bai-fu's refused unstable inverse) stays ``ok``:
    its parameters, orders and delay are estimates the bias and structure tables count.
    """
    ok = np.asarray(est.identifiable, bool)
    reasons = [str(r) for r in est.reason]
    silent = np.array([not r for r in reasons], bool)
    empty = ok & silent & ~np.isfinite(est.U).any(axis=1)
    infinite = ok & ~empty & _infinite_params(est)
    status = np.where(ok, np.where(empty | infinite, "failed", "ok"), "not-identifiable")
    return status, [
        NO_ESTIMATE if e else NON_FINITE if f else r
        for e, f, r in zip(empty, infinite, reasons, strict=True)
    ]


def _infinite_params(est: Estimate) -> np.ndarray:
    """Per run: whether a parameter within the run's orders is infinite (an overflow, never an
    estimate; ``nan`` stays how a method says the record does not determine it)."""
    bad = np.zeros(est.runs, bool)
    for values in est.params().values():
        with np.errstate(invalid="ignore"):
            bad |= np.isinf(np.asarray(values, float))
    return bad


def _shape_failed(problems: list[str]) -> bool:
    """Whether a shape problem of ``a``, ``b``, ``na`` or ``nb`` is among ``problems``."""
    return any(p.split(" ", 1)[0] in ("a", "b", "na", "nb") for p in problems)


def _whole(v: Any) -> bool:
    a = np.asarray(v)
    if a.dtype.kind in "iub":
        return True
    if a.dtype.kind != "f":
        return False
    with np.errstate(invalid="ignore"):
        return bool(np.all(np.isfinite(a) & (a == np.round(a))))


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
    _PARAMS,
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
    _PARAMS,
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
    :func:`bias_compensated_fit`, :func:`ols_fit`), with the same rule and options, share the
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
    st = _kept(
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
        y_idx = _runs(y, idx)
        reg = pp.quiet_regression(_runs(dy_all, idx), p, na, phases, tau, moments=lm.take(idx))
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
                y_idx, w, den, bb = _runs(y, good), w[sel], den[sel], bb[sel]
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

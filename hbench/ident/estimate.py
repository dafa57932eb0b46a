"""What a method is given and what it returns.

An identifier receives a :class:`~hbench.sim.records.Record` (``y`` always; ``x`` and ``r`` only if
it declares it needs them) and :class:`IdentifyOptions` (what the user knows a priori: p from the
record, the bound ``n0_b``, the ``na`` range, the fractional-delay range and the known multiple of p
in the delay, assumption A3). It returns an :class:`Estimate`. It never sees the truth; the oracle
is the one declared exception (``needs = {"truth"}``). :func:`check_identifiable` and
:func:`check_length` say why a record cannot be identified at all (:func:`empty_estimate` is the
estimate a method returns then).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np

from hbench.docparams import parameters
from hbench.errors import InputError
from hbench.sim.records import Record, Truth

#: numpydoc descriptions of the parameters the identification modules share
#: (:func:`hbench.docparams.parameters`)
PARAMETERS: dict[str, tuple[str, str]] = {
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


@parameters(
    PARAMETERS,
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
    PARAMETERS,
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


@parameters(PARAMETERS, options=("IdentifyOptions", "The given orders, or the ranges searched."))
def largest_order(options: IdentifyOptions) -> int:
    """The largest denominator order a method may fit under ``options``."""
    return int(options.na) if options.na is not None else int(options.na_range[1])


@parameters(
    PARAMETERS,
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
    PARAMETERS,
    parts=("sequence of ndarray", "2-D arrays with equal row counts."),
    width=("int", "Columns of the result (at least each part's)."),
)
def pad(parts: Sequence[np.ndarray], width: int) -> np.ndarray:
    """Zero-pad 2-D arrays on the right to ``width`` columns."""
    return np.stack([np.pad(p, (0, width - p.size)) for p in parts])

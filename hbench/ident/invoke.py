"""How a method is run and what it returned is judged.

:func:`identify` shows a method only what it declared it needs and checks the estimate it
returns (:func:`check_estimate`); :func:`run_status` reads each run's status and reason from a
checked estimate.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from hbench.docparams import parameters
from hbench.errors import InputError, MethodError
from hbench.ident.estimate import PARAMETERS, Estimate, Identifier, IdentifyOptions
from hbench.sim.records import Record, Truth


@parameters(
    PARAMETERS,
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
    PARAMETERS,
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


@parameters(PARAMETERS, est=("Estimate", "A checked estimate (:func:`check_estimate`)."))
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

"""Conformance checks every identification method must pass, built-in or third-party.

A method plugin's own test suite runs them on its method (installed, or given as a class)::

    from hbench.bench.conformance import check_method

    def test_my_method_conforms():
        check_method("my-method")

and ``python -m hbench.conformance my-method`` runs them from the shell. hbench's own suite
(``tests/test_conformance.py``) runs every check on every registered method.

The checks: the :class:`~hbench.ident.identifiers.Estimate` has one row per run and the documented
shapes, with ``b1 = 1``; ``U`` fits the true inner signal on noise-free data and is aligned with
``x`` (a one-sample shift ruins the fit); the method sees only the signals it declares (never the
truth, unless it declares ``"truth"``); the same record gives the same numbers twice; a run
alone gives the numbers it gets in a batch; a record where assumption A2 fails gives runs flagged
not identifiable, with a reason, instead of an exception. The records' arrays are read-only, so a
method that writes to its input fails. Tolerances: noise-free data, so a correct method's inner
signal fits the truth (fitness > 99 %, loose enough for methods that are exact only up to
rounding or regularisation).
"""

from __future__ import annotations

import copy
import functools
import sys
from collections.abc import Callable, Sequence
from dataclasses import replace
from typing import Any

import numpy as np

from hbench.bench.metrics import fitness
from hbench.ident.identifiers import Estimate, Identifier, IdentifyOptions, identify
from hbench.plugins import registry
from hbench.sim import scenarios
from hbench.sim.records import Record, Truth
from hbench.sim.simulate import simulate

#: A method to check: a registered name, an :class:`Identifier` subclass (built with its
#: ``test_options``) or an instance (copied afresh for every call).
MethodLike = str | type[Identifier] | Identifier


class Skipped(Exception):
    """A check that does not apply to a method (e.g. A2 for an oracle); the message says why."""


def paper_record(runs: int, seed: int, **top: Any) -> tuple[Record, Truth]:
    """The paper's Section 6 loop without noise (``sigma^2 = 0``), ``runs`` runs from ``seed``.

    ``top`` overrides top-level keys of the scenario (``p=3``). Kept (the checks share it), with
    ``y``, ``x``, ``r`` and the truth's arrays read-only: a method must not modify its inputs.

    Parameters
    ----------
    runs : int
        Monte Carlo runs.
    seed : int
        Seed of the simulation.
    **top : Any
        Top-level scenario keys overridden (``p=3``).
    """
    return _paper_record(runs, seed, tuple(sorted(top.items())))


@functools.cache
def _paper_record(runs: int, seed: int, top: tuple[tuple[str, Any], ...]) -> tuple[Record, Truth]:
    spec = copy.deepcopy(scenarios.PAPER_SECTION6)
    spec["noise"].pop("snr", None)
    spec["noise"]["sigma2"] = 0.0
    spec.update(dict(top))
    record, truth = simulate(scenarios.build(spec), runs, np.random.default_rng(seed))
    shared = (record.y, record.x, record.r, truth.U, truth.y0, truth.v)
    for arr in shared:  # shared by every check: a method (an oracle reads the truth) that
        if arr is not None:  # writes to its input fails instead of spoiling the next check's
            arr.flags.writeable = False
    return record, truth


def _data() -> tuple[Record, Truth]:
    """The record most checks use: three noise-free runs of the paper's example."""
    return paper_record(3, 21)


def method_factory(method: MethodLike) -> Callable[[], Identifier]:
    """A function returning a fresh instance of ``method`` (see :data:`MethodLike`).

    Its attribute ``name`` is the name the estimate must carry: the registered name for a name,
    else the class's ``name``.

    Parameters
    ----------
    method : str, Identifier subclass or Identifier
        A registered name, a class or an instance.
    """
    registered = method if isinstance(method, str) else None
    if isinstance(method, str):
        method = registry().get("identifiers", method)
    if isinstance(method, type):
        cls = method

        def make() -> Identifier:
            return cls(**getattr(cls, "test_options", {}))

    elif isinstance(method, Identifier):
        inst = method

        def make() -> Identifier:
            return copy.deepcopy(inst)

    else:
        raise TypeError(
            "expected a method name, an Identifier subclass or instance, got "
            f"{type(method).__name__}"
        )
    make.name = registered or method.name  # type: ignore[attr-defined]
    return make


def _run(make: Callable[[], Identifier], record: Record, truth: Truth, **opts: Any) -> Estimate:
    return identify(make(), record, IdentifyOptions(**opts), truth)


# --- the checks: each takes a factory of fresh instances, raises AssertionError or Skipped -----


def check_estimate_shapes(make: Callable[[], Identifier]) -> None:
    """An :class:`Estimate` named after the method, one row per run, ``b1 = 1``.

    Parameters
    ----------
    make : callable
        Returns a fresh instance of the method (:func:`method_factory`).
    """
    record, truth = _data()
    method = make()
    est = identify(method, record, IdentifyOptions(), truth)
    assert isinstance(est, Estimate), f"identify returned {type(est).__name__}, not an Estimate"
    R, K = record.runs, record.n_slow
    name = getattr(make, "name", method.name)
    assert est.method == name, f"Estimate.method is {est.method!r}, not {name!r}"
    assert est.U.shape == (R, K), f"U of shape {est.U.shape}, expected (runs, K) = {(R, K)}"
    for name in ("a", "b"):
        arr = getattr(est, name)
        assert arr.ndim == 2 and arr.shape[0] == R, (
            f"{name} of shape {arr.shape}, expected ({R}, order)"
        )
    for name in ("na", "nb", "tau", "sigma2", "identifiable"):
        shape = getattr(est, name).shape
        assert shape == (R,), f"{name} of shape {shape}, expected ({R},)"
    assert len(est.reason) == R, f"{len(est.reason)} reasons for {R} runs"
    np.testing.assert_array_equal(est.b[:, 0], 1.0, err_msg="b1 must be 1 (normalisation)")


def check_inner_signal_aligned_with_x(make: Callable[[], Identifier]) -> None:
    """``U[:, n]`` belongs with ``x[:, n]``: a one-sample shift would ruin the fit on this
    noise-free record, where a correct method's U fits the truth to > 99 %.

    Parameters
    ----------
    make : callable
        Returns a fresh instance of the method (:func:`method_factory`).
    """
    record, truth = _data()
    est = _run(make, record, truth)
    F = fitness(est.U, truth.U, gain=truth.plant.gain)
    assert np.all(F > 99.0), f"fitness of U on noise-free data {F}, expected > 99 in every run"
    shifted = fitness(est.U[:, 1:], truth.U[:, :-1], gain=truth.plant.gain)
    assert np.all(shifted < F - 1.0), (
        f"U shifted by one sample fits as well ({shifted} against {F}): U is not aligned with x"
    )


class _Spy:
    """Stands in for a method and records what :func:`hbench.ident.identifiers.identify`
    shows it."""

    def __init__(self, method: Identifier) -> None:
        self.method = method
        self.name, self.needs = method.name, method.needs
        self.seen: dict[str, Any] = {}

    def identify(
        self, record: Record, options: IdentifyOptions, truth: Truth | None = None
    ) -> Estimate:
        self.seen["record"], self.seen["truth"] = record, truth
        return self.method.identify(record, options, truth)


def check_sees_only_what_it_declares(make: Callable[[], Identifier]) -> None:
    """``x``, ``r`` and the truth reach the method only if it lists them in ``needs``.

    Parameters
    ----------
    make : callable
        Returns a fresh instance of the method (:func:`method_factory`).
    """
    record, truth = _data()
    spy = _Spy(make())
    identify(spy, record, IdentifyOptions(), truth)  # duck-typed: identify reads name, needs
    rec = spy.seen["record"]
    assert isinstance(rec, Record), f"the method was given {type(rec).__name__}"
    for signal in ("x", "r"):
        if signal not in spy.needs:
            assert getattr(rec, signal) is None, f"saw {signal} without declaring it in needs"
    if "truth" not in spy.needs:
        assert spy.seen["truth"] is None, "saw the truth without declaring it in needs"
    assert set(rec.meta) <= {"notices"}, f"saw the record's metadata {sorted(rec.meta)}"


def check_deterministic(make: Callable[[], Identifier]) -> None:
    """The same record twice (fresh instances) gives the same U, A and B, bit for bit.

    Parameters
    ----------
    make : callable
        Returns a fresh instance of the method (:func:`method_factory`).
    """
    record, truth = _data()
    # each call on its own copy of the record: a fresh cache, so nothing one call derived
    # (and memoised) can make the second agree with it
    first, second = _run(make, replace(record), truth), _run(make, replace(record), truth)
    for name in ("U", "a", "b"):
        np.testing.assert_array_equal(
            getattr(first, name), getattr(second, name), err_msg=f"{name} differs between calls"
        )


def check_unidentifiable_is_flagged_not_raised(make: Callable[[], Identifier]) -> None:
    """p = 3 < n0_b + 1 = 5 (assumption A2 fails): every run flagged, with a reason.

    Parameters
    ----------
    make : callable
        Returns a fresh instance of the method (:func:`method_factory`).
    """
    method = make()
    if "truth" in method.needs:
        raise Skipped("an oracle knows the structure: assumption A2 concerns blind estimation")
    record, truth = paper_record(2, 3, p=3)
    est = identify(method, record, IdentifyOptions(nb_max=4), truth)
    assert not est.identifiable.any(), (
        f"A2 fails (p = 3, n0_b = 4) but identifiable = {est.identifiable}"
    )
    assert all(est.reason), f"runs flagged without a reason: {est.reason}"


def check_single_run_and_batch_agree(make: Callable[[], Identifier]) -> None:
    """Batching over runs changes nothing: run 1 alone equals run 1 of the batch (1e-10).

    Parameters
    ----------
    make : callable
        Returns a fresh instance of the method (:func:`method_factory`).
    """
    record, truth = _data()
    batch = _run(make, record, truth)
    one = _run(make, record.select([1]), truth.select([1]))
    np.testing.assert_allclose(
        one.U[0], batch.U[1], rtol=0, atol=1e-10, err_msg="run 1 alone differs from the batch"
    )


#: Every check, by name (the order they run in).
CHECKS: dict[str, Callable[[Callable[[], Identifier]], None]] = {
    "estimate_shapes": check_estimate_shapes,
    "inner_signal_aligned_with_x": check_inner_signal_aligned_with_x,
    "sees_only_what_it_declares": check_sees_only_what_it_declares,
    "deterministic": check_deterministic,
    "unidentifiable_is_flagged_not_raised": check_unidentifiable_is_flagged_not_raised,
    "single_run_and_batch_agree": check_single_run_and_batch_agree,
}


def _label(method: MethodLike) -> str:
    if isinstance(method, str):
        return method
    return getattr(method, "name", "") or repr(method)


def run_check(method: MethodLike, check: str) -> str:
    """Run one check of :data:`CHECKS` on ``method``.

    Parameters
    ----------
    method : str, Identifier subclass or Identifier
        A registered name, a class or an instance.
    check : str
        A name of :data:`CHECKS`.

    Returns
    -------
    str
        ``""`` if it passed, or why it does not apply (skipped).

    Raises
    ------
    AssertionError
        The method fails the check; the message names the method and the check. An exception
        the method itself raises is reported the same way, its type and message included.
    """
    if check not in CHECKS:
        raise KeyError(f"unknown check {check!r} (known: {', '.join(CHECKS)})")
    make = method_factory(method)
    try:
        CHECKS[check](make)
    except Skipped as skip:
        return str(skip) or "skipped"
    except AssertionError as exc:
        raise AssertionError(
            f"method {_label(method)!r} fails check {check!r}: {str(exc).strip()}"
        ) from exc
    except Exception as exc:
        raise AssertionError(
            f"method {_label(method)!r} raised in check {check!r}: {type(exc).__name__}: {exc}"
        ) from exc
    return ""


def check_method(method: MethodLike, checks: Sequence[str] | None = None) -> dict[str, str]:
    """Run the conformance checks on one method; raise if any fails.

    Parameters
    ----------
    method : str, Identifier subclass or Identifier
        A registered name (``"my-method"``), a class (instantiated with its ``test_options``)
        or an instance.
    checks : sequence of str, optional
        Names of :data:`CHECKS` to run (default: all).

    Returns
    -------
    dict of str to str
        The checks that were skipped, with why (e.g. A2 for an oracle).

    Raises
    ------
    AssertionError
        One or more checks fail; the message lists each with the method's name and why.
    """
    failures, skipped = [], {}
    for name in checks if checks is not None else CHECKS:
        try:
            why = run_check(method, name)
        except AssertionError as exc:
            failures.append(str(exc))
            continue
        if why:
            skipped[name] = why
    if failures:
        raise AssertionError("\n".join(failures))
    return skipped


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m hbench.conformance NAME [NAME ...]``: check registered methods (0: all pass).

    Parameters
    ----------
    argv : sequence of str, optional
        Registered method names (default: ``sys.argv[1:]``).
    """
    names = list(sys.argv[1:] if argv is None else argv)
    if not names or names[0] in ("-h", "--help"):
        print("usage: python -m hbench.conformance METHOD [METHOD ...]")
        print(f"checks: {', '.join(CHECKS)}")
        return 0 if names else 2
    status = 0
    for name in names:
        if name not in registry().names("identifiers"):
            known = ", ".join(registry().names("identifiers"))
            print(f"FAIL {name}: no registered method of that name (known: {known})")
            status = 1
            continue
        for check in CHECKS:
            try:
                why = run_check(name, check)
            except (AssertionError, KeyError) as exc:
                print(f"FAIL {name} {check}: {exc}")
                status = 1
                continue
            print(f"skip {name} {check}: {why}" if why else f"ok   {name} {check}")
    return status


if __name__ == "__main__":
    sys.exit(main())

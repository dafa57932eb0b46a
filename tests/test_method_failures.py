"""A method (plugin) that breaks its interface fails its own rows, with a message naming it.

Before, a method returning an estimate of the wrong shape failed every method of the chunk
(the error came from the metrics, outside the per-method ``try``), ``None`` gave an
``AttributeError`` deep in the runner, an all-``nan`` estimate counted as an ok run, and
``hbench diagnose --method`` built a diagnosis on a wrong-length ``U``.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from hbench.bench.runner import methods_from_names, run_cell
from hbench.errors import MethodError, describe
from hbench.ident.identifiers import (
    NO_ESTIMATE,
    Identifier,
    IdentifyOptions,
    check_estimate,
    identify,
)
from hbench.io.readers import write_record
from hbench.plugins import registry
from hbench.sim.scenarios import build
from tests.helpers import paper_spec, registered_methods, sim

RunCli = Callable[[Sequence[str]], tuple[int, str, str]]


def _lsm(record: Any, options: Any) -> Any:
    return registry().get("identifiers", "wang-lsm")().identify(record, options, None)


class BadShape(Identifier):
    """wang-lsm's estimate with U three samples short."""

    name = "test-badshape"

    def identify(self, record: Any, options: Any, truth: Any = None) -> Any:
        est = _lsm(record, options)
        return replace(est, U=est.U[:, 3:])


class ReturnsNone(Identifier):
    name = "test-none"

    def identify(self, record: Any, options: Any, truth: Any = None) -> Any:
        return None


class AllNan(Identifier):
    """wang-lsm's estimate with U all nan in run 0 and half nan in the others."""

    name = "test-nan"

    def identify(self, record: Any, options: Any, truth: Any = None) -> Any:
        est = _lsm(record, options)
        U = est.U.copy()
        U[0] = np.nan
        U[1:, : U.shape[1] // 2] = np.nan
        return replace(est, U=U)


class Raises(Identifier):
    name = "test-raises"

    def identify(self, record: Any, options: Any, truth: Any = None) -> Any:
        raise ZeroDivisionError("plugin bug")


BROKEN = (BadShape, ReturnsNone, AllNan, Raises)


@pytest.fixture
def broken() -> Iterator[None]:
    with registered_methods("broken-methods-test", *BROKEN):
        yield


def _cell(methods: dict[str, Identifier]) -> Any:
    scenario = build(paper_spec(duration=120.0))
    return run_cell(scenario, methods, 4, 3).rows


def _slow_samples() -> int:
    return sim(runs=1, seed=0, duration=120.0)[0].n_slow


def test_a_malformed_estimate_fails_only_its_method() -> None:
    """Rows of the other methods are the same as in a cell without the broken ones."""
    good = methods_from_names(["wang-lsm", "bai-fu"])
    rows = _cell({**good, "test-badshape": BadShape(), "test-none": ReturnsNone()})
    alone = _cell(good)
    mine = rows[rows["method"].isin(good)].drop(columns="value").reset_index(drop=True)
    np.testing.assert_array_equal(
        rows[rows["method"].isin(good) & (rows["quantity"] != "seconds")]["value"],
        alone[alone["quantity"] != "seconds"]["value"],
    )
    assert (mine["status"] == alone.drop(columns="value")["status"]).all()
    assert (mine["status"] != "failed").all()
    bad = rows[rows["method"] == "test-badshape"]
    assert (bad["status"] == "failed").all()
    message = bad["error"].iloc[0]
    assert message.startswith("method 'test-badshape' returned an invalid estimate")
    K = _slow_samples()
    assert f"U of shape (4, {K - 3}), expected (4, {K})" in message
    none = rows[rows["method"] == "test-none"]
    assert (none["status"] == "failed").all()
    assert "method 'test-none' returned NoneType, not an hbench.ident.identifiers.Estimate" in set(
        none["error"]
    )


def test_an_estimate_without_any_finite_sample_is_a_failed_run() -> None:
    rows = _cell({"test-nan": AllNan()})
    fit = rows[rows["quantity"] == "fitness"].set_index("run")
    assert fit.loc[0, "status"] == "failed" and fit.loc[0, "error"] == NO_ESTIMATE
    # a partly undefined U is how an estimate says the record does not determine it: ok
    assert (fit.loc[1:, "status"] == "ok").all()
    assert np.isfinite(fit.loc[1:, "value"]).all()


def test_check_estimate_names_every_problem() -> None:
    record, _ = sim(runs=3, seed=1, duration=120.0)
    est = _lsm(record, IdentifyOptions())
    check_estimate(est, record, "fine")  # a method's own estimate passes
    broken = replace(
        est,
        U=est.U[:2],
        na=est.na[:, None],
        tau=est.tau + 0.5,
        b=est.b[:, :0],
        reason="why",
        delay_multiple=np.zeros(2, int),
    )
    with pytest.raises(MethodError) as info:
        check_estimate(broken, record, "mine")
    text = str(info.value)
    assert text.startswith("method 'mine' returned an invalid estimate for a record of 3 runs")
    K = record.n_slow
    for part in (
        f"U of shape (2, {K}), expected (3, {K})",
        "na of shape (3, 1), expected (3,)",
        "delay_multiple of shape (2,), expected (3,)",
        "b without b1",
        "tau holds values that are not whole numbers",
        "reason is str, expected one string per run (3)",
    ):
        assert part in text, part
    with pytest.raises(MethodError, match="returned dict, not an"):
        identify(_Returns({}), record, IdentifyOptions())
    # any sequence of one reason per run will do (an array of strings too)
    check_estimate(replace(est, reason=np.array(est.reason)), record, "fine")
    # orders beyond the coefficients given, and a one-run record's wording
    with pytest.raises(MethodError, match="na up to 9 with only"):
        check_estimate(replace(est, na=np.full(3, 9)), record, "mine")
    one, _ = sim(runs=1, seed=1, duration=120.0)
    with pytest.raises(MethodError, match="a record of 1 run and"):
        check_estimate(est, one, "mine")


class _Returns(Identifier):
    name = "returns"

    def __init__(self, value: Any) -> None:
        self.value = value

    def identify(self, record: Any, options: Any, truth: Any = None) -> Any:
        return self.value


def test_describe_is_one_line_with_where() -> None:
    try:
        raise ValueError("two\nlines")
    except ValueError as exc:
        text = describe(exc)
    assert text.startswith("ValueError: two lines (test_method_failures.py:")
    assert describe(MethodError("method 'm'\n broke")) == "method 'm' broke"


@pytest.fixture(scope="module")
def record_file(tmp_path_factory: pytest.TempPathFactory) -> Path:
    record, _ = sim(runs=1, seed=2, duration=300.0)
    return write_record(record, tmp_path_factory.mktemp("rec") / "rec.csv")


@pytest.mark.parametrize(
    ("method", "words"),
    [
        ("test-badshape", "returned an invalid estimate"),
        ("test-none", "returned NoneType"),
        ("test-raises", "failed: ZeroDivisionError: plugin bug (test_method_failures.py:"),
        ("test-nan", "failed: the method returned no finite inner-signal estimate"),
    ],
)
def test_diagnose_with_a_broken_method_is_one_line(
    run_cli: RunCli, record_file: Path, broken: None, method: str, words: str
) -> None:
    status, stdout, stderr = run_cli(["diagnose", str(record_file), "--method", method])
    assert status == 1
    assert stdout == ""
    lines = stderr.strip().splitlines()
    assert len(lines) == 1, stderr
    assert lines[0].startswith(f"hbench diagnose: error: method '{method}' ")
    assert words in lines[0]


def test_a_refused_inverse_stays_ok_with_the_methods_reason() -> None:
    """bai-fu refusing the unstable direct inverse of a non-minimum-phase B returns no U but
    says why: the run stays ok (its parameters, orders and delay are estimates the bias and
    structure tables count), with the method's reason; only a silent empty U is a failure."""
    from hbench.ident.identifiers import REFUSALS

    spec = paper_spec(duration=120.0, plant__name="nmp", plant__delay=1, reference__band=[0.0, 1.0])
    baifu = registry().get("identifiers", "bai-fu")
    rows = run_cell(build(spec), {"bai-fu": baifu(inverse="refuse")}, 3, 4).rows
    fit = rows[rows["quantity"] == "fitness"]
    refused = fit[fit["error"] == REFUSALS["refused-nmp"]]
    assert len(refused) and (refused["status"] == "ok").all()
    assert refused["value"].isna().all()
    assert (rows["status"] != "failed").all()

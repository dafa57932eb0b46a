"""Shared, generic fixtures: scenario specs with overrides, and the command line in-process."""

from __future__ import annotations

import copy
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import pytest

from hbench import cli
from hbench.sim import scenarios
from hbench.sim.simulate import Scenario

SpecFactory = Callable[..., dict[str, Any]]


def _make_spec(overrides: Mapping[str, Any] | None = None, **top: Any) -> dict[str, Any]:
    """A deep copy of the paper's scenario with overrides.

    ``overrides`` maps dotted keys to values (``{"plant.delay": 2, "noise.sigma2": 0.0}``); a
    value for a whole group (``{"nonlinearity": {"name": "deadband"}}``) replaces the group.
    Setting ``noise.sigma2`` or ``noise.snr`` removes the other level. Keyword arguments set
    top-level keys (``p=3, duration=60.0``).
    """
    spec = copy.deepcopy(scenarios.PAPER_SECTION6)
    for key, value in {**(overrides or {}), **top}.items():
        if key in ("noise.sigma2", "noise.snr"):
            spec["noise"].pop("sigma2", None)
            spec["noise"].pop("snr", None)
        scenarios.set_dotted(spec, key, copy.deepcopy(value))
    return spec


@pytest.fixture
def make_spec() -> SpecFactory:
    """``make_spec(overrides=None, **top)``: the paper's scenario spec with overrides."""
    return _make_spec


@pytest.fixture
def make_scenario() -> Callable[..., Scenario]:
    """``make_scenario(overrides=None, **top)``: :func:`hbench.sim.scenarios.build` of
    ``make_spec``."""

    def make(overrides: Mapping[str, Any] | None = None, **top: Any) -> Scenario:
        return scenarios.build(_make_spec(overrides, **top))

    return make


@pytest.fixture
def run_cli(capsys: pytest.CaptureFixture[str]) -> Callable[[Sequence[str]], tuple[int, str, str]]:
    """``run_cli(argv) -> (status, stdout, stderr)``: :func:`hbench.cli.main` in-process."""

    def run(argv: Sequence[str]) -> tuple[int, str, str]:
        capsys.readouterr()  # drop anything printed before
        status = cli.main(list(argv))
        out, err = capsys.readouterr()
        return status, out, err

    return run

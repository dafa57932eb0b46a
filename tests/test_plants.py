"""Tests of :mod:`hbench.model.plants`: the exact ZOH discretisation with (fractional) delay.

Independent references: the continuous step response comes from a partial-fraction expansion
(``scipy.signal.residue``) evaluated in closed form, and an arbitrary ZOH input goes through
``scipy.signal.lsim(..., interp=False)``, which integrates a piecewise-constant input exactly
(matrix exponential per grid step). Neither shares code with hbench's discretisation.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy import signal

from hbench.errors import InputError, UnstableError
from hbench.model import plants
from hbench.model.plants import ContinuousPlant, DiscretePlant

H = 0.12  # the paper's fast period: T = 0.6 s, p = 5


def _sig4(x: float) -> float:
    """``x`` rounded to four significant digits."""
    return float(f"{x:.4g}")


def _continuous_step(num: tuple[float, ...], den: tuple[float, ...], t: np.ndarray) -> np.ndarray:
    """Unit-step response of ``num(s)/den(s)`` at times ``t`` (zero for ``t < 0``), analytically.

    ``G(s)/s = sum_i r_i / (s - p_i)`` (distinct poles) gives ``y(t) = sum_i r_i e^{p_i t}``.
    """
    r, p, k = signal.residue(np.asarray(num, float), np.polymul(np.asarray(den, float), [1, 0]))
    assert k.size == 0 or np.all(k == 0)  # G(s)/s is strictly proper
    assert np.unique(np.round(p, 8)).size == p.size  # distinct poles: the formula holds
    y = np.real(sum(ri * np.exp(pi * np.clip(t, 0, None)) for ri, pi in zip(r, p, strict=True)))
    return np.where(t >= 0, y, 0.0)


def _discrete_step(plant: DiscretePlant, n: int) -> np.ndarray:
    return signal.lfilter(plant.num, plant.a, np.ones(n))


# --------------------------------------------------------------------------- the paper's example


def test_paper_example_coefficients() -> None:
    """Wang et al., Sec. 6, to four significant digits:

    G(q) = 0.05597 q^-3 (q^-1 - 0.7244 q^-2) / (1 - 1.962 q^-1 + 0.9623 q^-2).
    """
    g = plants.paper().discretize(H)
    assert g.na == 2 and g.nb == 2
    assert _sig4(g.b[0]) == 0.05597
    assert _sig4(g.b[1] / g.b[0]) == -0.7244
    assert _sig4(g.a[1]) == -1.962
    assert _sig4(g.a[2]) == 0.9623
    assert g.a[0] == 1.0
    assert g.delay == 3
    assert g.tau(5) == 3
    assert g.delay_multiple(5) == 0
    assert g.h == H


def test_paper_delay_in_seconds_is_the_same_plant() -> None:
    """0.36 s is exactly 3 h: the seconds path (``delay=None``) gives the sample-delay plant."""
    by_samples = plants.paper().discretize(H)
    by_seconds = plants.paper(delay=None, delay_s=0.36).discretize(H)
    assert by_seconds.delay == 3
    # same matrix exponentials; only the placement of the delay differs -> rounding only
    np.testing.assert_allclose(by_seconds.a, by_samples.a, rtol=0, atol=1e-14)
    np.testing.assert_allclose(by_seconds.b, by_samples.b, rtol=0, atol=1e-14)


# --------------------------------------------------------------------------- exactness of ZOH


@pytest.mark.parametrize("delay", [0, 3, 7])
def test_paper_step_response_is_sampled_continuous_step(delay: int) -> None:
    """A step is its own ZOH, so the discrete step response is the continuous one at k h."""
    model = plants.paper(delay=delay)
    g = model.discretize(H)
    k = np.arange(400)  # 48 s: the slow pole (s = -0.085) has risen to ~98 % of its final value
    expected = _continuous_step(model.num, model.den, k * H - delay * H)
    # Absolute 1e-10 on a response that rises to ~53 (DC gain 54.6): the IIR recursion with
    # poles at 0.98 and 0.99 accumulates rounding; observed ~1.2e-11.
    np.testing.assert_allclose(_discrete_step(g, k.size), expected, rtol=0, atol=1e-10)
    assert np.all(_discrete_step(g, k.size)[: delay + 1] == 0.0)  # nothing before the delay


@pytest.mark.parametrize("name", ["first-order", "nmp", "third-order"])
def test_builtin_step_response_is_sampled_continuous_step(name: str) -> None:
    model = plants.BUILTIN[name]()
    g = model.discretize(H)
    k = np.arange(300)
    expected = _continuous_step(model.num, model.den, (k - model.delay) * H)
    # Responses of order 1 to 3; rounding of the recursion, observed <= 1e-13.
    np.testing.assert_allclose(_discrete_step(g, k.size), expected, rtol=0, atol=1e-10)


def test_fractional_delay_step_response() -> None:
    """0.3 s = 2.5 h: the step enters half-way through a sample period."""
    model = plants.paper(delay=None, delay_s=0.3)
    g = model.discretize(H)
    assert g.delay == 2 and g.nb == 3  # q^-3 (b1 + b2 q^-1 + b3 q^-2): Gamma0 and Gamma1 terms
    k = np.arange(400)
    expected = _continuous_step(model.num, model.den, k * H - 0.3)
    # As for the integer delays: absolute 1e-10 on a response rising to ~53 (observed ~1e-11).
    np.testing.assert_allclose(_discrete_step(g, k.size), expected, rtol=0, atol=1e-10)


def test_fractional_delay_random_zoh_input_against_lsim() -> None:
    """A random ZOH input delayed by 0.3 s, integrated exactly on a grid of h/2 = 0.06 s.

    The delay is 5 grid steps, so the delayed input is piecewise constant on the grid and
    ``lsim(..., interp=False)`` (a ZOH integrator) is exact up to rounding.
    """
    model = plants.paper(delay=None, delay_s=0.3)
    g = model.discretize(H)
    n, sub = 400, 2
    u = np.random.default_rng(20240601).standard_normal(n)
    dt = H / sub
    t = np.arange(n * sub) * dt
    u_fine = np.concatenate([np.zeros(5), np.repeat(u, sub)])[: n * sub]
    _, y_cont, _ = signal.lsim((model.num, model.den), u_fine, t, interp=False)
    y_disc = signal.lfilter(g.num, g.a, u)
    # Outputs of order 5; two different exact integrators differ by rounding (observed 2e-13).
    np.testing.assert_allclose(y_disc, y_cont[::sub], rtol=0, atol=1e-10)


@pytest.mark.parametrize(("delay", "delay_s"), [(1, 0.0), (2, 0.0), (None, 0.12), (None, 0.3)])
def test_direct_feedthrough_plant_with_delay(delay: int | None, delay_s: float) -> None:
    """(s + 2)/(s + 3) has a feedthrough; with a delay >= h it is a valid plant, still exact."""
    model = ContinuousPlant((1.0, 2.0), (1.0, 3.0), delay, delay_s, "ft")
    g = model.discretize(H)
    shift = delay * H if delay is not None else delay_s
    k = np.arange(200)
    # responses of order 1; first-order recursion, observed 3e-16
    np.testing.assert_allclose(
        _discrete_step(g, k.size),
        _continuous_step(model.num, model.den, k * H - shift),
        rtol=0,
        atol=1e-12,
    )


# --------------------------------------------------------------------------- built-in plants


TRUE_PARAM_KEYS = {
    "paper": {"a1", "a2", "b2"},
    "first-order": {"a1"},
    "nmp": {"a1", "a2", "b2"},
    "third-order": {"a1", "a2", "a3", "b2", "b3"},
    "discrete": {"a1", "a2", "b2"},
}


def test_every_builtin_is_covered() -> None:
    assert set(plants.BUILTIN) == set(TRUE_PARAM_KEYS)


@pytest.mark.parametrize("name", sorted(TRUE_PARAM_KEYS))
def test_builtin_true_params(name: str) -> None:
    g = plants.BUILTIN[name]().discretize(H)
    params = g.true_params()
    assert set(params) == TRUE_PARAM_KEYS[name]
    for i in range(1, g.na + 1):
        assert params[f"a{i}"] == g.a[i]
    for j in range(2, g.nb + 1):
        assert params[f"b{j}"] == g.b[j - 1] / g.b[0]  # the blind normalisation b1 = 1


def test_nmp_has_zero_outside_unit_circle() -> None:
    g = plants.nonminimum_phase().discretize(H)
    assert np.max(np.abs(g.zeros)) > 1.0
    # the RHP zero s = 0.5 maps to about e^{0.5 h}; 2 % covers the ZOH's shift of the zero
    assert np.max(np.abs(g.zeros)) == pytest.approx(np.exp(0.5 * H), rel=0.02)
    assert g.is_minimum_phase is False
    assert g.is_stable is True


@pytest.mark.parametrize("name", ["paper", "first-order", "third-order"])
def test_minimum_phase_and_stable(name: str) -> None:
    g = plants.BUILTIN[name]().discretize(H)
    assert g.is_minimum_phase is True
    assert g.is_stable is True
    assert np.all(np.abs(g.zeros) < 1.0) and np.all(np.abs(g.poles) < 1.0)


# --------------------------------------------------------------------------- bad plants


def test_unstable_continuous_plant_names_the_plant() -> None:
    with pytest.raises(UnstableError, match=r"'my-unstable'.*unstable"):
        ContinuousPlant((1.0,), (1.0, -0.5), 1, 0.0, "my-unstable").discretize(H)


def test_unstable_discrete_plant_names_the_plant() -> None:
    with pytest.raises(UnstableError, match=r"plant 'discrete' is unstable"):
        plants.discrete(a=(1.0, -2.5, 1.2)).discretize(H)


@pytest.mark.parametrize("delay", [0, None])
def test_direct_feedthrough_without_delay_is_refused(delay: int | None) -> None:
    with pytest.raises(InputError, match="feedthrough"):
        ContinuousPlant((1.0, 2.0), (1.0, 3.0), delay, 0.0, "ft").discretize(H)


def test_improper_plant_is_refused() -> None:
    with pytest.raises(InputError, match="improper"):
        ContinuousPlant((1.0, 0.0, 0.0), (1.0, 1.0), 1, 0.0, "improper").discretize(H)

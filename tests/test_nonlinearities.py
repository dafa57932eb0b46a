"""Tests of the actuator models in :mod:`hbench.model.nonlinearities`.

Tolerance: every comparison is *exact* (``assert_array_equal``). The hand-worked sequences use
dyadic rationals (multiples of 1/8, 1/16 or 2**-10) for inputs and parameters, so every
sum, difference, sign flip and halving in the models is exact in binary floating point and the
hand results are the true values. Model-against-model checks compare outputs that the two
models compute with the same floating-point expression (``x - S/2`` against ``x - d/2`` with
``d = S``, or a copied previous value), so they agree bit for bit; on the random-normal inputs
only the threshold tests are computed differently, and an input within one ulp of a threshold
has negligible probability (the seeds are fixed, so the tests are deterministic).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest
from numpy.testing import assert_array_equal

from hbench.errors import InputError
from hbench.model.nonlinearities import (
    BUILTIN,
    Backlash,
    Deadband,
    Linear,
    Nonlinearity,
    Saturation,
    Stiction,
    StictionHe,
)

STATIC = (Linear, Deadband, Saturation)
WITH_MEMORY = (Backlash, Stiction, StictionHe)


def _dyadic_walk(rng: np.random.Generator, shape: tuple[int, ...], steps: list[int]) -> np.ndarray:
    """A random walk on the grid of multiples of 1/16 (exact in floating point)."""
    return np.cumsum(rng.choice(steps, size=shape), axis=-1) / 16


# --------------------------------------------------------------------------- hand-worked sequences


def test_linear_hand() -> None:
    u, state = Linear(gain=2.0).apply(np.array([1.0, -0.5, 0.0]))
    assert_array_equal(u, [2.0, -1.0, 0.0])
    assert state == {}


def test_deadband_hand() -> None:
    # Band [-0.25, 0.5], slope 2: m (x - d2) above, 0 inside (edges included), m (x + d1) below.
    x = np.array([-1.0, -0.25, -0.125, 0.0, 0.5, 0.75, 2.0])
    u, _ = Deadband(d1=0.25, d2=0.5, slope=2.0).apply(x)
    assert_array_equal(u, [-1.5, 0.0, 0.0, 0.0, 0.0, 0.5, 3.0])


def test_saturation_hand() -> None:
    x = np.array([-1.0, -0.25, 0.0, 0.5, 0.75])
    u, _ = Saturation(u_min=-0.25, u_max=0.5).apply(x)
    assert_array_equal(u, [-0.25, -0.25, 0.0, 0.5, 0.5])


def test_saturation_one_sided() -> None:
    u, _ = Saturation(u_min=-np.inf, u_max=0.5).apply(np.array([-1e9, 1.0]))
    assert_array_equal(u, [-1e9, 0.5])


def test_backlash_hand() -> None:
    # d = 0.5 (half-width 0.25), u(-1) = 0: u = clip(u_prev, x - 0.25, x + 0.25).
    x = np.array([0.125, 0.5, 0.75, 0.625, 0.25, 0.375, -0.25, 0.0])
    expected = [
        0.0,  # inside the band around 0
        0.25,  # dragged up: x - 0.25
        0.5,  # dragged up
        0.5,  # reversal: stuck
        0.5,  # x + 0.25 = 0.5 touches the output: still stuck
        0.5,  # turned back inside the band: stuck
        0.0,  # dragged down: x + 0.25
        0.0,  # reversal: stuck
    ]
    u, state = Backlash(d=0.5).apply(x)
    assert_array_equal(u, expected)
    assert_array_equal(state["u_prev"], [0.0])


def test_backlash_u0_none_starts_centred_on_first_input() -> None:
    x = np.array([1.0, 1.125, 1.5])
    u, _ = Backlash(d=0.5, u0=None).apply(x)
    assert_array_equal(u, [1.0, 1.0, 1.25])
    u, _ = Backlash(d=0.5).apply(x)  # u0 = 0: pulled to the band edge x - 0.25 at once
    assert_array_equal(u, [0.75, 0.875, 1.25])
    state = Backlash(u0=None).initial_state(2, np.array([1.0, -2.0]))
    assert_array_equal(state["u_prev"], [1.0, -2.0])
    assert_array_equal(Backlash(u0=None).initial_state(2)["u_prev"], [0.0, 0.0])


# Stiction(S=0.5, J=0.25): offset h = (S - J)/2 = 0.125. Initially at rest at u0 = 0 with
# d = +1 and x_ss = 0.125, so it breaks away when |x| > (S + J)/2 = 0.375.
STICTION_X = [0.25, 0.375, 0.5, 0.75, 0.625, 0.375, 0.25, 0.125, 0.0, 0.0, -0.125, -0.375,
              -0.25, -0.5, -0.75]  # fmt: skip
STICTION_U = [
    0.0,  # k=0  at rest: d (x - x_ss) = 0.125 <= J
    0.0,  # k=1  0.25 = J exactly: strict test, still stuck
    0.375,  # k=2  0.375 > J: slips up, u = x - h (jump J at the threshold x = 0.375)
    0.625,  # k=3  moving: u = x - h
    0.625,  # k=4  reversal: sticks, x_ss = 0.75
    0.625,  # k=5  -d (x - x_ss) = 0.375 <= S: stuck
    0.625,  # k=6  0.5 = S exactly: still stuck
    0.25,  # k=7  0.625 > S: slips down, d = -1, u = x + h (jump J at x = 0.25)
    0.125,  # k=8  moving down: u = x + h
    0.125,  # k=9  input stops: sticks, x_ss = 0.0
    0.125,  # k=10 same direction, d (x - x_ss) = 0.125 <= J: stuck
    -0.25,  # k=11 0.375 > J: slips on, u = x + h
    -0.25,  # k=12 reversal: sticks, x_ss = -0.375
    -0.25,  # k=13 input turns back while stuck: x_ss stays -0.375, 0.125 <= J
    -0.625,  # k=14 0.375 > J: slips on down, u = x + h
]


def test_stiction_hand() -> None:
    model = Stiction(S=0.5, J=0.25)
    u, state = model.apply(np.array(STICTION_X))
    assert_array_equal(u, STICTION_U)
    assert_array_equal(state["direction"], [-1.0])
    assert_array_equal(state["stuck"], [False])
    assert_array_equal(state["x_prev"], [-0.75])


def test_stiction_hand_slip_jumps_equal_J() -> None:
    # Output step at a slip = J + how far the input went past the threshold.
    u, x, J = STICTION_U, STICTION_X, 0.25
    assert u[2] - u[1] == J + (x[2] - 0.375)  # breakaway up: threshold u0 + (S + J)/2
    assert u[6] - u[7] == J + (0.25 - x[7])  # after the reversal: threshold x_ss - S = 0.25
    assert u[10] - u[11] == J + (-0.25 - x[11])  # after the stop: threshold x_ss - J = -0.25


@pytest.mark.parametrize("split", [1, 5, 7, 10, 13])
def test_stiction_memory_across_calls(split: int) -> None:
    model = Stiction(S=0.5, J=0.25)
    x = np.array(STICTION_X)
    u1, state = model.apply(x[:split])
    u2, _ = model.apply(x[split:], state)
    assert_array_equal(np.concatenate([u1, u2]), STICTION_U)


@pytest.mark.parametrize("split", [1, 3, 6])
def test_backlash_memory_across_calls(split: int) -> None:
    model = Backlash(d=0.5)
    x = np.array([0.125, 0.5, 0.75, 0.625, 0.25, 0.375, -0.25, 0.0])
    u1, state = model.apply(x[:split])
    u2, _ = model.apply(x[split:], state)
    assert_array_equal(np.concatenate([u1, u2]), [0.0, 0.25, 0.5, 0.5, 0.5, 0.5, 0.0, 0.0])


def test_stiction_u0_none_starts_at_first_input() -> None:
    # At rest at 1.0: x_ss = 1.125, breaks away above 1.0 + (S + J)/2 = 1.375.
    u, _ = Stiction(S=0.5, J=0.25, u0=None).apply(np.array([1.0, 1.25, 1.5]))
    assert_array_equal(u, [1.0, 1.0, 1.375])


def test_stiction_he_hand() -> None:
    # f_s = 0.5, f_d = 0.25; e = x - u(k-1); slip to x - sign(e) f_d when |e| > f_s.
    x = np.array([0.25, 0.5, 0.625, 0.75, 1.0, 0.875, 0.5, 0.25, 0.0])
    expected = [
        0.0,  # e = 0.25
        0.0,  # e = 0.5 = f_s: strict, stuck
        0.375,  # e = 0.625: slips, u = x - 0.25
        0.375,  # e = 0.375: sticks again while the input keeps rising (stick-slip)
        0.75,  # e = 0.625: slips
        0.75,  # e = 0.125
        0.75,  # e = -0.25
        0.75,  # e = -0.5: strict, stuck
        0.25,  # e = -0.75: slips down, u = x + 0.25
    ]
    u, _ = StictionHe(f_s=0.5, f_d=0.25).apply(x)
    assert_array_equal(u, expected)
    # Stiction with S = f_s + f_d, J = f_s - f_d: the same except at k=3, where it keeps moving.
    u, _ = Stiction(S=0.75, J=0.25).apply(x)
    assert_array_equal(u, [0.0, 0.0, 0.375, 0.5, 0.75, 0.75, 0.75, 0.75, 0.25])


# --------------------------------------------------------------------------- stiction properties


@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("u0", [0.0, 0.3, None])
@pytest.mark.parametrize("S", [0.0, 0.1, 0.5])
def test_stiction_J0_is_backlash_random(seed: int, u0: float | None, S: float) -> None:
    rng = np.random.default_rng(seed)
    # a random walk plus noise: many in-band reversals
    x = np.cumsum(rng.standard_normal((3, 400)), axis=1) / 20 + rng.standard_normal((3, 400)) / 10
    u_stiction, _ = Stiction(S=S, J=0.0, u0=u0).apply(x)
    u_backlash, _ = Backlash(d=S, u0=u0).apply(x)
    assert_array_equal(u_stiction, u_backlash)


@pytest.mark.parametrize("seed", [3, 4])
def test_stiction_J0_is_backlash_on_grid(seed: int) -> None:
    # On a grid inputs land exactly on thresholds, stops (zero steps) and in-band reversals
    # are frequent: the boundary cases must agree too.
    x = _dyadic_walk(np.random.default_rng(seed), (4, 500), [-3, -2, -1, 0, 0, 1, 2, 3])
    u_stiction, _ = Stiction(S=0.5, J=0.0, u0=0.25).apply(x)
    u_backlash, _ = Backlash(d=0.5, u0=0.25).apply(x)
    assert_array_equal(u_stiction, u_backlash)


@pytest.mark.parametrize("seed", [5, 6])
def test_stiction_J_equals_S_no_offset_while_moving(seed: int) -> None:
    rng = np.random.default_rng(seed)
    x = np.cumsum(rng.standard_normal((3, 300)), axis=1) / 10
    model = Stiction(S=0.2, J=0.2)
    state = model.initial_state(3)
    moved = 0
    for k in range(x.shape[1]):
        u, state = model.step(x[:, k], state)
        moving = ~state["stuck"]
        assert_array_equal(u[moving], x[moving, k])
        moved += int(moving.sum())
    assert moved > 100  # the valve did move, and stuck in between
    assert moved < x.size


def test_stiction_J_equals_S_ramp() -> None:
    x = np.arange(12) / 8  # 0, 1/8, ..., 11/8
    u, _ = Stiction(S=0.5, J=0.5).apply(x)
    # at rest at 0, breaks away when x > (S + J)/2 = 0.5, then u = x exactly
    assert_array_equal(u, np.where(x > 0.5, x, 0.0))


def test_stiction_zero_parameters_is_identity() -> None:
    x = np.cumsum(np.random.default_rng(7).standard_normal((2, 200)), axis=1)
    x[:, 50:60] = x[:, 49:50]  # a stop
    assert_array_equal(Stiction(S=0.0, J=0.0).apply(x)[0], x)
    assert_array_equal(StictionHe(f_s=0.0, f_d=0.0).apply(x)[0], x)


def test_stiction_slip_jump_on_fine_triangle() -> None:
    # Triangle wave with steps of 2**-10: every breakaway and every reversal slip overshoots the
    # threshold by exactly one step, so the largest output step is J + 2**-10.
    step = 2.0**-10
    up = np.arange(0, 1024) * step  # 0 .. 1 - step
    x = np.concatenate([up, up[::-1][1:], -up[1:], -up[::-1][1:-1]] * 2)  # two periods
    S, J = 0.5, 0.25
    u, _ = Stiction(S=S, J=J).apply(x)
    du = np.abs(np.diff(np.concatenate([[0.0], u])))
    assert du.max() == J + step
    # breakaway once, then one slip per reversal of the input
    reversals = int(np.sum(np.diff(np.sign(np.diff(x))) != 0))
    assert int(np.sum(du == J + step)) == 1 + reversals
    # all other moves follow the input step by step
    assert set(np.unique(du)) == {0.0, step, J + step}


@pytest.mark.parametrize("seed", [8, 9])
def test_stiction_he_fd_equals_fs_is_backlash(seed: int) -> None:
    rng = np.random.default_rng(seed)
    x = np.cumsum(rng.standard_normal((3, 400)), axis=1) / 20
    assert_array_equal(
        StictionHe(f_s=0.125, f_d=0.125, u0=0.1).apply(x)[0],
        Backlash(d=0.25, u0=0.1).apply(x)[0],
    )
    grid = _dyadic_walk(rng, (3, 400), [-3, -1, 0, 1, 3])
    assert_array_equal(
        StictionHe(f_s=0.25, f_d=0.25).apply(grid)[0], Backlash(d=0.5).apply(grid)[0]
    )


@pytest.mark.parametrize("seed", [10, 11])
def test_stiction_he_matches_stiction_when_steps_exceed_J(seed: int) -> None:
    # Every non-zero input step (>= 2/16) exceeds J = 1/16: the two models then coincide.
    x = _dyadic_walk(np.random.default_rng(seed), (4, 600), [-5, -3, -2, 0, 2, 3, 5])
    f_s, f_d = 7 / 32, 5 / 32  # S = 12/32, J = 2/32
    assert_array_equal(
        StictionHe(f_s=f_s, f_d=f_d).apply(x)[0],
        Stiction(S=f_s + f_d, J=f_s - f_d).apply(x)[0],
    )


# --------------------------------------------------------------------------- interface


def _random_input(seed: int, shape: tuple[int, int]) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return np.cumsum(rng.standard_normal(shape), axis=1) / 10


@pytest.mark.parametrize(
    ("cls", "kwargs"),
    [(cls, {}) for cls in BUILTIN] + [(cls, {"u0": None}) for cls in WITH_MEMORY],
)
def test_batch_equals_row_by_row(cls: type[Nonlinearity], kwargs: dict[str, Any]) -> None:
    model = cls(**kwargs)
    x = _random_input(12, (5, 60))
    u, state = model.apply(x)
    assert u.shape == x.shape
    for r in range(x.shape[0]):
        u_r, state_r = model.apply(x[r])
        assert u_r.shape == (x.shape[1],)
        assert_array_equal(u[r], u_r)
        for key, value in state.items():
            assert_array_equal(value[r], state_r[key][0])


@pytest.mark.parametrize("cls", STATIC)
def test_static_apply_equals_stepping(cls: type[Nonlinearity]) -> None:
    model = cls()
    x = _random_input(13, (3, 50))
    assert_array_equal(model.apply(x)[0], Nonlinearity.apply(model, x)[0])


@pytest.mark.parametrize("cls", WITH_MEMORY)
def test_state_is_not_mutated(cls: type[Nonlinearity]) -> None:
    model = cls()
    x = _random_input(14, (3, 80))
    _, state = model.apply(x[:, :40])
    saved = {k: v.copy() for k, v in state.items()}
    first, _ = model.apply(x[:, 40:], state)
    second, _ = model.apply(x[:, 40:], state)
    assert_array_equal(first, second)
    for key, value in saved.items():
        assert_array_equal(state[key], value)


def test_builtin_names_and_params() -> None:
    names = [cls.name for cls in BUILTIN]
    assert names == ["linear", "backlash", "deadband", "saturation", "stiction", "stiction-he"]
    assert {cls for cls in BUILTIN if cls.has_memory} == set(WITH_MEMORY)
    for cls in BUILTIN:
        model = cls()
        for value in model.params().values():
            assert value is None or type(value) is float
        assert repr(model).startswith(cls.__name__ + "(")
        assert cls(**model.params()).params() == model.params()


def test_defaults() -> None:
    assert Backlash().params() == {"d": 0.1, "u0": 0.0}
    assert Deadband().params() == {"d1": 0.05, "d2": 0.05, "slope": 1.0}
    assert Saturation().params() == {"u_min": -0.2, "u_max": 0.2}
    assert Stiction().params() == {"S": 0.1, "J": 0.02, "u0": 0.0}


@pytest.mark.parametrize(
    ("cls", "kwargs", "match"),
    [
        (Linear, {"gain": 0.0}, "gain"),
        (Linear, {"gain": float("nan")}, "gain"),
        (Linear, {"gain": "two"}, "gain must be a number"),
        (Backlash, {"d": -0.1}, "width d must be >= 0"),
        (Backlash, {"d": float("inf")}, "width d"),
        (Backlash, {"u0": float("nan")}, "u0"),
        (Deadband, {"d1": -0.01}, "d1 must be >= 0"),
        (Deadband, {"d2": -1.0}, "d2 must be >= 0"),
        (Deadband, {"slope": 0.0}, "slope"),
        (Saturation, {"u_min": 0.2, "u_max": 0.2}, "u_min must be < u_max"),
        (Saturation, {"u_min": 1.0, "u_max": -1.0}, "u_min must be < u_max"),
        (Saturation, {"u_max": float("nan")}, "u_max"),
        (Stiction, {"S": -0.1}, "S .* must be >= 0"),
        (Stiction, {"J": -0.01}, "J .* must be >= 0"),
        (Stiction, {"S": 0.1, "J": 0.2}, "J .* must not exceed S"),
        (Stiction, {"S": float("nan")}, "S"),
        (StictionHe, {"f_s": -1.0}, "f_s"),
        (StictionHe, {"f_s": 0.1, "f_d": 0.2}, "f_d .* must not exceed f_s"),
    ],
)
def test_bad_parameters_raise(cls: type[Nonlinearity], kwargs: dict[str, Any], match: str) -> None:
    with pytest.raises(InputError, match=match):
        cls(**kwargs)


@pytest.mark.parametrize("cls", BUILTIN)
def test_parameters_are_keyword_only(cls: type[Nonlinearity]) -> None:
    with pytest.raises(TypeError):
        cls(0.1)  # type: ignore[call-arg]


@pytest.mark.parametrize("cls", WITH_MEMORY)
def test_initial_state_shapes(cls: type[Nonlinearity]) -> None:
    state = cls().initial_state(3, np.array([0.1, 0.2, 0.3]))
    for value in state.values():
        assert value.shape == (3,)
    with pytest.raises(InputError, match="x0 must have shape"):
        cls(u0=None).initial_state(3, np.zeros(2))
    with pytest.raises(InputError, match="x0 must have shape"):
        cls().initial_state(3, np.zeros((3, 1)))

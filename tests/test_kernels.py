"""The compiled kernels (hbench/numerics/_kernels.c) give the numpy path's numbers exactly.

Exact equality is the claim, not a tolerance: each kernel performs the numpy path's
floating-point operations in the same order, without fused multiply-adds (compared as floats:
only the sign of an exact zero may differ). Where the extension
was not built (no C compiler) these comparisons skip; CI sets ``HBENCH_REQUIRE_KERNELS=1`` so
that a missing build fails there instead of silently benchmarking the numpy path.
"""

from __future__ import annotations

import os
import warnings
from typing import Any, ClassVar

import numpy as np
import pytest
from scipy import signal

from hbench.bench import kernel_status, metrics
from hbench.bench.runner import methods_from_names, run_cell
from hbench.errors import InputError
from hbench.ident import polyphase as pp
from hbench.ident.identifiers import IdentifyOptions, identify
from hbench.model import noise
from hbench.model import nonlinearities as nl
from hbench.numerics import kernels
from hbench.sim import loop_kernel, scenarios
from hbench.sim.simulate import simulate

BUILT = kernels.backend() == "c"
needs_build = pytest.mark.skipif(not BUILT, reason=f"kernels not in use: {kernels.status()}")

ACTUATORS = [
    {"name": "linear", "gain": 1.5},
    {"name": "deadband", "d1": 0.05, "d2": 0.1, "slope": 1.5},
    {"name": "saturation", "u_min": -0.2, "u_max": 0.3},
    {"name": "backlash", "d": 0.1},
    {"name": "stiction", "S": 0.1, "J": 0.02},
    {"name": "stiction", "S": 0.2, "J": 0.0, "u0": None},
    {"name": "stiction-he", "f_s": 0.06, "f_d": 0.04},
]
CONTROLLERS = [
    {"name": "p", "kp": 0.1},
    {"name": "pi", "kp": 0.05, "ki": 0.01},
    {"name": "p", "kp": 0.1, "delay": 2},
    {"name": "tf", "num": [0.1, -0.05, 0.02, 0.01], "den": [1.0, -0.5, 0.06, 0.01]},
]
PLANTS = [{"name": "paper", "delay": 3}, {"name": "third-order"}]


def _scenario(**over: Any):
    return scenarios.build({**scenarios.PAPER_SECTION6, "duration": 60.0, **over})


def test_ci_has_the_compiled_kernels() -> None:
    if os.environ.get("HBENCH_REQUIRE_KERNELS") != "1":
        pytest.skip("HBENCH_REQUIRE_KERNELS is not set (CI sets it)")
    assert BUILT, kernel_status.status()
    assert pp.lapack_is_reference(), kernel_status.status()  # eq. (27) runs compiled in CI
    assert kernels.lfilter_is_scipys(), kernel_status.status()  # and lfilter
    assert metrics.sums_are_numpys(), kernel_status.status()  # and the fitness


@needs_build
@pytest.mark.parametrize("plant", PLANTS, ids=lambda c: c["name"])
@pytest.mark.parametrize("controller", CONTROLLERS, ids=lambda c: f"{c['name']}{c.get('delay', 0)}")
@pytest.mark.parametrize("actuator", ACTUATORS, ids=lambda a: a["name"])
def test_closed_loop_is_the_numpy_loop(actuator: dict, controller: dict, plant: dict) -> None:
    """Equal as floats (``assert_array_equal``: only the sign of an exact zero may differ).
    The third-order plant and the three-state controller sum three or more non-zero terms,
    where an order of summation other than the kernel's would show."""
    sc = _scenario(nonlinearity=actuator, controller=controller, plant=plant)
    rec, truth = simulate(sc, 9, 3)
    with kernels.use("numpy"):
        rec0, truth0 = simulate(sc, 9, 3)
    for name in ("y", "x", "r"):
        np.testing.assert_array_equal(getattr(rec, name), getattr(rec0, name), err_msg=name)
    np.testing.assert_array_equal(truth.U, truth0.U)
    np.testing.assert_array_equal(truth.y0, truth0.y0)


@needs_build
def test_closed_loop_with_a_target_snr_is_the_numpy_loop() -> None:
    noise = {**scenarios.PAPER_SECTION6["noise"], "snr": 5.0}
    noise.pop("sigma2")
    sc = _scenario(noise=noise, nonlinearity={"name": "stiction", "S": 0.1, "J": 0.02})
    rec, truth = simulate(sc, 6, 11)
    with kernels.use("numpy"):
        rec0, truth0 = simulate(sc, 6, 11)
    np.testing.assert_array_equal(rec.y, rec0.y)
    np.testing.assert_array_equal(truth.sigma2, truth0.sigma2)


class _Relay(nl.Nonlinearity):
    """An actuator the kernel does not know (as a plugin's would be)."""

    name: ClassVar[str] = "test-relay"

    def step(self, x: np.ndarray, state: dict) -> tuple[np.ndarray, dict]:
        return 0.1 * np.sign(x), state


class _WiderBacklash(nl.Backlash):
    def step(self, x: np.ndarray, state: dict) -> tuple[np.ndarray, dict]:
        return super().step(1.1 * x, state)


def test_unknown_actuators_run_the_numpy_loop() -> None:
    sc = _scenario()
    assert loop_kernel.supports_loop(sc.controller, nl.Backlash(d=0.1))
    assert not loop_kernel.supports_loop(sc.controller, _Relay())
    # a subclass may change the rules: only the exact built-in types are compiled
    assert not loop_kernel.supports_loop(sc.controller, _WiderBacklash(d=0.1))


@needs_build
@pytest.mark.parametrize("na", [0, 1, 2, 4])
def test_filtered_output_is_the_numpy_path(na: int) -> None:
    rng = np.random.default_rng(na)
    y = rng.standard_normal((7, 301))
    a = np.concatenate([np.ones((7, 1)), rng.standard_normal((7, na))], axis=1)
    w = pp.filtered_output(y[:, 1:], a)  # a strided view, as blind_fit passes it
    with kernels.use("numpy"):
        w0 = pp.filtered_output(y[:, 1:], a)
    np.testing.assert_array_equal(w, w0)
    assert np.isnan(w[:, :na]).all() and np.isfinite(w[:, na:]).all()
    # with its differences in the same pass: the bits of delta(filtered_output(..))
    w1, dw = pp.filtered_output_and_delta(y[:, 1:], a)
    assert kernels.filtered_output_and_delta(y[:, 1:], a) is not None
    np.testing.assert_array_equal(w1, w0)
    np.testing.assert_array_equal(dw, pp.delta(w0))
    assert np.isnan(dw[:, : na + 1]).all() and np.isfinite(dw[:, na + 1 :]).all()
    with kernels.use("numpy"):
        assert kernels.filtered_output_and_delta(y[:, 1:], a) is None
        np.testing.assert_array_equal(pp.filtered_output_and_delta(y[:, 1:], a)[1], dw)


@needs_build
@pytest.mark.parametrize(("p", "shift", "t_min"), [(2, 1, 3), (5, 0, 3), (5, 4, 1), (7, 3, 12)])
def test_phase_variances_are_the_numpy_path(p: int, shift: int, t_min: int) -> None:
    """Sums of squares of widely ranging size, where another order of summation would show."""
    rng = np.random.default_rng(p + shift)
    dw = rng.standard_normal((6, 4001)) * np.exp(rng.uniform(-15, 15, (6, 4001)))
    v = pp.phase_variances(dw[:, 1:], p, shift, t_min)  # a strided view, as selections pass it
    with kernels.use("numpy"):
        v0 = pp.phase_variances(dw[:, 1:], p, shift, t_min)
    np.testing.assert_array_equal(v, v0)
    block = pp.period_block(dw, p, np.arange(3, 50), shift, p)
    np.testing.assert_array_equal(
        kernels.period_mean_squares(block), np.mean(np.square(block), axis=1)
    )
    wide = np.ascontiguousarray(block.transpose(0, 2, 1))  # any width >= 2, contiguous too
    np.testing.assert_array_equal(
        kernels.period_mean_squares(wide), np.mean(np.square(wide), axis=1)
    )
    # numpy sums a single column pairwise, and strided columns are not the kernel's: numpy runs
    assert kernels.period_mean_squares(block[:, :, :1]) is None
    assert kernels.period_mean_squares(block[:, :, ::-1]) is None


@needs_build
@pytest.mark.parametrize(("p", "na", "shift"), [(2, 0, 1), (5, 2, 0), (5, 4, 4), (7, 3, 2)])
def test_filtered_phase_variances_are_the_numpy_path(p: int, na: int, shift: int) -> None:
    """Table 2's variances straight from y (the kernel forms neither w nor Delta w) are those of
    the numpy lines, on samples of widely ranging size and with a run that holds a nan."""
    rng = np.random.default_rng(10 * p + na)
    y = rng.standard_normal((6, 3001)) * np.exp(rng.uniform(-15, 15, (6, 3001)))
    y[2, 1500] = np.nan
    a = np.concatenate([np.ones((6, 1)), rng.standard_normal((6, na))], axis=1)
    for t_min in (na + 1, na + 4):
        got = pp.filtered_phase_variances(y, a, p, shift, t_min)
        with kernels.use("numpy"):
            want = pp.filtered_phase_variances(y, a, p, shift, t_min)
        np.testing.assert_array_equal(got, want)
        np.testing.assert_array_equal(
            want, pp.phase_variances(pp.delta(pp.filtered_output(y, a)), p, shift, t_min)
        )
        assert np.isnan(got[2]).any() and np.isfinite(np.delete(got, 2, axis=0)).all()
    t0 = (na + 1) + p
    assert kernels.filtered_phase_variances(y, a, p, t0, 10) is not None
    # what the kernel does not take goes to numpy: p = 1 (numpy sums one column pairwise), a
    # window reaching an undefined w, or past the record's end
    assert kernels.filtered_phase_variances(y, a, 1, t0, 10) is None
    assert kernels.filtered_phase_variances(y, a, p, na, 10) is None
    assert kernels.filtered_phase_variances(y, a, p, t0, 3001) is None


@needs_build
@pytest.mark.parametrize("K", [1, 7, 8, 100, 128, 129, 500, 2049])
def test_fitness_is_the_numpy_path(K: int) -> None:
    """Row sums of every length class of numpy's pairwise summation (below 8, up to 128, split
    in halves), widely ranging magnitudes, undefined samples, a run with none in common with
    the truth and a constant truth: the kernel's fitness is numpy's, bit for bit."""
    rng = np.random.default_rng(K)
    U = rng.standard_normal((5, K)) * np.exp(rng.uniform(-20, 20, (5, K)))
    U_est = 1.3 * U + rng.standard_normal((5, K)) * np.exp(rng.uniform(-20, 20, (5, K)))
    U_est[1, : K // 3] = np.nan
    U_est[2] = np.nan
    U[3] = 2.5
    gain = rng.uniform(0.5, 2.0, 5)
    with np.errstate(all="ignore"):
        got = metrics.fitnesses(U_est, U, ("gain", "ls"), gain)
        want = metrics.fitnesses(U_est, U, ("gain", "ls"), gain, compiled=False)
    for s in ("gain", "ls"):
        np.testing.assert_array_equal(got[s], want[s])
    assert kernels.fitness(U_est, U, gain) is not None
    assert np.isnan(got["gain"][2]) and np.isnan(got["ls"][2])
    # layouts numpy would sum in another order go to numpy
    if K > 1:
        assert kernels.fitness(np.asfortranarray(U_est), U, gain) is None
    # a masked array keeps numpy's rules (its mask), and unaligned data is not the kernel's
    masked = np.ma.array(U_est, mask=np.zeros_like(U_est, bool))
    assert kernels.fitness(masked, U, gain) is None
    raw = np.empty(U_est.size * 8 + 1, np.uint8)[1:].view(np.float64).reshape(U_est.shape)
    raw[...] = U_est
    assert kernels.fitness(raw, U, gain) is None


@pytest.mark.parametrize("compiled", [True, False])
def test_fitness_of_a_zero_gain_is_silent_on_both_paths(compiled: bool) -> None:
    """A zero true gain gives the same non-finite fitness on both paths and no warning from
    either (numpy's path warned 'divide by zero', the compiled one did not)."""
    U = np.sin(np.arange(40.0))[None, :].repeat(2, axis=0)
    gain = np.array([0.0, 1.0])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        got = metrics.fitnesses(U.copy(), U, ("gain", "ls"), gain, compiled=compiled)
    assert not np.isfinite(got["gain"][0]) and got["gain"][1] == 100.0
    np.testing.assert_array_equal(got["ls"], [100.0, 100.0])


@needs_build
@pytest.mark.parametrize(("n_num", "n_den"), [(1, 2), (3, 2), (2, 4), (5, 3)])
def test_batched_lfilter_is_scipys(n_num: int, n_den: int) -> None:
    rng = np.random.default_rng(10 * n_num + n_den)
    x = rng.standard_normal((6, 401))
    num = rng.standard_normal((6, n_num))
    den = np.concatenate([1.0 + rng.random((6, 1)), 0.3 * rng.standard_normal((6, n_den - 1))], 1)
    y = pp.batched_lfilter(num, den, x[:, 3:])  # a strided view, as the direct inverse passes it
    with kernels.use("numpy"):
        y0 = pp.batched_lfilter(num, den, x[:, 3:])
    np.testing.assert_array_equal(y, y0)
    assert kernels.lfilter_rows(num, den[:, :1], x) is None  # scipy convolves instead: its path


def _eq27_cases(p: int = 5, M: int = 120, runs: int = 11):
    """SIMO systems of eq. (27): ordinary runs, an unknown in no equation (h(1) = 0), a run with a
    nan, a singular run (h(0) = h(1): the normal matrix is not positive definite) and record ends
    with missing samples."""
    rng = np.random.default_rng(p * M)
    w = rng.standard_normal((runs, (M + 2) * p)) * np.exp(rng.uniform(-3, 3, (runs, 1)))
    b = rng.standard_normal((runs, 3))
    b[:, 0] = 1.0
    h0, h1 = pp.simo_channels(b, p)
    h1[1] = 0.0  # U(n0 - 1) in no equation: pinned, reported nan
    w[2, w.shape[1] // 2] = np.nan  # a non-finite run: the Thomas loop
    h1[3] = h0[3]  # singular: dpttrf fails, the Thomas loop takes the run
    sys = pp.simo_system(w, p, 2, 7)
    return sys, h0, h1


@needs_build
@pytest.mark.parametrize(("p", "M"), [(5, 120), (2, 1), (3, 0), (7, 40)])
def test_inner_signal_ls_is_the_numpy_path(p: int, M: int) -> None:
    sys, h0, h1 = _eq27_cases(p, M)
    U = pp.inner_signal_ls(sys, h0, h1)
    with kernels.use("numpy"):
        U0 = pp.inner_signal_ls(sys, h0, h1)
    np.testing.assert_array_equal(U, U0)
    if M > 5:
        assert np.isnan(U[1, 0]) and np.isfinite(U[1, 1:]).all()
        assert np.isfinite(U[[0, 4, 5]]).all()
    # each run as solved on its own (the batch's other runs, a failing one among them, play no part)
    for r in range(U.shape[0]):
        one = pp.SimoSystem(W=sys.W[r : r + 1], valid=sys.valid, n0=sys.n0)
        np.testing.assert_array_equal(
            pp.inner_signal_ls(one, h0[r : r + 1], h1[r : r + 1]), U[r : r + 1]
        )
        with kernels.use("numpy"):
            np.testing.assert_array_equal(
                pp.inner_signal_ls(one, h0[r : r + 1], h1[r : r + 1]), U[r : r + 1]
            )
    assert kernels.inner_signal_ls(sys.W, sys.valid[:, :1], h0, h1) is None  # shapes differ


@needs_build
def test_inner_signal_ls_reads_w_in_place_as_the_blocks() -> None:
    """:func:`hbench.ident.polyphase.simo_system` leaves ``w`` in place: the kernel reads it where a
    sample exists (never past the record's end, nor before ``t_min``), the same numbers as the
    blocks ``W``; entries of ``W`` marked missing are ignored by both paths, whatever they hold."""
    sys, h0, h1 = _eq27_cases(5, 120)
    assert not sys.laid_out and not sys.valid.all()  # record ends with missing samples
    in_place = pp.inner_signal_ls(sys, h0, h1)
    assert not sys.laid_out  # the blocks were not formed
    blocks = kernels.inner_signal_ls(sys.W, sys.valid, h0, h1)
    np.testing.assert_array_equal(in_place, blocks)
    garbage = pp.SimoSystem(W=np.where(sys.valid, sys.W, np.nan), valid=sys.valid, n0=sys.n0)
    np.testing.assert_array_equal(pp.inner_signal_ls(garbage, h0, h1), in_place)
    with kernels.use("numpy"):
        np.testing.assert_array_equal(pp.inner_signal_ls(garbage, h0, h1), in_place)
    # a valid sample past the rows: refused (the numpy path runs), never read out of bounds
    short = sys.source[:, : sys.start + sys.valid.size - 1]
    assert kernels.inner_signal_ls(short, np.ones_like(sys.valid), h0, h1, start=sys.start) is None


@needs_build
def test_an_overflowing_run_leaves_its_neighbours_alone() -> None:
    """A run whose solution overflows (inf) would turn its predecessor in the batched LAPACK
    system into nan (inf times the zero coupling): such runs are solved again on their own, as the
    kernel solves every run (review's reproducer)."""
    W = np.array([[[1.0, 2.0]], [[1e200, 1e200]]])
    valid = np.ones((1, 2), bool)
    h0 = np.array([[1.0, 0.5], [1e-150, 2e-150]])
    h1 = np.array([[0.3, 0.2], [3e-150, 1e-150]])
    sys = pp.SimoSystem(W=W, valid=valid, n0=1)
    U = pp.inner_signal_ls(sys, h0, h1)
    with kernels.use("numpy"):
        U0 = pp.inner_signal_ls(sys, h0, h1)
        alone = pp.inner_signal_ls(pp.SimoSystem(W=W[:1], valid=valid, n0=1), h0[:1], h1[:1])
    np.testing.assert_array_equal(U, U0)
    np.testing.assert_array_equal(U0[:1], alone)
    assert np.isfinite(U0[0]).all() and not np.isfinite(U0[1]).all()
    assert (kernels.inner_signal_ls(W, valid, h0, h1) is None) == (not kernels.built())


def test_a_run_lapack_refuses_leaves_the_others_to_lapack() -> None:
    """``solve_tridiagonal``: a run that is not positive definite is solved by the loop alone;
    the others keep LAPACK's numbers (those of their own solve)."""
    rng = np.random.default_rng(4)
    R, M = 5, 60
    off = rng.uniform(-1.0, 1.0, (R, M - 1))
    diag = rng.uniform(2.5, 4.0, (R, M))
    rhs = rng.standard_normal((R, M))
    diag[2, 30] = -1.0  # not positive definite
    x = pp.solve_tridiagonal(off, diag, off, rhs)
    for r in range(R):
        o = off[r : r + 1]  # the same object twice: symmetric, LAPACK's route
        one = pp.solve_tridiagonal(o, diag[r : r + 1], o, rhs[r : r + 1])
        np.testing.assert_array_equal(x[r : r + 1], one)
    o = off[[0, 1]]
    lapack_x = pp.solve_tridiagonal(o, diag[[0, 1]], o, rhs[[0, 1]])
    np.testing.assert_array_equal(x[[0, 1]], lapack_x)
    loop = pp._thomas(off[2:3], diag[2:3], off[2:3], rhs[2:3])
    np.testing.assert_array_equal(x[2:3], loop)
    dense = np.diag(diag[2]) + np.diag(off[2], 1) + np.diag(off[2], -1)
    np.testing.assert_allclose(dense @ x[2], rhs[2], atol=1e-9)  # the loop still solves it


@needs_build
@pytest.mark.parametrize(
    "model",
    [
        noise.White(),
        noise.ARX(gain=0.3),
        noise.ARMA(c=[1.0, 0.4, -0.2], d=[1.0, -0.5]),
        noise.ContinuousFilter(num=[1.0], den=[1.0, 0.32, 0.02]),
    ],
    ids=lambda m: m.name,
)
def test_noise_shaping_is_scipys(model) -> None:
    """Every run's noise filtered as ``scipy.signal.lfilter`` filters it (white noise: scipy's
    own route, the kernel declines a denominator of length 1)."""
    plant = scenarios.build(scenarios.PAPER_SECTION6).discrete_plant
    e = np.random.default_rng(3).standard_normal((11, 500))
    c, d = model.filter(plant)
    np.testing.assert_array_equal(model.shape(e, plant), signal.lfilter(c, d, e, axis=-1))
    with kernels.use("numpy"):
        np.testing.assert_array_equal(model.shape(e, plant), signal.lfilter(c, d, e, axis=-1))


def _valve_inputs(rng: np.random.Generator, K: int) -> np.ndarray:
    """A wandering controller output with repeated values (reversals at equal inputs)."""
    return np.round(np.cumsum(rng.standard_normal(K)) * 0.3, 1)


@needs_build
@pytest.mark.parametrize("K", [1, 2, 57, 800])
def test_diagnosis_actuator_maps_are_the_numpy_path(K: int) -> None:
    """The diagnosis's batched backlash and stiction (every candidate, every start) give the
    numpy path's numbers, nan inputs included."""
    from hbench.diagnose import core

    rng = np.random.default_rng(K)
    x = _valve_inputs(rng, K)
    if K > 2:
        x[K // 2] = np.nan
    C = 64
    width, S = rng.uniform(0, 1.5, C), rng.uniform(0, 1.5, C)
    J = S * rng.uniform(0, 1.3, C)  # J > S too: the rules still apply
    # ties with the inputs' grid: J = 0 (backlash, where the fits start), S = J, S = 0, and
    # S, J on the 0.1 grid of x, so that ahead == J and -ahead == S occur
    S[:4], J[:4] = [0.3, 0.4, 0.0, 0.2], [0.0, 0.4, 0.0, 0.1]
    width[:2] = [0.0, 0.2]
    g0, d0 = rng.uniform(0, 1, C), rng.choice([-1.0, 1.0], C)
    got = core.backlash_batch(x, width, g0), core.stiction_batch(x, S, J, d0, g0)
    with kernels.use("numpy"):
        want = core.backlash_batch(x, width, g0), core.stiction_batch(x, S, J, d0, g0)
    for g, w in zip(got, want, strict=True):
        assert g.shape == (C, K)
        np.testing.assert_array_equal(g, w)


@needs_build
def test_the_actuator_maps_leave_their_arguments_alone() -> None:
    """The kernels update their state in copies: the caller's arrays are unchanged."""
    rng = np.random.default_rng(5)
    x = _valve_inputs(rng, 300)
    S, J, h = np.full(4, 0.5), np.full(4, 0.2), np.full(4, 0.15)
    d, x_ss, u = np.ones(4), np.full(4, x[0]), np.full(4, x[0] - 0.15)
    before = [a.copy() for a in (x, S, J, h, d, x_ss, u)]
    assert kernels.stiction_rows(x, x[0], S, J, h, d, x_ss, u) is not None
    for a, b in zip((x, S, J, h, d, x_ss, u), before, strict=True):
        np.testing.assert_array_equal(a, b)


def test_shapes_the_kernels_do_not_take_go_to_numpy_and_scipy() -> None:
    """One coefficient row for every run (numpy broadcasts it), no coefficient, a[0] = 0:
    the wrappers decline (``None``) and the numpy / scipy paths answer as they always did."""
    y = np.ones((3, 10))
    assert kernels.filtered_output(y, np.ones((1, 2))) is None
    assert kernels.filtered_output(y, np.ones((3, 0))) is None
    np.testing.assert_array_equal(pp.filtered_output(y, np.ones((1, 2)))[:, 1:], 2.0)
    assert kernels.lfilter_rows(np.ones((1, 2)), np.ones((3, 2)), y) is None
    assert kernels.lfilter_rows(np.ones((3, 2)), np.array([[0.0, 1.0]] * 3), y) is None
    assert kernels.backlash_rows(np.ones((2, 3)), np.ones(2), np.ones(2)) is None  # one x only
    assert kernels.stiction_rows(np.ones(3), 1.0, *(np.ones(2),) * 5, np.ones(3)) is None
    with pytest.raises(ValueError, match=r"a\[0\]"):
        pp.batched_lfilter(np.ones((3, 2)), np.array([[0.0, 1.0]] * 3), y)


@needs_build
def test_rows_do_not_depend_on_the_kernels() -> None:
    """Every built-in method, a small cell, both paths: the same tidy rows bit for bit."""
    names = [
        "wang-lsm",
        "wang-iv",
        "bai-fu",
        "oracle",
        "oracle-inv",
        "sun-liu-sano",
        "wang-lsm-cn",
        "wang-iv-opt",
        "joint-refine",
        "wang-delay",
    ]
    sc = _scenario()
    methods = methods_from_names(names)
    rows = run_cell(sc, methods, 12, 5).rows
    with kernels.use("numpy"):
        rows0 = run_cell(sc, methods, 12, 5).rows
    keep, keep0 = rows["quantity"] != "seconds", rows0["quantity"] != "seconds"
    a, b = rows[keep].reset_index(drop=True), rows0[keep0].reset_index(drop=True)
    assert a.drop(columns="value").equals(b.drop(columns="value"))
    np.testing.assert_array_equal(a["value"].to_numpy(), b["value"].to_numpy())


def test_a_selection_shared_on_a_record_equals_one_computed_alone() -> None:
    """The LSM's and the OLS's selection tables share regressions and Rm^+ through the
    record's cache: bai-fu after wang-lsm on one record gives what bai-fu gives alone."""
    rec, _ = simulate(_scenario(), 8, 4)
    methods = methods_from_names(["wang-lsm", "bai-fu"])
    opts = IdentifyOptions(delay_multiple=0)
    identify(methods["wang-lsm"], rec, opts)
    shared = identify(methods["bai-fu"], rec, opts)
    alone_rec, _ = simulate(_scenario(), 8, 4)
    alone = identify(methods["bai-fu"], alone_rec, opts)
    assert any(str(k).startswith("selection-regressions") for k in rec.cache)
    np.testing.assert_array_equal(shared.a, alone.a)
    np.testing.assert_array_equal(shared.U, alone.U)
    np.testing.assert_array_equal(shared.criteria["V"], alone.criteria["V"])


def test_backend_switch_and_bad_names() -> None:
    with kernels.use("numpy"):
        assert kernels.backend() == "numpy"
        assert kernels.status().startswith("numpy path (HBENCH_KERNELS=numpy)")
        assert kernels.filtered_output(np.zeros((1, 3)), np.ones((1, 1))) is None
    with pytest.raises(InputError, match="kernel backend must be one of auto, numpy"):
        with kernels.use("fortran"):
            pass
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("HBENCH_KERNELS", "gpu")
        with pytest.raises(InputError, match="HBENCH_KERNELS must be one of auto, numpy"):
            kernels.backend()
        with kernels.use("numpy"):  # use() overrides the environment
            assert kernels.backend() == "numpy"


def test_a_diverging_loop_overflows_quietly_on_both_paths() -> None:
    """The stability check of :func:`simulate` is bypassed: both paths run a loop that blows
    up, without a numpy warning (the kernel cannot warn), and return the same non-finite
    output, which :func:`simulate` turns into an UnstableError."""
    from hbench.sim.simulate import LiftedPlant, _run_loop

    sc = _scenario(controller={"name": "pi", "kp": 40.0, "ki": 5.0})
    lp = LiftedPlant.from_plant(sc.discrete_plant, sc.p)
    r = np.ones((2, 4000))
    v = np.zeros((2, 4000 * sc.p))
    outs = []
    for backend in ("auto", "numpy"):
        with kernels.use(backend), warnings.catch_warnings():
            warnings.simplefilter("error")
            outs.append(_run_loop(lp, sc.controller, sc.nonlinearity, r, v, sc.p))
    assert not np.all(np.isfinite(outs[1][0]))
    for a, b in zip(outs[0], outs[1], strict=True):
        np.testing.assert_array_equal(a, b)


def test_use_switches_the_backend_of_its_own_thread_only() -> None:
    import threading

    seen: dict[str, str] = {}
    inside, release = threading.Event(), threading.Event()

    def other() -> None:
        inside.wait()
        seen["other"] = kernels.backend()
        release.set()

    t = threading.Thread(target=other)
    t.start()
    outside = kernels.backend()
    with kernels.use("numpy"):
        inside.set()
        release.wait(10)
        seen["here"] = kernels.backend()
    t.join()
    assert seen == {"here": "numpy", "other": outside}
    assert kernels.backend() == outside


@needs_build
def test_the_library_checks_do_not_read_the_backend_switch() -> None:
    """Asked first inside ``use("numpy")``, the once-per-process checks still answer for the
    build (a cached "no" would have kept eq. (27) and lfilter off the kernels for good)."""
    checks = (pp.lapack_is_reference, kernels.lfilter_is_scipys, metrics.sums_are_numpys)

    def clear() -> None:
        for check in checks:
            check.cache_clear()

    clear()
    try:
        with kernels.use("numpy"):
            inside = tuple(check() for check in checks)
        assert inside == tuple(check() for check in checks)
        clear()
        assert inside == tuple(check() for check in checks)
    finally:
        clear()


@needs_build
def test_libraries_that_compute_otherwise_keep_their_own_route(monkeypatch) -> None:
    """Where scipy's dptsv or lfilter would not give the kernels' numbers (fused multiply-adds in
    their build), the kernels decline and say so: both backends then take the library's route."""
    monkeypatch.setattr(pp, "lapack_is_reference", lambda: False)
    monkeypatch.setattr(kernels, "lfilter_is_scipys", lambda: False)
    monkeypatch.setattr(metrics, "sums_are_numpys", lambda: False)

    def declined(*args: Any, **kwargs: Any) -> None:
        raise AssertionError("a kernel ran where its library computes otherwise")

    monkeypatch.setattr(kernels, "fitness", declined)
    monkeypatch.setattr(kernels, "inner_signal_ls", declined)
    x = np.ones((2, 10))
    metrics.fitnesses(x, x, ("gain", "ls"), 1.0)
    assert kernels.lfilter_rows(np.ones((2, 2)), np.array([[1.0, -0.5]] * 2), x) is None
    W, valid = np.ones((2, 3, 2)), np.ones((3, 2), bool)
    pp.inner_signal_ls(pp.SimoSystem(W=W, valid=valid, n0=1), x[:, :2], x[:, :2])
    status = kernel_status.status()
    assert "eq. (27)" in status and "lfilter" in status and "fitness" in status

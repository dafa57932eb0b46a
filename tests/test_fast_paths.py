"""The fast paths give the numbers of the plain computations they replace.

Tolerances: 1e-12 relative where the same sums are taken in another order (one Gram matrix
instead of one per regression, LAPACK instead of the Thomas loop), exact equality where the
computation is shared rather than reordered (a structure selection reused from the cache).
"""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from scipy import signal

from hbench.ident import polyphase as pp
from hbench.ident.identifiers import IdentifyOptions, identify
from hbench.plugins import registry
from tests.helpers import sim


@pytest.fixture(scope="module")
def noisy():
    return sim(runs=6, seed=21, noise__sigma2=1e-3)


def _rows(dy: np.ndarray, reg: pp.QuietRegression) -> tuple[np.ndarray, np.ndarray]:
    """The regression's rows written out: targets and regressors at its sample times."""
    lags = np.arange(1, reg.na + 1)
    return dy[:, reg.t], -dy[:, reg.t[:, None] - lags[None, :]]


@pytest.mark.parametrize(("phases", "shift"), [((5,), 0), ((5,), 4), ((3, 4, 5), 3)])
def test_lag_moments_equal_the_rows_gram(noisy, phases, shift):
    record, _ = noisy
    dy = pp.delta(record.y)
    lm = pp.LagMoments(dy, record.p, 5)
    for na in (1, 2, 5):
        reg = pp.quiet_regression(dy, record.p, na, phases, shift, moments=lm)
        y, phi = _rows(dy, reg)
        Z = np.concatenate([y[..., None], phi], axis=2)
        M = np.einsum("rni,rnj->rij", Z, Z) / y.shape[1]
        np.testing.assert_allclose(reg.all_moments(), M, rtol=1e-12, atol=1e-12 * np.abs(M).max())
        np.testing.assert_array_equal(reg.target, y)
        np.testing.assert_array_equal(reg.phi, phi)
        # every row's lags lie inside the record and after the undefined Delta y(0)
        assert reg.t.min() - na >= 1 and reg.t.max() < dy.shape[1]


def test_residual_from_moments_and_from_rows(noisy):
    record, _ = noisy
    dy = pp.delta(record.y)
    reg = pp.quiet_regression(dy, record.p, 2, (3, 4, 5), 3, moments=pp.LagMoments(dy, 5, 5))
    theta, _ = pp.bias_compensated(reg)
    y, phi = _rows(dy, reg)
    direct = np.mean((y - np.einsum("rni,ri->rn", phi, theta)) ** 2, axis=1)
    np.testing.assert_allclose(reg.residual_ms(theta), direct, rtol=1e-10)


def test_residual_of_noise_free_data_is_recomputed_from_rows():
    """Noise-free: the exact fit leaves a residual the moments cannot resolve (cancellation)."""
    record, truth = sim(runs=2, seed=11, noise__sigma2=0.0)
    dy = pp.delta(record.y)
    reg = pp.quiet_regression(dy, 5, 2, (5,), 3, moments=pp.LagMoments(dy, 5, 5))
    res = reg.residual_ms(np.broadcast_to(truth.plant.a[1:], (2, 2)))
    assert np.all(res < 1e-24), res


def test_iv_moments_equal_the_explicit_instruments(noisy):
    record, _ = noisy
    dy = pp.delta(record.y)
    reg = pp.quiet_regression(dy, 5, 2, (3, 4, 5), 3, moments=pp.LagMoments(dy, 5, 5))
    Z, ok = pp.instruments(record.r, reg.k, 6, 1)
    y, phi = _rows(dy, reg)
    Z, y, phi = Z[:, ok], y[:, ok], phi[:, ok]
    G = (
        np.concatenate(
            [np.einsum("rnm,rn->rm", Z, y)[..., None], np.einsum("rnm,rni->rmi", Z, phi)], axis=2
        )
        / ok.sum()
    )
    np.testing.assert_allclose(pp.iv_moments(reg, record.r, 6, 1), G, rtol=1e-12, atol=1e-15)


@pytest.mark.parametrize(
    ("na", "phases", "shift", "m", "lag0"),
    [(2, (5,), 0, 6, 1), (1, (3, 4, 5), 3, 4, 2), (4, (2, 3, 4, 5), 1, 9, 1), (0, (5,), 4, 3, 3)],
)
def test_iv_moments_are_exact_on_integer_data(na, phases, shift, m, lag0):
    """Integer data: every product and partial sum is exact, so any order of summation gives
    the same bits, and the moments must equal the explicit rows' exactly (no tolerance)."""
    rng = np.random.default_rng(na + m)
    y = np.cumsum(rng.integers(-50, 50, (3, 1001)), axis=1).astype(float)
    r = rng.integers(-9, 9, (3, 200)).astype(float)
    dy = pp.delta(y)
    reg = pp.quiet_regression(dy, 5, na, phases, shift, moments=pp.LagMoments(dy, 5, 5))
    Z, ok = pp.instruments(r, reg.k, m, lag0)
    yy, phi = _rows(dy, reg)
    Z, yy, phi = Z[:, ok], yy[:, ok], phi[:, ok]
    G = np.concatenate(
        [(Z * yy[..., None]).sum(axis=1)[..., None], np.einsum("rnm,rni->rmi", Z, phi)], axis=2
    )
    np.testing.assert_array_equal(pp.iv_moments(reg, r, m, lag0), G / ok.sum())
    one = pp.quiet_regression(dy[1:2], 5, na, phases, shift, moments=pp.LagMoments(dy[1:2], 5, 5))
    np.testing.assert_array_equal(pp.iv_moments(one, r[1:2], m, lag0), G[1:2] / ok.sum())


def _spd_tridiagonal(seed: int, R: int, M: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(off, diag, rhs)`` of R diagonally dominant (so positive definite) systems of size M."""
    rng = np.random.default_rng(seed)
    off = 0.3 * rng.standard_normal((R, M - 1))
    return off, 2.0 + rng.random((R, M)), rng.standard_normal((R, M))


def test_tridiagonal_lapack_equals_thomas():
    off, diag, rhs = _spd_tridiagonal(0, 7, 50)
    x = pp.solve_tridiagonal(off, diag, off, rhs)  # symmetric: LAPACK dptsv
    np.testing.assert_allclose(x, pp._thomas(off, diag, off, rhs), rtol=1e-12, atol=1e-12)
    # not positive definite: LAPACK refuses, the Thomas loop still solves it
    bad = diag.copy()
    bad[3, 10] = -5.0
    x = pp.solve_tridiagonal(off, bad, off, rhs)
    A = np.diag(bad[3]) + np.diag(off[3], 1) + np.diag(off[3], -1)
    np.testing.assert_allclose(A @ x[3], rhs[3], atol=1e-9)


def test_batched_polynomial_tools_match_scipy():
    rng = np.random.default_rng(4)
    b = np.concatenate([np.ones((5, 1)), rng.uniform(-1.5, 1.5, (5, 2))], axis=1)
    a = np.concatenate([np.ones((5, 1)), rng.uniform(-0.5, 0.5, (5, 2))], axis=1)
    roots = np.array([np.max(np.abs(np.roots(row))) for row in b])
    np.testing.assert_allclose(pp.max_root_modulus(b), roots, rtol=1e-12)
    x = rng.standard_normal((5, 40))
    ref = np.stack([signal.lfilter(b[i], a[i], x[i]) for i in range(5)])
    np.testing.assert_array_equal(pp.batched_lfilter(b, a, x), ref)


def test_methods_share_one_structure_selection(monkeypatch):
    """wang-iv after wang-lsm on one record reuses the selection (one table computed, not two)
    and gives the same estimate as alone; bai-fu (OLS selection) and a selection by a closure
    compute their own."""
    from hbench.ident import blind

    calls = []
    original = blind.select_structure

    def counting(*args, **kwargs):
        calls.append(1)
        return original(*args, **kwargs)

    monkeypatch.setattr(blind, "select_structure", counting)
    options = IdentifyOptions()
    iv = registry().get("identifiers", "wang-iv")()
    alone = identify(iv, sim(runs=6, seed=21, noise__sigma2=1e-3)[0], options)
    assert len(calls) == 1
    record, _ = sim(runs=6, seed=21, noise__sigma2=1e-3)
    identify(registry().get("identifiers", "wang-lsm")(), record, options)
    shared = identify(iv, record, options)
    assert len(calls) == 2  # wang-iv took wang-lsm's selection
    identify(registry().get("identifiers", "bai-fu")(), record, options)
    assert len(calls) == 3
    # the IV's own table (a closure reading r) is never taken from the cache
    identify(registry().get("identifiers", "wang-iv")(structure="iv"), record, options)
    assert len(calls) == 4
    for field in ("a", "b", "U", "na", "nb", "tau"):
        np.testing.assert_array_equal(getattr(shared, field), getattr(alone, field), field)


def test_record_cache_is_not_shared_with_other_data(noisy):
    record, _ = noisy
    identify(registry().get("identifiers", "wang-lsm")(), record, IdentifyOptions())
    assert record.cache
    assert record.withhold(frozenset()).cache is record.cache  # same y
    assert not record.select([0, 1]).cache  # other y: nothing carried over


def test_run_cell_rows_do_not_depend_on_worker_processes():
    """jobs=2 (forked workers, chunks of 3) gives exactly the rows of one process."""
    from hbench.bench.runner import methods_from_names, run_cell
    from hbench.sim import scenarios
    from tests.helpers import paper_spec

    sc = scenarios.build(paper_spec(duration=60.0))
    methods = methods_from_names(["wang-lsm", "bai-fu"])
    key = ["method", "run", "quantity"]

    def rows(**kw):
        r = run_cell(sc, methods, 6, 5, **kw).rows
        return r[r["quantity"] != "seconds"].sort_values(key).reset_index(drop=True)

    one = rows()
    two = rows(jobs=2, chunk=3)
    assert len(one) == len(two) > 0
    import pandas as pd

    pd.testing.assert_frame_equal(one, two, check_exact=True)


def test_a_runs_numbers_do_not_depend_on_chunks_or_workers():
    """30 noisy short runs (many structure groups, some of one run): chunks of 1, 7 and 30, and
    two workers, give bit-identical rows (the reproducibility rule)."""
    import pandas as pd

    from hbench.bench.runner import methods_from_names, run_cell
    from hbench.sim import scenarios
    from tests.helpers import paper_spec

    sc = scenarios.build(paper_spec(duration=60.0))
    reg = registry()
    names = reg.names("identifiers")  # every method hbench ships, not a third party's
    builtin = [n for n in names if reg.get("identifiers", n).__module__.startswith("hbench")]
    assert len(builtin) >= 10
    methods = methods_from_names(builtin)
    key = ["method", "run", "quantity"]

    def rows(**kw):
        r = run_cell(sc, methods, 30, 5, **kw).rows
        return r[r["quantity"] != "seconds"].sort_values(key).reset_index(drop=True)

    ref = rows(chunk=30)
    assert (ref["status"] == "ok").mean() > 0.9
    for kw in ({"chunk": 1}, {"chunk": 7}, {"chunk": 10, "jobs": 2}):
        pd.testing.assert_frame_equal(rows(**kw), ref, check_exact=True, obj=str(kw))


@pytest.mark.parametrize(
    ("runs", "chunk", "jobs", "sizes"),
    [
        (1000, 200, 1, [200] * 5),
        (1000, 200, 2, [167] * 4 + [166] * 2),  # 6 chunks, not 5: 3 rounds on 2 workers
        (250, 200, 1, [125, 125]),
        (5, 200, 2, [3, 2]),
        (3, 1, 2, [1, 1, 1]),  # never more chunks than runs
        (0, 200, 2, []),
    ],
)
def test_chunks_cover_the_runs_once_and_balance_the_workers(runs, chunk, jobs, sizes):
    from hbench.bench.runner import _pieces

    pieces = _pieces(runs, chunk, jobs)
    assert [n for _, n in pieces] == sizes
    assert [s for s, _ in pieces] == list(np.cumsum([0, *sizes])[:-1])


def test_a_non_finite_run_stays_in_its_run():
    """One run's nan must not reach the others through the one LAPACK call for all runs."""
    off, diag, rhs = _spd_tridiagonal(1, 4, 30)
    clean = pp.solve_tridiagonal(off, diag, off, rhs)
    rhs[1, 5] = np.nan
    x = pp.solve_tridiagonal(off, diag, off, rhs)
    assert np.isnan(x[1]).any()
    np.testing.assert_array_equal(x[[0, 2, 3]], clean[[0, 2, 3]])


def test_short_records_and_list_options_give_estimates_not_exceptions():
    """A record too short for the regressions: every blind method says so in ``reason``."""
    from hbench.sim.records import Record

    record, _ = sim(runs=2, seed=1, noise__sigma2=1e-3)
    short = Record(y=record.y[:, :10], x=record.x[:, :2], r=record.r[:, :2], p=5, h=record.h)
    options = IdentifyOptions(na_range=[1, 4], tau_range=[0, 4])  # lists, as from a config
    assert options.na_range == (1, 4) and options.tau_range == (0, 4)
    for name in ("wang-lsm", "wang-iv", "bai-fu", "sun-liu-sano", "wang-iv-opt", "wang-lsm-cn"):
        est = identify(registry().get("identifiers", name)(), short, options)
        assert not est.identifiable.any(), name
        assert "record too short" in est.reason[0], (name, est.reason[0])


class _TwoArgError(Exception):
    def __init__(self, a, b):  # pickles as Exception((a, b)): cannot be rebuilt
        super().__init__(f"{a} {b}")


def test_a_worker_failure_reaches_the_parent(monkeypatch):
    """An exception that cannot be unpickled must not hang the pool: it comes back as text."""
    import os

    from hbench.bench import runner
    from hbench.sim import scenarios
    from tests.helpers import paper_spec

    parent, run_chunk = os.getpid(), runner._run_chunk

    def broken(work, start, n):  # fails in the worker only (the parent computes chunks too)
        if os.getpid() == parent:
            return run_chunk(work, start, n)
        raise _TwoArgError("plugin", "broke")

    monkeypatch.setattr(runner, "_run_chunk", broken)
    sc = scenarios.build(paper_spec(duration=60.0))
    with pytest.raises(RuntimeError, match="plugin broke"):
        runner.run_cell(sc, runner.methods_from_names(["wang-lsm"]), 4, 0, jobs=2, chunk=2)


# --- shared passes that must give the same bits as the plain lines they replace ---


def test_tidy_blocks_assemble_into_the_frame_pandas_builds_from_object_arrays():
    from hbench.bench import tidy

    rng = np.random.default_rng(3)
    ids = {
        "cell": "c1",
        "nonlinearity": "backlash",
        "plant": None,
        "p": 5,
        "delay": 0,
        "sigma2": 1e-3,
        "snr_target": np.nan,
        "seed": "2026",
    }
    blocks, plain = [], []
    for method, start, R, status, error in (
        ("wang-lsm", 0, 4, ["ok", "not-identifiable", "ok", "ok"], ["", "why", "", ""]),
        ("bai-fu", 0, 4, ["failed"] * 4, ["boom (x.py:1)"] * 4),
        ("wang-lsm", 4, 3, ["ok"] * 3, ["", "", None]),
    ):
        values = {q: (rng.standard_normal(R), float(i)) for i, q in enumerate(("a1", "b2", "na"))}
        snr = rng.random(R)
        blocks.append(tidy.block(method, ids, start, values, snr, np.array(status), error))
        Q, n = len(values), R * len(values)
        cols = {c: np.full(n, v, dtype=tidy.ID_DTYPES.get(c, object)) for c, v in ids.items()}
        cols.update(
            method=method,
            run=np.repeat(np.arange(start, start + R), Q),
            quantity=np.tile(np.array(list(values), dtype=object), R),
            value=np.stack([v for v, _ in values.values()], axis=1).ravel(),
            true=np.tile(np.array([t for _, t in values.values()]), R),
            snr=np.repeat(snr, Q),
            status=np.repeat(np.array(status, dtype=object), Q),
            error=np.repeat(np.array(error, dtype=object), Q),
        )
        plain.append(pd.DataFrame(cols, columns=list(tidy.TIDY_COLUMNS)))
    expected = pd.concat(plain, ignore_index=True)
    pd.testing.assert_frame_equal(tidy.assemble(blocks), expected, check_exact=True)
    assert list(tidy.assemble([]).columns) == list(tidy.TIDY_COLUMNS)


def test_fitnesses_equal_fitness_one_scaling_at_a_time():
    from hbench.bench.metrics import SCALINGS, fitness, fitnesses

    rng = np.random.default_rng(8)
    U = rng.standard_normal((6, 40))
    est = 1.3 * U + 0.1 * rng.standard_normal((6, 40))
    est[1, :5] = np.nan
    est[2] = np.nan
    F = fitnesses(est, U, SCALINGS, 1.3)
    for s in SCALINGS:
        np.testing.assert_array_equal(
            F[s], fitness(est, U, s, 1.3 if s in ("gain", "gain-centred") else None)
        )
    assert np.isnan(F["gain"][2]) and F["gain"][0] > 90


@pytest.mark.parametrize(("shift", "width", "t_min"), [(0, 5, 1), (3, 2, 4), (4, 1, 9)])
def test_period_block_view_equals_the_gather(shift, width, t_min):
    dw = np.random.default_rng(1).standard_normal((3, 203))
    k = pp.common_periods(dw, 5, shift, t_min, width)
    t = k[:, None] * 5 + np.arange(1, width + 1)[None, :] + shift
    gathered = pp.take_periods(dw, t)
    view = pp.period_block(dw, 5, k, shift, width)
    np.testing.assert_array_equal(view, gathered)
    # reductions over either sum in the same order (the view's squares are C-ordered too)
    np.testing.assert_array_equal(np.mean(np.square(view), axis=1), np.mean(gathered**2, axis=1))
    # a non-consecutive k falls back to the gather
    np.testing.assert_array_equal(pp.period_block(dw, 5, k[::2], shift, width), gathered[:, ::2])


def test_mean_square_equals_nanmean():
    from hbench.ident.selection import _mean_square

    d = np.random.default_rng(2).standard_normal((4, 2501))
    d[:, 0] = np.nan
    d[2, 40] = np.nan
    cache: dict = {}
    np.testing.assert_array_equal(_mean_square(d, cache), np.nanmean(d**2, axis=1))
    assert _mean_square(d, cache) is cache["mean-square-delta-y"]


def test_validity_patterns_equal_numpys_unique_rows_in_order_and_layout():
    rng = np.random.default_rng(5)
    for M, p in ((1, 3), (40, 5), (9, 7)):
        valid = rng.random((M, p)) < 0.7
        valid[: M // 2] = True
        V, which = pp._validity_patterns(valid)
        pat, wh = np.unique(valid, axis=0, return_inverse=True)
        ref = pat.astype(float).T
        np.testing.assert_array_equal(V, ref)
        np.testing.assert_array_equal(which, wh.ravel())
        assert V.strides == ref.strides  # einsum sums in an order that follows the layout


def test_period_block_of_a_column_major_record_sums_as_one_run_does():
    """A column-major ``dw`` is gathered (a view of it would lay out, and sum, otherwise)."""
    rng = np.random.default_rng(9)
    dw = np.asfortranarray(rng.standard_normal((3, 2001)) * np.exp(rng.uniform(-12, 12, (3, 2001))))
    many = pp.b_lsm(dw, 5, 1, 3, np.zeros(3), 3)
    for i in range(3):
        np.testing.assert_array_equal(
            many[i : i + 1], pp.b_lsm(dw[i : i + 1], 5, 1, 3, np.zeros(1), 3)
        )
    np.testing.assert_array_equal(
        pp.phase_variances(dw, 5, 2, 4), pp.phase_variances(np.ascontiguousarray(dw), 5, 2, 4)
    )


@pytest.mark.parametrize("p", [62, 63, 64, 70])
def test_validity_patterns_of_many_phases(p):
    rng = np.random.default_rng(p)
    valid = rng.random((30, p)) < 0.5
    V, which = pp._validity_patterns(valid)
    np.testing.assert_array_equal(V[:, which].T.astype(bool), valid)
    pat = np.unique(valid, axis=0)
    np.testing.assert_array_equal(V, pat.astype(float).T)


def test_tidy_text_keeps_the_objects_it_was_given():
    from hbench.bench import tidy

    t = tidy.Text.of([None, "", 1, 1.0, True, None, "x"])
    assert [t.labels[c] for c in t.codes] == [None, "", 1, 1.0, True, None, "x"]
    assert [type(t.labels[c]) for c in t.codes[2:5]] == [int, float, bool]
    # a numpy scalar identifier is stored as np.full(..., dtype=object) stores it
    assert type(tidy.Text.constant(np.int64(4), 3).labels[0]) is int
    col = tidy._join_text([tidy.Text.of(["a", None]), tidy.Text.of([None, 0, False])])
    # mixed labels: pandas keeps objects; 0 and False are not merged, None is not made nan
    assert [(type(v), v) for v in col] == [
        (str, "a"),
        (type(None), None),
        (type(None), None),
        (int, 0),
        (bool, False),
    ]


def test_ols_and_lsm_share_one_least_squares_solution(noisy):
    """Both start from ``Rm^+ f`` and its residual, computed once per regression: the numbers are
    those of a regression that computed it afresh, and callers get arrays they may write to."""
    record, _ = noisy
    dy = pp.delta(record.y)

    def reg():
        return pp.quiet_regression(dy, 5, 2, (5,), 1, moments=pp.LagMoments(dy, 5, 2), fast=True)

    shared = reg()
    theta, ms, g11 = pp.ols(shared)
    lsm = pp.bias_compensated(shared)  # reuses what ols computed
    for got, fresh in zip(lsm, pp.bias_compensated(reg()), strict=True):
        np.testing.assert_array_equal(got, fresh)
    f = shared.moments()[1]
    np.testing.assert_array_equal(theta, np.einsum("rik,rk->ri", shared.inverse(), f))
    np.testing.assert_array_equal(ms, shared.residual_ms(theta))
    theta[:] = 0.0  # the caller's copy
    np.testing.assert_array_equal(pp.ols(shared)[0], pp.ols(reg())[0])
    assert g11.flags.writeable and ms.flags.writeable


def test_a_group_of_every_run_reads_the_record_without_copying_it(monkeypatch):
    """``runs_of`` gives a read-only view when the group is the whole batch (same values, same
    layout), a copy otherwise; the estimates are those computed from copies."""
    from hbench.ident import blind, selection

    a = np.arange(12.0).reshape(4, 3)
    every = selection.runs_of(a, np.arange(4))
    assert np.shares_memory(every, a) and not every.flags.writeable
    with pytest.raises(ValueError, match="read-only"):
        every[0, 0] = 1.0
    some = selection.runs_of(a, np.array([1, 3]))
    assert not np.shares_memory(some, a) and not some.flags.writeable
    np.testing.assert_array_equal(some, a[[1, 3]])
    fortran = np.asfortranarray(a)
    assert not np.shares_memory(selection.runs_of(fortran, np.arange(4)), fortran)  # copied
    record, _ = sim(runs=6, seed=31, noise__sigma2=1e-3)
    names = ("wang-lsm", "wang-iv", "bai-fu")
    got = [identify(registry().get("identifiers", n)(), record, IdentifyOptions()) for n in names]
    for module in (blind, selection):  # always a copy
        monkeypatch.setattr(module, "runs_of", lambda a, idx: a[idx])
    record.cache.clear()
    for name, est in zip(names, got, strict=True):
        want = identify(registry().get("identifiers", name)(), record, IdentifyOptions())
        for field in ("U", "a", "b", "sigma2", "na", "nb", "tau"):
            np.testing.assert_array_equal(getattr(est, field), getattr(want, field))


def test_regressions_inverted_together_equal_one_by_one(noisy):
    """The shifts of a selection table invert their ``Rm`` in one batched call: the numbers of
    one call per regression (LAPACK inverts matrix by matrix)."""
    record, _ = noisy
    dy = pp.delta(record.y)
    lm = pp.LagMoments(dy, 5, 3)

    def regs(na):
        return [pp.quiet_regression(dy, 5, na, (5,), s, moments=lm, fast=True) for s in range(5)]

    together, alone = regs(3), regs(3)
    pp.QuietRegression.invert_together(together)
    first = together[2].inverse()  # the first asked inverts all five
    assert all("Rinv" in reg._cache for reg in together)
    for a, b in zip(together, alone, strict=True):
        np.testing.assert_array_equal(a.inverse(), b.inverse())
        assert not a.inverse().flags.writeable
    assert first is together[2].inverse()
    mixed = [*regs(2)[:2], *regs(3)[:2]]  # different orders are left to invert alone
    pp.QuietRegression.invert_together(mixed)
    mixed[0].inverse()
    assert "Rinv" not in mixed[1]._cache


@pytest.mark.parametrize(("shift", "nb", "m"), [(0, 2, 6), (3, 3, 4), (4, 5, 1)])
def test_iv_numerator_from_lagged_rows_equals_the_gathered_instruments(noisy, shift, nb, m):
    """Eq. (21) with the instruments built lag by lag: the operands of the gathered, masked and
    transposed instruments, hence the same BLAS product, bit for bit."""
    record, _ = noisy
    dw = pp.delta(pp.filtered_output(record.y, np.array([[1.0, -1.6, 0.64]] * record.runs)))
    t_min = pp.first_valid(dw)
    k = pp.common_periods(dw, record.p, shift, t_min, nb)
    Z, ok = pp.instruments(record.r, k, m)
    kk = k[ok]
    C = np.matmul(
        np.ascontiguousarray(Z[:, ok].transpose(0, 2, 1)),
        np.ascontiguousarray(pp.period_block(dw, record.p, kk, shift, nb)),
    ) / len(kk)
    g = C[:, :, 0]
    want = np.ones((record.runs, nb))
    for l in range(2, nb + 1):
        want[:, l - 1] = np.einsum("rm,rm->r", g, C[:, :, l - 1]) / np.einsum("rm,rm->r", g, g)
    np.testing.assert_array_equal(pp.b_iv(dw, record.r, record.p, shift, nb, m, t_min), want)


@pytest.mark.parametrize(
    ("N", "p", "shift", "t_min"), [(4165, 5, 2, 3), (40, 5, 4, 12), (9, 3, 0, 1), (6, 5, 4, 9)]
)
def test_simo_periods_are_those_of_the_simo_system(N, p, shift, t_min):
    sys = pp.simo_system(np.ones((2, N)), p, shift, t_min)
    assert pp.simo_periods(N, p, shift, t_min) == (sys.n0, sys.W.shape[1])


@pytest.mark.parametrize("p", [1, 2, 3, 5, 8, 13])
def test_cyclic_blocks_from_tables_are_the_computed_ones(p: int) -> None:
    """The selection reads each shift's cyclic block and its last shift from tables built by
    ``_blocks`` and ``_last_of_block`` (p <= 12; p = 13 computes them): the same values."""
    from hbench.ident.selection import _blocks, _last_of_block, _own_blocks

    rng = np.random.default_rng(p)
    q = rng.random((40, 3, p, p)) < rng.random((40, 3, p, 1))
    own = np.einsum("rass->ras", q)
    diag = np.arange(p)[None, None, :, None]
    want = np.where(own, np.take_along_axis(_blocks(q), diag, axis=3)[..., 0], 0)
    block, last = _own_blocks(q, own)
    np.testing.assert_array_equal(block, want)
    np.testing.assert_array_equal(last, _last_of_block(want, p))
    assert block.dtype == want.dtype and last.dtype == _last_of_block(want, p).dtype


def test_first_valid_scans_from_the_start_as_a_whole_scan_would() -> None:
    from hbench.ident import polyphase as pp

    rng = np.random.default_rng(3)
    for _ in range(500):
        R, N = int(rng.integers(1, 5)), int(rng.integers(0, 200))
        z = rng.standard_normal((R, N))
        for r in range(R):
            z[r, : int(rng.integers(0, N + 1)) if N else 0] = np.nan
        if N and rng.random() < 0.3:
            z[rng.integers(0, R), rng.integers(0, N, 4)] = np.nan
        bad = np.isnan(z).any(axis=0)
        whole = int(np.argmin(bad)) if not bad.all() else N
        assert pp.first_valid(z) == whole == pp.first_valid(z, block=int(rng.integers(1, 9)))


@pytest.mark.parametrize("phases", [(5,), (3, 4, 5)])
def test_iv_products_a_few_runs_at_a_time_are_the_whole_batchs(monkeypatch, phases):
    """The IV's instruments are laid out and multiplied IV_BLOCK runs at a time (so they stay in
    cache): every run's moments and numerator are those of one product over the whole batch, and
    of the run alone, bit for bit (37 runs cross two block boundaries)."""
    record, _ = sim(runs=37, seed=5, noise__sigma2=1e-3)
    dy = pp.delta(record.y)
    lm = pp.LagMoments(dy, 5, 5)
    dw = pp.delta(pp.filtered_output(record.y, np.array([[1.0, -1.6, 0.64]] * 37)))
    t_min = pp.first_valid(dw)

    def both() -> tuple[np.ndarray, np.ndarray]:
        reg = pp.quiet_regression(dy, 5, 2, phases, 3, moments=lm)
        return pp.iv_moments(reg, record.r, 6), pp.b_iv(dw, record.r, 5, 2, 3, 6, t_min)

    blocked = both()
    monkeypatch.setattr(pp, "IV_BLOCK", 10**6)
    whole = both()
    for a, b in zip(blocked, whole, strict=True):
        np.testing.assert_array_equal(a, b)
    one = pp.quiet_regression(dy[20:21], 5, 2, phases, 3, moments=lm.take(np.array([20])))
    np.testing.assert_array_equal(pp.iv_moments(one, record.r[20:21], 6), blocked[0][20:21])


def _gram_stack(rng: np.random.Generator, count: int, n: int, rows: int = 40) -> np.ndarray:
    Z = rng.standard_normal((count, rows, n)) * np.exp(rng.uniform(-2, 2, (count, 1, n)))
    return np.einsum("bti,btj->bij", Z, Z) / rows


@pytest.mark.parametrize("n", [1, 2, 3, 4, 5, 7])
def test_cholesky_inverse_is_the_pseudo_inverse_of_well_conditioned_matrices(n: int) -> None:
    """Tolerance: both are backward stable, so they agree to ~cond * eps (cond here < 1e6,
    checked; 1e-9 relative to the inverse's largest entry)."""
    from hbench.numerics.ordered import cholesky_inverse

    A = _gram_stack(np.random.default_rng(n), 300, n)
    X, ok = cholesky_inverse(A)
    assert ok.all() and X.flags.c_contiguous
    assert np.linalg.cond(A).max() < 1e6
    P = np.linalg.pinv(A, rcond=1e-12, hermitian=True)
    scale = np.abs(P).max(axis=(1, 2), keepdims=True)
    np.testing.assert_array_less(np.abs(X - P) / scale, 1e-9)
    np.testing.assert_array_equal(X, np.swapaxes(X, 1, 2))  # symmetric, exactly
    # a matrix's inverse does not depend on the others of the stack (elementwise arithmetic)
    for i in (0, 7, 299):
        np.testing.assert_array_equal(cholesky_inverse(A[i : i + 1])[0][0], X[i])
        np.testing.assert_array_equal(cholesky_inverse(A[i])[0], X[i])  # one matrix, no stack


def test_empty_matrices_invert_as_numpys_pinv() -> None:
    """Order 0 (review): the empty inverses, as ``np.linalg.pinv`` gives them."""
    from hbench.numerics.ordered import cholesky_inverse

    A = np.empty((3, 0, 0))
    X, ok = cholesky_inverse(A)
    assert X.shape == (3, 0, 0) and ok.all()
    assert pp._pinv_sym(A).shape == np.linalg.pinv(A, hermitian=True).shape


def test_singular_and_bad_matrices_go_to_the_pseudo_inverse() -> None:
    """Singular (an order above the true one on noise-free data), ill-conditioned beyond the
    bound, indefinite and non-finite matrices are not accepted; ``_pinv_sym`` gives numpy's
    pseudo-inverse for them, bit for bit, and the inverse for the others."""
    from hbench.numerics.ordered import cholesky_inverse

    rng = np.random.default_rng(3)
    A = _gram_stack(rng, 6, 3)
    Z = rng.standard_normal((40, 2))
    singular = np.column_stack([Z, Z[:, 0] - 2.0 * Z[:, 1]])
    A[1] = singular.T @ singular / 40
    A[2] = np.diag([1.0, 1.0, 1e-10])  # condition 1e10: over the bound, under 1 / rcond
    A[3] = np.diag([1.0, -1.0, 1.0])
    A[4, 0, 0] = np.nan
    ok = cholesky_inverse(A)[1]
    np.testing.assert_array_equal(ok, [True, False, False, False, False, True])
    with pytest.raises(np.linalg.LinAlgError):  # as numpy's pinv alone does with a nan
        pp._pinv_sym(A)
    A, ok = np.delete(A, 4, axis=0), np.delete(ok, 4)
    X = pp._pinv_sym(A)
    bad = ~ok
    np.testing.assert_array_equal(X[bad], np.linalg.pinv(A[bad], rcond=1e-12, hermitian=True))
    np.testing.assert_array_equal(X[ok], cholesky_inverse(A[ok])[0])
    assert np.abs(X[1] @ A[1] @ X[1] - X[1]).max() < 1e-8 * np.abs(X[1]).max()  # a pinv's identity

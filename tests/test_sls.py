"""``sun-liu-sano``'s cross-relation Gram from the channels' moments: the same matrix, and the
same estimates, as the equations' rows written out."""

from __future__ import annotations

import numpy as np
import pytest
from hbench_sls import cross_relation_gram, cross_relation_numerator

from hbench.ident import polyphase as pp
from tests.helpers import TRUE_STRUCTURE, run_method, sim


def rows_gram(W: np.ndarray) -> np.ndarray:
    """``X^T X`` with ``X`` the cross-relation rows of every channel pair, formed explicitly."""
    R, n, p = W.shape
    cur, prev = W[:, 1:], W[:, :-1]
    rows = []
    for i in range(p):
        for j in range(i + 1, p):
            X = np.zeros((R, n - 1, 2 * p))
            X[:, :, 2 * j], X[:, :, 2 * j + 1] = cur[:, :, i], prev[:, :, i]
            X[:, :, 2 * i], X[:, :, 2 * i + 1] = -cur[:, :, j], -prev[:, :, j]
            rows.append(X)
    X = np.concatenate(rows, axis=1)
    return np.matmul(X.transpose(0, 2, 1), X)


@pytest.mark.parametrize("p", [2, 3, 5, 8])
def test_gram_from_moments_is_therows_gram(p):
    W = np.random.default_rng(p).standard_normal((4, 200, p))
    G, ref = cross_relation_gram(W), rows_gram(W)
    np.testing.assert_allclose(G, ref, rtol=0, atol=1e-12 * np.abs(ref).max())
    np.testing.assert_array_equal(G, G.transpose(0, 2, 1))  # symmetric as built


def test_numerator_unchanged(monkeypatch):
    """On the paper's example under noise: b from the moments' Gram equals b from the rows'."""
    record, _ = sim(runs=20, seed=3, noise__sigma2=1e-3)
    est = run_method("sun-liu-sano", record, options=TRUE_STRUCTURE)
    import hbench_sls

    monkeypatch.setattr(hbench_sls, "cross_relation_gram", rows_gram)
    ref = run_method("sun-liu-sano", record, options=TRUE_STRUCTURE)
    np.testing.assert_allclose(est.b, ref.b, rtol=0, atol=1e-9)
    np.testing.assert_allclose(est.U, ref.U, rtol=1e-8, atol=1e-12)
    # noise-free: exact either way
    record, truth = sim(runs=2, seed=3, noise__sigma2=0.0)
    w = pp.filtered_output(record.y, truth.plant.a[None].repeat(2, 0))
    b = cross_relation_numerator(w, record.p, 3, 2, pp.first_valid(w))
    np.testing.assert_allclose(b[:, 1], truth.plant.true_params()["b2"], atol=1e-8)

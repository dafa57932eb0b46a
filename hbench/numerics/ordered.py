"""Products summed in a fixed order: the reference arithmetic of the closed loop, and the
small symmetric inverses of the quiet-phase regressions (:func:`cholesky_inverse`).

``np.einsum`` and BLAS sum a product's terms in an order of their own (SIMD lanes, fused
multiply-adds on some machines) that can change with the build, the CPU and the batch size. The
closed loop (:func:`hbench.sim.simulate._run_loop`,
:meth:`hbench.model.controllers.Controller.step`) sums with :func:`ordered_products` instead, term
after term from the first, one multiply and one add at a time; the compiled kernel of
:mod:`hbench.numerics.kernels` does exactly the same, so the two give the same numbers on any
machine, and a run's numbers never depend on the runs batched with it."""

from __future__ import annotations

import numpy as np


def ordered_products(s: np.ndarray, M: np.ndarray) -> np.ndarray:
    """``out[..., m] = sum_l s[..., l] M[m, l]``, summed over ``l = 0, 1, ..`` in that order.

    Parameters
    ----------
    s : ndarray, shape (..., L)
        States (a batch of runs first).
    M : ndarray, shape (m, L)
        One row per output.

    Returns
    -------
    ndarray, shape (..., m)
        Zeros when ``L = 0``.
    """
    L = M.shape[1]
    if L == 0:
        return np.zeros((*s.shape[:-1], M.shape[0]))
    out = s[..., 0:1] * M[:, 0]
    for l in range(1, L):
        out = out + s[..., l : l + 1] * M[:, l]
    return out


def cholesky_inverse(A: np.ndarray, max_cond: float = 1e9) -> tuple[np.ndarray, np.ndarray]:
    """Inverses of symmetric positive definite matrices through their Cholesky factors.

    ``A = L L^T`` (the lower triangle of ``A`` is read), ``M = L^-1``, ``A^-1 = M^T M``: each
    matrix's entries computed one multiply and one add or subtract at a time, sums from their
    first term, vectorised over the stack (so a matrix's inverse never depends on the others of
    the stack, and elementwise IEEE arithmetic gives the same numbers on any machine). For the
    small matrices of the quiet-phase regressions (orders 1-5) it is ~10x faster than LAPACK's
    ``eigh`` behind ``np.linalg.pinv``, which spends most of its time per matrix.

    Parameters
    ----------
    A : ndarray, shape (..., n, n)
        Symmetric matrices.
    max_cond : float
        A matrix is accepted (``ok``) where its factor exists and ``tr(A) tr(A^-1) < max_cond``;
        that product bounds the condition number ``lambda_max / lambda_min`` from above, so
        where it holds an eigenvalue cut below ``rcond lambda_max`` with ``rcond < 1 /
        max_cond`` (a pseudo-inverse's) removes nothing and the inverse is the pseudo-inverse.

    Returns
    -------
    X : ndarray, shape (..., n, n)
        C-ordered; undefined where ``ok`` is False.
    ok : ndarray of bool, shape (...)
        Not positive definite (a pivot not > 0), not finite, or ill-conditioned: False.
    """
    A = np.asarray(A, dtype=float)
    n = A.shape[-1]
    if n == 0:  # nothing to invert (numpy's pinv gives the empty matrices too)
        return np.empty(A.shape), np.ones(A.shape[:-2], bool)
    a = np.moveaxis(A, (-2, -1), (0, 1))  # a[i, j]: that entry of every matrix
    L, M, X = np.empty_like(a), np.empty_like(a), np.empty_like(a)
    with np.errstate(all="ignore"):  # a failed factor gives nan or inf, flagged by ok
        good = np.ones(a.shape[2:], bool)
        for j in range(n):  # L, column after column
            d = a[j, j]
            for k in range(j):
                d = d - L[j, k] * L[j, k]
            good &= d > 0.0
            L[j, j] = np.sqrt(d)
            for i in range(j + 1, n):
                s = a[i, j]
                for k in range(j):
                    s = s - L[i, k] * L[j, k]
                L[i, j] = s / L[j, j]
        for j in range(n):  # M = L^-1, lower triangular
            M[j, j] = 1.0 / L[j, j]
            for i in range(j + 1, n):
                s = L[i, j] * M[j, j]
                for k in range(j + 1, i):
                    s = s + L[i, k] * M[k, j]
                M[i, j] = -s / L[i, i]
        for i in range(n):  # X = M^T M, symmetric
            for j in range(i + 1):
                s = M[i, i] * M[i, j]
                for k in range(i + 1, n):
                    s = s + M[k, i] * M[k, j]
                X[i, j] = s
                X[j, i] = s
        tr, tr_inv = a[0, 0], X[0, 0]
        for i in range(1, n):
            tr = tr + a[i, i]
            tr_inv = tr_inv + X[i, i]
        ok = good & (tr * tr_inv < max_cond)
    return np.ascontiguousarray(np.moveaxis(X, (0, 1), (-2, -1))), ok

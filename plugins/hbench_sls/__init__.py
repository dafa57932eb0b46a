"""Sun, Liu & Sano (1999), "Identification of a dynamical system with input nonlinearity",
IEE Proc. Control Theory Appl. 146(1) -- a RECONSTRUCTION, not the original algorithm.

The original is not available here. Taken from the source as Wang et al. (2007) describe it:
over-sampling of the output, the bias-compensated denominator with the Kagiwada et al. (1998)
variance estimate (here eqs. 14-15 of Wang et al., pooled over the quiet phases). Reconstructed
by this project (``shared/docs/methods-and-models.md``): the numerator by the cross-relation
method of blind SIMO identification (Xu, Liu, Tong & Kailath 1995) on the polyphase channels of
eq. (25), ``H_j(q) w_i = H_i(q) w_j``, taking the right singular vector of the smallest singular
value; the inner signal by a least-squares multichannel inverse (MINT) of the identified
channels, which for these order-one channels is the minimum-norm degree-0 Bezout combiner.
Reports label this method a reconstruction.
"""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np

from hbench import polyphase as pp
from hbench.hookspecs import Register, hookimpl
from hbench.identifiers import (
    Estimate,
    Identifier,
    IdentifyOptions,
    bias_compensated_fit,
    blind_fit,
)
from hbench.records import Record, Truth


def cross_relation_numerator(
    dw_or_w: np.ndarray, p: int, tau: int, nb: int, t_min: int
) -> np.ndarray:
    """b (b1 = 1) from the cross-relation equations of the SIMO channels built on ``w``.

    For channels ``i < j``:
    ``h_j(0) w_i(n) + h_j(1) w_i(n-1) - h_i(0) w_j(n) - h_i(1) w_j(n-1) = 0`` (noise-free),
    linear in ``theta = [h_1(0), h_1(1), .., h_p(0), h_p(1)]``. ``theta`` is the eigenvector of the
    smallest eigenvalue of the cross-relation Gram matrix; then ``b_l = h_l(0) - h_{l-1}(0)``
    averaged with ``h_{l-1}(1) - h_l(1)``, normalised to b1 = 1.
    """
    w = dw_or_w
    sys = pp.simo_system(w, p, tau, t_min)
    full = np.all(sys.valid, axis=1)
    W = sys.W[:, full]  # (R, n, p): w_i(n)
    cur, prev = W[:, 1:], W[:, :-1]
    R = W.shape[0]
    rows = []
    for i in range(p):
        for j in range(i + 1, p):
            X = np.zeros((R, cur.shape[1], 2 * p))
            X[:, :, 2 * j] = cur[:, :, i]
            X[:, :, 2 * j + 1] = prev[:, :, i]
            X[:, :, 2 * i] = -cur[:, :, j]
            X[:, :, 2 * i + 1] = -prev[:, :, j]
            rows.append(X)
    X = np.concatenate(rows, axis=1)
    G = np.matmul(X.transpose(0, 2, 1), X)
    _, vecs = np.linalg.eigh(G)
    theta = vecs[:, :, 0]
    h0, h1 = theta[:, 0::2], theta[:, 1::2]
    b_from_h0 = np.diff(np.concatenate([np.zeros((R, 1)), h0], axis=1), axis=1)[:, :nb]
    b_from_h1 = np.concatenate([h0[:, :1], -np.diff(h1, axis=1)], axis=1)[:, :nb]
    b = 0.5 * (b_from_h0 + b_from_h1)
    return b / b[:, :1]


def mint_inner(y, w, a, b, p, tau, t_min):
    """Least-squares multichannel inverse (degree-0 MINT = minimum-norm Bezout combiner)."""
    sys = pp.simo_system(w, p, tau, t_min)
    h0, h1 = pp.simo_channels(b, p)
    return pp.inner_signal_bezout(sys, h0, h1), sys.n0 - 1, "mint"


class SunLiuSano(Identifier):
    """Sun, Liu & Sano (1999) variant -- a reconstruction (see the module docstring)."""

    name: ClassVar[str] = "sun-liu-sano"
    summary: ClassVar[str] = (
        "Sun, Liu & Sano 1999 (reconstruction): compensated LS A, cross-relation B, MINT inverse"
    )
    reconstruction: ClassVar[bool] = True

    def options(self) -> dict[str, Any]:
        return {"pooled": True, "reconstruction": True}

    def identify(
        self, record: Record, options: IdentifyOptions, truth: Truth | None = None
    ) -> Estimate:
        p = record.p

        def numerator(dw, tau, nb, sigma2, idx):
            # the cross relation acts on w: rebuild it from dw up to a constant c, which cancels
            # exactly, c (h_j(0) + h_j(1) - h_i(0) - h_i(1)) = c (B(1) - B(1)) = 0
            t0 = pp.first_valid(dw)
            w = np.full_like(dw, np.nan)
            w[:, t0 - 1 :] = np.concatenate(
                [np.zeros((dw.shape[0], 1)), np.cumsum(dw[:, t0:], axis=1)], axis=1
            )
            return cross_relation_numerator(w, p, tau, nb, t0)

        return blind_fit(
            self.name,
            record,
            options,
            denominator=bias_compensated_fit,
            numerator=numerator,
            inner=mint_inner,
            pooled=True,
            info=self.options(),
        )


@hookimpl
def register_identifiers(register: Register) -> None:
    register(SunLiuSano.name, SunLiuSano)

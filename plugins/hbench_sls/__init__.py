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

from hbench.hookspecs import Register, hookimpl
from hbench.ident import polyphase as pp
from hbench.ident.identifiers import (
    Estimate,
    Identifier,
    IdentifyOptions,
    bias_compensated_fit,
    blind_fit,
)
from hbench.sim.records import Record, Truth


def cross_relation_gram(W: np.ndarray) -> np.ndarray:
    """The Gram matrix ``X^T X`` of the cross-relation equations of the SIMO channels ``W``
    ``(runs, n, p)`` (consecutive periods), in ``theta = [h_1(0), h_1(1), .., h_p(0), h_p(1)]``.

    For channels ``i < j`` and periods ``n = 1 .. n - 1`` the equation
    ``h_j(0) w_i(n) + h_j(1) w_i(n-1) - h_i(0) w_j(n) - h_i(1) w_j(n-1) = 0`` is a row ``x`` with
    ``z_i(n) = [w_i(n), w_i(n-1)]`` in the slots of channel j and ``-z_j(n)`` in those of i. So
    the ``2 x 2`` block ``(a, b)`` of ``X^T X`` is ``delta_ab T - S_ba`` with
    ``S_ab = sum_n z_a(n) z_b(n)^T`` (the channels' lag-0 and lag-1 moments) and
    ``T = sum_c S_cc``: one ``2p x 2p`` product per run instead of ``p (p - 1) / 2`` blocks of
    rows (the same matrix to rounding).
    """
    R, n, p = W.shape
    Z = np.empty((R, max(n - 1, 0), p, 2))
    Z[..., 0] = W[:, 1:]
    Z[..., 1] = W[:, :-1]
    Z = Z.reshape(R, -1, 2 * p)
    S = np.matmul(Z.transpose(0, 2, 1), Z).reshape(R, p, 2, p, 2)
    T = np.einsum("rcicj->rij", S)
    G = -S.transpose(0, 3, 2, 1, 4)
    for c in range(p):
        G[:, c, :, c, :] += T
    return G.reshape(R, 2 * p, 2 * p)


def cross_relation_numerator(
    dw_or_w: np.ndarray, p: int, tau: int, nb: int, t_min: int
) -> np.ndarray:
    """b (b1 = 1) from the cross-relation equations of the SIMO channels built on ``w``.

    For channels ``i < j``:
    ``h_j(0) w_i(n) + h_j(1) w_i(n-1) - h_i(0) w_j(n) - h_i(1) w_j(n-1) = 0`` (noise-free),
    linear in ``theta = [h_1(0), h_1(1), .., h_p(0), h_p(1)]``. ``theta`` is the eigenvector of the
    smallest eigenvalue of the cross-relation Gram matrix (:func:`cross_relation_gram`); then
    ``b_l = h_l(0) - h_{l-1}(0)`` averaged with ``h_{l-1}(1) - h_l(1)``, normalised to b1 = 1.
    """
    w = dw_or_w
    sys = pp.simo_system(w, p, tau, t_min)
    full = np.all(sys.valid, axis=1)
    G = cross_relation_gram(sys.W[:, full])
    R = G.shape[0]
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

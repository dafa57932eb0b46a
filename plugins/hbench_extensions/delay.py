"""``wang-delay``: assumption A3 relaxed, the delay's multiple of p from the x-U alignment."""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np

from hbench.errors import InputError
from hbench.ident.identifiers import Estimate, Identifier, IdentifyOptions
from hbench.sim.records import Record, Truth

from .coloured import ColoredNoiseLSM


def delay_multiple_from_alignment(
    x: np.ndarray, U_tilde: np.ndarray, max_multiple: int
) -> tuple[np.ndarray, np.ndarray]:
    """The delay's multiple of p from the alignment of x(n) with the estimated inner signal.

    ``U~(n) = U(n - m)`` when the delay is ``tau + m p``; the actuator passes the changes of x
    into U (exactly for static maps, outside the dead band for backlash and stiction), so
    ``m = argmax_j |corr(Delta x(n), Delta U~(n + j))|`` (absolute: the blind gain has either
    sign). Returns ``(m, corr)`` with ``corr`` of shape ``(runs, max_multiple + 1)``.
    """
    R, K = x.shape
    dx = np.diff(x, axis=1)
    dU = np.diff(U_tilde, axis=1)
    corr = np.full((R, max_multiple + 1), np.nan)
    for j in range(max_multiple + 1):
        a = dx[:, : K - 1 - j]
        b = dU[:, j:]
        m = np.isfinite(a) & np.isfinite(b)
        n = m.sum(axis=1)
        nn = np.maximum(n, 1)[:, None]
        a0 = np.where(m, a - np.where(m, a, 0.0).sum(axis=1, keepdims=True) / nn, 0.0)
        b0 = np.where(m, b - np.where(m, b, 0.0).sum(axis=1, keepdims=True) / nn, 0.0)
        den = np.sqrt(np.sum(a0**2, axis=1) * np.sum(b0**2, axis=1))
        c = np.sum(a0 * b0, axis=1) / np.where(den > 0, den, 1.0)
        corr[:, j] = np.where((n > 10) & (den > 0), c, np.nan)
    best = np.argmax(np.nan_to_num(np.abs(corr), nan=-1.0), axis=1)
    return best, corr


class DelayEstimating(Identifier):
    """Relaxes assumption A3: the delay's multiple of p estimated from x.

    Derivation. Output fast-sampling identifies the fractional delay tau in [0, p) (Section 3.4)
    but not its multiple m of p: y alone cannot tell ``tau`` from ``tau + m p``. The controller
    output x is measured, though, and ``U(n)`` is a (possibly memoryful) function of ``x(n)``;
    the blind estimate computed with m = 0 is ``U~(n) = U(n - m)`` up to scale, so m is the lag
    that best aligns ``Delta U~`` with ``Delta x`` (:func:`delay_multiple_from_alignment`). The
    estimate of the base method (``base``) is then re-aligned by the estimated m.

    Parameters
    ----------
    base : str
        The blind method run first (``wang-lsm-cn`` or ``wang-lsm``).
    max_multiple : int
        Largest multiple of p considered.
    """

    name: ClassVar[str] = "wang-delay"
    needs: ClassVar[frozenset[str]] = frozenset({"x"})
    summary: ClassVar[str] = "Delay beyond A3: multiple of p from the x-U alignment"

    def __init__(self, base: str = "wang-lsm-cn", max_multiple: int = 3) -> None:
        if base not in ("wang-lsm-cn", "wang-lsm"):
            raise InputError(f"wang-delay base must be wang-lsm-cn or wang-lsm, got {base!r}")
        if int(max_multiple) < 0:
            raise InputError(f"wang-delay max_multiple must be >= 0, got {max_multiple}")
        self.base, self.max_multiple = base, int(max_multiple)

    def options(self) -> dict[str, Any]:
        return {"base": self.base, "max_multiple": self.max_multiple}

    def identify(
        self, record: Record, options: IdentifyOptions, truth: Truth | None = None
    ) -> Estimate:
        from dataclasses import replace

        from hbench_wang import WangLSM

        method = ColoredNoiseLSM() if self.base == "wang-lsm-cn" else WangLSM()
        est = method.identify(record, replace(options, delay_multiple=0))
        m, corr = delay_multiple_from_alignment(record.x, est.U, self.max_multiple)
        K = record.n_slow
        U = np.full_like(est.U, np.nan)
        for j in np.unique(m):
            rows = m == j
            U[rows, : K - j] = est.U[rows, j:]
        est.U = U
        est.method = self.name
        est.delay_multiple = m
        est.criteria = {**est.criteria, "delay_corr": corr}
        est.info = {**est.info, **self.options()}
        return est

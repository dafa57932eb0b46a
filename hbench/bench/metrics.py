"""Metrics comparing an estimate with the truth of a simulation.

Fitness (the paper's Table 5, MATLAB ``compare``): ``F = 100 (1 - ||Us - U|| / ||U - mean U||)`` on
the slow-rate inner signal, over the samples both signals define. The blind estimate carries the
gain ambiguity of ``b1 = 1`` (``U_est = b1 U`` for a perfect estimate), so it must be scaled first:

* ``"gain"`` (default, the paper's "the gain of G(q) is assumed to be known"):
  ``Us = U_est / b1_true``;
* ``"ls"``: the least-squares scale ``c = <U_est, U> / <U_est, U_est>``;
* ``"ls-affine"``: least-squares scale and offset;
* ``"gain-centred"``: the true gain as in ``"gain"``, and the offset by least squares: with
  ``e = U_est / b1_true - U`` over the ``K`` samples both signals define,
  ``Us = U_est / b1_true - mean(U_est / b1_true) + mean(U)``, so ``Us - U = e - mean(e)`` and
  ``||Us - U||^2 = ||e||^2 - K mean(e)^2``: the ``"gain"`` fitness with the estimate's constant
  offset error removed (``min_c ||U_est / b1_true + c - U||`` is reached at
  ``c = mean(U - U_est / b1_true)``). Never below ``"gain"``, equal to it where ``mean(e) = 0``;
  ``"ls-affine"`` with the slope fixed at the known gain instead of fitted.
"""

from __future__ import annotations

import functools

import numpy as np

from hbench.errors import InputError
from hbench.numerics import kernels

SCALINGS = ("gain", "ls", "ls-affine", "gain-centred")


def fitness(
    U_est: np.ndarray, U: np.ndarray, scaling: str = "gain", gain: float | np.ndarray | None = None
) -> np.ndarray:
    """Fitness in % per run (``nan`` where the estimate is absent).

    Parameters
    ----------
    U_est, U : ndarray, shape (runs, K)
        Estimated (nan where undetermined) and true slow-rate inner signals, aligned.
    scaling : {"gain", "ls", "ls-affine", "gain-centred"}
        How the gain ambiguity is removed (see the module docstring).
    gain : float or ndarray, optional
        The true b1 (required for ``"gain"`` and ``"gain-centred"``).
    """
    return fitnesses(U_est, U, (scaling,), gain)[scaling]


def fitnesses(
    U_est: np.ndarray,
    U: np.ndarray,
    scalings: tuple[str, ...] = SCALINGS,
    gain: float | np.ndarray | None = None,
    *,
    compiled: bool = True,
) -> dict[str, np.ndarray]:
    """:func:`fitness` under several scalings, ``{scaling: (runs,)}``; the masks, the centred
    truth and its norm are computed once for all of them (the same numbers as one by one).

    The scalings ``"gain"`` and ``"ls"`` are computed by a compiled kernel where one is built
    (:func:`hbench.numerics.kernels.fitness`: the same operations and sums); ``compiled=False``
    keeps to numpy."""
    for scaling in scalings:
        if scaling not in SCALINGS:
            raise InputError(
                f"fitness scaling must be one of {', '.join(SCALINGS)}, got {scaling!r}"
            )
    for needs_gain in ("gain", "gain-centred"):
        if needs_gain in scalings and gain is None:
            raise InputError(f"fitness scaling {needs_gain!r} needs the true gain b1")
    U_est = np.atleast_2d(U_est)
    U = np.atleast_2d(U)
    if compiled and set(scalings) <= {"gain", "ls"} and sums_are_numpys():
        both = kernels.fitness(U_est, U, 1.0 if gain is None else gain)
        if both is not None:
            return {s: both[0] if s == "gain" else both[1] for s in scalings}
    m = np.isfinite(U_est) & np.isfinite(U)
    n = m.sum(axis=1)
    e = np.where(m, U_est, 0.0)
    u = np.where(m, U, 0.0)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean_u = np.sum(u, axis=1) / n
        den = np.sqrt(np.sum(np.where(m, u - mean_u[:, None], 0.0) ** 2, axis=1))
    out = {}
    if gain is not None:  # the estimate over the known gain (``"gain"``, ``"gain-centred"``)
        with np.errstate(invalid="ignore", divide="ignore"):  # gain 0: -inf, as compiled
            eg = e / np.broadcast_to(np.asarray(gain, float), (U.shape[0],))[:, None]
    for scaling in scalings:
        if scaling == "gain":
            us = eg
        elif scaling == "gain-centred":
            with np.errstate(invalid="ignore", divide="ignore"):
                shift = np.sum(np.where(m, eg - u, 0.0), axis=1) / n  # mean(e) over the mask
            us = eg - shift[:, None]
        elif scaling == "ls":
            with np.errstate(invalid="ignore", divide="ignore"):
                c = np.sum(e * u, axis=1) / np.sum(e * e, axis=1)
            us = c[:, None] * e
        else:
            with np.errstate(invalid="ignore", divide="ignore"):
                me = np.sum(e, axis=1) / n
                mu = np.sum(u, axis=1) / n
                ec = np.where(m, e - me[:, None], 0.0)
                c = np.sum(ec * np.where(m, u - mu[:, None], 0.0), axis=1) / np.sum(ec * ec, axis=1)
            us = c[:, None] * ec + mu[:, None]
        with np.errstate(invalid="ignore", divide="ignore"):
            num = np.sqrt(np.sum(np.where(m, us - u, 0.0) ** 2, axis=1))
            out[scaling] = np.where(n > 1, 100.0 * (1.0 - num / den), np.nan)
    return out


@functools.cache
def sums_are_numpys() -> bool:
    """Whether the kernel of :func:`hbench.numerics.kernels.fitness` gives numpy's numbers here: its
    row sums follow numpy's pairwise summation, which a numpy release may change. Checked once per
    process on rows of many lengths and magnitudes with undefined samples; where it fails, the
    fitness is computed by numpy on both backends. Independent of the backend switch."""
    rng = np.random.default_rng(12)
    for K in (1, 2, 7, 8, 9, 15, 16, 17, 127, 128, 129, 130, 255, 256, 257, 500, 1001, 4099):
        U = rng.standard_normal((4, K)) * np.exp(rng.uniform(-30, 30, (4, K)))
        U_est = 1.7 * U + rng.standard_normal((4, K)) * np.exp(rng.uniform(-30, 30, (4, K)))
        U_est[1, : min(K, 3)] = np.nan
        U_est[2] = np.nan
        U[3, K // 2] = np.inf
        gain = rng.uniform(0.5, 2.0, 4)
        got = kernels.fitness_built(U_est, U, gain)
        want = fitnesses(U_est, U, ("gain", "ls"), gain, compiled=False)
        if got is None:
            return False
        pairs = zip(got, want.values(), strict=True)
        if not all(np.array_equal(g, w, equal_nan=True) for g, w in pairs):
            return False
    return True

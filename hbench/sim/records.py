"""The record: what an identifier sees of a closed loop, simulated or measured.

A :class:`Record` is batched over runs with time last. Its fast grid has period ``h``; the slow
(controller) grid has period ``T = p h``. Fast sample ``k p + i`` (``i = 0 .. p-1``) lies in slow
period ``k``, over which the controller output ``x[:, k]`` and the reference ``r[:, k]`` are held.

``Truth`` holds what a simulation knows and an identifier must not see: the inner signal, the
noise-free output, the noise and the plant. It travels beside the record, never inside it.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from hbench.errors import RecordError


@dataclass(frozen=True)
class Record:
    """Sampled closed-loop data: fast-rate output ``y`` and slow-rate ``x`` (and ``r``).

    Parameters
    ----------
    y : ndarray, shape (runs, K p)
        Measured process output at the fast period ``h``.
    x : ndarray or None, shape (runs, K)
        Controller output ``x(n)`` at the slow period ``T``; ``None`` when withheld from a method.
    r : ndarray or None, shape (runs, K)
        Reference ``r(n)`` at the slow period; ``None`` when absent or withheld.
    p : int
        Fast-sampling ratio ``T / h``.
    h : float
        Fast sampling period in seconds.
    source : str
        Where the record comes from (a file path or ``"simulation"``).
    meta : dict
        Free-form metadata (scenario summary, reader notices ...).
    """

    y: np.ndarray
    x: np.ndarray | None
    r: np.ndarray | None
    p: int
    h: float
    source: str = "simulation"
    meta: dict[str, Any] = field(default_factory=dict)
    #: What methods derive from ``y`` alone (the quiet-phase moments, a structure selection),
    #: shared by the methods run on this record and its :meth:`withhold` copies; never part of
    #: the data. Emptied by :func:`dataclasses.replace` (a new ``y``). Arrays of a record are
    #: not to be modified in place.
    cache: dict[str, Any] = field(default_factory=dict, init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        if self.p < 1 or int(self.p) != self.p:
            raise RecordError(f"p must be a positive integer, got {self.p!r}")
        if not self.h > 0:
            raise RecordError(f"h must be positive, got {self.h!r}")
        y = np.atleast_2d(np.asarray(self.y, dtype=float))
        object.__setattr__(self, "y", y)
        if y.shape[1] % self.p:
            raise RecordError(f"y has {y.shape[1]} fast samples, not a multiple of p = {self.p}")
        K = y.shape[1] // self.p
        for name in ("x", "r"):
            arr = getattr(self, name)
            if arr is None:
                continue
            arr = np.atleast_2d(np.asarray(arr, dtype=float))
            if arr.shape != (y.shape[0], K):
                raise RecordError(
                    f"{name} has shape {arr.shape}, expected {(y.shape[0], K)} (runs, K = N / p)"
                )
            object.__setattr__(self, name, arr)

    @property
    def runs(self) -> int:
        """Number of runs in the batch."""
        return self.y.shape[0]

    @property
    def n_fast(self) -> int:
        """Number of fast samples ``N``."""
        return self.y.shape[1]

    @property
    def n_slow(self) -> int:
        """Number of slow samples ``K = N / p``."""
        return self.y.shape[1] // self.p

    @property
    def T(self) -> float:
        """Slow (controller) period ``p h``."""
        return self.p * self.h

    @property
    def t(self) -> np.ndarray:
        """Fast time grid in seconds, shape ``(N,)``."""
        return np.arange(self.n_fast) * self.h

    def hold(self, slow: np.ndarray) -> np.ndarray:
        """A slow-rate array held over each period at the fast rate (zero-order hold)."""
        return np.repeat(np.asarray(slow), self.p, axis=-1)

    def select(self, index: slice | np.ndarray | list[int]) -> Record:
        """The sub-batch of runs ``index``."""

        def take(a):
            return None if a is None else np.atleast_2d(a[index])

        return replace(self, y=take(self.y), x=take(self.x), r=take(self.r))

    def withhold(self, keep: frozenset[str] | set[str]) -> Record:
        """A copy that shows only the optional signals in ``keep`` (``"x"``, ``"r"``).

        ``y`` is always shown. Methods receive the record through this, so a method that did not
        declare it needs ``x`` or ``r`` cannot read them.
        """
        out = replace(
            self,
            x=self.x if "x" in keep else None,
            r=self.r if "r" in keep else None,
            meta={k: v for k, v in self.meta.items() if k in {"notices"}},
        )
        object.__setattr__(out, "cache", self.cache)  # same y: what was derived from it holds
        return out


@dataclass(frozen=True)
class Truth:
    """What a simulation knows and identifiers never see.

    Attributes
    ----------
    U : ndarray, shape (runs, K)
        Slow-rate inner signal ``U(n) = u(p n)`` (the valve output), aligned with ``x``.
    y0 : ndarray, shape (runs, N)
        Noise-free part of the closed-loop output, ``y0 = G(q) u``.
    v : ndarray, shape (runs, N)
        Additive output noise, ``y = y0 + v``.
    plant : DiscretePlant
        The fast-rate plant the data came from (``hbench.model.plants.DiscretePlant``).
    sigma2 : ndarray, shape (runs,)
        Variance of the white noise source driving ``v``.
    snr : ndarray, shape (runs,)
        ``||y0||_2 / ||v||_2`` per run (a ratio of norms, the paper's definition).
    """

    U: np.ndarray
    y0: np.ndarray
    v: np.ndarray
    plant: Any
    sigma2: np.ndarray
    snr: np.ndarray

    @property
    def u(self) -> np.ndarray:
        """Fast-rate inner signal, ``U`` held over each slow period."""
        p = self.y0.shape[1] // self.U.shape[1]
        return np.repeat(self.U, p, axis=-1)

    def select(self, index: slice | np.ndarray | list[int]) -> Truth:
        """The sub-batch of runs ``index``."""
        return replace(
            self,
            U=np.atleast_2d(self.U[index]),
            y0=np.atleast_2d(self.y0[index]),
            v=np.atleast_2d(self.v[index]),
            sigma2=np.atleast_1d(self.sigma2[index]),
            snr=np.atleast_1d(self.snr[index]),
        )

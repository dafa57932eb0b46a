"""Output noise models ``v = C(q)/D(q) e`` at the fast rate, ``e`` white of variance sigma^2.

The level is set by the scenario, either as ``sigma2`` (variance of ``e``) or as a target SNR
``||y0||_2 / ||v||_2`` (the paper's definition, a ratio of norms); see :mod:`hbench.sim.simulate`.
"""

from __future__ import annotations

import warnings
from typing import Any, ClassVar

import numpy as np
from scipy import signal

from hbench.errors import InputError
from hbench.model.plants import DiscretePlant
from hbench.numerics import kernels

#: Discretisation methods for a continuous noise filter (``scipy.signal.cont2discrete`` names).
CONT2DISCRETE_METHODS = ("zoh", "foh", "impulse", "bilinear", "euler", "backward_diff")


class NoiseModel:
    """Base class: a rational filter driven by white Gaussian noise at the fast rate."""

    name: ClassVar[str] = ""

    def params(self) -> dict[str, Any]:
        return {}

    def filter(self, plant: DiscretePlant) -> tuple[np.ndarray, np.ndarray]:
        """``(c, d)``: numerator and denominator in powers of ``q^-1``."""
        raise NotImplementedError

    def shape(self, e: np.ndarray, plant: DiscretePlant) -> np.ndarray:
        """Filter white noise ``e`` (shape ``(runs, N)``) from rest along the last axis."""
        c, d = self.filter(plant)
        if np.any(np.abs(np.roots(d)) >= 1.0) if d.size > 1 else False:
            raise InputError(f"noise model {self.name!r} has an unstable denominator")
        if e.ndim == 2:  # compiled: scipy's arithmetic, 8 runs at a time (the same bits)
            c, d = np.atleast_1d(np.asarray(c, float)), np.atleast_1d(np.asarray(d, float))
            R = e.shape[0]
            shaped = kernels.lfilter_rows(
                np.broadcast_to(c, (R, c.size)), np.broadcast_to(d, (R, d.size)), e
            )
            if shaped is not None:
                return shaped
        return signal.lfilter(c, d, e, axis=-1)

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self.params()})"


class White(NoiseModel):
    """White measurement noise ``v = e``."""

    name: ClassVar[str] = "white"

    def filter(self, plant: DiscretePlant) -> tuple[np.ndarray, np.ndarray]:
        return np.array([1.0]), np.array([1.0])


class ARX(NoiseModel):
    """Equation-error noise ``v = g e / A(q)`` with the plant's own A: the paper's eq. (2).

    ``gain`` g (default 1) scales the equation noise ``A(q) v = g e``. The paper's Section 6 filter
    discretised by ZOH has equation noise ``(c1 q^-1 + c2 q^-2) e`` with ``c1^2 + c2^2 ~ 1.04e-4``
    at h = 0.12 s, so ``gain=0.01`` puts sigma^2 on the paper's scale of equation-noise levels.
    """

    name: ClassVar[str] = "arx"

    def __init__(self, gain: float = 1.0) -> None:
        self.gain = float(gain)
        if not np.isfinite(self.gain) or self.gain <= 0:
            raise InputError(f"ARX noise gain must be > 0, got {gain}")

    def params(self) -> dict[str, Any]:
        return {"gain": self.gain}

    def filter(self, plant: DiscretePlant) -> tuple[np.ndarray, np.ndarray]:
        return np.array([self.gain]), plant.a


class ARMA(NoiseModel):
    """``v = C(q)/D(q) e`` with given ``c = [c0, c1, ...]`` and ``d = [1, d1, ...]``."""

    name: ClassVar[str] = "arma"

    def __init__(self, c: Any = (1.0, 0.5), d: Any = (1.0, -0.9)) -> None:
        self.c = np.atleast_1d(np.asarray(c, dtype=float))
        self.d = np.atleast_1d(np.asarray(d, dtype=float))
        if self.d.size == 0 or self.d[0] == 0:
            raise InputError("ARMA noise: d must start with a non-zero coefficient")
        if self.d.size > 1 and np.any(np.abs(np.roots(self.d)) >= 1):
            raise InputError("ARMA noise: D(q) must have its roots inside the unit circle")

    def params(self) -> dict[str, Any]:
        return {"c": self.c.tolist(), "d": self.d.tolist()}

    def filter(self, plant: DiscretePlant) -> tuple[np.ndarray, np.ndarray]:
        return self.c / self.d[0], self.d / self.d[0]


class ContinuousFilter(NoiseModel):
    """White noise through a continuous filter ``num(s)/den(s)``, discretised at h.

    The paper (Section 6) passes white noise of variance sigma^2 through 1/(s^2 + 0.32 s + 0.02)
    without saying how the filter is discretised. Default ``method="zoh"``: the filter is
    discretised by zero-order hold and driven by discrete white noise of variance sigma^2 at
    the fast rate. This matches the paper's Table 2, whose quiet-phase variances of Delta w
    (about 1e-7 at sigma^2 = 1e-3) equal sigma^2 (c1^2 + c2^2) for the ZOH numerator
    c1 q^-1 + c2 q^-2 ~ (h^2/2)(q^-1 + q^-2). Other methods are those of
    ``scipy.signal.cont2discrete``; ``"zoh"`` with ``scale="none"`` is the default.

    Parameters
    ----------
    num, den : array_like
        Continuous filter, highest power of s first.
    method : str
        One of ``zoh, foh, impulse, bilinear, euler, backward_diff``.
    """

    name: ClassVar[str] = "continuous"

    def __init__(
        self, num: Any = (1.0,), den: Any = (1.0, 0.32, 0.02), method: str = "zoh"
    ) -> None:
        if method not in CONT2DISCRETE_METHODS:
            raise InputError(
                f"noise discretisation method {method!r} unknown "
                f"(choose from {', '.join(CONT2DISCRETE_METHODS)})"
            )
        self.num = tuple(float(v) for v in np.atleast_1d(num))
        self.den = tuple(float(v) for v in np.atleast_1d(den))
        self.method = method
        self._cache: dict[float, tuple[np.ndarray, np.ndarray]] = {}

    def params(self) -> dict[str, Any]:
        return {"num": list(self.num), "den": list(self.den), "method": self.method}

    def filter(self, plant: DiscretePlant) -> tuple[np.ndarray, np.ndarray]:
        h = plant.h
        if h not in self._cache:
            with warnings.catch_warnings():
                # ZOH leaves a q^0 numerator coefficient at rounding level: trimmed just below
                warnings.simplefilter("ignore", signal.BadCoefficients)
                c, d, _ = signal.cont2discrete((self.num, self.den), h, method=self.method)
            c = np.atleast_1d(np.squeeze(c))
            c[np.abs(c) < 1e-14 * np.abs(c).max()] = 0.0
            self._cache[h] = (c / d[0], np.asarray(d, dtype=float) / d[0])
        return self._cache[h]


BUILTIN: tuple[type[NoiseModel], ...] = (White, ARX, ARMA, ContinuousFilter)

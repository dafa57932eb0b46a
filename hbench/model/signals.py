"""Reference signals r(n) at the slow (controller) period, batched over runs.

Each reference draws from the run's own generator (see :mod:`hbench.sim.seeding`), so run i's
reference does not depend on how many runs are drawn. With ``per_run=False`` every run gets the
reference of run 0 (a fixed excitation, with noise the only random part).
"""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np
from scipy import signal

from hbench.errors import InputError


class Reference:
    """Base class of reference generators."""

    name: ClassVar[str] = ""
    per_run: bool = True

    def params(self) -> dict[str, Any]:
        return {"per_run": self.per_run}

    def draw(self, rng: np.random.Generator, K: int) -> np.ndarray:
        """One realisation of length ``K`` from ``rng``."""
        raise NotImplementedError

    def generate(self, rngs: list[np.random.Generator], K: int) -> np.ndarray:
        """Shape ``(runs, K)``: one realisation per run generator (or run 0's for all)."""
        if not self.per_run:
            one = self.draw(rngs[0], K)
            return np.broadcast_to(one, (len(rngs), K)).copy()
        return np.stack([self.draw(g, K) for g in rngs]) if rngs else np.zeros((0, K))

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self.params()})"


class RBS(Reference):
    """Random binary sequence in a frequency band, values ``+-amplitude`` (MATLAB idinput style).

    Convention (documented because the paper's "frequency band [0, 0.5]" leaves it open): ``band``
    is ``[lo, hi]`` as fractions of the Nyquist frequency of the slow rate, as in MATLAB's
    ``idinput(N, 'rbs', band)``. White Gaussian noise is band-pass filtered, then its sign taken.
    ``filter="butter"`` uses a causal Butterworth filter of order ``order`` (default 8) after a
    burn-in of ``burn_in`` samples; ``filter="ideal"`` zeroes the FFT bins outside the band. A
    band of ``[0, 1]`` gives a white binary sequence.
    """

    name: ClassVar[str] = "rbs"

    def __init__(
        self,
        band: Any = (0.0, 0.5),
        amplitude: float = 1.0,
        filter: str = "butter",
        order: int = 8,
        burn_in: int = 200,
        per_run: bool = True,
    ) -> None:
        lo, hi = (float(v) for v in band)
        if not 0.0 <= lo < hi <= 1.0:
            raise InputError(f"rbs band must satisfy 0 <= lo < hi <= 1 (Nyquist), got {band}")
        if filter not in ("butter", "ideal"):
            raise InputError(f"rbs filter must be 'butter' or 'ideal', got {filter!r}")
        self.band, self.amplitude, self.filter = (lo, hi), float(amplitude), filter
        self.order, self.burn_in, self.per_run = int(order), int(burn_in), bool(per_run)
        self._sos = None
        if filter == "butter" and (lo, hi) != (0.0, 1.0):
            if lo == 0.0:
                self._sos = signal.butter(self.order, hi, btype="low", output="sos")
            elif hi == 1.0:
                self._sos = signal.butter(self.order, lo, btype="high", output="sos")
            else:
                self._sos = signal.butter(self.order, (lo, hi), btype="band", output="sos")

    def params(self) -> dict[str, Any]:
        return {
            "band": list(self.band),
            "amplitude": self.amplitude,
            "filter": self.filter,
            "order": self.order,
            "burn_in": self.burn_in,
            "per_run": self.per_run,
        }

    def _raw_length(self, K: int) -> int:
        lo, hi = self.band
        return K + self.burn_in if self.filter == "butter" and (lo, hi) != (0.0, 1.0) else K

    def _shape(self, g: np.ndarray, K: int) -> np.ndarray:
        """Band-limit Gaussian draws (time last, any leading shape) and take their sign."""
        lo, hi = self.band
        if (lo, hi) == (0.0, 1.0):
            pass
        elif self.filter == "butter":
            g = signal.sosfilt(self._sos, g, axis=-1)[..., self.burn_in :]
        else:
            spec = np.fft.rfft(g, axis=-1)
            f = np.linspace(0.0, 1.0, spec.shape[-1])
            spec[..., (f < lo) | (f > hi)] = 0.0
            g = np.fft.irfft(spec, n=K, axis=-1)
        return np.where(g >= 0.0, self.amplitude, -self.amplitude)

    def draw(self, rng: np.random.Generator, K: int) -> np.ndarray:
        return self._shape(rng.standard_normal(self._raw_length(K)), K)

    def generate(self, rngs: list[np.random.Generator], K: int) -> np.ndarray:
        """Each run draws from its own generator; the filtering is one call over the batch."""
        if not self.per_run or not rngs:
            return super().generate(rngs, K)
        n = self._raw_length(K)
        return self._shape(np.stack([g.standard_normal(n) for g in rngs]), K)


class PRBS(Reference):
    """Maximum-length pseudo-random binary sequence, each value held ``hold`` slow periods.

    ``nbits`` sets the period ``2^nbits - 1``; the shift register's initial state is drawn from
    the run's generator.
    """

    name: ClassVar[str] = "prbs"

    def __init__(
        self, nbits: int = 10, hold: int = 2, amplitude: float = 1.0, per_run: bool = True
    ) -> None:
        if not 2 <= int(nbits) <= 32:
            raise InputError(f"prbs nbits must be in 2..32, got {nbits}")
        if int(hold) < 1:
            raise InputError(f"prbs hold must be >= 1, got {hold}")
        self.nbits, self.hold, self.amplitude = int(nbits), int(hold), float(amplitude)
        self.per_run = bool(per_run)

    def params(self) -> dict[str, Any]:
        return {
            "nbits": self.nbits,
            "hold": self.hold,
            "amplitude": self.amplitude,
            "per_run": self.per_run,
        }

    def draw(self, rng: np.random.Generator, K: int) -> np.ndarray:
        state = rng.integers(0, 2, size=self.nbits)
        if not state.any():
            state[0] = 1
        n_bits = -(-K // self.hold)
        seq, _ = signal.max_len_seq(self.nbits, state=state, length=n_bits)
        return (self.amplitude * (2.0 * seq - 1.0)).repeat(self.hold)[:K]


class Steps(Reference):
    """Deterministic steps: ``levels[i]`` from slow sample ``at[i]`` on (0 before the first)."""

    name: ClassVar[str] = "steps"

    def __init__(self, at: Any = (0, 200, 400, 600), levels: Any = (1.0, -1.0, 0.5, -0.5)) -> None:
        self.at = [int(v) for v in np.atleast_1d(at)]
        self.levels = [float(v) for v in np.atleast_1d(levels)]
        if len(self.at) != len(self.levels):
            raise InputError("steps: 'at' and 'levels' must have the same length")
        if any(b <= a for a, b in zip(self.at, self.at[1:], strict=False)):
            raise InputError("steps: 'at' must be increasing")
        self.per_run = False

    def params(self) -> dict[str, Any]:
        return {"at": self.at, "levels": self.levels}

    def draw(self, rng: np.random.Generator, K: int) -> np.ndarray:
        out = np.zeros(K)
        for a, lev in zip(self.at, self.levels, strict=True):
            out[min(a, K) :] = lev
        return out


BUILTIN: tuple[type[Reference], ...] = (RBS, PRBS, Steps)

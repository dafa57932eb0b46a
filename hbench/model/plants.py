"""Plants: continuous transfer functions with a pure delay, discretised exactly under ZOH at h.

Conventions follow ``scipy.signal``: polynomials are coefficient arrays, highest power first for
``s``; discrete polynomials are in powers of ``q^-1`` (``[1, a1, a2, ...]``). A fast-rate plant is

    y(t) = q^-delay B(q) / A(q) u(t),   A(q) = 1 + a1 q^-1 + ..., B(q) = b1 q^-1 + ... + b_nb q^-nb,

the paper's eq. (2) with ``delay`` the integer delay in fast samples (``tau`` in the paper once
the part that is a multiple of p is taken off, assumption A3). B is strictly proper, so the loop
always holds at least one sample of delay.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np
from scipy import linalg, signal

from hbench.errors import InputError, UnstableError


@dataclass(frozen=True)
class DiscretePlant:
    """A fast-rate linear plant ``y = q^-delay B(q)/A(q) u``.

    Parameters
    ----------
    a : array_like
        Denominator ``[1, a1, ..., a_na]`` in powers of ``q^-1``.
    b : array_like
        Numerator coefficients ``[b1, ..., b_nb]`` of ``q^-1 .. q^-nb`` (b1 != 0).
    delay : int
        Extra integer delay in fast samples.
    h : float
        Fast sampling period in seconds.
    name : str
        Label for tables.
    """

    a: np.ndarray
    b: np.ndarray
    delay: int
    h: float
    name: str = "plant"
    info: dict[str, Any] = field(default_factory=dict, compare=False)

    def __post_init__(self) -> None:
        a = np.atleast_1d(np.asarray(self.a, dtype=float))
        b = np.trim_zeros(np.atleast_1d(np.asarray(self.b, dtype=float)), "b")
        if a.ndim != 1 or a.size < 1 or a[0] == 0:
            raise InputError(f"plant {self.name}: denominator must start with a non-zero a0")
        a = a / a[0]
        a = np.trim_zeros(a, "b")
        if b.size == 0:
            raise InputError(f"plant {self.name}: numerator B(q) is zero")
        # leading zeros of b are extra delay
        lead = int(np.argmax(b != 0))
        b = b[lead:]
        if int(self.delay) != self.delay or self.delay < 0:
            raise InputError(f"plant {self.name}: delay must be a non-negative integer of samples")
        if not np.all(np.isfinite(a)) or not np.all(np.isfinite(b)):
            raise InputError(f"plant {self.name}: coefficients must be finite")
        object.__setattr__(self, "a", a)
        object.__setattr__(self, "b", b)
        object.__setattr__(self, "delay", int(self.delay) + lead)

    # --- structure -------------------------------------------------------------------------
    @property
    def na(self) -> int:
        """Order of A(q)."""
        return self.a.size - 1

    @property
    def nb(self) -> int:
        """Order of B(q) (number of coefficients b1 .. b_nb)."""
        return self.b.size

    @property
    def gain(self) -> float:
        """b1, the scale that the blind normalisation b1 = 1 removes."""
        return float(self.b[0])

    @property
    def b_normalised(self) -> np.ndarray:
        """``[1, b2/b1, ...]``: B(q) under the paper's normalisation b1 = 1."""
        return self.b / self.b[0]

    def tau(self, p: int) -> int:
        """The delay's part in ``[0, p)``: what blind identification estimates."""
        return self.delay % p

    def delay_multiple(self, p: int) -> int:
        """The delay's integer multiple of p (known a priori, assumption A3)."""
        return self.delay // p

    @property
    def num(self) -> np.ndarray:
        """Full numerator in powers of ``q^-1`` including the delay: ``[0, ..., 0, b1, ...]``."""
        return np.concatenate([np.zeros(self.delay + 1), self.b])

    @property
    def den(self) -> np.ndarray:
        """Denominator ``[1, a1, ...]``."""
        return self.a

    @property
    def poles(self) -> np.ndarray:
        """Roots of A (in z)."""
        return np.roots(self.a) if self.na else np.array([])

    @property
    def zeros(self) -> np.ndarray:
        """Roots of B(q) q^(nb) (in z), excluding the zeros at the origin of the delay."""
        return np.roots(self.b) if self.nb > 1 else np.array([])

    @property
    def is_stable(self) -> bool:
        """All poles strictly inside the unit circle."""
        return bool(np.all(np.abs(self.poles) < 1.0))

    @property
    def is_minimum_phase(self) -> bool:
        """All zeros of B strictly inside the unit circle."""
        return bool(np.all(np.abs(self.zeros) < 1.0))

    @property
    def dc_gain(self) -> float:
        """G(1) = B(1) / A(1)."""
        return float(self.b.sum() / self.a.sum())

    def true_params(self) -> dict[str, float]:
        """The identified parameters under b1 = 1: ``a1 .. a_na, b2 .. b_nb``."""
        out = {f"a{i}": float(v) for i, v in enumerate(self.a[1:], start=1)}
        out.update({f"b{j}": float(v) for j, v in enumerate(self.b_normalised[1:], start=2)})
        return out

    def check_stable(self) -> None:
        """Raise :class:`UnstableError` naming the plant and its largest pole if unstable."""
        if not self.is_stable:
            rho = float(np.max(np.abs(self.poles)))
            raise UnstableError(
                f"plant {self.name!r} is unstable at h = {self.h:g} s "
                f"(largest pole modulus {rho:.4g} >= 1)"
            )

    def state_space(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """A minimal-order companion realisation ``(F, G, H)`` of the full delayed plant.

        ``s(t+1) = F s(t) + G u(t)``, ``y(t) = H s(t)`` (no feedthrough: B is strictly proper).
        """
        num = self.num  # q^0 .. q^-(delay+nb), num[0] = 0
        L = max(self.na, num.size - 1)
        den_z = np.zeros(L + 1)
        den_z[: self.a.size] = self.a
        num_z = np.zeros(L + 1)
        num_z[: num.size] = num
        with warnings.catch_warnings():
            # the delay's leading zeros in the numerator are exact, not a conditioning problem
            warnings.simplefilter("ignore", signal.BadCoefficients)
            F, G, H, D = signal.tf2ss(num_z, den_z)
        if np.any(np.abs(D) > 0):  # pragma: no cover - excluded by construction
            raise AssertionError("plant has feedthrough")
        return F, G[:, 0], H[0]

    def __str__(self) -> str:
        a = " ".join(f"{v:+.6g}" for v in self.a)
        b = " ".join(f"{v:+.6g}" for v in self.b)
        return f"{self.name}: A = [{a}], B = [{b}], delay = {self.delay} (h = {self.h:g} s)"


class PlantModel(Protocol):
    """Anything that yields a fast-rate plant for a given fast period h."""

    name: str

    def discretize(self, h: float) -> DiscretePlant: ...


def _zoh_blocks(A: np.ndarray, B: np.ndarray, t: float) -> tuple[np.ndarray, np.ndarray]:
    """``(e^{A t}, int_0^t e^{A s} ds B)`` through one matrix exponential."""
    n = A.shape[0]
    M = np.zeros((n + 1, n + 1))
    M[:n, :n] = A * t
    M[:n, n] = B * t
    E = linalg.expm(M)
    return E[:n, :n], E[:n, n]


def zoh_with_delay(num: Any, den: Any, h: float, delay_s: float) -> tuple[np.ndarray, np.ndarray]:
    """Exact ZOH discretisation of ``num(s)/den(s) e^{-delay_s s}`` at period ``h``.

    Returns ``(b_full, a)`` in powers of ``q^-1`` (``b_full[0]`` the ``q^0`` coefficient).
    A fractional delay ``delay_s = (d - 1) h + tau'`` with ``0 < tau' <= h`` is handled as in
    Åström & Wittenmark, *Computer-Controlled Systems*, Sec. 2.3:
    ``x(k+1) = Phi x(k) + Gamma0 u(k-d+1) + Gamma1 u(k-d)``.
    """
    num = np.atleast_1d(np.asarray(num, dtype=float))
    den = np.atleast_1d(np.asarray(den, dtype=float))
    if np.trim_zeros(num, "f").size > np.trim_zeros(den, "f").size:
        raise InputError("continuous plant is improper (numerator degree > denominator degree)")
    if delay_s < 0 or not np.isfinite(delay_s):
        raise InputError(f"delay must be a finite non-negative time, got {delay_s}")
    A, B, C, D = signal.tf2ss(num, den)
    B = B[:, 0]
    C = C[0]
    D = float(D[0, 0]) if D.size else 0.0
    n = A.shape[0]
    ratio = delay_s / h
    d_int = round(ratio)
    if abs(ratio - d_int) < 1e-9:  # an integer number of samples: tau' = h
        d, tau_p = d_int + 1, h
    else:
        d = int(np.floor(ratio)) + 1
        tau_p = delay_s - (d - 1) * h
    Phi, Gamma_h = _zoh_blocks(A, B, h)
    integer = np.isclose(tau_p, h)
    # the held input seen through the feedthrough D: u(k-d+1) for an integer delay, else u(k-d)
    d_feed = d - 1 if integer else d
    if n == 0:
        b_full = np.zeros(d + 1)
        b_full[d_feed] += D
        return b_full, np.array([1.0])
    if integer:  # u(kh - (d-1)h) enters whole through Gamma: it is the u(k-d+1) term
        Gamma0, Gamma1 = Gamma_h, np.zeros(n)
    else:
        Phi_rest, Gamma0 = _zoh_blocks(A, B, h - tau_p)
        _, int_tau = _zoh_blocks(A, B, tau_p)
        Gamma1 = Phi_rest @ int_tau
    a = np.poly(Phi)
    # C (zI - Phi)^-1 Gamma = N(z)/a(z); in q^-1, N has a zero q^0 coefficient
    num0 = signal.ss2tf(Phi, Gamma0[:, None], C[None, :], np.zeros((1, 1)))[0][0]
    num1 = signal.ss2tf(Phi, Gamma1[:, None], C[None, :], np.zeros((1, 1)))[0][0]
    L = n + d + 1
    b_full = np.zeros(L)
    b_full[d - 1 : d - 1 + n + 1] += num0
    b_full[d : d + n + 1] += num1
    if D:
        b_full[d_feed : d_feed + n + 1] += D * a
    b_full[np.abs(b_full) < 1e-15 * max(1.0, np.abs(b_full).max())] = 0.0
    return b_full, np.real(a)


@dataclass(frozen=True)
class ContinuousPlant:
    """``num(s)/den(s) e^{-s delay_s}``, discretised exactly under ZOH at the fast period.

    Parameters
    ----------
    num, den : array_like
        Continuous transfer function, highest power of s first.
    delay : int or None
        Delay in fast samples, added after discretisation (the sweep axis). Overrides ``delay_s``.
    delay_s : float
        Delay in seconds; a fraction of h gives the extra numerator term of a fractional delay.
    name : str
        Label.
    """

    num: tuple[float, ...]
    den: tuple[float, ...]
    delay: int | None = None
    delay_s: float = 0.0
    name: str = "continuous"

    def discretize(self, h: float) -> DiscretePlant:
        if not h > 0:
            raise InputError(f"h must be positive, got {h}")
        delay_s = 0.0 if self.delay is not None else float(self.delay_s)
        b_full, a = zoh_with_delay(self.num, self.den, h, delay_s)
        nz = np.flatnonzero(b_full)
        if nz.size == 0:
            raise InputError(f"plant {self.name!r} discretises to a zero numerator")
        first = int(nz[0])
        extra = 0 if self.delay is None else int(self.delay)
        if first == 0:
            if extra < 1:
                raise InputError(
                    f"plant {self.name!r} has direct feedthrough: give it a delay of at least "
                    "one fast sample so that the loop holds a sample of delay"
                )
            first, extra = 1, extra - 1
            b_full = np.concatenate([[0.0], b_full])
            first = 1
        delay = first - 1 + extra
        plant = DiscretePlant(
            a=a,
            b=b_full[first:],
            delay=delay,
            h=h,
            name=self.name,
            info={"num": list(self.num), "den": list(self.den), "delay_s": self.delay_s},
        )
        plant.check_stable()
        return plant


@dataclass(frozen=True)
class GivenDiscretePlant:
    """A plant given directly at the fast rate: ``a = [1, a1, ...]``, ``b = [b1, ...]``.

    ``h`` is only checked against the scenario's fast period when ``h`` is given here.
    """

    a: tuple[float, ...]
    b: tuple[float, ...]
    delay: int = 0
    h: float | None = None
    name: str = "discrete"

    def discretize(self, h: float) -> DiscretePlant:
        if self.h is not None and not np.isclose(self.h, h):
            raise InputError(
                f"plant {self.name!r} is defined at h = {self.h:g} s but the scenario's fast "
                f"period is h = {h:g} s (T / p)"
            )
        plant = DiscretePlant(a=self.a, b=self.b, delay=self.delay, h=h, name=self.name)
        plant.check_stable()
        return plant


# --- built-in plants ---------------------------------------------------------------------------


def paper(delay: int | None = 3, delay_s: float = 0.36) -> ContinuousPlant:
    """Wang et al. Section 6: Gc(s) = (0.4095 s + 1.0921)/(s^2 + 0.32 s + 0.02) e^{-0.36 s}.

    At T = 0.6 s, p = 5 (h = 0.12 s) this is G(q) = 0.05597 q^-3 (q^-1 - 0.7244 q^-2) /
    (1 - 1.962 q^-1 + 0.9623 q^-2): delay 3 fast samples. ``delay`` counts fast samples (the
    sweep axis); set ``delay=None`` to use ``delay_s`` seconds instead.
    """
    return ContinuousPlant((0.4095, 1.0921), (1.0, 0.32, 0.02), delay, delay_s, "paper")


def first_order(gain: float = 1.0, time_constant: float = 2.0, delay: int = 1) -> ContinuousPlant:
    """``gain / (time_constant s + 1)``: na = nb = 1."""
    return ContinuousPlant((gain,), (time_constant, 1.0), delay, 0.0, "first-order")


def nonminimum_phase(delay: int = 1) -> ContinuousPlant:
    """``(1 - 2 s) / (s^2 + 1.2 s + 0.35)``: a right-half-plane zero at s = 0.5.

    Its ZOH discretisation has a zero outside the unit circle (about e^{0.5 h}), so the direct
    inverse A(q)/B(q) is unstable. na = nb = 2.
    """
    return ContinuousPlant((-2.0, 1.0), (1.0, 1.2, 0.35), delay, 0.0, "nmp")


def third_order(delay: int = 2) -> ContinuousPlant:
    """``(s + 0.5) / ((s + 0.4)(s + 1)(s + 2))``: na = nb = 3, minimum phase at h = 0.12 s."""
    den = np.poly([-0.4, -1.0, -2.0])
    return ContinuousPlant((1.0, 0.5), tuple(float(v) for v in den), delay, 0.0, "third-order")


def discrete(
    a: tuple[float, ...] = (1.0, -1.5, 0.7),
    b: tuple[float, ...] = (1.0, 0.5),
    delay: int = 0,
    h: float | None = None,
) -> GivenDiscretePlant:
    """A plant given at the fast rate (default: poles 0.75 +- 0.37j, zero at -0.5)."""
    return GivenDiscretePlant(tuple(a), tuple(b), delay, h, "discrete")


BUILTIN = {
    "paper": paper,
    "first-order": first_order,
    "nmp": nonminimum_phase,
    "third-order": third_order,
    "discrete": discrete,
}

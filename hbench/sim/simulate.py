"""The sampled-data closed loop with output fast-sampling (the paper's Figure 1), batched over runs.

At each slow instant ``n`` the controller reads ``y(p n) = y0(p n) + v(p n)``, outputs ``x(n)``,
the actuator gives ``U(n) = f(x(n))`` (with memory where the model has it), and the ZOH holds
``u(t) = U(n)`` for ``t = p n .. p n + p - 1``. The fast-rate plant ``q^-delay B/A`` is lifted to
the slow rate, so one slow step is one matrix product over the batch; the loop over time is forced
by the feedback and the actuator's memory, and its body is array operations over runs only.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field
from functools import cached_property
from typing import Any

import numpy as np

from hbench.errors import InputError, UnstableError
from hbench.model.controllers import Controller
from hbench.model.noise import NoiseModel
from hbench.model.nonlinearities import Nonlinearity
from hbench.model.plants import DiscretePlant, PlantModel
from hbench.model.signals import Reference
from hbench.numerics.ordered import ordered_products
from hbench.sim import loop_kernel
from hbench.sim.records import Record, Truth
from hbench.sim.seeding import as_generator, run_streams
from hbench.system import limits


class ZeroOutputWarning(UserWarning):
    """A simulated run whose noise-free output is identically zero (the actuator never moved).

    Legal data (the record is noise only, SNR 0), but rarely what was meant: it is what a
    stickband or dead zone wider than the controller output's excursion gives.
    """


@dataclass
class Scenario:
    """Everything that defines a simulated closed loop.

    Parameters
    ----------
    plant : PlantModel
        Continuous or discrete plant; discretised at ``h = T / p``.
    nonlinearity, controller, noise, reference
        The actuator model, the controller (slow rate), the output noise model, the reference.
    T : float
        Controller (ZOH) period in seconds.
    p : int
        Fast-sampling ratio.
    duration : float
        Record length in seconds; ``K = floor(duration / T)`` slow samples.
    sigma2 : float or None
        Variance of the white noise driving the noise filter.
    snr : float or None
        Target ``||y0||_2 / ||v||_2`` per run instead of ``sigma2`` (exactly one of the two).
    name : str
        Label.
    """

    plant: PlantModel
    nonlinearity: Nonlinearity
    controller: Controller
    noise: NoiseModel
    reference: Reference
    T: float = 0.6
    p: int = 5
    duration: float = 500.0
    sigma2: float | None = 1e-3
    snr: float | None = None
    name: str = "scenario"
    meta: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        for name in ("T", "duration", "sigma2", "snr"):
            value = getattr(self, name)
            if value is None:
                continue
            try:
                setattr(self, name, float(value))
            except (TypeError, ValueError):
                raise InputError(f"{name} must be a number, got {value!r}") from None
        try:
            self.p = int(self.p) if float(self.p) == int(float(self.p)) else self.p
        except (TypeError, ValueError):
            raise InputError(f"p must be a positive integer, got {self.p!r}") from None
        if int(self.p) != self.p or self.p < 1:
            raise InputError(f"p must be a positive integer, got {self.p}")
        if not self.T > 0:
            raise InputError(f"T must be positive, got {self.T}")
        if (self.sigma2 is None) == (self.snr is None):
            raise InputError("give exactly one of noise sigma2 and snr")
        if self.sigma2 is not None and not self.sigma2 >= 0:
            raise InputError(f"sigma2 must be >= 0, got {self.sigma2}")
        if self.snr is not None and not self.snr > 0:
            raise InputError(f"snr must be > 0, got {self.snr}")
        if self.K < 2:
            raise InputError(
                f"duration {self.duration} s holds fewer than 2 periods of T = {self.T}"
            )

    @property
    def h(self) -> float:
        """Fast period ``T / p``."""
        return self.T / self.p

    @property
    def K(self) -> int:
        """Number of slow samples."""
        return int(np.floor(self.duration / self.T + 1e-9))

    @cached_property
    def discrete_plant(self) -> DiscretePlant:
        """The plant at the fast rate (checked stable)."""
        plant = self.plant.discretize(self.h)
        plant.check_stable()
        return plant

    def describe(self) -> dict[str, Any]:
        """A plain-data summary for provenance."""
        plant = self.discrete_plant
        return {
            "name": self.name,
            "plant": {
                "name": plant.name,
                "a": plant.a.tolist(),
                "b": plant.b.tolist(),
                "delay": plant.delay,
            },
            "nonlinearity": {"name": self.nonlinearity.name, **self.nonlinearity.params()},
            "controller": {"name": self.controller.name, **self.controller.params()},
            "noise": {"name": self.noise.name, **self.noise.params()},
            "reference": {"name": self.reference.name, **self.reference.params()},
            "T": self.T,
            "p": self.p,
            "h": self.h,
            "duration": self.duration,
            "K": self.K,
            "sigma2": self.sigma2,
            "snr": self.snr,
        }


@dataclass(frozen=True)
class LiftedPlant:
    """The fast-rate plant seen at the slow rate under a ZOH input.

    ``s(n+1) = Fp s(n) + Gp U(n)``; the fast outputs of period ``n`` are
    ``y0(p n + i) = Ob[i] . s(n) + Db[i] U(n)``, ``i = 0 .. p-1`` (``Db[0] = 0``).
    """

    Fp: np.ndarray
    Gp: np.ndarray
    Ob: np.ndarray
    Db: np.ndarray

    @classmethod
    def from_plant(cls, plant: DiscretePlant, p: int) -> LiftedPlant:
        F, G, H = plant.state_space()
        L = F.shape[0]
        Ob = np.empty((p, L))
        Db = np.zeros(p)
        Fi = np.eye(L)
        acc = np.zeros(L)  # sum_{j<i} F^j G
        for i in range(p):
            Ob[i] = H @ Fi
            Db[i] = H @ acc
            acc = acc + Fi @ G
            Fi = F @ Fi
        return cls(Fp=Fi, Gp=acc, Ob=Ob, Db=Db)


def closed_loop_radius(plant: DiscretePlant, controller: Controller, p: int) -> float:
    """Spectral radius of the slow-rate closed loop with the actuator replaced by unit gain."""
    lp = LiftedPlant.from_plant(plant, p)
    L, c = lp.Fp.shape[0], controller.A.shape[0]
    d = controller.delay
    # states: plant s (L), controller sc (c), delay buffer (d); e = -H s (r = v = 0)
    H = lp.Ob[0]
    n = L + c + d
    M = np.zeros((n, n))
    # controller output before the delay line: xc = Cc sc + Dc e
    xc = np.zeros(n)
    xc[:L] = -controller.D * H
    xc[L : L + c] = controller.C
    if d:
        U = np.zeros(n)
        U[L + c] = 1.0  # oldest buffer entry
        for k in range(d - 1):
            M[L + c + k, L + c + k + 1] = 1.0
        M[L + c + d - 1] = xc
    else:
        U = xc
    M[:L, :L] += lp.Fp
    M[:L] += np.outer(lp.Gp, U)
    M[L : L + c, L : L + c] = controller.A
    M[L : L + c, :L] += -np.outer(controller.B, H)
    return float(np.max(np.abs(np.linalg.eigvals(M)))) if n else 0.0


def _run_loop(
    lp: LiftedPlant,
    controller: Controller,
    nonlinearity: Nonlinearity,
    r: np.ndarray,
    v: np.ndarray,
    p: int,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The closed loop over slow time. Returns ``(y0, x, U)``.

    Runs compiled (:func:`hbench.sim.loop_kernel.closed_loop`, the same numbers) for the built-in
    actuators and controllers; the numpy loop below is the reference and serves the others. Its
    products sum in a fixed order (:func:`hbench.numerics.ordered.ordered_products`): the same on
    any machine and for any batch, and what the kernel mirrors."""
    compiled = loop_kernel.closed_loop(lp, controller, nonlinearity, r, v[:, ::p], p)
    if compiled is not None:
        return compiled
    R, K = r.shape
    L = lp.Fp.shape[0]
    s = np.zeros((R, L))
    S = np.empty((K, R, L))
    X = np.empty((K, R))
    U = np.empty((K, R))
    H, Fp, Gp = lp.Ob[:1], lp.Fp, lp.Gp
    v_slow = v[:, ::p]
    cstate = controller.initial_state(R)
    nstate = nonlinearity.initial_state(R)
    Y0pn = np.empty((K, R))
    # a diverging loop overflows quietly, as the kernel does: simulate() reports it (UnstableError)
    with np.errstate(over="ignore", invalid="ignore"):
        for n in range(K):
            S[n] = s
            Y0pn[n] = ordered_products(s, H)[:, 0]
            e = r[:, n] - (Y0pn[n] + v_slow[:, n])
            x, cstate = controller.step(e, cstate)
            u, nstate = nonlinearity.step(x, nstate)
            X[n] = x
            U[n] = u
            s = ordered_products(s, Fp) + u[:, None] * Gp
        # fast outputs of every period at once: (K, R, p) -> (R, K p)
        y0 = (ordered_products(S, lp.Ob) + U[:, :, None] * lp.Db).transpose(1, 0, 2).copy()
    y0[:, :, 0] = Y0pn.T  # the very values the controller read (same rounding)
    return y0.reshape(R, K * p), X.T.copy(), U.T.copy()


def _describe_nonlinearity(nonlinearity: Nonlinearity) -> str:
    """``"stiction S=0.2, J=0.02, u0=0"``: the actuator's name and parameters, for messages.

    Parameters
    ----------
    nonlinearity : Nonlinearity
        The actuator model.

    Returns
    -------
    str
        Its name (its class name if it has none) followed by its parameters.
    """
    name = nonlinearity.name or type(nonlinearity).__name__
    params = ", ".join(
        f"{k}={v:g}" if isinstance(v, int | float) and not isinstance(v, bool) else f"{k}={v}"
        for k, v in nonlinearity.params().items()
    )
    return f"{name} {params}" if params else name


def _zero_output_cause(
    nonlinearity: Nonlinearity, y0: np.ndarray, x: np.ndarray, U: np.ndarray
) -> tuple[np.ndarray, str]:
    """The runs whose noise-free output is identically zero, and why, in words.

    Parameters
    ----------
    nonlinearity : Nonlinearity
        The actuator model (named in the cause).
    y0, x, U : numpy.ndarray
        Noise-free output ``(runs, N)``, controller output and actuator output ``(runs, K)``.

    Returns
    -------
    zero : numpy.ndarray
        Boolean mask ``(runs,)`` of the runs whose ``y0`` is zero at every sample.
    cause : str
        ``"the actuator never moves (...)"`` when the actuator output of those runs is
        constant (with the range of the controller output), else a plainer description;
        empty when no run is zero.
    """
    zero = ~np.any(y0 != 0, axis=-1)
    if not zero.any():
        return zero, ""
    what = f"nonlinearity {_describe_nonlinearity(nonlinearity)}"
    Uz, xz = U[zero], x[zero]
    if np.all(Uz == Uz[:, :1]):
        cause = (
            f"the actuator never moves ({what}; its input x stays within "
            f"[{xz.min():.3g}, {xz.max():.3g}])"
        )
    else:
        cause = f"the plant's response to the actuator output is zero ({what})"
    return zero, cause


def _batch(start: int, runs: int) -> str:
    """``"run 4"`` or ``"runs 0..199"``: the runs of a batch, for messages (a cell simulated in
    chunks says which chunk)."""
    return f"run {start}" if runs == 1 else f"runs {start}..{start + runs - 1}"


def _snr(y0: np.ndarray, v: np.ndarray) -> np.ndarray:
    nv = np.linalg.norm(v, axis=-1)
    with np.errstate(divide="ignore"):
        return np.where(nv > 0, np.linalg.norm(y0, axis=-1) / np.where(nv > 0, nv, 1.0), np.inf)


def simulate(
    scenario: Scenario,
    runs: int,
    rng: np.random.Generator | int,
    *,
    start: int = 0,
    snr_tol: float = 1e-3,
    snr_accept: float = 1e-2,
    max_iter: int = 20,
) -> tuple[Record, Truth]:
    """Simulate ``runs`` independent realisations of the closed loop.

    Parameters
    ----------
    scenario : Scenario
        The loop to simulate.
    runs : int
        Number of Monte Carlo runs (the batch).
    rng : numpy.random.Generator or int
        Parent generator; run ``i`` draws from child ``start + i`` of its seed sequence.
    start : int
        Index of the first run (to simulate a large batch in chunks with identical results).
    snr_tol : float
        With a target SNR, a run stops iterating (its scale freezes) once its SNR is within this
        relative error, so a run's result never depends on the other runs of its batch.
    snr_accept : float
        A run that has not met ``snr_tol`` after ``max_iter`` passes (the SNR of a memoryful
        actuator jumps with the scale) keeps its best pass if within this relative error;
        otherwise the target is refused with :class:`InputError`.
    max_iter : int
        At most this many closed-loop passes when targeting an SNR.

    Returns
    -------
    record : Record
        What an identifier may see (``y``, ``x``, ``r``, ``p``, ``h``).
    truth : Truth
        Inner signal, noise-free output, noise, plant, sigma^2 and SNR per run.

    Raises
    ------
    InputError
        Bad ``runs``; a target SNR that is not reached (see ``snr_accept``), or that cannot be
        set because the noise-free output of some run is identically zero (an actuator that
        never leaves its stickband or dead zone).
    UnstableError
        An unstable or diverging closed loop.

    Warns
    -----
    ZeroOutputWarning
        With ``sigma2``: the noise-free output of some run is identically zero, so its record
        is noise only (SNR 0).
    """
    rng = as_generator(rng)
    if int(runs) != runs or runs < 1:
        raise InputError(f"runs must be a positive integer, got {runs}")
    sc = scenario
    plant, p, K = sc.discrete_plant, sc.p, sc.K
    N = K * p
    # sizes before any work (hbench.system.limits): the loop's state dimension, then the arrays
    limits.check_states(plant, f"the plant of scenario {sc.name!r}")
    limits.check(
        f"simulating {runs} run{'s' if runs != 1 else ''} of {N} fast samples",
        limits.simulation_bytes(N, runs),
        "shorten the duration or simulate fewer runs at once",
    )
    rho = closed_loop_radius(plant, sc.controller, p)
    if rho >= 1.0:
        raise UnstableError(
            f"closed loop of scenario {sc.name!r} is unstable (linearised with the actuator as "
            f"unit gain, spectral radius {rho:.4g} >= 1): lower the controller gain"
        )
    streams = run_streams(rng, runs, ("reference", "noise"), start=start)
    r = sc.reference.generate(streams["reference"], K)
    e = np.empty((runs, N))
    for i, g in enumerate(streams["noise"]):
        g.standard_normal(out=e[i])  # the same draws as standard_normal(N), without a stack
    v_unit = sc.noise.shape(e, plant)
    lp = LiftedPlant.from_plant(plant, p)

    if sc.snr is None:
        sigma2 = np.full(runs, float(sc.sigma2))
        v = np.sqrt(sigma2)[:, None] * v_unit
        y0, x, U = _run_loop(lp, sc.controller, sc.nonlinearity, r, v, p)
        zero, cause = _zero_output_cause(sc.nonlinearity, y0, x, U)
        if zero.any() and np.all(np.isfinite(y0)):  # legal data (noise only), but say so
            those = "that record is" if zero.sum() == 1 else "those records are"
            what = "noise only (SNR = 0)" if float(sc.sigma2) > 0 else "all zeros (sigma2 = 0)"
            warnings.warn(
                f"scenario {sc.name!r}: the noise-free output is zero in {int(zero.sum())} of "
                f"{_batch(start, runs)}: {cause}; {those} {what}",
                ZeroOutputWarning,
                stacklevel=2,
            )
    else:
        # fixed-point iteration on the per-run scale: the loop feeds the noise back into y0
        y0, x, U = _run_loop(lp, sc.controller, sc.nonlinearity, r, np.zeros_like(v_unit), p)
        if not np.all(np.isfinite(y0)):
            raise UnstableError(f"closed loop of scenario {sc.name!r} diverged (non-finite output)")
        zero, cause = _zero_output_cause(sc.nonlinearity, y0, x, U)
        if zero.any():  # no noise level gives ||y0|| / ||v|| = snr: refuse before scaling
            raise InputError(
                f"scenario {sc.name!r}: the noise-free output is zero in {int(zero.sum())} of "
                f"{_batch(start, runs)}: {cause}: an SNR cannot be set (target {sc.snr:g}); "
                "narrow the actuator's band, raise the reference amplitude or the controller "
                "gain, or give sigma2 instead of snr"
            )
        # Each run's scale follows its own iteration and freezes once that run has converged,
        # so a run's result does not depend on the other runs of its batch (chunking).
        nv = np.linalg.norm(v_unit, axis=-1)
        scale = np.linalg.norm(y0, axis=-1) / (sc.snr * nv)
        done = np.zeros(runs, bool)
        best_scale, best_err = scale.copy(), np.full(runs, np.inf)
        for _ in range(max_iter):
            v = scale[:, None] * v_unit
            y0, x, U = _run_loop(lp, sc.controller, sc.nonlinearity, r, v, p)
            ratio = _snr(y0, v) / sc.snr
            err = np.abs(ratio - 1.0)
            better = ~done & (err < best_err)
            best_scale = np.where(better, scale, best_scale)
            best_err = np.where(better, err, best_err)
            done |= err <= snr_tol
            if done.all():
                break
            scale = np.where(done, scale, scale * ratio)
        if not done.all():
            # memoryful actuators make the SNR jump with the scale: the iteration can cycle
            # around the target; take each run's best pass when it is within snr_accept
            if np.any(best_err[~done] > snr_accept):
                bad = ~done & (best_err > snr_accept)
                raise InputError(
                    f"target SNR {sc.snr:g} not reached within {100 * snr_accept:g} % in "
                    f"{max_iter} passes for {int(bad.sum())} of {runs} runs (best relative error "
                    f"{best_err[bad].min():.3g} .. {best_err[bad].max():.3g}): the noise fed back "
                    "through the loop bounds ||y0|| / ||v||; choose a larger SNR or give sigma2"
                )
            scale = np.where(done, scale, best_scale)
            v = scale[:, None] * v_unit
            y0, x, U = _run_loop(lp, sc.controller, sc.nonlinearity, r, v, p)
        sigma2 = scale**2
    if not np.all(np.isfinite(y0)):
        raise UnstableError(f"closed loop of scenario {sc.name!r} diverged (non-finite output)")
    y = y0 + v
    record = Record(
        y=y,
        x=x,
        r=r,
        p=p,
        h=sc.h,
        source="simulation",
        meta={"scenario": sc.name, "start": start},
    )
    truth = Truth(U=U, y0=y0, v=v, plant=plant, sigma2=sigma2, snr=_snr(y0, v))
    return record, truth

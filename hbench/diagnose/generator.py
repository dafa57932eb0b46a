"""Synthetic records with one hidden effect, for testing ``hbench diagnose``.

A *case* is drawn from a seed: a plant among the built-ins with random parameters
(``first-order``: gain 0.5-2, time constant 1-4 s, delay 1-2 samples; ``discrete``: a complex
pole pair of radius 0.75-0.9 or two real poles in 0.5-0.9, ``b = (1, 0.2-0.6)``, delay 0-2),
a nonlinearity class with random parameters, a proportional controller (loop gain 0.3-1.2 at
DC), ``p`` in {4, 5, 6} at ``T = 0.6 s``, 800-1000 slow samples, the noise level and, unless
the case is nominal, ONE effect from the catalogue with random parameters in the ranges below.
The record is simulated in closed loop (:func:`hbench.sim.simulate.simulate`; the time-varying
case runs the same lifted loop with a plant that changes mid-record) and written with
:func:`hbench.io.readers.write_record`, so a test sees only the file.

Nominal conditions (what the nominal model of :mod:`hbench.diagnose.nominal` assumes): plant of
order ``na <= 2`` with the delay's multiple of p equal to 0 (A3), equation-error noise
``v = sigma e / A(q)`` with the plant's own ``A`` (the paper's eq. 2, which the
bias-compensated LSM is built for) at SNR ``std(y0) / std(v)`` 10 to 30, time-invariant, no
outliers. The reference is a random-level signal (:class:`RandomLevels`), so that ``x``
visits its whole range. Effects (ranges, with ``s`` the standard deviation of the noise-free
output of a linear pilot run):

* ``colored-noise``: coloured equation noise (the paper's Table 4 case, which biases the LSM)
  ``v = sigma (1 + c1 q^-1) / ((1 - d1 q^-1) A(q)) e``, ``d1`` in [0.85, 0.97], ``c1`` in
  [0, 0.5], at SNR 1.5 to 3, instead of the nominal ``e / A``.
* ``drift``: a ramp ``D t / t_end`` plus a random walk of 5 % of ``D`` over the record added to
  ``y`` (inside the loop: the controller sees it), ``|D|`` in [1.5, 3] ``s``.
* ``delay``: the plant's delay grows by ``k p`` fast samples, ``k`` in {1, 2, 3}: ``x`` and the
  inner signal are misaligned by ``k`` slow periods against the nominal A3.
* ``outliers``: spikes on 0.5 to 1.5 % of the fast samples, amplitude 3 to 6 ``s`` with a random
  sign (inside the loop).
* ``time-varying``: at a fraction 0.3 to 0.42 of the record the plant's gain is multiplied by
  ``g`` in [1.8, 2.5] or [0.35, 0.55] and its poles' time constants by 0.6 to 0.8 (same orders,
  the state carried over).
* ``order``: a third-order plant (``discrete`` with a slow real pole in [0.9, 0.97] and a
  resonant pair of radius 0.75-0.9 at 0.3-0.7 rad) against the nominal ``na <= 2``.

Nonlinearity parameters scale with ``r_x``, the 1st-99th percentile range of ``x`` in the pilot
run: backlash ``width`` 0.2 to 0.4 ``r_x``; dead zone band ``[-d1, d2]`` with ``d1, d2`` 0.1 to
0.2 ``r_x``; saturation at the 10-25 % and 75-90 % quantiles of ``x``; stiction ``S`` 0.2 to 0.4
``r_x`` and ``J / S`` 0.4 to 0.8.
"""

from __future__ import annotations

import copy
import json
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from hbench.model.noise import NoiseModel
from hbench.model.plants import DiscretePlant
from hbench.model.signals import Reference
from hbench.sim import scenarios
from hbench.sim.records import Record
from hbench.sim.simulate import LiftedPlant, Scenario, simulate

EFFECTS: tuple[str, ...] = (
    "none",
    "colored-noise",
    "drift",
    "delay",
    "outliers",
    "time-varying",
    "order",
)
CLASSES: tuple[str, ...] = ("linear", "backlash", "deadband", "saturation", "stiction")

#: Nominal plants (na <= 2), drawn with random parameters. Left out: the built-in ``nmp``, whose
#: ``B(1)`` is 5 % of ``b1``, next to assumption A4, so that its inner signal is barely
#: determined (the blind estimate of U is off by 60-90 %); and ``paper``, whose DC gain of 55
#: with poles at 0.99 makes the open-loop simulation from ``x`` ill-conditioned (the nominal
#: model's validation fit is 10-40 % even without an effect), which hides every effect.
NOMINAL_PLANTS: tuple[str, ...] = ("first-order", "discrete")
#: Third-order plants for the ``order`` effect: ``discrete`` with a slow real pole and a
#: resonant pair, which no second-order model follows. (The built-in ``third-order`` has a zero
#: at s = -0.5 next to its pole at -0.4, so it is second order in effect: a second-order model
#: simulates it to 92-96 %.)
ORDER_PLANTS: tuple[str, ...] = ("discrete3",)


def _draw_plant(name: str, rng: np.random.Generator) -> tuple[dict[str, Any], float]:
    """A plant spec with random parameters and a proportional gain for a well-damped loop."""
    if name == "first-order":
        gain = float(rng.uniform(0.5, 2.0))
        spec = {
            "name": "first-order",
            "gain": gain,
            "time_constant": float(rng.uniform(1.0, 4.0)),
            "delay": int(rng.integers(1, 3)),
        }
        return spec, float(rng.uniform(0.5, 1.2)) / gain
    if name == "third-order":
        return {"name": "third-order", "delay": int(rng.integers(1, 3))}, float(
            rng.uniform(0.8, 1.2)
        )
    if name == "discrete":
        if rng.random() < 0.5:
            rad, ang = rng.uniform(0.75, 0.9), rng.uniform(0.2, 0.5)
            poles = [rad * np.exp(1j * ang), rad * np.exp(-1j * ang)]
        else:
            poles = list(np.sort(rng.uniform(0.5, 0.9, 2)))
        a = np.real(np.poly(poles))
        b = np.array([1.0, float(rng.uniform(0.2, 0.6))])
    else:  # discrete3: a slow real pole and a resonant pair
        rad, ang = rng.uniform(0.75, 0.9), rng.uniform(0.3, 0.7)
        poles = [rng.uniform(0.9, 0.97), rad * np.exp(1j * ang), rad * np.exp(-1j * ang)]
        a = np.real(np.poly(poles))
        b = np.array([1.0, float(rng.uniform(0.2, 0.6))])
    spec = {
        "name": "discrete",
        "a": [float(v) for v in a],
        "b": [float(v) for v in b],
        "delay": int(rng.integers(0, 3)),
    }
    # loop gain 0.3-0.6 at DC: the slow-rate loop sees p fast steps of the plant
    return spec, float(rng.uniform(0.3, 0.6) * np.sum(a) / np.sum(b))


class RandomLevels(Reference):
    """Random steps: levels uniform in ``[-amplitude, amplitude]`` held for a geometric number
    of slow periods (mean ``hold``), so that ``x`` visits its whole range (a binary reference
    leaves the middle of an actuator's characteristic unseen)."""

    name = "random-levels"

    def __init__(self, amplitude: float = 1.0, hold: float = 2.5) -> None:
        self.amplitude, self.hold, self.per_run = float(amplitude), float(hold), True

    def params(self) -> dict[str, Any]:
        return {"amplitude": self.amplitude, "hold": self.hold}

    def draw(self, rng: np.random.Generator, K: int) -> np.ndarray:
        out = np.empty(K)
        k = 0
        while k < K:
            n = int(rng.geometric(1.0 / self.hold))
            out[k : k + n] = rng.uniform(-self.amplitude, self.amplitude)
            k += n
        return out


class InjectedNoise(NoiseModel):
    """The output disturbance of a case: white or ARMA noise plus a drift and spikes.

    ``shape`` returns the disturbance itself (the scenario's ``sigma2`` is 1), so the effect's
    amplitudes are absolute.
    """

    name = "injected"

    def __init__(
        self, sigma: float, c: Any = (1.0,), d: Any = None, additive: np.ndarray | None = None
    ) -> None:
        self.sigma = float(sigma)
        self.c = np.asarray(c, float)
        self.d = None if d is None else np.asarray(d, float)
        self.additive = None if additive is None else np.asarray(additive, float)

    def params(self) -> dict[str, Any]:
        return {
            "sigma": self.sigma,
            "c": self.c.tolist(),
            "d": None if self.d is None else self.d.tolist(),
        }

    def filter(self, plant: DiscretePlant) -> tuple[np.ndarray, np.ndarray]:
        """``(c, d)``; ``d`` None means the plant's own ``A`` (ARX noise, the paper's eq. 2)."""
        return self.c, (plant.a if self.d is None else self.d)

    def shape(self, e: np.ndarray, plant: DiscretePlant) -> np.ndarray:
        v = self.sigma * super().shape(e, plant)
        if self.additive is not None:
            v = v + self.additive[None, : v.shape[1]]
        return v


@dataclass(frozen=True)
class Case:
    """One synthetic record's recipe (plain data; JSON-ready through :meth:`as_dict`)."""

    seed: int
    effect: str
    cls: str
    plant: dict[str, Any]
    kp: float
    p: int
    T: float
    K: int
    snr: float
    nl_params: dict[str, float] = field(default_factory=dict)
    effect_params: dict[str, Any] = field(default_factory=dict)

    @property
    def name(self) -> str:
        return f"case{self.seed:04d}_{self.effect}_{self.cls}"

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)


# --------------------------------------------------------------------------- drawing a case


def _spec(
    plant: dict[str, Any],
    kp: float,
    p: int,
    T: float,
    K: int,
    nl: dict[str, Any],
    noise: dict[str, Any],
) -> dict[str, Any]:
    spec = copy.deepcopy(scenarios.PAPER_SECTION6)
    spec.update(
        name="diagnose-case",
        plant=copy.deepcopy(plant),
        nonlinearity=nl,
        controller={"name": "p", "kp": kp},
        noise=noise,
        reference={"name": "rbs", "band": [0.0, 0.4], "amplitude": 1.0},  # replaced below
        T=T,
        p=p,
        duration=K * T,
    )
    return spec


def _pilot(
    plant: dict[str, Any], kp: float, p: int, T: float, K: int, seed: int
) -> tuple[np.ndarray, np.ndarray]:
    """``(x, y0)`` of the loop with a linear actuator and no noise."""
    spec = _spec(plant, kp, p, T, K, {"name": "linear"}, {"name": "white", "sigma2": 0.0})
    sc = scenarios.build(spec)
    sc.reference = RandomLevels()
    rec, truth = simulate(sc, 1, np.random.default_rng(seed))
    return rec.x[0], truth.y0[0]


def _radius(plant: dict[str, Any], kp: float, p: int, T: float) -> float:
    from hbench.sim.simulate import closed_loop_radius

    sc = scenarios.build(
        _spec(plant, kp, p, T, 10, {"name": "linear"}, {"name": "white", "sigma2": 0.0})
    )
    return closed_loop_radius(sc.discrete_plant, sc.controller, p)


def _nl_params(cls: str, x: np.ndarray, rng: np.random.Generator) -> dict[str, float]:
    lo, hi = np.percentile(x, [1, 99])
    rx = float(hi - lo)
    if cls == "linear":
        return {}
    if cls == "backlash":
        return {"d": rx * rng.uniform(0.2, 0.4)}
    if cls == "deadband":
        return {"d1": rx * rng.uniform(0.1, 0.2), "d2": rx * rng.uniform(0.1, 0.2)}
    if cls == "saturation":
        return {
            "u_min": float(np.quantile(x, rng.uniform(0.1, 0.25))),
            "u_max": float(np.quantile(x, rng.uniform(0.75, 0.9))),
        }
    if cls == "stiction":
        S = rx * rng.uniform(0.2, 0.4)
        return {"S": S, "J": S * rng.uniform(0.4, 0.8)}
    raise ValueError(cls)


def draw_case(seed: int, effect: str | None = None, cls: str | None = None) -> Case:
    """The case of ``seed``; ``effect`` and ``cls`` are drawn too unless given."""
    rng = np.random.default_rng(np.random.SeedSequence([20240601, seed]))
    effect = effect if effect is not None else EFFECTS[int(rng.integers(len(EFFECTS)))]
    cls = cls if cls is not None else CLASSES[int(rng.integers(len(CLASSES)))]
    if effect not in EFFECTS:
        raise ValueError(f"unknown effect {effect!r}")
    table = ORDER_PLANTS if effect == "order" else NOMINAL_PLANTS
    p = int(rng.choice([4, 5, 6]))
    T = 0.6
    K = int(rng.integers(800, 1001))
    for _ in range(20):  # redraw a plant whose loop is not stable enough
        plant, kp = _draw_plant(table[int(rng.integers(len(table)))], rng)
        if _radius(plant, kp, p, T) < 0.9:
            break
    snr = float(rng.uniform(10, 30))
    x, y0 = _pilot(plant, kp, p, T, K, seed)
    nl_params = _nl_params(cls, x, rng)
    s = float(np.std(y0))
    ep: dict[str, Any] = {}
    if effect == "colored-noise":
        snr = float(rng.uniform(1.5, 3.0))
        ep = {"d1": float(rng.uniform(0.85, 0.97)), "c1": float(rng.uniform(0.0, 0.5))}
    elif effect == "drift":
        ep = {"D": float(rng.choice([-1, 1]) * rng.uniform(1.5, 3.0) * s), "walk": 0.05}
    elif effect == "delay":
        ep = {"k": int(rng.integers(1, 4))}
    elif effect == "outliers":
        ep = {"share": float(rng.uniform(0.005, 0.015)), "amplitude": [3.0 * s, 6.0 * s]}
    elif effect == "time-varying":
        g = rng.uniform(1.8, 2.5) if rng.random() < 0.5 else rng.uniform(0.35, 0.55)
        ep = {
            "at": float(rng.uniform(0.3, 0.42)),
            "gain": float(g),
            "time_constant": float(rng.uniform(0.6, 0.8)),
        }
    ep["s"] = s
    return Case(
        seed=seed,
        effect=effect,
        cls=cls,
        plant=plant,
        kp=float(kp),
        p=p,
        T=T,
        K=K,
        snr=snr,
        nl_params=nl_params,
        effect_params=ep,
    )


# --------------------------------------------------------------------------- simulating a case


def _nl_spec(case: Case) -> dict[str, Any]:
    out: dict[str, Any] = {"name": case.cls, **case.nl_params}
    if case.cls in ("backlash", "stiction"):
        out["u0"] = None
    return out


def impulse_response(c: Any, d: Any, n: int = 4000) -> np.ndarray:
    """The first ``n`` terms of the impulse response of ``C(q) / D(q)``."""
    from scipy import signal as sps

    imp = np.zeros(n)
    imp[0] = 1.0
    return sps.lfilter(c, d, imp)


def filter_norm(c: Any, d: Any, n: int = 4000) -> float:
    """``||C/D||_2`` over the first ``n`` terms of the impulse response: the standard deviation
    of ``C/D e`` for unit white ``e``."""
    return float(np.linalg.norm(impulse_response(c, d, n)))


def additive_effect(
    effect: str, ep: dict[str, Any], N: int, rng: np.random.Generator
) -> np.ndarray:
    """What ``drift`` (a ramp ``D t / t_end`` plus a random walk reaching ``walk |D|``) and
    ``outliers`` (spikes of the given ``share`` of the samples, amplitudes in ``amplitude``,
    random sign, none in the first 50 samples) add to ``y``; zeros for the other effects."""
    add = np.zeros(N)
    if effect == "drift":
        t = np.arange(N) / N
        walk = np.cumsum(rng.standard_normal(N))
        walk = walk / max(float(np.max(np.abs(walk))), 1e-12) * ep["walk"] * abs(ep["D"])
        add = ep["D"] * t + walk
    elif effect == "outliers":
        n_out = max(round(ep["share"] * N), 3)
        at = rng.choice(np.arange(50, N), size=n_out, replace=False)
        lo, hi = ep["amplitude"]
        add[at] = rng.choice([-1.0, 1.0], n_out) * rng.uniform(lo, hi, n_out)
    return add


def write_truth(
    record: Record, name: str, truth: dict[str, Any], directory: Path | str, suffix: str = ".csv"
) -> Path:
    """Write ``record`` to ``directory`` as ``name + suffix`` and ``truth`` beside it as
    ``name.truth.json`` (a sidecar the diagnosis never reads)."""
    from hbench.io.readers import write_record

    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    path = write_record(record, directory / f"{name}{suffix}")
    (directory / f"{name}.truth.json").write_text(json.dumps(truth, indent=1))
    return path


def _noise(case: Case, N: int, rng: np.random.Generator, plant: DiscretePlant) -> InjectedNoise:
    ep, s = case.effect_params, case.effect_params["s"]
    c: tuple[float, ...] = (1.0,)
    d: tuple[float, ...] | None = None  # ARX: the plant's own A
    if case.effect == "colored-noise":
        # coloured equation noise: A v = (1 + c1 q^-1) / (1 - d1 q^-1) e
        c, d = (1.0, ep["c1"]), tuple(np.convolve([1.0, -ep["d1"]], plant.a))
    add = additive_effect(case.effect, ep, N, rng)
    # sigma so that the noise (without drift and spikes) has the case's SNR
    sigma = s / case.snr / filter_norm(c, plant.a if d is None else d)
    return InjectedNoise(sigma, c, d, add)


def _scenario(case: Case, noise: NoiseModel, plant: dict[str, Any] | None = None) -> Scenario:
    plant = copy.deepcopy(plant or case.plant)
    if case.effect == "delay":
        plant["delay"] = int(plant.get("delay", 0)) + case.effect_params["k"] * case.p
    spec = _spec(
        plant, case.kp, case.p, case.T, case.K, _nl_spec(case), {"name": "white", "sigma2": 1.0}
    )
    sc = scenarios.build(spec)
    sc.noise = noise
    sc.reference = RandomLevels()
    return sc


def _changed_plant(plant: DiscretePlant, gain: float, tc: float) -> DiscretePlant:
    """``plant`` with its gain times ``gain`` and the time constants of its poles times ``tc``."""
    poles = plant.poles
    new_poles = np.where(
        np.abs(poles) > 0, np.abs(poles) ** (1 / tc) * np.exp(1j * np.angle(poles) / tc), poles
    )
    a = np.real(np.poly(new_poles)) if poles.size else np.ones(1)
    b = plant.b * gain * np.sum(a) / np.sum(plant.a)  # DC gain times ``gain``
    return DiscretePlant(a=a, b=b, delay=plant.delay, h=plant.h, name=plant.name + "-changed")


def _simulate_switched(
    sc: Scenario, plant2: DiscretePlant, n_switch: int, rng: np.random.Generator
) -> Record:
    """The closed loop of ``sc`` with the plant replaced by ``plant2`` from slow sample
    ``n_switch`` on (the state vector carried over: same orders, same realisation). The noise
    is scaled by ``sc.sigma2`` as :func:`hbench.sim.simulate.simulate` scales it (the generator's
    own noise carries its level and has ``sigma2 = 1``); a scenario that sets its level by
    ``snr`` instead is refused."""
    from hbench.sim.seeding import run_streams

    if sc.sigma2 is None:
        raise ValueError("the switched loop needs a scenario with sigma2, not snr")
    p, K = sc.p, sc.K
    N = K * p
    streams = run_streams(rng, 1, ("reference", "noise"))
    r = sc.reference.generate(streams["reference"], K)
    e = np.stack([g.standard_normal(N) for g in streams["noise"]])
    v = np.sqrt(float(sc.sigma2)) * sc.noise.shape(e, sc.discrete_plant)
    lps = [LiftedPlant.from_plant(sc.discrete_plant, p), LiftedPlant.from_plant(plant2, p)]
    s = np.zeros((1, lps[0].Fp.shape[0]))
    cstate = sc.controller.initial_state(1)
    nstate = sc.nonlinearity.initial_state(1)
    y0 = np.empty((1, N))
    X = np.empty((1, K))
    for n in range(K):
        lp = lps[int(n >= n_switch)]
        yfast = s @ lp.Ob.T  # (1, p) before this period's input
        x, cstate = sc.controller.step(r[:, n] - (yfast[:, 0] + v[:, n * p]), cstate)
        u, nstate = sc.nonlinearity.step(x, nstate)
        y0[:, n * p : (n + 1) * p] = yfast + u[:, None] * lp.Db[None, :]
        X[:, n] = x
        s = s @ lp.Fp.T + u[:, None] * lp.Gp
    return Record(y=y0 + v, x=X, r=r, p=p, h=sc.h, source="simulation", meta={"scenario": sc.name})


def simulate_case(case: Case) -> Record:
    """The record of ``case`` (one run)."""
    rng = np.random.default_rng(np.random.SeedSequence([20240602, case.seed]))
    N = case.K * case.p
    sc = _scenario(case, InjectedNoise(0.0))
    sc.noise = _noise(case, N, rng, sc.discrete_plant)
    return simulate_effect(sc, case.effect, case.effect_params, case.K, rng)


def simulate_effect(
    sc: Scenario, effect: str, ep: dict[str, Any], K: int, rng: np.random.Generator
) -> Record:
    """One run of ``sc``; for ``time-varying`` the plant changes (gain times ``ep["gain"]``,
    time constants times ``ep["time_constant"]``) at the share ``ep["at"]`` of the ``K``
    slow samples."""
    if effect == "time-varying":
        plant2 = _changed_plant(sc.discrete_plant, ep["gain"], ep["time_constant"])
        return _simulate_switched(sc, plant2, int(ep["at"] * K), rng)
    record, _ = simulate(sc, 1, rng)
    return record


def write_case(case: Case, directory: Path | str, suffix: str = ".csv") -> Path:
    """Simulate ``case`` and write its record to ``directory``; the truth goes to a sidecar
    ``.truth.json`` that the diagnosis never reads."""
    return write_truth(simulate_case(case), case.name, case.as_dict(), directory, suffix)


def balanced_cases(n: int, start: int = 0) -> list[Case]:
    """``n`` cases cycling through every (effect, class) pair: seed ``start + i`` gets effect
    ``EFFECTS[i % 7]`` and class ``CLASSES[(i // 7) % 5]``."""
    return [
        draw_case(start + i, EFFECTS[i % len(EFFECTS)], CLASSES[(i // len(EFFECTS)) % len(CLASSES)])
        for i in range(n)
    ]


def cases_per_effect(
    per_effect: int, start: int = 0, effects: tuple[str, ...] = EFFECTS
) -> list[Case]:
    """``per_effect`` cases of every effect (``none`` included), seeds ``start, start + 1, ..``
    in turn, the class cycling through :data:`CLASSES`."""
    out = []
    i = 0
    for _ in range(per_effect):
        for effect in effects:
            out.append(draw_case(start + i, effect, CLASSES[i % len(CLASSES)]))
            i += 1
    return out


# --------------------------------------------------------------------------- p = 1 plant loops

#: Loop types of the plant-log-like records (``p = 1``, one sample per controller period).
LOOP_TYPES: tuple[str, ...] = ("flow", "pressure", "level", "slow")
#: Valve classes of the plant-log-like records.
LOOP_VALVES: tuple[str, ...] = ("linear", "stiction", "backlash", "deadband", "saturation")
#: Disturbance scenarios of the plant-log-like records, each with white measurement noise.
LOOP_DISTURBANCES: tuple[str, ...] = (
    "load",  # coloured (AR(1)) load disturbance at the process input
    "setpoint",  # random set-point moves (steps and a ramp)
    "external",  # a slow sinusoidal disturbance from outside the loop (not the valve)
    "drift",  # a slowly drifting operating point (random walk at the process input)
)


@dataclass(frozen=True)
class LoopCase:
    """One plant-log-like record's recipe (``p = 1``): a loop type, a PI controller, a valve and
    a disturbance scenario. Plain data (JSON-ready through :meth:`as_dict`).

    ``plant``: ``a`` (pole; 1 for an integrating level loop), ``k`` (gain, PV units per % of
    valve), ``delay`` (samples); ``pi``: ``kc``, ``ti`` (samples); ``valve``: the class and its
    parameters (% of valve travel); ``dist``: the scenario's parameters; ``quant``: the PV's
    measurement resolution (0: none).
    """

    seed: int
    loop: str
    cls: str
    disturbance: str
    plant: dict[str, float]
    pi: dict[str, float]
    valve: dict[str, float]
    dist: dict[str, float]
    noise: float
    quant: float
    K: int = 751

    @property
    def name(self) -> str:
        return f"loop{self.seed:04d}_{self.loop}_{self.cls}_{self.disturbance}"

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)


def draw_loop_case(
    seed: int, cls: str | None = None, loop: str | None = None, disturbance: str | None = None
) -> LoopCase:
    """The plant-log-like case of ``seed`` (``cls``, ``loop``, ``disturbance`` drawn unless given).

    Ranges (``Ts = 10 s``, 751 samples, OP in % of valve travel around 30-70 %):

    * ``flow``: first order, time constant 0.5-3 samples, delay 0-1; PI with ``ti`` 1-4 samples,
      loop gain ``kc k`` 0.2-0.8.
    * ``pressure``: first order, time constant 3-15 samples, delay 0-3; ``ti`` 3-20, ``kc k``
      0.3-1.5.
    * ``level``: integrating, ``k`` per sample; delay 0-2; ``ti`` 20-80, ``kc k`` 0.02-0.1.
    * ``slow``: first order, time constant 20-60 samples, delay 2-6; ``ti`` 15-60, ``kc k``
      0.3-1.
    * valves: ``stiction`` ``S`` 1-6 % and ``J / S`` 0.15-1 (clear of
      ``nominal.MIN_JUMP_SHARE``, 0.1, below which the chooser calls a stiction fit a
      backlash); ``backlash`` width 1-5 %; ``deadband`` of 1-3 % either side of the operating
      point; ``saturation`` at 1-5 % beyond the operating point on one side.
    * disturbances: ``load``: AR(1) at the process input, pole 0.9-0.99, standard deviation
      1-4 % of valve; ``setpoint``: steps every 50-250 samples of 0.5-3 % of valve equivalent
      plus a ramp; ``external``: a sinusoid of period 20-120 samples, amplitude 1-4 % of valve,
      at the process input, plus a weak AR(1) load; ``drift``: a random walk at the process
      input reaching 2-8 % of valve.
    * measurement: white noise of 0.2-1 % of valve equivalent on PV; quantised to 0.2-1 of that
      noise level in half the records.
    """
    rng = np.random.default_rng(np.random.SeedSequence([20250601, seed]))
    # always drawn, then overridden: a given class leaves the other parameters as drawn
    drawn = (
        LOOP_TYPES[int(rng.integers(len(LOOP_TYPES)))],
        LOOP_VALVES[int(rng.integers(len(LOOP_VALVES)))],
        LOOP_DISTURBANCES[int(rng.integers(len(LOOP_DISTURBANCES)))],
    )
    loop = loop if loop is not None else drawn[0]
    cls = cls if cls is not None else drawn[1]
    disturbance = disturbance if disturbance is not None else drawn[2]
    k = float(rng.uniform(0.3, 3.0))  # PV units per % of valve
    if loop == "flow":
        tau, delay = rng.uniform(0.5, 3.0), int(rng.integers(0, 2))
        ti, lg = rng.uniform(1.0, 4.0), rng.uniform(0.2, 0.8)
    elif loop == "pressure":
        tau, delay = rng.uniform(3.0, 15.0), int(rng.integers(0, 4))
        ti, lg = rng.uniform(3.0, 20.0), rng.uniform(0.3, 1.5)
    elif loop == "level":
        tau, delay = np.inf, int(rng.integers(0, 3))
        ti, lg = rng.uniform(20.0, 80.0), rng.uniform(0.02, 0.1)
    elif loop == "slow":
        tau, delay = rng.uniform(20.0, 60.0), int(rng.integers(2, 7))
        ti, lg = rng.uniform(15.0, 60.0), rng.uniform(0.3, 1.0)
    else:
        raise ValueError(f"unknown loop type {loop!r}")
    a = 1.0 if not np.isfinite(tau) else float(np.exp(-1.0 / tau))
    plant = {"a": a, "k": k, "delay": float(delay)}
    pi = {"kc": float(lg / k), "ti": float(ti)}
    if cls == "linear":
        valve: dict[str, float] = {}
    elif cls == "stiction":
        S = float(rng.uniform(1.0, 6.0))
        # J >= 0.15 S, clear of nominal.MIN_JUMP_SHARE (0.1): with no slip jump stiction is a
        # dead band (backlash), scored as such
        valve = {"S": S, "J": S * float(rng.uniform(0.15, 1.0))}
    elif cls == "backlash":
        valve = {"d": float(rng.uniform(1.0, 5.0))}
    elif cls == "deadband":
        valve = {"d1": float(rng.uniform(1.0, 3.0)), "d2": float(rng.uniform(1.0, 3.0))}
    elif cls == "saturation":
        valve = {"margin": float(rng.uniform(1.0, 5.0)), "side": float(rng.choice([-1.0, 1.0]))}
    else:
        raise ValueError(f"unknown valve class {cls!r}")
    if disturbance == "load":
        dist = {"pole": float(rng.uniform(0.9, 0.99)), "std": float(rng.uniform(1.0, 4.0))}
    elif disturbance == "setpoint":
        dist = {
            "every": float(rng.uniform(50, 250)),
            "step": float(rng.uniform(0.5, 3.0)),
            "ramp": float(rng.uniform(-3.0, 3.0)),
            "pole": 0.95,
            "std": float(rng.uniform(0.3, 1.0)),
        }
    elif disturbance == "external":
        dist = {
            "period": float(rng.uniform(20, 120)),
            "amplitude": float(rng.uniform(1.0, 4.0)),
            "pole": 0.95,
            "std": float(rng.uniform(0.2, 0.6)),
        }
    elif disturbance == "drift":
        dist = {"reach": float(rng.uniform(2.0, 8.0)), "pole": 0.95, "std": 0.3}
    else:
        raise ValueError(f"unknown disturbance {disturbance!r}")
    noise = float(rng.uniform(0.2, 1.0))
    quant = float(rng.uniform(0.2, 1.0)) * noise if rng.random() < 0.5 else 0.0
    return LoopCase(seed, loop, cls, disturbance, plant, pi, valve, dist, noise, quant)


def _ar1(rng: np.random.Generator, n: int, pole: float, std: float) -> np.ndarray:
    """An AR(1) series of stationary standard deviation ``std``."""
    from scipy import signal as sps

    e = rng.standard_normal(n) * std * np.sqrt(1 - pole**2)
    return sps.lfilter([1.0], [1.0, -pole], e)


def simulate_loop(case: LoopCase) -> Record:
    """The plant log of ``case``: ``x`` the controller output (OP, %), ``y`` the measured
    process variable, ``r`` the set point; ``p = 1``, ``h = 10 s``. The loop runs 300 samples
    before the log starts, so the log begins in steady operation."""
    return simulate_loop_truth(case)[0]


def simulate_loop_truth(case: LoopCase) -> tuple[Record, np.ndarray]:
    """:func:`simulate_loop`'s record and the valve position ``u`` over the log (never part of
    the record: a detector sees only what a plant historian logs)."""
    from hbench.model import nonlinearities as nls

    rng = np.random.default_rng(np.random.SeedSequence([20250602, case.seed]))
    warm = 300
    n = case.K + warm
    pl, pi, dist = case.plant, case.pi, case.dist
    a, k, delay = pl["a"], pl["k"], int(pl["delay"])
    op0 = float(rng.uniform(30.0, 70.0))
    # disturbances in % of valve at the process input; set point in PV units
    d_in = np.zeros(n)
    sp = np.zeros(n)
    t = np.arange(n)
    d_in += _ar1(rng, n, dist["pole"], dist["std"])
    if case.disturbance == "setpoint":
        level, k0 = 0.0, 0
        while k0 < n:
            sp[k0:] = level
            k0 += int(rng.geometric(1.0 / dist["every"]))
            level += float(rng.choice([-1.0, 1.0])) * dist["step"] * k
        sp += dist["ramp"] * k * np.clip((t - warm) / case.K, 0.0, 1.0)
    elif case.disturbance == "external":
        ph = rng.uniform(0, 2 * np.pi)
        d_in += dist["amplitude"] * np.sin(2 * np.pi * t / dist["period"] + ph)
    elif case.disturbance == "drift":
        w = np.cumsum(rng.standard_normal(n))
        w = w - w[warm]
        d_in += w / max(float(np.max(np.abs(w[warm:]))), 1e-12) * dist["reach"]
    valve: nls.Nonlinearity
    if case.cls == "stiction":
        valve = nls.Stiction(S=case.valve["S"], J=case.valve["J"], u0=op0)
    elif case.cls == "backlash":
        valve = nls.Backlash(d=case.valve["d"], u0=op0)
    else:
        valve = nls.Linear()
    state = valve.initial_state(1, np.array([op0]))
    y = np.zeros(n)  # deviation of PV from its operating value
    u_hist = np.full(n, op0)
    x = np.full(n, op0)
    noise = rng.standard_normal(n) * case.noise * k
    ym = np.zeros(n)
    e_prev = 0.0
    x_prev = op0
    for i in range(n):
        if i > 0:
            j = i - 1 - delay
            uj = u_hist[j] if j >= 0 else op0
            dj = d_in[j] if j >= 0 else 0.0
            if a >= 1.0:
                y[i] = y[i - 1] + k * (uj - op0 + dj)
            else:
                y[i] = a * y[i - 1] + k * (1 - a) * (uj - op0 + dj)
        ym[i] = y[i] + noise[i]
        if case.quant > 0:
            ym[i] = case.quant * k * np.round(ym[i] / (case.quant * k))
        e = sp[i] - ym[i]
        xi = x_prev + pi["kc"] * ((e - e_prev) + e / pi["ti"])
        xi = float(np.clip(xi, 0.0, 100.0))
        x[i] = xi
        e_prev, x_prev = e, xi
        if case.cls in ("stiction", "backlash"):
            ui, state = valve.step(np.array([xi]), state)
            u = float(ui[0])
        elif case.cls == "deadband":
            lo, hi = op0 - case.valve["d1"], op0 + case.valve["d2"]
            u = xi - float(np.clip(xi, lo, hi)) + op0
        elif case.cls == "saturation":
            lim = op0 + case.valve["side"] * case.valve["margin"]
            u = min(xi, lim) if case.valve["side"] > 0 else max(xi, lim)
        else:
            u = xi
        u_hist[i] = u
    pv0 = float(rng.uniform(10.0, 100.0))
    sl = slice(warm, n)
    record = Record(
        y=(pv0 + ym[sl])[None, :],
        x=x[sl][None, :],
        r=(pv0 + sp[sl])[None, :],
        p=1,
        h=10.0,
        source=case.name,
        meta={"case": case.as_dict()},
    )
    return record, u_hist[sl].copy()


def loop_cases(n: int, start: int = 0) -> list[LoopCase]:
    """``n`` plant-log-like cases, seed ``start + i``: the valve cycles with ``stiction`` every
    other record (the others in turn through the rest of :data:`LOOP_VALVES`), then the loop
    type every 8 records and the disturbance every 32 (every combination in 128 records)."""
    valves = (
        "stiction",
        "linear",
        "stiction",
        "backlash",
        "stiction",
        "deadband",
        "stiction",
        "saturation",
    )
    out = []
    for i in range(n):
        out.append(
            draw_loop_case(
                start + i,
                valves[i % len(valves)],
                LOOP_TYPES[(i // 8) % len(LOOP_TYPES)],
                LOOP_DISTURBANCES[(i // 32) % len(LOOP_DISTURBANCES)],
            )
        )
    return out

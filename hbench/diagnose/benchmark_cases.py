"""Synthetic records of the benchmark's own loops, with one hidden effect, for ``hbench diagnose``.

:mod:`hbench.diagnose.generator` draws fast loops (first-order and discrete second-order plants
under P control). The sweeps and the paper live elsewhere: the paper's Section 6 loop (a plant
with poles at 0.97 and 0.99 at h = 0.12 s, DC gain 55), and the built-in ``first-order``,
``third-order`` and ``nmp`` plants, under P or PI control. This module draws records there.

A *benchmark case* (:class:`BenchCase`) is drawn from a seed (:func:`draw_bench_case`):

* plant: ``paper`` (Section 6), ``first-order`` (gain 0.5-2, time constant 1-4 s), ``third-order``,
  ``nmp``, with their built-in fast-sample delays;
* ``p``: 5 or 8 for ``paper`` (its delay of 0.36 s is 3 fast samples at p = 5), one of 3, 4, 5, 8
  for the others; ``T = 0.6 s``, 500 s (833 slow samples), the paper's reference (RBS, band
  [0, 0.3], amplitude 1);
* controller: P or PI (half each), gains drawn around each plant's reference gain
  (:data:`KP_REF`) and redrawn until the slow-rate closed loop's spectral radius is below
  :data:`MAX_RADIUS` with the nominal plant and the plants the effect makes of it;
* noise: the plant's own process noise, white noise through ``1 / den(s)`` discretised by ZOH
  (``C(q) / A(q) e``, the paper's noise for the paper plant), at ``sigma^2`` log-uniform in
  [1e-4, 1e-2]. For the paper plant ``sigma^2`` is the paper's own; for the others the noise is
  scaled to the SNR the paper's loop has at that ``sigma^2`` (:func:`paper_snr`, from the
  paper's Tables 4 and 5), so every plant sees the same range of difficulty;
* the valve, with parameters in units of the range ``r_x`` of ``x`` (1st-99th percentile) of a
  linear pilot run, scaled from the paper loop's ranges (:data:`R_X_PAPER`): backlash width
  0.02-0.2, stiction ``S`` 0.05-0.3 (at most half of ``r_x``) with ``J / S`` 0.1-1, dead zone
  0.05-0.2 wide, all on the paper loop's x scale; saturation clipping 5-30 % of the samples of
  ``x``; redrawn until the valve moves in the record (:func:`valve_moves`): a valve held at
  rest for the whole record (under P control a sticking band wider than the excursions of
  ``x`` holds it there) leaves an output of noise alone, in which neither the class nor the
  effect on the plant can be seen;
* ONE effect, or none:

  - ``colored-noise``: noise with dynamics of its own (Box-Jenkins, ``C / D e`` with
    ``D != A``) added to the nominal noise: ``(1 + c1 q^-1) / (1 - d1 q^-1)``, ``d1`` in
    [0.85, 0.97], ``c1`` in [0, 0.5], its standard deviation ``s / snr`` with ``snr`` 1.5-3;
  - ``drift``: a ramp ``D t / t_end`` plus a random walk of 5 % of ``D`` added to ``y`` (inside
    the loop), ``|D|`` in [1.5, 3] ``s``;
  - ``delay``: the plant's delay grows by ``k p`` fast samples, ``k`` in {1, 2, 3};
  - ``outliers``: spikes on 0.5-1.5 % of the fast samples, 3-6 ``s``, random sign;
  - ``time-varying``: at 30-42 % of the record the plant's gain is multiplied by 1.8-2.5 or
    0.35-0.55 and its time constants by 0.6-0.8;
  - ``order``: extra first-order lags (time constant 1-3 s) until the plant has three poles.

  ``s`` is the standard deviation of the noise-free output of the linear pilot run.

Seeds: :data:`CALIBRATION_SEEDS` choose thresholds and levels; :data:`HELD_OUT_SEEDS` measure,
and are never used to choose anything.
"""

from __future__ import annotations

import copy
import warnings
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
from scipy import signal

from hbench.diagnose.generator import (
    CLASSES,
    EFFECTS,
    InjectedNoise,
    _changed_plant,
    additive_effect,
    filter_norm,
    simulate_effect,
    write_truth,
)
from hbench.model.controllers import PI, P
from hbench.model.noise import ContinuousFilter
from hbench.model.plants import BUILTIN as PLANTS
from hbench.model.plants import ContinuousPlant
from hbench.sim import scenarios
from hbench.sim.records import Record
from hbench.sim.simulate import Scenario, ZeroOutputWarning, closed_loop_radius, simulate

#: The plants of the benchmark (the paper's first).
BENCH_PLANTS: tuple[str, ...] = ("paper", "first-order", "third-order", "nmp")
#: Seeds that choose (thresholds, margins); never used to measure.
CALIBRATION_SEEDS: range = range(10_000, 20_000)
#: Seeds that measure; never used to choose anything.
HELD_OUT_SEEDS: range = range(20_000, 30_000)
#: Proportional gains around which a case's gain is drawn (x 0.5-1.5): the paper's 0.1 for its
#: plant, a DC loop gain of about 1 for the others.
KP_REF: dict[str, float] = {"paper": 0.1, "first-order": 1.0, "third-order": 1.0, "nmp": 0.35}
#: Range of x (1st-99th percentile) of the paper's loop with a linear valve: the issue's
#: parameter ranges are stated on this scale.
R_X_PAPER = 0.41
#: The paper's SNR column (Tables 4 and 5) at its noise levels.
_PAPER_SNR = ((1e-4, 16.2627), (5e-4, 7.2287), (1e-3, 5.1003), (5e-3, 2.4956), (1e-2, 1.8889))


def paper_snr(sigma2: float) -> float:
    """The paper loop's SNR at noise variance ``sigma2``: log-log interpolation of the paper's
    SNR column, extrapolated linearly in logs beyond it."""
    ls = np.log([s for s, _ in _PAPER_SNR])
    lr = np.log([r for _, r in _PAPER_SNR])
    x = np.log(float(sigma2))
    if x <= ls[0] or x >= ls[-1]:
        i = (0, 1) if x <= ls[0] else (-2, -1)
        slope = (lr[i[1]] - lr[i[0]]) / (ls[i[1]] - ls[i[0]])
        return float(np.exp(lr[i[0]] + slope * (x - ls[i[0]])))
    return float(np.exp(np.interp(x, ls, lr)))


@dataclass(frozen=True)
class BenchCase:
    """One benchmark record's recipe (plain data; JSON-ready through :meth:`as_dict`)."""

    seed: int
    effect: str
    cls: str
    plant: str
    p: int
    controller: dict[str, Any]
    sigma2: float
    K: int = 833
    T: float = 0.6
    nl_params: dict[str, float] = field(default_factory=dict)
    effect_params: dict[str, Any] = field(default_factory=dict)
    noise_sigma: float = 0.0

    @property
    def name(self) -> str:
        return f"bench{self.seed:05d}_{self.plant}_{self.effect}_{self.cls}"

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)


def _plant(name: str, rng: np.random.Generator | None = None) -> ContinuousPlant:
    if name == "first-order" and rng is not None:
        return PLANTS["first-order"](
            gain=float(rng.uniform(0.5, 2.0)), time_constant=float(rng.uniform(1.0, 4.0))
        )
    return PLANTS[name]()


def _with_lags(plant: ContinuousPlant, taus: list[float]) -> ContinuousPlant:
    den = np.asarray(plant.den, float)
    for tau in taus:
        den = np.convolve(den, [tau, 1.0])
    return ContinuousPlant(plant.num, tuple(float(v) for v in den), plant.delay, 0.0, plant.name)


def _spec(case: BenchCase, nl: dict[str, Any]) -> dict[str, Any]:
    spec = copy.deepcopy(scenarios.PAPER_SECTION6)
    spec.update(
        name="diagnose-bench-case",
        nonlinearity=nl,
        controller={"name": "p", "kp": 0.1},
        noise={"name": "white", "sigma2": 1.0},
        T=case.T,
        p=case.p,
        duration=case.K * case.T,
    )
    return spec


def _scenario(case: BenchCase, plant: ContinuousPlant, nl: dict[str, Any]) -> Scenario:
    sc = scenarios.build(_spec(case, nl))
    sc.plant = plant
    c = case.controller
    sc.controller = P(c["kp"]) if c["name"] == "p" else PI(c["kp"], c["ki"], case.T)
    return sc


def noise_filter(plant: ContinuousPlant, at: Any) -> tuple[np.ndarray, np.ndarray]:
    """``(C, A)``: white noise through ``1 / den(s)`` of ``plant``, ZOH at the fast period of
    ``at`` (a discrete plant)."""
    return ContinuousFilter((1.0,), plant.den).filter(at)


#: The slow-rate closed loop (actuator as unit gain) must have a spectral radius below this.
MAX_RADIUS = 0.99


def _draw_controller(
    name: str, plants: list[Any], p: int, rng: np.random.Generator
) -> dict[str, Any]:
    """A P or PI controller whose slow-rate loop has spectral radius below :data:`MAX_RADIUS`
    with every one of ``plants`` (discrete: the nominal plant and the plants an effect makes of
    it); gains shrink after every 10 draws that fail, and a PI that keeps failing becomes P."""
    pi = bool(rng.random() < 0.5)
    spec: dict[str, Any] = {}
    shrink = 1.0
    for attempt in range(60):
        if attempt and attempt % 10 == 0:
            shrink *= 0.6
        if attempt == 30:
            pi = False
        kp = shrink * KP_REF[name] * float(rng.uniform(0.5, 1.5))
        spec = {"name": "p", "kp": kp}
        ctl: P | PI = P(kp)
        if pi:
            ti = float(rng.uniform(5.0, 20.0))  # integral time in seconds
            spec = {"name": "pi", "kp": kp, "ki": kp / ti}
            ctl = PI(kp, kp / ti, 0.6)
        if all(closed_loop_radius(dp, ctl, p) < MAX_RADIUS for dp in plants):
            return spec
    raise RuntimeError(f"no stable controller found for the {name} plant at p = {p}")


def _nl_params(cls: str, x: np.ndarray, rng: np.random.Generator) -> dict[str, float]:
    lo, hi = np.percentile(x, [1, 99])
    scale = float(hi - lo) / R_X_PAPER  # the ranges are on the paper loop's x scale
    if cls == "linear":
        return {}
    if cls == "backlash":
        return {"d": scale * float(rng.uniform(0.02, 0.2))}
    if cls == "deadband":
        width = scale * float(rng.uniform(0.05, 0.2))
        share = float(rng.uniform(0.3, 0.7))
        return {"d1": width * share, "d2": width * (1 - share)}
    if cls == "saturation":
        clip = float(rng.uniform(0.05, 0.3))
        low = clip * float(rng.uniform(0.3, 0.7))
        return {
            "u_min": float(np.quantile(x, low)),
            "u_max": float(np.quantile(x, 1 - (clip - low))),
        }
    if cls == "stiction":
        # at most half the range of x: a larger band leaves a valve that hardly ever moves
        S = min(scale * float(rng.uniform(0.05, 0.3)), 0.5 * (hi - lo))
        return {"S": S, "J": S * float(rng.uniform(0.1, 1.0))}
    raise ValueError(cls)


def _pilot(case: BenchCase, plant: ContinuousPlant) -> tuple[np.ndarray, np.ndarray]:
    """``(x, y0)`` of the loop with a linear valve and no noise."""
    sc = _scenario(case, plant, {"name": "linear"})
    sc.sigma2 = 0.0
    rec, truth = simulate(
        sc, 1, np.random.default_rng(np.random.SeedSequence([20261127, case.seed]))
    )
    return rec.x[0], truth.y0[0]


#: Draws of the valve's parameters tried before :func:`draw_bench_case` gives up on a seed.
MAX_VALVE_DRAWS = 20


def draw_bench_case(
    seed: int, effect: str | None = None, cls: str | None = None, plant: str | None = None
) -> BenchCase:
    """The benchmark case of ``seed``; ``effect``, ``cls`` and ``plant`` drawn unless given
    (drawn always, then overridden, so a given one leaves the rest as drawn)."""
    rng = np.random.default_rng(np.random.SeedSequence([20261126, seed]))
    drawn = (
        EFFECTS[int(rng.integers(len(EFFECTS)))],
        CLASSES[int(rng.integers(len(CLASSES)))],
        BENCH_PLANTS[int(rng.integers(len(BENCH_PLANTS)))],
    )
    effect = effect if effect is not None else drawn[0]
    cls = cls if cls is not None else drawn[1]
    plant = plant if plant is not None else drawn[2]
    if effect not in EFFECTS:
        raise ValueError(f"unknown effect {effect!r}")
    if plant not in BENCH_PLANTS:
        raise ValueError(f"unknown benchmark plant {plant!r}")
    p = int(rng.choice([5, 8])) if plant == "paper" else int(rng.choice([3, 4, 5, 8]))
    base = _plant(plant, rng)
    ep: dict[str, Any] = {"plant_den": list(base.den), "plant_num": list(base.num)}
    sigma2 = float(10 ** rng.uniform(-4, -2))
    # the effect's parameters that shape the loop (the amplitudes follow the pilot run)
    if effect == "colored-noise":
        ep.update(
            d1=float(rng.uniform(0.85, 0.97)),
            c1=float(rng.uniform(0.0, 0.5)),
            snr=float(rng.uniform(1.5, 3.0)),
        )
    elif effect == "delay":
        ep.update(k=int(rng.integers(1, 4)))
    elif effect == "time-varying":
        g = rng.uniform(1.8, 2.5) if rng.random() < 0.5 else rng.uniform(0.35, 0.55)
        ep.update(
            at=float(rng.uniform(0.3, 0.42)),
            gain=float(g),
            time_constant=float(rng.uniform(0.6, 0.8)),
        )
    elif effect == "order":
        n_lags = max(3 - (len(base.den) - 1), 1)
        ep.update(taus=[float(v) for v in rng.uniform(1.0, 3.0, n_lags)])
    draft = BenchCase(
        seed, effect, cls, plant, p, {"name": "p", "kp": 0.0}, sigma2, effect_params=ep
    )
    h = draft.T / p
    loops = [base.discretize(h), case_plant(draft).discretize(h)]
    if effect == "time-varying":
        loops.append(_changed_plant(loops[0], ep["gain"], ep["time_constant"]))
    ctl = _draw_controller(plant, loops, p, rng)
    case = BenchCase(seed, effect, cls, plant, p, ctl, sigma2, effect_params=ep)
    x, y0 = _pilot(case, base)
    s = float(np.std(y0))
    nl_params = _nl_params(cls, x, rng)
    ep["s"] = s
    if effect == "drift":
        ep.update(D=float(rng.choice([-1, 1]) * rng.uniform(1.5, 3.0) * s), walk=0.05)
    elif effect == "outliers":
        ep.update(share=float(rng.uniform(0.005, 0.015)), amplitude=[3.0 * s, 6.0 * s])
    # the nominal noise's level: the paper's sigma^2 on its plant, the paper's SNR elsewhere
    c, d = noise_filter(base, loops[0])
    sigma = np.sqrt(sigma2) if plant == "paper" else s / paper_snr(sigma2) / filter_norm(c, d, 8000)
    case = BenchCase(
        seed,
        effect,
        cls,
        plant,
        p,
        ctl,
        sigma2,
        nl_params=nl_params,
        effect_params=ep,
        noise_sigma=float(sigma),
    )
    attempt = 0
    while not valve_moves(case):
        attempt += 1
        if attempt == MAX_VALVE_DRAWS:
            raise RuntimeError(
                f"benchmark case {seed} ({plant}, {effect}): the {cls} valve stays at rest "
                f"in {MAX_VALVE_DRAWS} draws of its parameters"
            )
        # the valve's parameters alone, from a stream of their own: the rest of the case (and
        # every case whose valve moves at its first draw) is as drawn
        again = np.random.default_rng(np.random.SeedSequence([20261126, seed, attempt]))
        case = replace(case, nl_params=_nl_params(cls, x, again))
    return case


def valve_moves(case: BenchCase) -> bool:
    """Whether the valve's output ``u`` changes over the record of ``case``: the valve run on
    the record's ``x`` from the state the simulation starts it in (deterministic, so this is
    the record's own ``u``)."""
    if case.cls == "linear":
        return True
    valve = _scenario(case, case_plant(case), _nl_spec(case)).nonlinearity
    with warnings.catch_warnings():  # a valve at rest is what this asks, not news
        warnings.simplefilter("ignore", ZeroOutputWarning)
        x = simulate_bench_case(case).x[:1]
    u, _ = valve.apply(x, valve.initial_state(1))
    return bool(np.ptp(u) > 0)


def _nl_spec(case: BenchCase) -> dict[str, Any]:
    out: dict[str, Any] = {"name": case.cls, **case.nl_params}
    if case.cls in ("backlash", "stiction"):
        out["u0"] = None
    return out


def nominal_plant(case: BenchCase) -> ContinuousPlant:
    """The plant the case was drawn with, before any effect changes it."""
    ep = case.effect_params
    return ContinuousPlant(
        tuple(ep["plant_num"]), tuple(ep["plant_den"]), PLANTS[case.plant]().delay, 0.0, case.plant
    )


def case_plant(case: BenchCase) -> ContinuousPlant:
    """The plant that generates the record (with the ``order`` effect's lags and the ``delay``
    effect's extra delay)."""
    ep = case.effect_params
    base = nominal_plant(case)
    if case.effect == "order":
        base = _with_lags(base, list(ep["taus"]))
    if case.effect == "delay":
        base = ContinuousPlant(
            base.num, base.den, int(base.delay or 0) + ep["k"] * case.p, 0.0, base.name
        )
    return base


def simulate_bench_case(case: BenchCase) -> Record:
    """The record of ``case`` (one run)."""
    rng = np.random.default_rng(np.random.SeedSequence([20261128, case.seed]))
    ep = case.effect_params
    N = case.K * case.p
    sc = _scenario(case, case_plant(case), _nl_spec(case))
    # the nominal noise: the nominal plant's own process noise (an extra lag or delay of the
    # plant is the effect, not the noise's)
    c, d = noise_filter(nominal_plant(case), sc.discrete_plant)
    if case.effect == "colored-noise":
        cc, dd = (1.0, ep["c1"]), (1.0, -ep["d1"])
        col = signal.lfilter(cc, dd, rng.standard_normal(N))
        add = col * (ep["s"] / ep["snr"]) / max(float(np.std(col)), 1e-300)
    else:
        add = additive_effect(case.effect, ep, N, rng)
    sc.noise = InjectedNoise(case.noise_sigma, c, d, add)
    sc.sigma2 = 1.0
    return simulate_effect(sc, case.effect, ep, case.K, rng)


def write_bench_case(case: BenchCase, directory: Path | str, suffix: str = ".csv") -> Path:
    """Simulate ``case`` and write its record to ``directory``; the truth goes to a sidecar
    ``.truth.json`` that the diagnosis never reads."""
    return write_truth(simulate_bench_case(case), case.name, case.as_dict(), directory, suffix)


def bench_grid(
    start: int,
    seeds_per_cell: int,
    plants: tuple[str, ...] = BENCH_PLANTS,
    effects: tuple[str, ...] = EFFECTS,
    classes: tuple[str, ...] = CLASSES,
) -> list[BenchCase]:
    """Every (plant, class, effect) cell ``seeds_per_cell`` times, seeds from ``start`` on
    (consecutive, in the order plant, class, effect, repeat)."""
    out = []
    seed = start
    for plant in plants:
        for cls in classes:
            for effect in effects:
                for _ in range(seeds_per_cell):
                    out.append(draw_bench_case(seed, effect, cls, plant))
                    seed += 1
    return out

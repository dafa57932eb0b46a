"""Steps 2-4 of the workflow: residual tests, the cause, and the validation gain.

The record is split into a fit part (the first ``fit_fraction``, default 2/3) and a validation
part (the rest). The nominal model and every extension are fitted on the fit part only and
scored on the validation part, ``fit = 100 (1 - ||y - y_hat|| / ||y - mean y||)`` there, under
one stated criterion (:class:`Criterion`, the JSON's ``criterion``):

* ``simulation``: ``y_hat`` simulated from the measured ``x`` over the whole record;
* ``prediction-K``: ``y_hat(t | t - K)``, the K-step-ahead prediction with the model's noise
  model (MATLAB's ``compare(data, sys, K)``);
* ``closed-loop`` (a record that carries ``r``): the loop re-simulated from ``r`` with the
  model in place of the valve and the plant and the controller identified from ``(r - y, x)``
  (:mod:`hbench.diagnose.loop`).

The default (``auto``) is ``simulation``; the report also shows the ``prediction-K`` fit with K
the dominant time constant of the nominal noise model ``1 / A`` in fast samples
(:func:`dominant_horizon`; ``--criterion prediction`` chooses on it) and the ``closed-loop``
fit (``--criterion closed-loop`` chooses on it). The closed-loop fit names the cause less often
than the simulation on the benchmark loops' calibration seeds (README.md's `--criterion` item
gives the counts): a PI loop rejects the drift extension's output ramp as the real loop
rejected the drift, and a wrong model can make the re-simulated loop unstable. On a slow plant (the
paper's: poles 0.97 and 0.99) the simulation error holds the realisation of the process noise
that the loop has cancelled, integrated by the plant's poles; the prediction removes what the
noise model explains up to ``t - K``. Yet for naming the cause the simulation is the better
criterion on the benchmark loops' calibration seeds: most catalogued effects (drift, a delay, a
change of the plant, a missing pole) act at the low frequencies that a K-step predictor forgives
(``docs/experiments/diagnose-benchmark-loops.md``).

The cause (``rule``, :data:`CAUSE_RULES`): every registered effect's detector runs on what the
nominal model leaves on the fit part, and every effect's extension is fitted (``validation``, the
default for ``p >= 2``) or only the fired detectors' (``detectors``, the default for a plant log).
Under ``validation`` the candidates are the fired effects whose extension gains at least
``MIN_GAIN["validation"]`` points of validation fit, and any effect whose extension gains at
least :data:`MIN_GAIN_UNDETECTED` on the whole validation part and on each of its two halves
(a gain its detector missed, which must persist: :data:`HALVES`, :func:`clears`) except those
of :data:`DETECTED_ONLY` (``colored-noise``, whose refit of the dynamics gains on many records:
it needs its detector); under ``detectors``, the fired effects gaining
``MIN_GAIN["detectors"]``.
The cause is the candidate that gains the most (with one parsimony rule, :data:`PARSIMONY`: a
noise model that gains nearly as much as one more pole is preferred to it, whether or not its
detector fired; with its detector quiet, it must also gain ``MIN_GAIN["validation"]`` on each
half). With no candidate:
``none`` when the nominal model explains the validation part better than its mean (fit above
:data:`NONE_MIN_FIT`), else ``unexplained``;
under ``detectors`` also ``unexplained`` when a detector fired but no extension gained.
``extended_fit`` is the cause's extended model's fit (the nominal's for ``none`` and
``unexplained``) and ``gain = extended_fit - baseline_fit``.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy import signal

from hbench.diagnose import classes, core
from hbench.diagnose import nominal as nm
from hbench.diagnose.effects import BUILTIN, Detection, Effect
from hbench.diagnose.loop import (
    LoopController,
    controller_error,
    identify_controller,
    simulate_loop,
)
from hbench.errors import InputError
from hbench.sim.records import Record
from hbench.system import runtime

#: The contract's effect names, in the order the JSON lists them.
CONTRACT_EFFECTS: tuple[str, ...] = (
    "colored-noise",
    "drift",
    "delay",
    "outliers",
    "time-varying",
    "order",
)
#: How the cause is chosen (:func:`diagnose`'s ``rule``).
CAUSE_RULES: tuple[str, ...] = ("validation", "detectors")
#: An extension must add at least this many points of validation fit to be the cause, per
#: rule (the ``validation`` rule's fired extensions; ``detectors``: every candidate).
MIN_GAIN: dict[str, float] = {"validation": 2.0, "detectors": 0.5}
#: ``validation`` rule: an extension whose detector stayed quiet is a candidate when it gains
#: at least this many points (a gain the detector missed), on the whole validation part and on
#: each of its halves (:data:`HALVES`).
MIN_GAIN_UNDETECTED = 20.0
#: Effects that are candidates only when their detector fired (never through
#: :data:`MIN_GAIN_UNDETECTED`): the colored-noise extensions re-fit the nominal's dynamics
#: from ``x`` to ``y``, which gains on many records whose blind nominal simulates worse than
#: such a fit, whatever their effect; its gain alone is no evidence of coloured noise. (The
#: :data:`PARSIMONY` rule still weighs such an extension against one more pole.)
DETECTED_ONLY: tuple[str, ...] = ("colored-noise",)
#: ``validation`` rule: an extension whose detector stayed quiet is a candidate only when it
#: gains :data:`MIN_GAIN_UNDETECTED` on each half of the validation part as well as on the whole
#: (the first and the second half in time, each fit against that half's own mean): its gain is
#: its only evidence, and a model that fits one stretch of the record better and the other
#: worse has found nothing that persists. On a slow loop, where the noise fed back and
#: integrated by the plant is much of the output, an extension can gain on the whole validation
#: part by fitting that noise. A fired detector is evidence of its own: its extension needs the
#: gain on the whole only (asked of every candidate, the rule lost more records with an effect
#: than it saved records without one: ``docs/experiments/validation-halves.md``). The same holds
#: for the simpler extension of :data:`PARSIMONY`: with its detector quiet, its 2 points on each
#: half too.
HALVES = True
#: ``none`` needs a nominal validation fit above this (%): better than the validation mean.
#: Not tuned; no nominal calibration record (seeds 5000-5199) has a fit below 43 %.
NONE_MIN_FIT = 0.0
#: Parsimony: (simpler, richer, share): when the richer extension is the best but the simpler
#: one gains at least ``share`` of its gain, the simpler is the cause. A noise model changes
#: nothing of the plant, one more pole does; and the pole of coloured equation noise passes
#: the order test too, where the two extensions then gain about the same.
PARSIMONY: tuple[tuple[str, str, float], ...] = (("colored-noise", "order", 0.8),)
#: The criterion ``auto`` chooses for a record that carries ``r`` (``p >= 2``): chosen on the
#: benchmark loops' calibration seeds (paper loop from 10000, other plants from 11000, one
#: record per cell), where the simulation names the cause more often than the closed-loop
#: re-simulation (``docs/experiments/diagnose-benchmark-loops.md``, section 4).
DEFAULT_CRITERION = "simulation"


@dataclass
class Extension:
    """An effect's extended model and its validation fit."""

    name: str
    model: core.Model | None
    val_fit: float
    error: str = ""
    #: The validation fit under every criterion the report shows (``simulation``,
    #: ``prediction-K``), the chosen one among them.
    fits: dict[str, float] = field(default_factory=dict)
    #: The chosen criterion's fit on the first and on the second half of the validation part
    #: (:func:`half_fits`); ``None``: not measured (then :func:`clears` reads the whole only).
    halves: tuple[float, float] | None = None
    #: Whether the effect's detector fired (the halves are read only where not:
    #: :func:`unread_halves`).
    detected: bool = False


@dataclass
class Diagnosis:
    """Everything ``hbench diagnose`` found about one record."""

    source: str
    ctx: nm.Context
    nominal: nm.Nominal
    detections: list[Detection]
    extensions: dict[str, Extension]
    cause: str
    baseline_fit: float
    extended_fit: float
    extended: core.Model
    seconds: float = 0.0
    info: dict[str, Any] = field(default_factory=dict)
    #: The criterion the cause was chosen on and ``baseline_fit``/``extended_fit`` measured
    #: with (``simulation``, ``prediction-K``).
    criterion: str = "simulation"
    #: The nominal's and the extended model's validation fits under every criterion shown.
    fits: dict[str, dict[str, float]] = field(default_factory=dict)
    #: How the cause was chosen (:data:`CAUSE_RULES`).
    rule: str = "validation"
    #: The nominal's fit on the two halves of the validation part (:attr:`Extension.halves`).
    baseline_halves: tuple[float, float] | None = None

    @property
    def gain(self) -> float:
        return self.extended_fit - self.baseline_fit

    def set_aside(self) -> list[tuple[Extension, tuple[float, float]]]:
        """The extensions the ``validation`` rule set aside for their halves alone: detector
        quiet, not of :data:`DETECTED_ONLY`, :data:`MIN_GAIN_UNDETECTED` gained on the whole
        validation part but not on each half; with their gains on the two halves."""
        if self.rule != "validation":
            return []
        out = []
        for e in self.extensions.values():
            h = half_gains(e, self.baseline_halves)
            if (
                e.name in DETECTED_ONLY
                or h is None
                or not clears(e, self.baseline_fit, None, MIN_GAIN_UNDETECTED)
                or clears(e, self.baseline_fit, self.baseline_halves, MIN_GAIN_UNDETECTED)
            ):
                continue
            out.append((e, h))
        return out

    @property
    def why(self) -> str:
        """One line: why the cause is what it is."""
        fired = [d.name for d in self.detections if d.fired]
        g, crit = MIN_GAIN[self.rule], self.criterion
        fired_note = f"; fired: {', '.join(fired)}" if fired else "; no detector fired"
        if not np.isfinite(self.baseline_fit):
            return (
                f"the nominal model's {crit} fit is {format_fit(self.baseline_fit)}: no "
                f"extension's gain can be measured against it{fired_note}"
            )
        if self.rule == "validation":
            where = " on the whole validation part and on each of its halves" if HALVES else ""
            missed = (
                f"no fired detector's extension gains {g:g} points of {crit} fit and no other "
                f"gains {MIN_GAIN_UNDETECTED:g}{where}"
            )
            aside = self.set_aside()
            aside_note = (
                "; set aside, their detectors quiet and their gains not on both halves: "
                + ", ".join(
                    f"{e.name} ({e.val_fit - self.baseline_fit:+.1f}; halves {h[0]:+.1f} / "
                    f"{h[1]:+.1f})"
                    for e, h in aside
                )
                if aside
                else ""
            )
            if self.cause == "none":
                return (
                    f"{missed}; the nominal model ({format_fit(self.baseline_fit)}) explains the "
                    f"validation part better than its mean{fired_note}{aside_note}"
                )
            if self.cause == "unexplained":
                return (
                    f"{missed}, and the nominal model's fit ({format_fit(self.baseline_fit)}) "
                    f"is no better than the validation part's mean{fired_note}{aside_note}"
                )
            det = next((d for d in self.detections if d.name == self.cause), None)
            said = "" if det is None else f" (its detector: {'fired' if det.fired else 'quiet'})"
            return (
                f"{self.cause}'s extension gains the most {crit} fit among the candidates, "
                f"{self.gain:+.1f} points{said}{aside_note}"
            )
        if self.cause == "none":
            return (
                f"no detector fired, and the nominal model explains the validation part "
                f"({crit} fit {format_fit(self.baseline_fit)})"
            )
        if self.cause == "unexplained" and not fired:
            return (
                f"no detector fired, but the nominal model's {crit} fit "
                f"({format_fit(self.baseline_fit)}) is no better than the validation part's mean"
            )
        if self.cause == "unexplained":
            return f"{', '.join(fired)} fired, but no extension gained {g:g} points of {crit} fit"
        return (
            f"{', '.join(fired)} fired; {self.cause}'s extension was chosen (see the evidence "
            f"table), gaining {self.gain:+.1f} points of {crit} fit"
        )

    def _final_class(self) -> tuple[core.Model, dict[str, classes.ClassFit]]:
        """The model whose actuator is reported and the class fits its class was chosen on:
        the extension's own when it chose a class of its own among those it fitted; the
        nominal's (every class) when the class is the nominal's, so that the margin is to the
        runner-up of every class, not of the few an extension re-fitted (the colored-noise
        extensions re-fit the nominal's class alone, the blind re-fits ``linear``, the
        nominal's class and the graph's best)."""
        m = self.extended if self.ctx.p >= 2 else self.nominal.model
        own = self.nominal.class_fits
        fits = m.info.get("class_fits") or own
        if m.cls == self.nominal.chosen or m.cls not in fits:
            fits = own
        return m, fits

    @property
    def nonlinearity(self) -> dict[str, Any]:
        """The actuator of the final model (the extended one when a cause was named: a
        misaligned, coloured or spiky record also misleads the nominal's class choice); for
        ``p = 1`` the nominal's, decided on the whole record."""
        m, fits = self._final_class()
        scores = {c: float(f.score) for c, f in fits.items()}
        margin, _ = class_margin(m.cls, fits)
        return {
            "class": m.cls,
            "params": classes.public_params(m.cls, m.theta),
            "scores": {c: round(v, 6) for c, v in scores.items()},
            "margin": round(_finite(margin), 6),
            "confident": bool(margin >= CONFIDENT_MARGIN),
        }

    def findings(self) -> list[str]:
        """The lines a report opens with: the valve class with its parameters in % of the
        range of ``x`` and its margin, then the cause and its gain on the stated criterion,
        then the validation fits under every criterion shown."""
        nl = self.nonlinearity
        rx = core.scale_of(self.ctx.x)
        parts = []
        for k, v in nl["params"].items():
            if v is None:
                parts.append(f"{k} none")
            elif k in ("u_min", "u_max", "lower", "upper"):
                lo = float(np.percentile(self.ctx.x, 1))
                parts.append(f"{k} {v:.4g} (at {100 * (v - lo) / rx:.0f} % of the x range)")
            else:
                parts.append(f"{k} {v:.4g} ({100 * v / rx:.1f} % of the x range)")
        fits = self._final_class()[1]
        _, runner = class_margin(nl["class"], fits)
        own = fits.get(nl["class"])
        own_score = float(own.score) if isinstance(own, classes.ClassFit) else 0.0
        nested = "; ".join(
            f"{c}'s fit (score {float(fits[c].score):.1f}, {nl['class']}'s {own_score:.1f}) is "
            f"no rival: {why}"
            for c, why in nested_rivals(nl["class"], fits).items()
        )
        if nl["confident"] or not runner:
            valve = f"valve: {nl['class']}" + (f", {', '.join(parts)}" if parts else "")
            said = [f"margin {nl['margin']:.2f} over {runner}"] if runner else []
            if said or nested:
                valve += f" ({'; '.join(said + ([nested] if nested else []))})"
        else:
            valve = (
                f"valve: {nl['class']} or {runner}: the data cannot tell (margin "
                f"{nl['margin']:.2f}, below {CONFIDENT_MARGIN:g}); as {nl['class']}: "
                + (", ".join(parts) if parts else "no parameters")
                + (f"; {nested}" if nested else "")
            )
        crit = self.criterion
        cause = f"cause: {self.cause}"
        if self.cause in ("none", "unexplained"):
            cause += f" ({self.why})"
        else:
            cause += (
                f", gain {self.gain:+.1f} points of {crit} fit (nominal {self.baseline_fit:.1f} %"
                f" -> extended {self.extended_fit:.1f} %)"
            )
        ctl = self.info.get("controller")
        fits = "validation fits: " + "; ".join(
            f"{c} {format_fit(self.fits.get('nominal', {}).get(c, float('nan')))} nominal, "
            f"{format_fit(self.fits.get('extended', {}).get(c, float('nan')))} extended"
            + (f" (controller {ctl.describe()})" if c == "closed-loop" and ctl else "")
            + (" (the criterion)" if c == crit else "")
            for c in self.fits.get("nominal", {})
        )
        return [valve, cause, fits]

    def as_json(self) -> dict[str, Any]:
        """The contract's JSON object."""
        return {
            "record": self.source,
            "p": int(self.ctx.p),
            "h": float(self.ctx.h),
            "nonlinearity": self.nonlinearity,
            "effects": [d.as_json() for d in self.detections],
            "cause": self.cause,
            "baseline_fit": round(_finite(self.baseline_fit), 6),
            "extended_fit": round(_finite(self.extended_fit), 6),
            "gain": round(_finite(self.extended_fit) - _finite(self.baseline_fit), 6),
            "criterion": self.criterion,
        }


#: ``nonlinearity.confident`` needs a margin (:func:`class_margin`) of at least this: below
#: it the runner-up's score is within this share of the chosen class's, and the report says
#: the data cannot tell the two apart. Rule: the level where the class's accuracy below and
#: above it differs most, among levels leaving at least 10 % of the records below. Set on the
#: benchmark loops' calibration seeds (:data:`hbench.diagnose.benchmark_cases.CALIBRATION_SEEDS`,
#: 10000-10139, ``docs/experiments/diagnose-class-ceiling.md``): 57 % right below, 75 % above.
#: No level reaches 90 % above it there: most wrong classes are chosen with a wide margin (an
#: effect that distorts the class, a misfit of the dynamics that a nonlinearity absorbs).
CONFIDENT_MARGIN = 0.10


def nested_rivals(chosen: str, fits: dict[str, Any]) -> dict[str, str]:
    """The classes of ``fits`` whose fit is the chosen class in another form, so no rival of
    it, each with why: a stiction fit whose slip jump is below
    :data:`hbench.diagnose.nominal.MIN_JUMP_SHARE` of its band beside a chosen backlash
    (``J = 0`` is backlash); a one-sided dead zone (:func:`hbench.diagnose.classes.one_sided`)
    beside a chosen saturation. Bare scores nest nothing."""
    out: dict[str, str] = {}
    f = fits.get("stiction")
    if chosen == "backlash" and isinstance(f, classes.ClassFit) and f.theta:
        J, S = float(f.theta.get("J", 0.0)), float(f.theta.get("S", 0.0))
        if S > 0 and J < nm.MIN_JUMP_SHARE * S:
            out["stiction"] = (
                f"its slip jump, {100 * J / S:.1f} % of its band, is below "
                f"{100 * nm.MIN_JUMP_SHARE:g} %: a backlash"
            )
    f = fits.get("deadband")
    if chosen == "saturation" and isinstance(f, classes.ClassFit) and f.info.get("one_sided"):
        out["deadband"] = "next to no sample beyond one of its edges: the saturation it nests"
    return out


def class_margin(chosen: str, fits: dict[str, Any]) -> tuple[float, str]:
    """The relative score gap between the chosen class and the best other one (the runner-up):
    ``(s_chosen - s_runner) / max(|s_chosen|, |s_runner|, 1)``, ``linear`` scoring 0.

    ``fits`` maps classes to :class:`~hbench.diagnose.classes.ClassFit` (or to bare scores).
    A class whose fit is the chosen one in another form (:func:`nested_rivals`) is no rival.
    Negative where a rule other than the score chose (stiction needs a slip jump, a class needs
    its minimum score); ``(inf, "")`` with no other class."""
    nested = nested_rivals(chosen, fits)
    scores = {
        c: float(f.score) if isinstance(f, classes.ClassFit) else float(f)
        for c, f in fits.items()
        if c not in nested
    }
    others = {c: v for c, v in scores.items() if c != chosen and np.isfinite(v)}
    if not others:
        return float("inf"), ""
    runner = max(others, key=lambda c: others[c])
    sc, sr = float(scores.get(chosen, 0.0)), others[runner]
    return (sc - sr) / max(abs(sc), abs(sr), 1.0), runner


#: A validation fit below this (%) is printed as a bound: the model's output has run away
#: (an unstable re-simulated loop, a diverging simulation), and its digits say nothing.
FIT_FLOOR = -1000.0


def format_fit(v: float) -> str:
    """A validation fit for the findings: ``12.3 %``; below :data:`FIT_FLOOR` ``< -1000 %
    (diverges)``; ``n/a`` when it could not be computed."""
    v = float(v)
    if np.isnan(v):
        return "n/a"
    if v < FIT_FLOOR:
        return f"< {FIT_FLOOR:.0f} % (diverges)"
    return f"{v:.1f} %"


def _finite(v: float) -> float:
    v = float(v)
    if np.isnan(v):
        return 0.0
    return float(np.clip(v, -1e6, 1e6))


def effect_classes() -> list[type[Effect]]:
    """The registered effects (the ``register_effects`` hook), contract names first."""
    try:
        from hbench.plugins import registry

        reg = registry()
        found = {n: reg.get("effects", n) for n in reg.names("effects")}
    except Exception:
        found = {}
    if not found:
        found = {cls.name: cls for cls in BUILTIN}
    order = [n for n in CONTRACT_EFFECTS if n in found]
    order += sorted(n for n in found if n not in CONTRACT_EFFECTS)
    return [found[n] for n in order]


def val_fit(ctx: nm.Context, model: core.Model) -> float:
    """The model's simulation fit on the validation part, in %."""
    idx = ctx.val_idx
    return core.fit_percent(ctx.y[idx], model.simulate(ctx.x)[idx])


#: The prediction horizon is never shorter than this many fast samples ...
HORIZON_MIN = 2
#: ... nor longer than this share of the validation part.
HORIZON_MAX_SHARE = 0.25


@dataclass(frozen=True)
class Criterion:
    """How a model's validation fit is measured.

    ``loop`` set: ``closed-loop``, the loop re-simulated from ``r`` with the model in place of
    the valve and the plant and ``loop`` the controller identified from the record
    (:mod:`hbench.diagnose.loop`). Else ``horizon`` 0: simulation of ``y`` from the measured
    ``x`` (open loop). ``horizon`` K > 0:
    K-step-ahead prediction of ``y`` with a noise model ``v = e / D(q)`` (MATLAB's
    ``compare(data, sys, K)``): the predictor of ``y = y_sim + v`` from ``y`` up to ``t - K``
    and ``x`` up to ``t`` is

        y_hat(t | t - K) = y(t) - F_K(q) D(q) (y(t) - y_sim(t)),

    with ``F_K`` the first K terms of the impulse response of ``1 / D`` (the K-step prediction
    error of ``e / D`` is ``F_K e``). K = infinity gives the simulation, K = 1 the one-step
    predictor. ``D`` is the candidate's own noise model where it has one (the coloured-noise
    extension's), else the nominal model's (``A(q)``, the paper's equation error). On a slow
    plant the simulation error is dominated by the open-loop realisation of the process noise
    the loop has cancelled (its poles near 1 integrate it), whatever the model; the K-step
    prediction removes what the noise model explains up to ``t - K`` and scores the rest.
    """

    horizon: int = 0
    #: The identified controller of the ``closed-loop`` criterion (then ``horizon`` is 0).
    loop: LoopController | None = None

    @property
    def name(self) -> str:
        if self.loop is not None:
            return "closed-loop"
        return "simulation" if self.horizon <= 0 else f"prediction-{self.horizon}"


def dominant_horizon(a: np.ndarray, n_val: int) -> int:
    """The stated horizon rule: the dominant time constant of ``1 / A(q)`` in fast samples,
    ``ceil(-1 / ln |lambda_max|)``, clipped to [:data:`HORIZON_MIN`, :data:`HORIZON_MAX_SHARE`
    of the validation part]. ``A = 1`` (no dynamics) gives :data:`HORIZON_MIN`."""
    a = np.asarray(a, float)
    hi = max(HORIZON_MIN, int(HORIZON_MAX_SHARE * n_val))
    if a.size <= 1:
        return HORIZON_MIN
    lam = float(np.max(np.abs(np.roots(a))))
    if not 0 < lam < 1:
        return hi
    return int(np.clip(np.ceil(-1.0 / np.log(lam)), HORIZON_MIN, hi))


def noise_filter(model: core.Model, nominal: core.Model) -> np.ndarray | None:
    """The ``D(q)`` of the candidate's noise model ``e / D``: its own (``info["noise_filter"]``)
    where it has one, else the nominal model's (:func:`hbench.diagnose.nominal.noise_denominator`;
    ``None``: white output noise)."""
    own = model.info.get("noise_filter")
    if own is not None:
        return np.asarray(own, float)
    return nm.noise_denominator(nominal)


def predict(y: np.ndarray, ysim: np.ndarray, d: np.ndarray | None, horizon: int) -> np.ndarray:
    """``y_hat(t | t - horizon)`` of :class:`Criterion` (the simulation for ``horizon <= 0`` or
    white output noise, ``d`` None)."""
    if horizon <= 0 or d is None:
        return ysim
    imp = np.zeros(horizon)
    imp[0] = 1.0
    fk = signal.lfilter([1.0], d, imp)  # the first K terms of the impulse response of 1 / D
    return y - signal.lfilter(np.convolve(fk, d), [1.0], y - ysim)


def criterion_output(
    ctx: nm.Context,
    model: core.Model,
    nominal: core.Model,
    crit: Criterion,
    ysim: np.ndarray | None = None,
) -> np.ndarray:
    """The model's ``y_hat`` over the whole record under ``crit`` (``ysim``: its open-loop
    simulation when already computed)."""
    if crit.loop is not None and ctx.r is not None:
        return simulate_loop(model, crit.loop, ctx.r, float(ctx.x[0]))[0]
    if ysim is None:
        ysim = model.simulate(ctx.x)
    return predict(ctx.y, ysim, noise_filter(model, nominal), crit.horizon)


def criteria_outputs(
    ctx: nm.Context, model: core.Model, nominal: core.Model, criteria: list[Criterion]
) -> dict[str, np.ndarray]:
    """The model's ``y_hat`` over the whole record under each of ``criteria``, by name (the
    model simulated once for all of them)."""
    ysim = model.simulate(ctx.x)
    return {c.name: criterion_output(ctx, model, nominal, c, ysim) for c in criteria}


def criteria_fits(
    ctx: nm.Context,
    model: core.Model,
    nominal: core.Model,
    criteria: list[Criterion],
    outputs: dict[str, np.ndarray] | None = None,
) -> dict[str, float]:
    """The model's fit in % on the validation part under each of ``criteria``, by name
    (``outputs``: :func:`criteria_outputs` when already computed)."""
    idx = ctx.val_idx
    if outputs is None:
        outputs = criteria_outputs(ctx, model, nominal, criteria)
    return {c.name: core.fit_percent(ctx.y[idx], outputs[c.name][idx]) for c in criteria}


def half_fits(ctx: nm.Context, y_hat: np.ndarray) -> tuple[float, float]:
    """The fit in % of ``y_hat`` on the first and on the second half of the validation part
    (the second holds the odd sample), each against that half's own mean."""
    idx = ctx.val_idx
    m = idx.size // 2
    first, second = idx[:m], idx[m:]
    return (
        core.fit_percent(ctx.y[first], y_hat[first]),
        core.fit_percent(ctx.y[second], y_hat[second]),
    )


def half_gains(e: Extension, base_halves: tuple[float, float] | None) -> tuple[float, float] | None:
    """The extension's gain in points over the nominal on each half of the validation part;
    ``None`` where either side's halves were not measured."""
    if e.halves is None or base_halves is None:
        return None
    return (e.halves[0] - base_halves[0], e.halves[1] - base_halves[1])


def unread_halves(e: Extension, rule: str = "validation") -> str:
    """Why the cause rule ``rule`` does not read the extension's gains on the two halves of the
    validation part (``""`` where it reads them: :data:`HALVES`, the ``validation`` rule, the
    effect's detector quiet)."""
    if rule != "validation":
        return f"{rule} rule"
    if not HALVES:
        return "HALVES is off"
    if e.detected:
        return "detector fired"
    return ""


def clears(e: Extension, base: float, base_halves: tuple[float, float] | None, bar: float) -> bool:
    """Whether the extension ``e`` gains at least ``bar`` points over the nominal's validation
    fit ``base``; with :data:`HALVES`, for an extension whose detector stayed quiet, over the
    nominal's fit on each half of the validation part (``base_halves``) too. Halves not
    measured, or a nominal half fit that is not finite (a constant half, a diverging output),
    leave the whole to decide. An extension without a model, or with a fit that is not a
    number, gains nothing, and nothing gains against a nominal fit that is not finite (a
    re-simulated loop that diverges: every finite fit would gain ``+inf``)."""
    if e.model is None or not np.isfinite(e.val_fit) or not np.isfinite(base):
        return False
    if e.val_fit - base < bar:
        return False
    g = half_gains(e, base_halves)
    if g is None or unread_halves(e) or not np.all(np.isfinite(base_halves)):
        return True
    return all(h >= bar for h in g)  # a half of the extension that is nan gains nothing


def loop_criterion(ctx: nm.Context, structure: str = "auto") -> Criterion | None:
    """The ``closed-loop`` criterion of the record: its controller identified from
    ``(r - y, x)`` (:func:`hbench.diagnose.loop.identify_controller`, ``structure`` auto, P or
    PI); ``None`` when the record carries no ``r``."""
    if ctx.r is None or ctx.K < 4 or not np.all(np.isfinite(ctx.r)):
        return None
    e = controller_error(ctx.y, ctx.r, ctx.p)
    return Criterion(0, identify_controller(ctx.x, e, structure))


def parse_criterion(rule: str) -> Criterion | None:
    """The criterion ``rule`` names when it fixes one (``simulation``, ``prediction-K``);
    ``None`` for ``prediction``, ``closed-loop`` and ``auto``, which depend on the record.
    Raises :class:`~hbench.errors.InputError` for anything else."""
    rule = str(rule).strip().lower()
    if rule == "simulation":
        return Criterion(0)
    if rule in ("prediction", "closed-loop", "auto"):
        return None
    if rule.startswith("prediction-"):
        k = rule.split("-", 1)[1]
        if k.isdigit() and int(k) >= 1:
            return Criterion(int(k))
        raise InputError(f"the prediction horizon must be a positive integer, got {rule!r}")
    raise InputError(
        f"unknown validation criterion {rule!r} (choose auto, simulation, closed-loop, "
        "prediction or prediction-K)"
    )


def choose_criterion(
    ctx: nm.Context, nominal: nm.Nominal, rule: str = "simulation", controller: str = "auto"
) -> Criterion:
    """The criterion ``rule`` names for this record: ``simulation``; ``prediction-K`` (K
    given); ``prediction``: the horizon by :func:`dominant_horizon` from the nominal's noise
    model ``e / A`` (the blind route, ``p >= 2``), or the simulation where the nominal's noise
    is white output noise (``p = 1``: there the two are the same); ``closed-loop``: the loop
    re-simulated with the controller of structure ``controller`` identified from the record
    (:func:`loop_criterion`), the simulation for a record without ``r``; ``auto``:
    :data:`DEFAULT_CRITERION` for a record with ``r`` and ``p >= 2``, else the simulation."""
    rule = str(rule).strip().lower()
    if rule == "auto":
        rule = DEFAULT_CRITERION if ctx.r is not None and ctx.p >= 2 else "simulation"
    fixed = parse_criterion(rule)
    if fixed is not None:
        return fixed
    if rule == "closed-loop":
        return loop_criterion(ctx, controller) or Criterion(0)
    d = nm.noise_denominator(nominal.model)
    if d is None:
        return Criterion(0)
    return Criterion(dominant_horizon(d, ctx.val_idx.size))


def choose_extension(
    pool: list[Extension],
    extensions: dict[str, Extension],
    base: float,
    min_gain: float,
    base_halves: tuple[float, float] | None = None,
) -> Extension | None:
    """The extension of ``pool`` whose validation fit beats ``base`` the most, by at least
    ``min_gain`` points (the :data:`PARSIMONY` rule applied: a simpler extension from
    ``extensions`` that gains nearly as much as the richer one wins); ``None`` when none does.
    ``base_halves`` given: the gain of an extension whose detector stayed quiet also on each
    half of the validation part (:func:`clears`)."""
    ok = [e for e in pool if clears(e, base, base_halves, min_gain)]
    if not ok:
        return None
    best = max(ok, key=lambda e: e.val_fit)
    for simple, rich, share in PARSIMONY:
        alt = extensions.get(simple)
        if (
            best.name == rich
            and alt is not None
            and clears(alt, base, base_halves, min_gain)
            and alt.val_fit - base >= share * (best.val_fit - base)
        ):
            best = alt
    return best


def diagnose(
    record: Record,
    *,
    source: str | None = None,
    method: str = "wang-lsm",
    fit_fraction: float = 2 / 3,
    delay_multiple: int = 0,
    effects: list[type[Effect]] | None = None,
    criterion: str = "auto",
    also: tuple[Criterion, ...] = (),
    extend_all: bool = False,
    rule: str = "auto",
    controller: str = "auto",
    progress: Callable[[str], None] | None = None,
) -> Diagnosis:
    """Run the workflow on a one-run record.

    A record with ``p >= 2`` is taken to start possibly from rest (simulations do), so the
    fits carry a start-up transient term; a plant log (``p = 1``) starts in steady operation.
    ``criterion`` names the validation criterion (:func:`choose_criterion`); ``also`` adds
    criteria whose fits are recorded beside it (``Diagnosis.fits``, ``Extension.fits``).
    ``rule`` (:data:`CAUSE_RULES`) says how the cause is chosen: ``validation`` fits every
    effect's extension and names the one that gains the most validation fit (among the
    candidates of :data:`MIN_GAIN`, :data:`MIN_GAIN_UNDETECTED` and :data:`HALVES`); ``detectors``
    only those whose detector fired; ``auto`` (default) is ``validation`` for ``p >= 2``,
    where it is calibrated, and ``detectors`` for a plant log (``p = 1``). ``extend_all`` fits
    every extension under the ``detectors`` rule too (for calibration; the cause is still
    chosen among the fired). ``progress``, if given, is called with a line of text as each
    step ends (the nominal model, the detectors, each extension), once the record has been
    accepted: a refused record raises before the first line. It runs with one BLAS thread
    (restored on return): a
    multi-threaded BLAS sums in another order on another core count, so only then are its
    numbers (class scores, margins, fits) the same to the last bit on any machine.
    """
    if rule == "auto":
        rule = "validation" if record.p >= 2 else "detectors"
    if rule not in CAUSE_RULES:
        raise InputError(f"unknown cause rule {rule!r} (choose auto, {', '.join(CAUSE_RULES)})")
    with core.transient(record.p >= 2), runtime.one_blas_thread():
        return _diagnose(
            record,
            source=source,
            method=method,
            fit_fraction=fit_fraction,
            delay_multiple=delay_multiple,
            effects=effects,
            criterion=criterion,
            also=also,
            extend_all=extend_all or rule == "validation",
            rule=rule,
            controller=controller,
            progress=progress,
        )


def _diagnose(
    record: Record,
    *,
    source: str | None,
    method: str,
    fit_fraction: float,
    delay_multiple: int,
    effects: list[type[Effect]] | None,
    criterion: str = "auto",
    also: tuple[Criterion, ...] = (),
    extend_all: bool = False,
    rule: str = "validation",
    controller: str = "auto",
    progress: Callable[[str], None] | None = None,
) -> Diagnosis:
    t0 = time.perf_counter()
    # made first: an effect's settings are checked before any work (a bad one raises)
    instances = [cls() for cls in (effects if effects is not None else effect_classes())]

    def say(text: str) -> None:
        if progress is not None:
            progress(f"{text} ({time.perf_counter() - t0:.1f} s)")

    min_gain = MIN_GAIN[rule]
    ctx = nm.make_context(record, fit_fraction)
    nominal = nm.fit_nominal(ctx, method, delay_multiple)
    crit = choose_criterion(ctx, nominal, criterion, controller)
    shown = [Criterion(0)]
    pred = choose_criterion(ctx, nominal, "prediction")
    cl = crit if crit.loop is not None else loop_criterion(ctx, controller)
    for c in (pred, *([cl] if cl is not None else []), crit, *also):
        if c.name not in {x.name for x in shown}:
            shown.append(c)

    def fits_of(model: core.Model) -> tuple[dict[str, float], tuple[float, float]]:
        out = criteria_outputs(ctx, model, nominal.model, shown)
        return criteria_fits(ctx, model, nominal.model, shown, out), half_fits(ctx, out[crit.name])

    base_fits, base_halves = fits_of(nominal.model)
    base = base_fits[crit.name]
    say(f"nominal model: {nominal.chosen} valve, {crit.name} fit {format_fit(base)}")
    detections: list[Detection] = []
    extensions: dict[str, Extension] = {}
    for eff in instances:
        detections.append(eff.detect(ctx, nominal))
    fired = [d for d in detections if d.fired]
    say(f"detectors: {', '.join(d.name for d in fired) if fired else 'none'} fired")
    todo = [(e, d) for e, d in zip(instances, detections, strict=True) if d.fired or extend_all]
    for i, (eff, det) in enumerate(todo, 1):
        try:
            model = eff.extend(ctx, nominal, det)
            ext_fits, ext_halves = fits_of(model)
            extensions[eff.name] = Extension(
                eff.name,
                model,
                ext_fits[crit.name],
                fits=ext_fits,
                halves=ext_halves,
                detected=det.fired,
            )
        except Exception as exc:
            extensions[eff.name] = Extension(
                eff.name, None, -np.inf, f"{type(exc).__name__}: {exc}", detected=det.fired
            )
        done = "fitted" if extensions[eff.name].model is not None else "failed"
        say(f"extension {i} of {len(todo)} ({eff.name}) {done}")
    names = {d.name for d in fired}
    pool = [e for e in extensions.values() if e.name in names]
    halves = base_halves if rule == "validation" else None
    if rule == "validation":
        pool = [e for e in pool if clears(e, base, halves, min_gain)] + [
            e
            for e in extensions.values()
            if e.name not in names
            and e.name not in DETECTED_ONLY
            and clears(e, base, halves, MIN_GAIN_UNDETECTED)
        ]
    best = choose_extension(pool, extensions, base, min_gain, halves)
    cause, extended, ext_fit, ext_fits = "none", nominal.model, base, base_fits
    if best is not None:
        cause, extended, ext_fit, ext_fits = best.name, best.model, best.val_fit, best.fits
    elif not base > NONE_MIN_FIT or (rule == "detectors" and fired):
        cause = "unexplained"
    return Diagnosis(
        source=source if source is not None else record.source,
        ctx=ctx,
        nominal=nominal,
        detections=detections,
        extensions=extensions,
        cause=cause,
        baseline_fit=base,
        extended_fit=ext_fit,
        extended=extended,
        seconds=time.perf_counter() - t0,
        criterion=crit.name,
        fits={"nominal": base_fits, "extended": ext_fits},
        rule=rule,
        baseline_halves=base_halves,
        info={"criterion": crit, "controller": None if cl is None else cl.loop},
    )

"""Steps 2-4 of the workflow: residual tests, the cause, and the validation gain.

The record is split into a fit part (the first ``fit_fraction``, default 2/3) and a validation
part (the rest). The nominal model and every extension are fitted on the fit part only; each is
simulated from the measured ``x`` over the whole record and scored on the validation part:
``fit = 100 (1 - ||y - y_hat|| / ||y - mean y||)`` there.

The cause: every registered effect's detector runs on what the nominal model leaves on the fit
part. ``none`` when no detector fires and the nominal model explains the validation part
better than its mean (fit above :data:`NONE_MIN_FIT`); with no detector firing and a fit at or
below it, ``unexplained`` (a model no better than a constant does not "already explain the
data": seen on records with white measurement noise, where the blind route fails;
``docs/experiments/none-needs-a-fit.md``). Otherwise each fired effect's extension is fitted, and
the cause is the one whose validation fit beats the nominal's the most, by at least
:data:`MIN_GAIN` points (with one parsimony rule, :data:`PARSIMONY`: a noise model that gains
nearly as much as one more pole is preferred to it); ``unexplained`` when none does
(structure remains that no catalogued extension removes). ``extended_fit`` is the cause's
extended model's fit (the nominal's for ``none`` and ``unexplained``) and
``gain = extended_fit - baseline_fit``.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from hbench.diagnose import classes, core
from hbench.diagnose import nominal as nm
from hbench.diagnose.effects import BUILTIN, Detection, Effect
from hbench.records import Record

#: The contract's effect names, in the order the JSON lists them.
CONTRACT_EFFECTS: tuple[str, ...] = (
    "colored-noise",
    "drift",
    "delay",
    "outliers",
    "time-varying",
    "order",
)
#: An extension must add at least this many points of validation fit to be the cause.
MIN_GAIN = 0.5
#: ``none`` needs a nominal validation fit above this (%): better than the validation mean.
#: Not tuned; no nominal calibration record (seeds 5000-5199) has a fit below 43 %.
NONE_MIN_FIT = 0.0
#: Parsimony: (simpler, richer, share): when the richer extension is the best but the simpler
#: one gains at least ``share`` of its gain, the simpler is the cause. A noise model changes
#: nothing of the plant, one more pole does; and the pole of coloured equation noise passes
#: the order test too, where the two extensions then gain about the same.
PARSIMONY: tuple[tuple[str, str, float], ...] = (("colored-noise", "order", 0.8),)


@dataclass
class Extension:
    """A fired effect's extended model and its validation fit."""

    name: str
    model: core.Model | None
    val_fit: float
    error: str = ""


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

    @property
    def gain(self) -> float:
        return self.extended_fit - self.baseline_fit

    @property
    def why(self) -> str:
        """One line: why the cause is what it is."""
        fired = [d.name for d in self.detections if d.fired]
        if self.cause == "none":
            return (
                f"no detector fired, and the nominal model explains the validation part "
                f"(fit {self.baseline_fit:.1f} %)"
            )
        if self.cause == "unexplained" and not fired:
            return (
                f"no detector fired, but the nominal model's validation fit "
                f"({self.baseline_fit:.1f} %) is no better than the validation part's mean"
            )
        if self.cause == "unexplained":
            return (
                f"{', '.join(fired)} fired, but no extension gained {MIN_GAIN:g} points of "
                f"validation fit"
            )
        return (
            f"{', '.join(fired)} fired; {self.cause}'s extension was chosen (see the evidence "
            f"table), gaining {self.gain:+.1f} points of validation fit"
        )

    @property
    def nonlinearity(self) -> dict[str, Any]:
        """The actuator of the final model (the extended one when a cause was named: a
        misaligned, coloured or spiky record also misleads the nominal's class choice); for
        ``p = 1`` the nominal's, decided on the whole record."""
        m = self.extended if self.ctx.p >= 2 else self.nominal.model
        fits = m.info.get("class_fits") or self.nominal.class_fits
        if m.cls not in fits:
            fits = self.nominal.class_fits
        return {
            "class": m.cls,
            "params": classes.public_params(m.cls, m.theta),
            "scores": {c: round(float(f.score), 6) for c, f in fits.items()},
        }

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
        }


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


def diagnose(
    record: Record,
    *,
    source: str | None = None,
    method: str = "wang-lsm",
    fit_fraction: float = 2 / 3,
    delay_multiple: int = 0,
    effects: list[type[Effect]] | None = None,
) -> Diagnosis:
    """Run the workflow on a one-run record.

    A record with ``p >= 2`` is taken to start possibly from rest (simulations do), so the
    fits carry a start-up transient term; a plant log (``p = 1``) starts in steady operation.
    """
    with core.transient(record.p >= 2):
        return _diagnose(
            record,
            source=source,
            method=method,
            fit_fraction=fit_fraction,
            delay_multiple=delay_multiple,
            effects=effects,
        )


def _diagnose(
    record: Record,
    *,
    source: str | None,
    method: str,
    fit_fraction: float,
    delay_multiple: int,
    effects: list[type[Effect]] | None,
) -> Diagnosis:
    t0 = time.perf_counter()
    ctx = nm.make_context(record, fit_fraction)
    nominal = nm.fit_nominal(ctx, method, delay_multiple)
    base = val_fit(ctx, nominal.model)
    detections: list[Detection] = []
    extensions: dict[str, Extension] = {}
    instances = [cls() for cls in (effects if effects is not None else effect_classes())]
    for eff in instances:
        detections.append(eff.detect(ctx, nominal))
    for eff, det in zip(instances, detections, strict=True):
        if not det.fired:
            continue
        try:
            model = eff.extend(ctx, nominal, det)
            extensions[eff.name] = Extension(eff.name, model, val_fit(ctx, model))
        except Exception as exc:
            extensions[eff.name] = Extension(
                eff.name, None, -np.inf, f"{type(exc).__name__}: {exc}"
            )
    fired = [d for d in detections if d.fired]
    cause, extended, ext_fit = "none", nominal.model, base
    if not fired and not base > NONE_MIN_FIT:
        cause = "unexplained"
    if fired:
        cause = "unexplained"
        ok = [e for e in extensions.values() if e.model is not None and np.isfinite(e.val_fit)]
        if ok:
            best = max(ok, key=lambda e: e.val_fit)
            for simple, rich, share in PARSIMONY:
                alt = extensions.get(simple)
                if (
                    best.name == rich
                    and alt is not None
                    and alt.model is not None
                    and alt.val_fit - base >= max(MIN_GAIN, share * (best.val_fit - base))
                ):
                    best = alt
            if best.val_fit - base >= MIN_GAIN:
                cause, extended, ext_fit = best.name, best.model, best.val_fit
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
    )

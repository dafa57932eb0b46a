"""Tests of the ``colored-noise`` effect (:class:`hbench.diagnose.effects.ColoredNoise`): the
Granger residual test's level and power on closed loops with known dynamics, the detector on
benchmark-loop calibration records, and the cause rule's treatment of its extension."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
from scipy import signal

from hbench.diagnose import benchmark_cases as bc
from hbench.diagnose import core, effects, generator, nominal, stats, validate
from hbench.diagnose.effects import ColoredNoise, Detection, Effect, format_p

# --------------------------------------------------------------------------- the Granger test


def _loop(rng: np.random.Generator, n: int, runs: int) -> tuple[np.ndarray, np.ndarray]:
    """``runs`` P-controlled first-order plants ``y0 = 0.2 q^-1 / (1 - 0.9 q^-1) u`` with a
    white reference and the ARMAX noise ``C / A e`` (the plant's own pole, ``C = 1 + 0.5
    q^-1``); ``(y, u)``, each ``(runs, n)``."""
    a, b, kp = 0.9, 0.2, 1.5
    e = 0.3 * rng.standard_normal((runs, n))
    v = signal.lfilter([1.0, 0.5], [1.0, -a], e, axis=-1)
    ref = rng.standard_normal((runs, n))
    y = np.zeros((runs, n))
    u = np.zeros((runs, n))
    s = np.zeros(runs)  # the plant's state
    for t in range(n):
        y[:, t] = s + v[:, t]
        u[:, t] = kp * (ref[:, t] - y[:, t])
        s = a * s + b * u[:, t]
    return y, u


def _residual(y: np.ndarray, u: np.ndarray, a: float, b: float) -> np.ndarray:
    """``y`` minus the first-order model ``b q^-1 / (1 - a q^-1) u`` simulated from ``u``."""
    return y - signal.lfilter([0.0, b], [1.0, -a], u)


def test_granger_input_test_keeps_its_level_in_a_closed_loop() -> None:
    """Residual of the TRUE dynamics (it is the noise ``C / A e``), input fed back from the
    noisy output: the plain cross-correlation of residual and input is large (the feedback),
    but the input terms given the residual's own past reject at the F-test's level. 400 loops
    of 1500 samples at 5 %: the binomial standard deviation is 1.1 %, so 2-8 % is a +-3 sd
    band."""
    rng = np.random.default_rng(11)
    reject = 0
    xcorr = []
    draws = 400
    ys, us = _loop(rng, 1500, draws)
    for y, u in zip(ys, us, strict=True):
        r = _residual(y, u, 0.9, 0.2)
        g = stats.granger(r - r.mean(), u - u.mean(), 8, 20, 60)
        reject += g["input_p"] < 0.05
        xcorr.append(abs(np.corrcoef(r[1:], u[:-1])[0, 1]))
    assert 0.02 <= reject / draws <= 0.08, reject
    # the feedback: the residual and the past input are correlated far beyond 2 / sqrt(n)
    assert np.median(xcorr) > 5 * 2 / np.sqrt(1500)


def test_granger_sees_wrong_dynamics_through_the_noise() -> None:
    """The residual of a model with the wrong pole (0.7 for 0.9, the DC gain kept): past
    inputs explain it beyond its own past (p < 1e-6, share above the detector's level), on
    every one of 20 loops; its own past explains it too (the noise is coloured)."""
    rng = np.random.default_rng(12)
    ys, us = _loop(rng, 1500, 20)
    for y, u in zip(ys, us, strict=True):
        r = _residual(y, u, 0.7, 0.2 * 0.3 / 0.1)
        g = stats.granger(r - r.mean(), u - u.mean(), 8, 20, 60)
        assert g["input_p"] < 1e-6
        assert g["input_share"] > ColoredNoise.INPUT_SHARE
        assert g["own_p"] < 1e-6


# --------------------------------------------------------------------------- the detector


def _bench_nominal(seed: int, effect: str, cls: str) -> tuple[nominal.Context, nominal.Nominal]:
    case = bc.draw_bench_case(seed, effect, cls, "paper")
    rec = bc.simulate_bench_case(case)
    with core.transient(True), np.errstate(all="ignore"):
        ctx = nominal.make_context(rec)
        return ctx, nominal.fit_nominal(ctx)


@pytest.mark.xfail(
    strict=True,
    reason="not met: with the chosen class's parameters started at the Box-Jenkins estimate "
    "(nominal.THETA_START) the nominal's residual on this record owes 2.06 % of its variance "
    "to past inputs, just above the bias route's 2 % level, so the route stays quiet "
    "(docs/experiments/box-jenkins-classes.md)",
)
def test_detector_fires_on_box_jenkins_noise_of_the_paper_loop() -> None:
    """Calibration record 16001 (paper loop, linear valve, Box-Jenkins noise ``d1`` 0.94, no
    other effect): the nominal's residual is noise to its inputs (share below the level), the
    output-error refit lowers the simulation residual by far more than the level: the
    detector fires, and its printed p-value is below the level the verdict states."""
    ctx, nom = _bench_nominal(16001, "colored-noise", "linear")
    with core.transient(True), np.errstate(all="ignore"):
        det = ColoredNoise().detect(ctx, nom)
    assert det.fired, det.evidence
    assert det.info["route"] == "bias"
    assert det.info["input_share"] < ColoredNoise.INPUT_SHARE
    assert det.info["drop"] > 3 * ColoredNoise.DROP
    # the verdict's p-value is the bias route's own-past F-test's, the one printed with it
    assert det.p_value == det.info["own_p"]
    assert f"the route's p-value {format_p(det.p_value)}" in det.evidence


def test_the_whiteness_route_fires_on_the_design_generators_coloured_equation_noise() -> None:
    """The design generator's coloured record of seed 1 (a fast loop, backlash valve, equation
    noise ``(1 + c1 q^-1) / ((1 - d1 q^-1) A) e``): the bias route is quiet (past inputs explain
    the nominal residual far beyond the level), the whiteness route fires and the detector
    reports it."""
    (case,) = [c for c in generator.cases_per_effect(3, 0) if c.seed == 1]
    assert case.effect == "colored-noise"
    rec = generator.simulate_case(case)
    with core.transient(True), np.errstate(all="ignore"):
        ctx = nominal.make_context(rec)
        det = ColoredNoise().detect(ctx, nominal.fit_nominal(ctx))
    assert det.fired, det.evidence
    assert det.info["route"] == "whiteness"
    assert det.info["input_share"] > 5 * ColoredNoise.INPUT_SHARE
    assert det.info["whiteness"] > det.info["bias"]


@pytest.mark.parametrize(
    ("seed", "effect", "cls"),
    [
        (16000, "none", "linear"),  # the nominal noise C / A e only
        (16006, "order", "linear"),  # a missing pole
        (16013, "order", "backlash"),  # a missing pole, and a memory valve
    ],
)
def test_detector_is_quiet_on_nominal_noise_and_a_missing_pole(
    seed: int, effect: str, cls: str
) -> None:
    """Calibration records of the paper loop without coloured noise: quiet (the missing pole
    leaves a residual that past inputs explain; the nominal-noise record's refit moves the
    simulation by less than the level)."""
    ctx, nom = _bench_nominal(seed, effect, cls)
    with core.transient(True), np.errstate(all="ignore"):
        det = ColoredNoise().detect(ctx, nom)
    assert not det.fired, det.evidence
    assert det.info["refit_error"] == ""  # quiet with the refit made, not for want of it
    if effect == "order":  # past inputs explain the residual: dynamics, not noise
        assert det.info["input_share"] > ColoredNoise.INPUT_SHARE
    else:  # the refit hardly moves the simulation
        assert det.info["drop"] < ColoredNoise.DROP


# --------------------------------------------------------------------------- the cause rule


class _Refit(Effect):
    """A test effect whose extension is the output-error refit and whose detector never
    fires."""

    threshold = 1.0

    def detect(self, ctx: nominal.Context, nom: nominal.Nominal) -> Detection:
        return self._det(0.0, 1.0, "never")

    def extend(self, ctx: nominal.Context, nom: nominal.Nominal, det: Detection) -> core.Model:
        return ColoredNoise().oe_refit(ctx, nom)


class _QuietColoured(_Refit):
    name = "colored-noise"


class _QuietOther(_Refit):
    name = "order"


def test_a_quiet_colored_noise_detector_is_never_the_cause_by_its_gain_alone(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Calibration record 16022 (paper loop, Box-Jenkins noise), its nominal's parameters
    started at the graph's fit (the rule under test needs a nominal that leaves a large gain):
    the output-error refit gains more than :data:`~hbench.diagnose.validate.MIN_GAIN_UNDETECTED`
    points. Under another effect's name with a quiet detector it is the cause (a gain the
    detector missed); under ``colored-noise`` it is not
    (:data:`~hbench.diagnose.validate.DETECTED_ONLY`)."""
    monkeypatch.setattr(nominal, "THETA_START", "graph")
    case = bc.draw_bench_case(16022, "colored-noise", "saturation", "paper")
    rec = bc.simulate_bench_case(case)
    with np.errstate(all="ignore"):
        other = validate.diagnose(rec, effects=[_QuietOther])
        coloured = validate.diagnose(rec, effects=[_QuietColoured])
    gain = other.extensions["order"].val_fit - other.baseline_fit
    assert gain >= validate.MIN_GAIN_UNDETECTED
    assert other.cause == "order"
    assert coloured.extensions["colored-noise"].val_fit == pytest.approx(
        other.extensions["order"].val_fit
    )
    assert coloured.cause == "none"


# --------------------------------------------------------------------------- the route choice


@pytest.mark.parametrize(
    ("bias", "whiteness", "route", "fired"),
    [
        ((3.0, 1e-6), (5.0, 1e-9), "bias", True),  # both fire: the bias route
        ((3.0, 0.5), (2.0, 1e-9), "whiteness", True),  # bias large but not significant
        ((0.2, 1e-9), (2.0, 1e-9), "whiteness", True),
        ((0.5, 1e-9), (0.3, 1e-9), "bias", False),  # neither fires: the larger statistic
        ((0.3, 1e-9), (0.5, 1e-9), "whiteness", False),
        ((float("nan"), float("nan")), (0.5, 1e-9), "bias", False),  # nan: quiet, no evidence
    ],
)
def test_the_detector_reports_the_route_that_fires_with_its_own_p_value(
    monkeypatch: pytest.MonkeyPatch,
    bias: tuple[float, float],
    whiteness: tuple[float, float],
    route: str,
    fired: bool,
) -> None:
    """The reported statistic and p-value are one route's, so the verdict agrees with the
    p-value printed beside it."""
    info = {"input_share": 1.0, "drop": 20.0, "own_p": bias[1], "refit_error": ""}
    monkeypatch.setattr(ColoredNoise, "_bias", lambda self, c, n, u: (*bias, "b", info))
    monkeypatch.setattr(ColoredNoise, "_whiteness", lambda self, c, n, u: (*whiteness, "w"))
    monkeypatch.setattr(effects, "_u_fast", lambda model, ctx: None)
    nom = SimpleNamespace(model=None)
    det = ColoredNoise().detect(None, nom)  # type: ignore[arg-type]
    assert det.info["route"] == route
    assert det.fired is fired
    stat, p = bias if route == "bias" else whiteness
    assert det.statistic == stat or (np.isnan(stat) and np.isnan(det.statistic))
    assert det.p_value == p or (np.isnan(p) and np.isnan(det.p_value))
    assert det.evidence.startswith(f"reported: the {route} route")


def test_granger_refuses_a_start_before_its_lags() -> None:
    r = np.zeros(100)
    with pytest.raises(ValueError, match="start"):
        stats.granger(r, r, 8, 20, 10)


@pytest.mark.parametrize(("coloured_gain", "cause"), [(9.0, "colored-noise"), (7.0, "order")])
def test_parsimony_weighs_a_quiet_colored_noise_extension_against_one_more_pole(
    coloured_gain: float, cause: str
) -> None:
    """``colored-noise`` is not a candidate with a quiet detector, but the parsimony rule
    (:data:`~hbench.diagnose.validate.PARSIMONY`, share 0.8) prefers its noise model to the
    candidate ``order`` when it gains at least 0.8 of that pole's gain."""
    model = core.Model.__new__(core.Model)  # only "not None" matters to the rule
    order = validate.Extension("order", model, 50.0 + 10.0)
    coloured = validate.Extension("colored-noise", model, 50.0 + coloured_gain)
    extensions = {"order": order, "colored-noise": coloured}
    best = validate.choose_extension([order], extensions, 50.0, 2.0)
    assert best is not None and best.name == cause


def test_a_colored_noise_diagnosis_reports_the_margin_over_every_class(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Calibration record 16001, its nominal's parameters started at the graph's fit (where
    the cause is ``colored-noise``): the extension re-fits the nominal's class alone; the
    reported class's scores and margin are the nominal's over every class, so the margin is
    finite and names a runner-up (not the infinite margin of a class compared with
    nothing)."""
    monkeypatch.setattr(nominal, "THETA_START", "graph")
    case = bc.draw_bench_case(16001, "colored-noise", "linear", "paper")
    with np.errstate(all="ignore"):
        d = validate.diagnose(bc.simulate_bench_case(case))
    assert d.cause == "colored-noise"
    nl = d.nonlinearity
    assert set(nl["scores"]) == set(core.CLASSES)
    assert np.isfinite(nl["margin"]) and abs(nl["margin"]) < 1e6
    assert " over " in d.findings()[0] or "cannot tell" in d.findings()[0]

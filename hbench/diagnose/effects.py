"""Step 3 of the workflow: the catalogue of effects the nominal model may miss.

Each effect is a plugin registered on the ``register_effects`` hook (:mod:`hbench.builtin`
registers the classes below; a third-party package can add its own). An effect is a class with

* ``name`` (one of the contract's ``colored-noise, drift, delay, outliers, time-varying, order``
  for the built-ins), ``summary`` and ``threshold``;
* ``detect(ctx, nominal) -> Detection``: a statistic on what the nominal model leaves on the
  *fit part*, its p-value (analytic where a distribution is known, else an approximation the
  evidence names) and whether it passes ``threshold``;
* ``extend(ctx, nominal, detection) -> Model``: the nominal model extended by what the effect
  adds, fitted on the fit part only. What it could not do while still giving a model (a
  candidate that failed) goes in the model's ``info["notes"]``, a list of lines the report
  shows beside the extension's fit (the JSON does not carry them); an exception it raises
  marks the extension failed, with its message.

Thresholds are calibrated on records of :mod:`hbench.diagnose.generator` whose seeds the tests
never use: nominal records (seeds 5000-5199) for the false-positive side, records with each
effect (seeds 6000-6209 and 7000-7139) for the power. Each statistic is an effect size (not a
significance level, which every small misfit of the nominal model reaches on records of a few
thousand samples), and each threshold sits at or above the 99th percentile of its nominal
distribution where most records with the effect exceed it; the numbers are in the report of
``python -m hbench.diagnose.calibrate --effect none --start 5000 --n 200``. The drift
detector's low-frequency threshold and the time-varying threshold also rise, per record, to
the 99th percentile of their statistic under the record's own nominal noise model
(:mod:`hbench.diagnose.null`), since that noise can be far slower than the calibration
records' (the paper's example); the drift detector also tests a ramp under that noise model
(:class:`Drift`). A detector that fires spuriously costs little: the cause also needs a
validation gain.

Innovations and residuals: ``resid = y - y_hat`` (simulation error) and ``innov``, the nominal
noise model's one-step errors (``A(q) resid`` for the blind route, whose noise model is the
paper's equation error ``e / A``; ``resid`` for ``p = 1``).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any, ClassVar

import numpy as np

from hbench.diagnose import classes, core, null, stats
from hbench.diagnose import nominal as nm
from hbench.errors import InputError, MethodError, describe

__all__ = ["BUILTIN", "Detection", "Effect"]


@dataclass
class Detection:
    """What a detector found."""

    name: str
    statistic: float
    p_value: float
    threshold: float
    fired: bool
    evidence: str
    info: dict[str, Any] = field(default_factory=dict)

    def as_json(self) -> dict[str, Any]:
        """The contract's ``{name, statistic, p_value, evidence}`` (finite numbers: JSON has no
        ``nan``). A p-value no test could give is 1 (no evidence), never 0, which would read
        as the strongest evidence; an undefined statistic is 0. The verdict closes the
        evidence: ``(threshold T: fires)`` or ``(threshold T: quiet)``; it compares the
        statistic, an effect size, with T, so a small p-value alone does not fire a detector."""
        return {
            "name": self.name,
            "statistic": _num(self.statistic, 0.0),
            "p_value": _num(self.p_value, 1.0),
            "evidence": self.evidence,
        }


def _num(v: float, undefined: float) -> float:
    """``v`` as a finite JSON number: ``undefined`` for ``nan``, +-1e300 for infinities."""
    v = float(v)
    if np.isnan(v):
        return undefined
    if np.isinf(v):
        return 1e300 if v > 0 else -1e300
    return v


def format_p(p: float) -> str:
    """A p-value for the evidence and the report: ``< 1e-300`` below that, ``n/a`` for nan."""
    if np.isnan(p):
        return "n/a"
    return f"{p:.2g}" if p >= 1e-300 else "< 1e-300"


#: A detector fires when its effect size exceeds its threshold AND its test rejects at this
#: level: the verdict never contradicts the p-value printed beside it.
ALPHA = 0.01


class Effect:
    """Base class of the catalogued effects.

    The verdict rule (:meth:`_det`): a detector fires when its statistic, an effect size,
    exceeds its threshold and its p-value is below :data:`ALPHA`; the evidence line says which
    condition kept a quiet detector quiet."""

    name: ClassVar[str] = ""
    summary: ClassVar[str] = ""
    #: The statistic must exceed this for the detector to fire (calibrated, module notes).
    threshold: ClassVar[float] = np.inf
    #: Settings of the effect (class attributes) and the values each may take.
    CHOICES: ClassVar[dict[str, tuple[str, ...]]] = {}

    def __init__(self) -> None:
        self.check_settings()

    def check_settings(self) -> None:
        """Raises ``ValueError`` for a setting of :attr:`CHOICES` with another value (checked
        when the effect is made, before a diagnosis's work, and again by ``extend``)."""
        for name, allowed in self.CHOICES.items():
            value = getattr(self, name)
            if value not in allowed:
                raise ValueError(
                    f"{name} must be one of {', '.join(map(repr, allowed))}, got {value!r}"
                )

    def detect(self, ctx: nm.Context, nom: nm.Nominal) -> Detection:
        raise NotImplementedError

    def extend(self, ctx: nm.Context, nom: nm.Nominal, det: Detection) -> core.Model:
        """The extended model. What it could not do while still giving a model (a candidate
        that failed) goes in its ``info["notes"]`` (a list of lines), shown beside its fit."""
        raise NotImplementedError

    @staticmethod
    def _passes(statistic: float, p_value: float, threshold: float) -> tuple[bool, bool]:
        """``(effect size above threshold, p-value below ALPHA)``: a detector fires on both."""
        large = bool(np.isfinite(statistic) and statistic > threshold)
        significant = bool(np.isfinite(p_value) and p_value < ALPHA)
        return large, significant

    def _det(
        self,
        statistic: float,
        p_value: float,
        evidence: str,
        *,
        threshold: float | None = None,
        **info: Any,
    ) -> Detection:
        """The detection of ``statistic`` against ``threshold`` (default: the class's
        calibrated :attr:`threshold`; a detector whose null depends on the record passes its
        own, never below the calibrated one)."""
        t = float(self.threshold)
        if threshold is not None and np.isfinite(threshold):
            t = max(t, float(threshold))
        large, significant = self._passes(statistic, p_value, t)
        fired = large and significant
        if fired:
            verdict = f"fires: effect size above it and p < {ALPHA:g}"
        elif large:
            verdict = (
                f"quiet: effect size above it but p = {format_p(p_value)} is not below {ALPHA:g}"
            )
        elif significant:
            verdict = (
                f"quiet: p < {ALPHA:g} but the effect size is below the threshold (an effect "
                "too small to matter here)"
            )
        else:
            verdict = "quiet"
        return Detection(
            self.name,
            float(statistic),
            float(p_value),
            t,
            fired,
            f"{evidence} (threshold {t:.4g}: {verdict})",
            info,
        )


#: Fast samples skipped at the start of the fit part (the simulation starts from rest).
SETTLE = 20


def _fit(ctx: nm.Context, nom: nm.Nominal, x: np.ndarray) -> np.ndarray:
    """``x`` over the fit part after the first :data:`SETTLE` samples."""
    return np.asarray(x)[ctx.fit_idx][SETTLE:]


def null_draws(ctx: nm.Context, nom: nm.Nominal) -> np.ndarray | None:
    """The nominal noise model's draws (:func:`hbench.diagnose.null.residual_draws`, from
    :func:`hbench.diagnose.null.generator`) that the drift and time-varying detectors judge
    their statistics against: drawn once per nominal model and shared."""
    if "null_draws" not in nom.cache:
        nom.cache["null_draws"] = null.residual_draws(ctx, nom, null.generator(), settle=SETTLE)
    return nom.cache["null_draws"]


def _u_fast(model: core.Model, ctx: nm.Context) -> np.ndarray:
    return np.repeat(model.inner(ctx.x), ctx.p)


def _blind_model_of(ctx: nm.Context, kw: dict[str, Any], est: Any, label: str) -> core.Model:
    """The nominal route's model (:func:`hbench.diagnose.nominal.blind_model`) of the blind
    estimate ``est``, with the nominal's options ``kw`` (:func:`_nominal_kw`)."""
    return nm.blind_model(
        ctx, est, delay_multiple=kw["delay_multiple"], label=label, candidates=kw["candidates"]
    )[0]


def _blind_of_order(ctx: nm.Context, kw: dict[str, Any], na: int, label: str) -> core.Model:
    """The nominal route with ``na`` poles given (the blind method's selection over
    ``1 .. na`` held at ``na``)."""
    est = nm.identify_blind(
        ctx, kw["method"], na=na, na_range=(1, na), delay_multiple=kw["delay_multiple"]
    )
    return _blind_model_of(ctx, kw, est, label)


def _simulation_bic(ctx: nm.Context, m: core.Model) -> float:
    """BIC of ``m``'s simulation error over the fit part, ``n log(RSS / n) + (2 na + nb) log n``
    (the order and drift extensions choose among their candidates by it)."""
    n = ctx.fit_idx.size
    rss = nm.simulation_rss(m, ctx)
    return float(n * np.log(max(rss, 1e-300) / n) + (2 * m.lin.na + m.lin.nb) * np.log(n))


def _sim_rss_or_inf(ctx: nm.Context, m: core.Model, idx: np.ndarray) -> float:
    """:func:`hbench.diagnose.nominal.simulation_rss` of ``m`` over ``idx``, or ``inf`` where
    it is not finite (a run-away simulation loses a comparison of candidates)."""
    rss = nm.simulation_rss(m, ctx, idx)
    return rss if np.isfinite(rss) else np.inf


# --------------------------------------------------------------------------- colored noise


class ColoredNoise(Effect):
    """Coloured noise: noise with dynamics of its own that the nominal noise model lacks.

    The convention: noise ``C(q) / A(q) e`` (ARMAX, the plant's own poles) belongs to the
    nominal model; ``colored-noise`` is Box-Jenkins noise ``C(q) / D(q) e`` with ``D != A``
    (``C / (D A) e``, coloured equation noise, among it). Two routes look for it, each with its
    own statistic over its own level (both scaled to the threshold 1) and its own p-value; the
    detector reports one route, with that route's statistic and p-value, so the verdict is that
    route's: the route that fires (the bias route first when both do), else the one with the
    larger statistic. Both routes' evidence is printed.

    **Whiteness** (where the noise's shape shows: plants whose poles are not near 1). Two
    measures, each the sum of squared autocorrelations over lags 1-:attr:`NLAGS` (the
    Ljung-Box ``Q`` divided by the number of samples): (i) of the nominal model's innovations
    ``A(q) (y - y_hat)`` and (ii) of the residual of the equation-error regression of ``y`` on
    its past and the nominal inner signal (the paper's eq. 2 with the nominal orders); the
    equation-error fit moves its poles towards those of coloured noise, which whitens (i) but
    not (ii). Statistic: the larger of the two over its level (:attr:`INNOV_WHITE`,
    :attr:`EQ_WHITE`, calibrated on the design generator's loops); p-value: the Ljung-Box
    chi-square of the larger. It fires on coloured noise and also on many records whose nominal
    model is wrong in another way (innovations of a mis-specified model are coloured); the
    extension's validation gain decides between them.

    **Bias** (where it does not: on a slow plant ``A(q)`` with poles near 1 nearly differences
    twice, and the pole of ``D`` hardly shows in ``A (y - y_hat)``). What a Box-Jenkins noise
    does show is the bias it puts into the nominal's equation-error estimate of the dynamics
    (the equation error weighs the data by ``A``, as if the noise were ``e / A``), which an
    estimate whose noise model is independent of the dynamics (output error: the Box-Jenkins
    structure's estimate of the dynamics with a flat noise model) does not carry. The route asks
    three things of the fit part (after :data:`SETTLE` samples):

    * **the residual is noise, not dynamics** (Granger-style residual analysis,
      :func:`hbench.diagnose.stats.granger`): the nominal simulation residual ``y - y_hat``
      regressed on its own past (:attr:`AR_LAGS` lags) and on the nominal inner signal's past
      (:attr:`INPUT_LAGS` fast samples beyond the nominal delay). A wrong valve class, a
      missing pole or a wrong delay leave a residual that past inputs explain beyond its own
      past; a wrong noise model leaves one that its own past predicts and past inputs do
      not. Conditioning on the residual's own past removes what the feedback puts into the
      input's past (past noise), which makes the plain cross-correlation no test in a closed
      loop. Effect size: the share (%) of what the residual's own past leaves that past inputs
      explain (a partial R^2); it must stay below :attr:`INPUT_SHARE`. Its F-test p-value is
      reported, not used: on a few thousand samples any small misfit of the nominal is
      significant;
    * **the residual is coloured**: its own past explains it given the input's past, by the
      F-test at :data:`ALPHA` (the route's p-value; it holds for the nominal noise ``C / A e``
      too, so it is no evidence of ``D != A`` by itself);
    * **the nominal's dynamics are biased**: the output-error refit of the dynamics and of the
      nominal class's parameters (:func:`hbench.diagnose.nominal.hammerstein_pem`) lowers the
      simulation residual's power on the fit part by more than :attr:`DROP` %: under the
      nominal's noise the two estimates differ little (``docs/experiments/colored-noise.md``,
      section 2).

    Statistic: ``min(drop / DROP, INPUT_SHARE / input share)``: above 1 exactly when the first
    and third conditions hold. A record with only the nominal noise but a slow, large noise can
    pass all three (its dynamics' small misfit hides in the noise); there the extension's
    validation gain decides. Levels chosen on the benchmark loops' calibration seeds
    (``docs/experiments/colored-noise.md``).

    Extension, by the route that fired:

    * bias (fired): the Box-Jenkins estimate of the dynamics by output error, the nominal class's
      parameters and the linear part (nominal orders and delay) re-fitted from ``x`` to ``y``,
      a memory actuator's start state re-chosen on the simulation. (Prediction error with an
      AR(8) noise model of the residual prefiltering the data lost to it on every benchmark-loop
      calibration record looked at: it weighs the high frequencies, where a slow plant's output
      is small, and the simulation criterion scores the low ones.)
    * otherwise (the whiteness route fired, or neither did): prediction error, the nominal
      class's parameters and linear part re-fitted on data pre-whitened by an AR(8) model of
      the residual (Box-Jenkins style, twice), the start state of a memory actuator re-chosen
      on the simulation (where the plant is fast, the prefilter's weighting costs little and
      the noise model is what is missing). This is also the model the validation rule's
      parsimony (``hbench.diagnose.validate.PARSIMONY``) weighs against one more pole when
      the detector is quiet: the output-error refit gains on too many records of other causes
      for that (``docs/experiments/colored-noise.md``).

    Either way its noise model is ``e / D`` with ``D`` an AR(8) model of its residual (the
    K-step predictor of the ``prediction-K`` criterion uses it).
    """

    name = "colored-noise"
    summary = (
        "non-white innovations or equation error, or a residual its own past explains and past "
        "inputs do not with an output-error refit that moves the dynamics; extension: "
        "Box-Jenkins dynamics and noise model"
    )
    threshold = 1.0
    #: Whiteness route: lags of the autocorrelation sums and their levels.
    NLAGS = 20
    INNOV_WHITE = 1.2
    EQ_WHITE = 0.8
    #: Bias route: lags of the residual's own past (fast samples) ...
    AR_LAGS = 8
    #: ... and of the inner signal's past beyond the nominal delay, in the Granger regressions.
    INPUT_LAGS = 20
    #: The input share (%) must stay below this ...
    INPUT_SHARE = 2.0
    #: ... and the output-error refit must lower the fit part's simulation RSS by more (%).
    DROP = 10.0

    #: The Granger regressions' first sample in the fit part (after :data:`SETTLE`): at least
    #: this many, and at least the longest lag set.
    GRANGER_START = 60

    def oe_refit(self, ctx: nm.Context, nom: nm.Nominal) -> core.Model:
        """The output-error refit (the bias route's model), computed once per nominal."""
        if "oe_refit" not in nom.cache:
            nom.cache["oe_refit"] = nm.hammerstein_pem(
                ctx, nom.model, ctx.fit_idx, label="colored-noise", which=(nom.chosen,)
            )[0]
        return nom.cache["oe_refit"]

    def _whiteness(
        self, ctx: nm.Context, nom: nm.Nominal, u: np.ndarray
    ) -> tuple[float, float, str]:
        e = _fit(ctx, nom, nom.innov)
        q1, p1 = stats.ljung_box(e, self.NLAGS)
        s1 = q1 / e.size
        r = stats.acf(e, 3)[1:]
        m = nom.model
        if ctx.p >= 2:
            eq = core.arx_residual(
                u,
                ctx.y,
                m.lin.na,
                max(m.lin.nb, 2),
                m.lin.delay,
                ctx.fit_idx[SETTLE:],
            )
            q2, p2 = stats.ljung_box(eq, self.NLAGS)
            s2 = q2 / eq.size
        else:  # the output-error route has no equation error of its own
            s2, p2 = 0.0, 1.0
        stat = max(s1 / self.INNOV_WHITE, s2 / self.EQ_WHITE)
        p = p1 if s1 / self.INNOV_WHITE >= s2 / self.EQ_WHITE else p2
        text = (
            f"whiteness route: innovations' autocorrelation at lags 1-3 {r[0]:.2f}, {r[1]:.2f}, "
            f"{r[2]:.2f}; sum of r^2 over {self.NLAGS} lags {s1:.3g} (level {self.INNOV_WHITE:g}), "
            f"of the equation error {s2:.3g} (level {self.EQ_WHITE:g}); statistic {stat:.3g}, "
            f"the route's p-value (Ljung-Box) {format_p(p)}"
        )
        return stat, p, text

    def _bias(
        self, ctx: nm.Context, nom: nm.Nominal, u: np.ndarray
    ) -> tuple[float, float, str, dict]:
        r = _fit(ctx, nom, nom.resid)
        m_lags = self.INPUT_LAGS + int(nom.model.lin.delay)
        start = max(self.GRANGER_START, m_lags, self.AR_LAGS)
        g = stats.granger(r, _fit(ctx, nom, u), self.AR_LAGS, m_lags, start)
        try:
            ro = _fit(ctx, nom, ctx.y - self.oe_refit(ctx, nom).simulate(ctx.x))
            drop = 100.0 * (1.0 - float(ro @ ro) / max(float(r @ r), 1e-300))
            why = ""
        except Exception as exc:  # a valid record gets a diagnosis: no refit, no evidence
            drop = 0.0
            why = f" (no output-error refit: {type(exc).__name__}: {exc})"
        share = g["input_share"]
        if np.isfinite(share) and np.isfinite(drop):
            stat = min(drop / self.DROP, self.INPUT_SHARE / max(share, 1e-12))
        else:  # an undefined share or drop is no evidence either way
            stat = float("nan")
        text = (
            f"bias route: the nominal residual's own past ({self.AR_LAGS} lags) explains "
            f"{g['own_share']:.3g} % of it beyond past inputs (F = {g['own_f']:.3g}, the route's "
            f"p-value {format_p(g['own_p'])}); past inputs ({m_lags} lags) explain "
            f"{share:.3g} % beyond its own past (level {self.INPUT_SHARE:g} %; F = "
            f"{g['input_f']:.3g}, p = {format_p(g['input_p'])}, not used); the output-error "
            f"refit lowers the simulation RSS by {drop:.3g} % (level {self.DROP:g} %){why}; "
            f"statistic min(drop / {self.DROP:g}, {self.INPUT_SHARE:g} / input share) {stat:.3g}"
        )
        info = {"input_share": share, "drop": drop, "own_p": g["own_p"], "refit_error": why}
        return stat, g["own_p"], text, info

    def detect(self, ctx: nm.Context, nom: nm.Nominal) -> Detection:
        u = _u_fast(nom.model, ctx)  # the nominal inner signal at the fast rate, for both
        sw, pw, tw = self._whiteness(ctx, nom, u)
        sb, pb, tb, info = self._bias(ctx, nom, u)
        t = float(self.threshold)
        bias_fires = all(self._passes(sb, pb, t))
        white_fires = all(self._passes(sw, pw, t))
        # the route reported: one that fires (the bias route first), else the larger statistic
        if bias_fires or (not white_fires and not sw > sb):
            route, stat, p = "bias", sb, pb
        else:
            route, stat, p = "whiteness", sw, pw
        first, second = (tb, tw) if route == "bias" else (tw, tb)
        return self._det(
            stat,
            p,
            f"reported: the {route} route. {first}. Also: {second}",
            route=route,
            whiteness=sw,
            bias=sb,
            **info,
        )

    def extend(self, ctx: nm.Context, nom: nm.Nominal, det: Detection) -> core.Model:
        idx = ctx.fit_idx
        if not (det.fired and det.info.get("route") == "bias"):
            # the nominal's class is kept: coloured noise biases the parameters, not the class
            m = nom.model
            for _ in range(2):  # noise model from the residual, refit, noise model again
                r = _fit(ctx, nom, ctx.y - m.simulate(ctx.x))
                d = _ar(r - r.mean(), NOISE_AR)
                m = nm.hammerstein_pem(
                    ctx, m, idx, prefilter=d, label="colored-noise", which=(nom.chosen,)
                )[0]
        else:
            m = self.oe_refit(ctx, nom).with_()
        # the extension's own noise model, e / D with D the AR model of its residual (the
        # K-step predictor of the validation criterion uses it)
        r = _fit(ctx, nom, ctx.y - m.simulate(ctx.x))
        m.info = {**m.info, "noise_filter": _ar(r - r.mean(), NOISE_AR)}
        return m


#: Order of the AR noise models of the colored-noise extensions (``e / D``).
NOISE_AR = 8


def _ar(r: np.ndarray, order: int) -> np.ndarray:
    """``[1, d1, ..]`` of an AR(order) model of ``r`` by least squares (stable)."""
    R = np.stack([r[order - k - 1 : r.size - k - 1] for k in range(order)], axis=1)
    th = np.linalg.lstsq(R, r[order:], rcond=None)[0]
    return core.stabilise(np.concatenate([[1.0], -th]))


# --------------------------------------------------------------------------- drift


class Drift(Effect):
    """Drift: a ramp in the residual, or residual power piled up at the lowest frequencies.

    Two tests on the simulation residual over the fit part (after :data:`SETTLE` samples):

    * **ramp** (blind route, p >= 2): the slope of a linear trend under the nominal noise model
      ``e / A`` (:func:`hbench.diagnose.stats.noise_model_trend`: the residual and the ramp
      filtered by ``A(q)``, so that the noise is the white ``e``, then the t-test of the
      slope). Its size: the fitted ramp extrapolated over the whole record, relative to the
      range of ``y`` over the fit part. It passes when the size exceeds :attr:`RAMP_LEVEL` and
      its p-value is below :data:`ALPHA`. A slow plant's noise ``e / A`` wanders over the
      record (the paper's loop: poles 0.97 and 0.99 at the fast rate), but ``A(q)`` whitens it,
      so the ramp test keeps its level there. p = 1 (output error) has no noise model that
      whitens the residual, so the ramp test is left out (an ordinary t-test on a coloured
      residual rejects far too often).
    * **low frequency**: the mean periodogram over the 3 lowest bins against bins 4-20
      (``F(6, 34)`` for a stationary disturbance whose correlation time is short next to the
      record). It passes when the ratio exceeds its threshold, the calibrated
      :attr:`LF_THRESHOLD` or, for the blind route, the 99th percentile of the same ratio over
      draws of the nominal noise model (:mod:`hbench.diagnose.null`) when that is larger (a
      slow plant's ``e / A`` alone piles its power there), and its F-test p-value is below
      :data:`ALPHA`. The record's threshold is ``info["lf_threshold"]``.

    The detector fires when either test passes. ``statistic`` is the larger of the two tests'
    statistics each divided by its own level (ramp size / :attr:`RAMP_LEVEL`, ratio / the
    record's low-frequency threshold), so :attr:`threshold` is 1; the statistic and ``p_value``
    are those of one test: the one that passes (the larger normalised statistic if both do),
    otherwise the one with the larger normalised statistic, so the verdict (statistic above 1
    and p below :data:`ALPHA`) is the reported test's. The evidence names both tests, their
    levels and which one is reported; ``info`` holds both (``ramp``, ``ramp_t``, ``ramp_p``,
    ``lf_ratio``, ``lf_p``, ``lf_threshold``, ``test``).

    Extension: a drift state, a ramp ``c t`` in the output: the ramp the residual shows is taken
    off ``y``, the nominal route runs again (a drift also distorts the blind inner signal, hence
    the class), and the ramp is fitted with the output scale and extrapolated over the
    validation part. The drift's random walk is a unit root in the output's noise, outside the
    equation error ``e / A`` that the blind route's order selection assumes, and that selection
    can take it for one pole near 1: on the paper loop's drift records it keeps ``na = 1`` (a
    pole near 1) where the same records without the walk give the plant's two poles, and the
    one-pole model, ramp or not, cannot simulate the slow plant. So when the route selects
    fewer poles than the nominal family's largest order
    (:data:`hbench.diagnose.nominal.NA_NOMINAL`), the blind model of that largest order is
    fitted too (same route, order given; not when a root of its fit lies on the radius that
    :func:`hbench.diagnose.core.stabilise` moves a root on or outside the unit circle to,
    :data:`hbench.diagnose.core.STABLE_RADIUS`: that fit took the walk's unit root for a
    pole), each with the ramp, and the extension is the one with the smaller BIC of its
    simulation error over the fit part (``n log(RSS / n) + (2 na + nb) log n``,
    :class:`Order`'s rule), so an order the record does not support is not taken.
    """

    name = "drift"
    summary = (
        "a ramp under the nominal noise model or low-frequency residual power; "
        "extension: a ramp (drift state) in the output"
    )
    #: The statistic is normalised by each test's own level: it fires above 1.
    threshold = 1.0
    #: The ramp test's level: the fitted ramp over the record against the output's range.
    RAMP_LEVEL = 0.02
    #: The low-frequency ratio's calibrated threshold (raised per record by the noise null).
    LF_THRESHOLD = 8.0

    def detect(self, ctx: nm.Context, nom: nm.Nominal) -> Detection:
        e = _fit(ctx, nom, nom.resid)
        ratio, p_lf = stats.low_frequency_ratio(e)
        draws = null_draws(ctx, nom)
        q, noise = self.LF_THRESHOLD, ""
        if draws is not None:
            q_null = null.percentile(stats.low_frequency_ratios(draws[:, SETTLE:]))
            q = max(q, q_null)
            noise = (
                f", the larger of {self.LF_THRESHOLD:g} and the nominal noise model's "
                f"{q_null:.3g} ({null.QUANTILE:g}th percentile of {draws.shape[0]} draws)"
            )
        tests = {"low-frequency": (ratio / q, p_lf)}
        lf_text = (
            f"low-frequency test: residual power in the 3 lowest frequency bins is {ratio:.3g} x "
            f"that of bins 4-20 (F-test p = {format_p(p_lf)}; level {q:.3g}{noise})"
        )
        ramp = ramp_t = np.nan
        p_ramp = 1.0
        a = nm.noise_denominator(nom.model)
        y_fit = ctx.y[ctx.fit_idx]
        y_range = float(np.ptp(y_fit[np.isfinite(y_fit)])) if np.isfinite(y_fit).any() else 0.0
        if a is not None and y_range > 0:
            ramp, ramp_t, p_ramp = stats.noise_model_trend(e, a, scale=y_range, span=ctx.N)
            tests["ramp"] = (ramp / self.RAMP_LEVEL, p_ramp)
            ramp_text = (
                f"ramp test under the noise model e/A: a ramp of {100 * ramp:.3g} % of the "
                f"output's range over the record (t = {ramp_t:.3g}, p = {format_p(p_ramp)}; "
                f"level {100 * self.RAMP_LEVEL:g} %)"
            )
        elif a is None:
            ramp_text = (
                "ramp test: not run (output-error noise model: nothing whitens the residual)"
            )
        else:
            ramp_text = "ramp test: not run (the output is constant over the fit part)"

        def passes(k: str) -> bool:
            s, p = tests[k]
            return bool(np.isfinite(s) and s > self.threshold and p < ALPHA)

        def size(k: str) -> float:
            s = tests[k][0]
            return float(s) if np.isfinite(s) else -np.inf

        passing = [k for k in tests if passes(k)]
        test = max(passing or list(tests), key=size)
        statistic, p = tests[test]
        return self._det(
            statistic,
            p,
            f"{ramp_text}; {lf_text}; passing (above the level with p < {ALPHA:g}): "
            f"{', '.join(passing) or 'neither'}; reported: the {test} test, its statistic "
            "over its level",
            threshold=self.threshold,
            test=test,
            ramp=ramp,
            ramp_t=ramp_t,
            ramp_p=p_ramp,
            lf_ratio=ratio,
            lf_p=p_lf,
            lf_threshold=q,
        )

    def extend(self, ctx: nm.Context, nom: nm.Nominal, det: Detection) -> core.Model:
        idx = ctx.fit_idx
        tb = core.trend_basis(ctx.N, 1)[:, 0]
        # the ramp that the residual shows, taken off y before the nominal route runs again
        # (a drift also distorts the blind inner signal, hence the class)
        r = nom.resid[idx][SETTLE:]
        t = tb[idx][SETTLE:]
        slope = float(np.polyfit(t, r, 1)[0])
        y_d = replace(ctx, y=ctx.y - slope * tb)
        kw = _nominal_kw(ctx, nom)
        cands = [nm.fit_nominal(y_d, **kw).model]
        na = nm.NA_NOMINAL[1]
        if ctx.p >= 2 and nom.estimate is not None and cands[0].lin.na < na:
            # the drift's random walk misleads the blind order selection (the class's notes):
            # the nominal family's largest order competes on the fit part
            try:
                m = _blind_of_order(y_d, kw, na, "drift")
                # a pole on the stabilisation radius: the fit put a root on or outside the
                # unit circle, the walk's unit root taken for the plant's: not a candidate
                if float(np.max(np.abs(np.roots(m.lin.a)))) < core.STABLE_RADIUS - 1e-9:
                    cands.append(m)
            except (InputError, MethodError):
                pass
        m = min(
            (core.fit_output(cand, ctx.x, ctx.y, idx, trend=1) for cand in cands),
            key=lambda fitted: _simulation_bic(ctx, fitted),
        )
        m.info["drift_slope"] = slope
        return m


# --------------------------------------------------------------------------- delay


class Delay(Effect):
    """Delay: ``x`` and the inner signal line up at a non-zero multiple of ``p``.

    ``p >= 2``: the nominal class is fitted to ``(x(n - k), U(n))`` for ``k = 0 .. 4``;
    statistic: ``RSS(0) / RSS(k*)``, the best shift ``k* >= 1`` against the assumed alignment
    (the part of the delay assumption A3 takes as known). ``p = 1``: the output-error model's
    delay searched up to 30 samples beyond the nominal range 0-8; statistic: the RSS ratio.
    p-value: an F approximation (the shifted fit as one extra parameter). Extension: the shift.
    """

    name = "delay"
    summary = "x-U alignment at a non-zero multiple of p; extension: that shift"
    threshold = 1.3
    KMAX = 4

    def detect(self, ctx: nm.Context, nom: nm.Nominal) -> Detection:
        if ctx.p >= 2 and nom.U is not None:
            cls_set = tuple(dict.fromkeys(("linear", nom.chosen)))
            rss = []
            for k in range(self.KMAX + 1):
                fits = classes.fit_graph(ctx.x[: ctx.k_fit], nom.U[: ctx.k_fit], cls_set, shift=k)
                rss.append(min(f.rss for f in fits.values()))
            rss = np.array(rss)
            k_best = int(np.argmin(rss[1:]) + 1)
            ratio = float(rss[0] / max(rss[k_best], 1e-300))
            n = int(np.isfinite(nom.U[: ctx.k_fit]).sum())
            f = (rss[0] - rss[k_best]) / (rss[k_best] / max(n - 4, 1))
            p = stats.f_pvalue(f, 1, max(n - 4, 1)) if ratio > 1 else 1.0
            return self._det(
                ratio,
                p,
                f"x-U graph fits best at a shift of {k_best} slow "
                f"period(s) ({k_best} p = {k_best * ctx.p} fast samples beyond the "
                f"assumed delay): RSS ratio {ratio:.3g}",
                shift=k_best,
                rss=rss,
            )
        # p = 1: a delay beyond the nominal search range
        m = nom.model
        u = _u_fast(m, ctx)
        base = core.oe_fit(u, ctx.y, m.lin.na, max(m.lin.nb, 1), m.lin.delay, ctx.fit_idx)
        best_d, best_rss = m.lin.delay, base.rss
        for d in range(nm.DELAYS_DYNAMIC.stop, nm.DELAYS_DYNAMIC.stop + 30):
            f = core.oe_fit(u, ctx.y, m.lin.na, max(m.lin.nb, 1), d, ctx.fit_idx)
            if f.rss < best_rss:
                best_d, best_rss = d, f.rss
        ratio = float(base.rss / max(best_rss, 1e-300))
        n = ctx.n_fit
        f = (base.rss - best_rss) / (best_rss / max(n - 4, 1))
        p = stats.f_pvalue(f, 1, n - 4) if ratio > 1 else 1.0
        return self._det(
            ratio,
            p,
            f"output-error fit best at a delay of {best_d} samples "
            f"(nominal {m.lin.delay}): RSS ratio {ratio:.3g}",
            delay=best_d,
        )

    def extend(self, ctx: nm.Context, nom: nm.Nominal, det: Detection) -> core.Model:
        if ctx.p >= 2 and nom.estimate is not None:
            k = int(det.info["shift"])
            kw = _nominal_kw(ctx, nom)
            return nm.blind_model(
                ctx,
                nom.estimate,
                shift=k,
                delay_multiple=kw["delay_multiple"],
                label="delay",
                candidates=kw["candidates"],
            )[0]
        m = nm.refit_linear(nom.model, ctx, ctx.fit_idx, delay=int(det.info["delay"]))
        return core.fit_output(m, ctx.x, ctx.y, ctx.fit_idx)


# --------------------------------------------------------------------------- outliers


class Outliers(Effect):
    """Outliers: isolated spikes in the residual.

    Statistic: the share (in %) of fit-part samples where the residual departs from the mean
    of its two neighbours by more than 6 robust sigmas of that departure, and more than its
    neighbours do (one-sample spikes; :func:`hbench.diagnose.stats.isolated_spikes`); p-value:
    that many or more beyond 6 sigmas among Gaussian samples. Extension: robust re-fitting:
    the spikes of the measured ``y`` in the fit part are replaced by the mean of their
    neighbours and the nominal model is fitted again (blind route, every valve class compared:
    :attr:`REFIT_CLASSES`), with Huber weights in the final least squares. Raises
    ``ValueError`` for an unknown :attr:`REFIT_CLASSES`.
    """

    name = "outliers"
    summary = "heavy-tailed residuals (spikes); extension: robust re-weighting"
    threshold = 0.3
    K_SIGMA = 6.0
    #: The classes the nominal fitted again on the cleaned record compares: ``all``, as the
    #: nominal does (spikes mislead the nominal's class as they mislead its dynamics);
    #: ``nominal`` (the nominal's class, ``linear`` and the cleaned graph's best, as the other
    #: extensions that run the nominal route again); or ``both`` (one fit of each, the one
    #: that simulates the cleaned fit part better kept). Measured in
    #: ``docs/experiments/extension-classes.md``.
    REFIT_CLASSES = "all"
    CHOICES: ClassVar[dict[str, tuple[str, ...]]] = {"REFIT_CLASSES": ("all", "nominal", "both")}

    def detect(self, ctx: nm.Context, nom: nm.Nominal) -> Detection:
        e = _fit(ctx, nom, nom.resid)
        mask, _d, _s = stats.isolated_spikes(e, self.K_SIGMA)
        count = int(mask.sum())
        share = 100.0 * count / e.size
        p = stats.gaussian_tail_pvalue(count, e.size, self.K_SIGMA)
        kurt = stats.excess_kurtosis(e)
        return self._det(
            share,
            p,
            f"{count} isolated residual spikes beyond {self.K_SIGMA:g} "
            f"robust sigmas ({share:.2g} % of the fit part, p = {format_p(p)}); "
            f"excess kurtosis {kurt:.3g}",
            count=count,
        )

    def extend(self, ctx: nm.Context, nom: nm.Nominal, det: Detection) -> core.Model:
        self.check_settings()
        y = ctx.y.copy()
        fit = np.zeros(ctx.N, bool)
        fit[SETTLE : ctx.n_fit] = True  # the validation part stays untouched
        for _ in range(3):  # spikes of y itself (model-free), until none is left
            mask, _d, _s = stats.isolated_spikes(y, self.K_SIGMA)
            mask &= fit
            if not mask.any():
                break
            i = np.flatnonzero(mask)
            y[i] = 0.5 * (y[i - 1] + y[i + 1])
        which = self.REFIT_CLASSES
        kw = _nominal_kw(ctx, nom)
        cleaned = replace(ctx, y=y)
        fits = []  # for p = 1 the candidates change nothing: one fit
        if which == "nominal" or (which == "both" and ctx.p >= 2):
            fits.append(nm.fit_nominal(cleaned, **kw).model)
        if which in ("all", "both"):
            fits.append(nm.fit_nominal(cleaned, **{**kw, "candidates": None}).model)
        m = min(fits, key=lambda c: _sim_rss_or_inf(cleaned, c, ctx.fit_idx))
        r = (y - m.simulate(ctx.x))[ctx.fit_idx]
        s = stats.robust_sigma(r)
        w = np.ones(ctx.N)
        if s > 0:
            a = np.abs(r) / (1.345 * s)
            w[ctx.fit_idx] = np.where(a > 1, 1 / np.maximum(a, 1e-12), 1.0)
        m = core.fit_output(m, ctx.x, y, ctx.fit_idx, weights=w)
        m.info["cleaned"] = int(np.sum(y != ctx.y))
        return m


def _nominal_kw(ctx: nm.Context, nom: nm.Nominal) -> dict[str, Any]:
    """How an extension runs the nominal route again: the same method and delay multiple,
    and the nominal's class among the candidates (:func:`hbench.diagnose.nominal.blind_model`)."""
    return {
        "method": nom.info.get("method", "wang-lsm"),
        "delay_multiple": int(nom.model.info.get("delay_multiple", 0)),
        "candidates": (nom.chosen,),
    }


# --------------------------------------------------------------------------- time-varying


class TimeVarying(Effect):
    """Time-varying: the parameters change within the record.

    Two Chow-type scans over break points at 20-80 % of the fit part, each an effect size:
    the drop (in %) of the RSS when (i) the equation-error regression of ``y`` on its past and
    the nominal inner signal (nominal orders and delay) and (ii) the nominal simulation's
    output scale and offset are fitted on each side of the break instead of once. Equation
    error sees a change of the poles best, the simulation a change of the gain (the
    equation error of a slow plant is dominated by its own past). The simulation part's one
    fit has the nominal output fit's columns (simulation, offset and, for a record that
    starts from rest, the start-up transient), the change model the simulation's scale and
    offset on each side with the transient common. Statistic: the larger of the two drops,
    each divided by its threshold (:data:`EQ_DROP`; :data:`SIM_DROP`, or for the blind route
    the 99th percentile of the largest simulation drop over draws of the nominal noise model,
    :mod:`hbench.diagnose.null`, when that is larger: a slow plant's noise alone is taken
    away by separate offsets); p-value: the equation-error F at the best break times the
    number of breaks tried (a Bonferroni bound).

    Extension: the model of the regime after the change, fitted on the fit part from
    :meth:`segment_start` on (the detector's break when it fired, else the fit part's last
    :data:`LATEST` share): the nominal family re-fitted there, or the blind route run again on
    that segment, whichever simulates the segment better. The blind route's valve class is
    chosen on the segment alone, every class compared through the dynamics as the nominal's is
    (:attr:`SEGMENT_CLASS`): a fit over both regimes lends the valve what the plant's change
    did (``docs/experiments/extension-classes.md``).
    """

    name = "time-varying"
    summary = "parameters change within the record; extension: segment-wise model"
    threshold = 1.0
    EQ_DROP = 10.0
    SIM_DROP = 25.0
    BREAKS = np.linspace(0.2, 0.8, 13)
    #: Share of the fit part, at its end, that the extension models when the detector is
    #: quiet (:meth:`segment_start`).
    LATEST = 0.3
    #: How the blind candidate on the segment after the change chooses its valve class:
    #: ``equation-error`` (every class compared through the dynamics on the segment, as the
    #: nominal's: :func:`hbench.diagnose.nominal.blind_model`) or ``graph`` (the segment's
    #: blind (x, U) graph alone).
    SEGMENT_CLASS = "equation-error"
    CHOICES: ClassVar[dict[str, tuple[str, ...]]] = {"SEGMENT_CLASS": ("equation-error", "graph")}

    def detect(self, ctx: nm.Context, nom: nm.Nominal) -> Detection:
        m = nom.model
        u = _u_fast(m, ctx)
        na, nb, d = m.lin.na, max(m.lin.nb, 1), m.lin.delay
        idx = ctx.fit_idx[SETTLE:]
        rss_p, k = core.arx_rss(u, ctx.y, na, nb, d, idx)
        n = idx.size
        breaks = [int(frac * n) for frac in self.BREAKS]
        # the simulation part: the nominal output fit's columns (simulation, offset, start-up
        # transient) once, against the simulation's scale and offset on each side of a break
        # (the start-up transient stays one column: it belongs to the start, not to a change)
        cols = core.output_columns(m, ctx.x)[idx]
        Y = ctx.y[idx][:, None]
        draws = null_draws(ctx, nom)
        if draws is not None:
            Y = np.hstack([Y, draws[:, SETTLE:].T])
        sims = self.simulation_drops(Y, cols, breaks)  # (breaks, 1 + draws) in %
        sim_t = self.SIM_DROP
        if draws is not None:
            sim_t = max(sim_t, null.percentile(sims[:, 1:].max(axis=0)))
        best = (-np.inf, 0, 0.0, 0.0, 0.0)
        for j, b in enumerate(breaks):
            r1, _ = core.arx_rss(u, ctx.y, na, nb, d, idx[:b])
            r2, _ = core.arx_rss(u, ctx.y, na, nb, d, idx[b:])
            f = ((rss_p - r1 - r2) / k) / ((r1 + r2) / max(n - 2 * k, 1))
            eq = 100.0 * (1.0 - (r1 + r2) / rss_p) if rss_p > 0 else 0.0
            sim = float(sims[j, 0])
            stat = max(eq / self.EQ_DROP, sim / sim_t)
            if stat > best[0]:
                best = (stat, b, float(f), eq, sim)
        stat, b, f, eq, sim = best
        p = min(1.0, stats.f_pvalue(f, k, n - 2 * k) * self.BREAKS.size)
        at = b + SETTLE
        null_note = (
            f"; the simulation's threshold is the {null.QUANTILE:g}th percentile of the "
            f"largest drop over {draws.shape[0]} draws of the nominal noise model"
            if draws is not None and sim_t > self.SIM_DROP
            else ""
        )
        return self._det(
            stat,
            p,
            f"separate fits before and after {100 * at / ctx.n_fit:.0f} % "
            f"of the fit part (t = {at * ctx.h:.4g} s) lower the equation-error RSS "
            f"by {eq:.3g} % and the simulation's by {sim:.3g} % (Chow F {f:.3g}, "
            f"Bonferroni p = {format_p(p)}); statistic: the larger drop over its "
            f"threshold ({self.EQ_DROP:g} %, {sim_t:.3g} %){null_note}",
            at=at,
        )

    @staticmethod
    def simulation_drops(Y: np.ndarray, cols: np.ndarray, breaks: list[int]) -> np.ndarray:
        """The simulation part's RSS drop (in %) of every column of ``Y`` (``(n, m)``) at
        every break: the columns ``cols`` (``(n, k)``; the first is the simulation, the
        second the offset) fitted once, against the first two fitted on each side of the
        break (the rest kept common). Returns ``(len(breaks), m)``; a column the one fit
        already explains to rounding (RSS below 1e-12 of its variation about its mean) has no
        drop."""
        n = Y.shape[0]
        base = null.projection_rss(Y, cols)
        Yc = Y - Y.mean(axis=0)
        ok = base > 1e-12 * np.einsum("nm,nm->m", Yc, Yc)
        safe = np.where(ok, base, 1.0)
        out = np.zeros((len(breaks), Y.shape[1]))
        for j, b in enumerate(breaks):
            after = (np.arange(n) >= b)[:, None]
            X = np.hstack([cols[:, :2] * ~after, cols[:, :2] * after, cols[:, 2:]])
            rss = null.projection_rss(Y, X)
            out[j] = np.where(ok, 100.0 * (1.0 - rss / safe), 0.0)
        return out

    def segment_start(self, ctx: nm.Context, det: Detection) -> int:
        """Where the extension's segment starts (fast samples into the fit part): the
        detector's break when it fired, else the start of the fit part's last :data:`LATEST`
        share.

        The extension is a model of the regime the validation part continues, so its segment
        must hold no data from before the change: a segment that starts before it fits a
        mixture of the two regimes. A fired detector has located the change; a quiet one's
        best break is mostly noise and often lies before the change. The most recent window
        is then the model of the current regime, at the cost of the data before it (a
        sliding-window estimate). Measurements and the alternative of choosing the start by
        how well each start's model simulates the fit part's end:
        ``docs/experiments/time-varying-segment.md``."""
        if det.fired:
            return int(det.info["at"])
        return round((1.0 - self.LATEST) * ctx.n_fit)

    def extend(self, ctx: nm.Context, nom: nm.Nominal, det: Detection) -> core.Model:
        self.check_settings()
        b = self.segment_start(ctx, det)
        idx = ctx.fit_idx[b:]
        cands = [nm.nominal_family_fit(nom.model, ctx, idx)]
        k0 = -(-b // ctx.p)
        if ctx.p >= 2 and nom.estimate is not None and ctx.k_fit - k0 >= nm.MIN_FIT:
            try:
                cands.append(nm.arx_refine(self.segment_blind(ctx, nom, k0), ctx, idx))
            except Exception as exc:  # a valid record gets a diagnosis: the family fit stands
                note = f"the blind route on the segment failed ({describe(exc)})"
                cands[0] = cands[0].with_(info={**cands[0].info, "notes": [note]})
        m = cands[0] if len(cands) == 1 else min(cands, key=lambda c: _sim_rss_or_inf(ctx, c, idx))
        m.info["segment_start"] = b
        return m

    def segment_blind(self, ctx: nm.Context, nom: nm.Nominal, k0: int) -> core.Model:
        """The blind route run again on the fit part's slow samples ``k0`` on (the nominal's
        method and delay multiple), its valve class chosen as :attr:`SEGMENT_CLASS` says.
        The model's output scale and offset belong to the segment; the caller refits them.
        Its ``info`` is the segment's own (orders, delay, class fits)."""
        self.check_settings()
        kw = _nominal_kw(ctx, nom)
        seg = ctx.fit_segment(k0)
        est = nm.identify_blind(seg, kw["method"], delay_multiple=kw["delay_multiple"])
        route = nm.blind_model if self.SEGMENT_CLASS == "equation-error" else nm.model_from_blind
        return route(seg, est, delay_multiple=kw["delay_multiple"], label="time-varying")[0]


# --------------------------------------------------------------------------- order


class Order(Effect):
    """Order: structure that one more pole (and zero) removes.

    Statistic: how much (in %) the equation-error regression's RSS drops with ``na + 1,
    nb + 1`` against the nominal family's largest order ``na`` (2 for the blind route: an
    ``na = 1`` choice inside the family is the nominal's own business; the ``p = 1`` route's
    selected order), with the nominal inner signal; an effect size rather than the F
    statistic, which grows with the record until any small misfit of the actuator model is
    "significant" (the p-value, from ``F(2, n - k)``, is reported). Coloured equation noise
    also lowers it (its pole passes for one of the plant): the two extensions then compete
    on the validation fit. Extension: the
    linear part re-fitted by output error with ``na + 1`` (and ``na + 2`` when that has the
    smaller BIC) poles and zeros.
    """

    name = "order"
    summary = "residual structure removed by na + 1; extension: higher order"
    threshold = 40.0

    def _na0(self, ctx: nm.Context, nom: nm.Nominal) -> int:
        if ctx.p >= 2:
            return max(nm.NA_NOMINAL[1], nom.model.lin.na)
        return nom.model.lin.na

    def detect(self, ctx: nm.Context, nom: nm.Nominal) -> Detection:
        m = nom.model
        u = _u_fast(m, ctx)
        na0 = self._na0(ctx, nom)
        nb0 = max(m.lin.nb, na0 if ctx.p == 1 else m.lin.nb, 1)
        d = m.lin.delay
        idx = ctx.fit_idx
        r0, k0 = core.arx_rss(u, ctx.y, na0, nb0, d, idx)
        r1, k1 = core.arx_rss(u, ctx.y, na0 + 1, nb0 + 1, d, idx)
        n = idx.size
        f = ((r0 - r1) / (k1 - k0)) / (r1 / max(n - k1, 1))
        p = stats.f_pvalue(f, k1 - k0, n - k1)
        drop = 100.0 * (1.0 - r1 / r0) if r0 > 0 else 0.0
        return self._det(
            drop,
            p,
            f"one more pole and zero (na {na0} -> {na0 + 1}) lower the "
            f"equation-error RSS by {drop:.3g} % (F = {f:.3g}, p = {format_p(p)})",
            na0=na0,
            nb0=nb0,
        )

    def extend(self, ctx: nm.Context, nom: nm.Nominal, det: Detection) -> core.Model:
        na0 = int(det.info["na0"])
        kw = _nominal_kw(ctx, nom)
        best: tuple[float, core.Model] | None = None
        for na in (na0 + 1, na0 + 2):
            if ctx.p >= 2 and nom.estimate is not None:
                try:
                    est = nm.identify_blind(
                        ctx,
                        kw["method"],
                        na=na,
                        na_range=(1, na),
                        delay_multiple=kw["delay_multiple"],
                    )
                except Exception:
                    est = None
                if est is not None:
                    cand_m = _blind_model_of(ctx, kw, est, "order")
                else:
                    cand_m = core.fit_output(
                        nm.refit_linear(
                            nom.model, ctx, ctx.fit_idx, na=na, nb=max(nom.model.lin.nb, 1) + 1
                        ),
                        ctx.x,
                        ctx.y,
                        ctx.fit_idx,
                    )
            else:
                cand_m = core.fit_output(
                    nm.refit_linear(nom.model, ctx, ctx.fit_idx, na=na, nb=na),
                    ctx.x,
                    ctx.y,
                    ctx.fit_idx,
                )
            bic = _simulation_bic(ctx, cand_m)
            if best is None or bic < best[0]:
                best = (bic, cand_m)
        assert best is not None
        return best[1]


BUILTIN: tuple[type[Effect], ...] = (ColoredNoise, Drift, Delay, Outliers, TimeVarying, Order)

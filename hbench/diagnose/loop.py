"""Closed-loop re-simulation: the validation criterion ``closed-loop`` of a record that carries r.

The controller is identified from the record itself. It sees ``e(n) = r(n) - y(p n)`` (the
fast sample at the start of slow period ``n``, :mod:`hbench.model.controllers`) and puts out
``x(n)``; two structures are fitted by least squares over the whole record:

* ``P``: ``x(n) = b0 e(n) + c`` (a proportional controller with a bias);
* ``PI``: ``x(n) - x(n-1) = b0 e(n) + b1 e(n-1)`` (the velocity form of ``b0 + b1 q^-1`` over
  ``1 - q^-1``: ``kp = -b1``, ``ki T = b0 + b1``).

The controller's equation holds exactly (``x`` is computed from the measured ``y``; the noise
is in ``e`` and the equation has none), so the right structure leaves only rounding. The
structure with the smaller ``BIC = n ln(RSS / n) + k ln n`` is taken (both have ``k = 2``; the
RSS is floored at ``1e-20`` of the variation of ``x`` about its mean, where ``P`` wins the tie:
``PI`` nests a ``P`` without bias); ``structure`` fixes it instead (the CLI's
``--controller``).

The re-simulation runs the loop with the model in place of the plant and the valve: at slow
period ``n``

    y_hat(p n) = gain [G(q) (u - u(0))](p n) + offset + trend(p n) + init s(p n),
    e_hat(n) = r(n) - y_hat(p n),   x_hat(n) = controller(e_hat, x_hat),
    u(n) = f(x_hat(n - shift); theta),

with ``G``, ``f``, ``shift`` and the output terms (``s`` the start-up step response) those of
:class:`hbench.diagnose.core.Model`; ``G`` is strictly proper at the fast rate
(``num[0] = 0``), so ``y_hat(p n)`` needs ``u`` up to period ``n - 1`` only, and ``u(n)`` is
held over the ``p`` fast samples of period ``n``. It starts at the record's first controller
output, ``x_hat(0) = x(0)``. With ``x_hat = x`` forced it is the model's open-loop simulation
(:meth:`~hbench.diagnose.core.Model.simulate`). In the loop the controller corrects what the
model gets wrong at low frequencies as it corrects the process noise, so the error does not
integrate on a slow plant (poles near 1) as the open-loop simulation's does; what remains is
the error of the model inside the loop's bandwidth. Noise-free, with the record's own model,
it reproduces ``y``.

A model and controller whose loop is unstable diverge: from the first fast sample where the
re-simulated output is no longer finite (it overflowed), the rest of ``y_hat`` is an infinity
(of the overflow's sign where it has one: ``_diverged``) and the later ``x_hat`` are ``nan``;
the fit is then ``-inf``, which the findings print as diverging. Numpy's overflow warnings are
not raised on the way. (A valve's limit may be infinite: a one-sided saturation. A model or
controller with a parameter that is not a number, or with dynamics or a controller that are
not finite, is simulated as it is, without this check.)
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import signal

from hbench.diagnose import core
from hbench.errors import InputError

#: The controller structures :func:`identify_controller` fits.
STRUCTURES: tuple[str, ...] = ("P", "PI")
#: The RSS floor of the structure choice, relative to the variation of ``x`` about its mean.
RSS_FLOOR = 1e-20
#: :meth:`LoopController.describe` shows a bias at or below this share of the largest ``|x|``
#: as 0 (a least-squares zero, e.g. 1e-19 for a controller without a bias).
BIAS_ZERO = 1e-9


@dataclass(frozen=True)
class LoopController:
    """``x(n) = a x(n-1) + b0 e(n) + b1 e(n-1) + c`` (``P``: ``a = b1 = 0``; ``PI``: ``a = 1,
    c = 0``), with the residual sum of squares of its fit to the record."""

    structure: str
    b0: float
    b1: float
    c: float
    rss: float
    #: The largest ``|x|`` of the record it was fitted to (what a bias is small against).
    x_scale: float = 0.0

    @property
    def a(self) -> float:
        return 1.0 if self.structure == "PI" else 0.0

    def describe(self) -> str:
        """One line: the structure and its parameters."""
        if self.structure == "P":
            c = 0.0 if abs(self.c) <= BIAS_ZERO * self.x_scale else self.c
            return f"P, kp {self.b0:.4g}, bias {c:.4g}"
        return f"PI, kp {-self.b1:.4g}, ki T {self.b0 + self.b1:.4g}"


def controller_error(y: np.ndarray, r: np.ndarray, p: int) -> np.ndarray:
    """``e(n) = r(n) - y(p n)``, what the controller saw."""
    return np.asarray(r, float) - np.asarray(y, float)[:: int(p)][: np.asarray(r).size]


def identify_controller(x: np.ndarray, e: np.ndarray, structure: str = "auto") -> LoopController:
    """The controller from ``(e, x)`` at the slow rate, by least squares (module notes).

    Parameters
    ----------
    x, e
        The controller's output and error, ``(K,)`` each.
    structure
        ``auto`` (the smaller BIC), ``P`` or ``PI``.

    Returns
    -------
    LoopController
        The fitted controller.
    """
    x = np.asarray(x, float)
    e = np.asarray(e, float)
    wanted = structure.upper() if structure != "auto" else "auto"
    if wanted not in (*STRUCTURES, "auto"):
        raise InputError(f"unknown controller structure {structure!r} (choose auto, P or PI)")
    if x.size < 4:
        raise InputError("the record is too short to identify its controller")
    floor = RSS_FLOOR * max(float(np.sum((x - x.mean()) ** 2)), 1e-300)
    scale = float(np.max(np.abs(x)))  # what describe() judges a bias small against
    fits: dict[str, tuple[float, LoopController]] = {}
    for s in STRUCTURES if wanted == "auto" else (wanted,):
        if s == "P":
            X, t = np.stack([e, np.ones_like(e)], axis=1), x
        else:
            X, t = np.stack([e[1:], e[:-1]], axis=1), np.diff(x)
        th, *_ = np.linalg.lstsq(X, t, rcond=None)
        rss = float(np.sum((t - X @ th) ** 2))
        n = t.size
        bic = n * np.log(max(rss, floor) / n) + X.shape[1] * np.log(n)
        ctl = (
            LoopController("P", float(th[0]), 0.0, float(th[1]), rss, scale)
            if s == "P"
            else LoopController("PI", float(th[0]), float(th[1]), 0.0, rss, scale)
        )
        fits[s] = (bic, ctl)
    return min(fits.values(), key=lambda f: f[0])[1]


def _diverged(y_hat: np.ndarray, x_hat: np.ndarray, n: int, p: int) -> None:
    """Mark the loop diverged in period ``n`` (module notes): ``y_hat`` from its first sample
    in the period that is not finite on (from the next period where the period's output is
    finite and only ``x_hat(n)`` overflowed), ``x_hat`` ``nan`` after period ``n``. The fill
    is the first non-finite sample where it is an infinity, else an infinity of the sign of
    the last finite sample (a ``nan`` of an overflow's ``inf - inf`` or ``0 inf`` has no
    sign)."""
    t0 = n * p
    bad = np.flatnonzero(~np.isfinite(y_hat[t0 : t0 + p]))
    first = t0 + (int(bad[0]) if bad.size else p)
    if bad.size and np.isinf(y_hat[first]):
        v = float(y_hat[first])
    else:
        v = math.copysign(math.inf, y_hat[first - 1] if first > 0 else 1.0)
    y_hat[first:] = v
    x_hat[n + 1 :] = np.nan


def simulate_loop(
    model: core.Model, ctl: LoopController, r: np.ndarray, x0: float
) -> tuple[np.ndarray, np.ndarray]:
    """The loop of ``model`` and ``ctl`` driven by ``r`` (module notes), from ``x_hat(0) = x0``.

    Parameters
    ----------
    model
        The Hammerstein model in place of the valve and the plant.
    ctl
        The controller.
    r
        The reference at the slow rate, ``(K,)``.
    x0
        The record's first controller output.

    Returns
    -------
    y_hat : numpy.ndarray
        ``(K p,)``: the re-simulated output at the fast rate (``+-inf`` from where it
        overflows: module notes).
    x_hat : numpy.ndarray
        ``(K,)``: the re-simulated controller output (``nan`` after the period where the
        output overflows).
    """
    r = np.asarray(r, float)
    K, p = r.size, int(model.p)
    N = K * p
    num, a = model.lin.num, model.lin.a
    extra = np.full(N, float(model.offset))
    if model.trend.size:
        extra = extra + core.trend_basis(N, model.trend.size) @ model.trend
    if model.init.size:
        extra = extra + model.init[0] * core.step_response(model.lin, N)
    zi = np.zeros(max(num.size, a.size) - 1)
    y_hat, x_hat, u = np.empty(N), np.empty(K), np.empty(K)
    valve = core.nl_stepper(model.cls, model.theta, float(x0))
    e_prev = 0.0
    # a model without a nan among its numbers can give a non-finite output only by
    # overflowing (a valve's parameter may be infinite: a one-sided saturation)
    sound = (
        all(np.all(np.isfinite(v)) for v in (num, a, model.gain, extra, r, x0))
        and all(math.isfinite(v) for v in (ctl.b0, ctl.b1, ctl.c))
        and not any(math.isnan(float(v)) for v in model.theta.values())
    )
    with np.errstate(over="ignore", invalid="ignore"):  # a diverging loop: checked below
        for n in range(K):
            t0 = n * p
            # strictly proper G: its output at p n is the filter state's, before u(n) enters
            e = r[n] - (model.gain * zi[0] + extra[t0])
            if n == 0:
                x_hat[n] = x0
            else:
                x_hat[n] = ctl.a * x_hat[n - 1] + ctl.b0 * e + ctl.b1 * e_prev + ctl.c
            e_prev = e
            u[n] = valve(x_hat[n])
            un = u[n - model.shift] if n >= model.shift else u[0]
            z, zi = signal.lfilter(num, a, np.full(p, un - u[0]), zi=zi)
            y_hat[t0 : t0 + p] = model.gain * z + extra[t0 : t0 + p]
            if sound and not (math.isfinite(y_hat[t0 + p - 1]) and math.isfinite(x_hat[n])):
                _diverged(y_hat, x_hat, n, p)
                break
    return y_hat, x_hat

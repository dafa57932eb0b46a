"""Actuator (valve) models between the controller output x and the inner signal u.

Each model works on slow-rate sequences (one value per controller period), vectorised over runs:
``step(x, state)`` takes ``x`` of shape ``(runs,)`` and returns ``(u, state)``. Models with memory
(backlash, stiction) carry their state across calls, so a closed-loop simulation can call
``step`` once per slow period, and ``apply`` can continue from a previous state.

Static: :class:`Linear`, :class:`Deadband` (dead zone), :class:`Saturation`. With memory:
:class:`Backlash` (play operator), :class:`Stiction` (Choudhury et al. 2005) and
:class:`StictionHe` (He et al. 2007). ``BUILTIN`` lists them for :mod:`hbench.builtin`.
"""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np

from hbench.errors import InputError

State = dict[str, np.ndarray]


class Nonlinearity:
    """Base class of actuator models.

    Subclasses set ``name`` and ``has_memory``, define ``__init__`` with keyword parameters
    (validated, with clear errors), and implement ``initial_state`` and ``step``. A static
    model may also override ``apply`` with a vectorised expression.
    """

    name: ClassVar[str] = ""
    has_memory: ClassVar[bool] = False

    def params(self) -> dict[str, Any]:
        """The model's parameters as plain numbers (for tables and reports)."""
        return {}

    def initial_state(self, runs: int, x0: np.ndarray | None = None) -> State:
        """State before the first sample; ``x0`` (shape ``(runs,)``) is the first input if known."""
        return {}

    def step(self, x: np.ndarray, state: State) -> tuple[np.ndarray, State]:
        """One slow period: ``u(n)`` from ``x(n)`` and the state; returns ``(u, new_state)``."""
        raise NotImplementedError

    def apply(self, x: np.ndarray, state: State | None = None) -> tuple[np.ndarray, State]:
        """Apply to a whole sequence ``x`` of shape ``(runs, K)`` (or ``(K,)``).

        Without ``state`` it starts from ``initial_state(runs, x[:, 0])``. Returns ``u`` of the
        same shape and the final state, so a later call can continue.
        """
        x = np.asarray(x, dtype=float)
        squeeze = x.ndim == 1
        x2 = np.atleast_2d(x)
        if state is None:
            state = self.initial_state(x2.shape[0], x2[:, 0] if x2.shape[1] else None)
        u = np.empty_like(x2)
        for n in range(x2.shape[1]):
            u[:, n], state = self.step(x2[:, n], state)
        return (u[0] if squeeze else u), state

    def __repr__(self) -> str:
        args = ", ".join(f"{k}={v!r}" for k, v in self.params().items())
        return f"{type(self).__name__}({args})"


# --------------------------------------------------------------------------- parameter checks


def _number(name: str, value: Any, finite: bool = True) -> float:
    """``value`` as a float; an :class:`InputError` naming ``name`` if it is not a number."""
    try:
        out = float(value)
    except (TypeError, ValueError):
        raise InputError(f"{name} must be a number, got {value!r}") from None
    if np.isnan(out) or (finite and not np.isfinite(out)):
        raise InputError(f"{name} must be a finite number, got {out}")
    return out


def _positive(name: str, value: Any, allow_zero: bool = True) -> float:
    value = _number(name, value)
    if value < 0 or (value == 0 and not allow_zero):
        raise InputError(f"{name} must be {'>=' if allow_zero else '>'} 0, got {value}")
    return value


def _optional(name: str, value: Any) -> float | None:
    return None if value is None else _number(name, value)


def _first_input(runs: int, x0: np.ndarray | None) -> np.ndarray | None:
    """``x0`` checked and as a float array of shape ``(runs,)`` (a scalar is broadcast)."""
    if int(runs) < 0:
        raise InputError(f"runs must be >= 0, got {runs}")
    if x0 is None:
        return None
    x0 = np.asarray(x0, dtype=float)
    if x0.shape not in {(), (int(runs),)}:
        raise InputError(f"x0 must have shape ({int(runs)},), got {x0.shape}")
    return np.broadcast_to(x0, (int(runs),)).copy()


def _start_output(u0: float | None, runs: int, x0: np.ndarray | None) -> np.ndarray:
    """The output before the first sample: ``u0``, or ``x0`` when ``u0`` is None (else 0)."""
    x0 = _first_input(runs, x0)
    if u0 is None and x0 is not None:
        return x0
    return np.full(int(runs), 0.0 if u0 is None else u0)


# --------------------------------------------------------------------------- static models


class _Static(Nonlinearity):
    """A memoryless model ``u = f(x)``: ``step`` and ``apply`` both evaluate ``_map``."""

    has_memory: ClassVar[bool] = False

    def _map(self, x: np.ndarray) -> np.ndarray:
        raise NotImplementedError

    def step(self, x: np.ndarray, state: State) -> tuple[np.ndarray, State]:
        """One slow period: ``u(n) = f(x(n))``; the (empty) state is passed through."""
        return self._map(np.asarray(x, dtype=float)), state

    def apply(self, x: np.ndarray, state: State | None = None) -> tuple[np.ndarray, State]:
        """``f`` applied elementwise to ``x`` of any shape, without a loop over time."""
        return self._map(np.asarray(x, dtype=float)), ({} if state is None else state)


class Linear(_Static):
    """A linear actuator, ``u = gain * x``: the reference case with no nonlinearity.

    Parameters
    ----------
    gain : float, default 1.0
        Static gain (finite, non-zero).

    Notes
    -----
    The trivial Hammerstein nonlinearity; a benchmark's control case.
    """

    name: ClassVar[str] = "linear"

    def __init__(self, *, gain: float = 1.0) -> None:
        self.gain = _number("linear: gain", gain)
        if self.gain == 0:
            raise InputError("linear: gain must be non-zero, got 0.0")

    def params(self) -> dict[str, Any]:
        """``{"gain": gain}``."""
        return {"gain": self.gain}

    def _map(self, x: np.ndarray) -> np.ndarray:
        return self.gain * x


class Deadband(_Static):
    """A dead zone: zero output inside the band ``[-d1, d2]``, slope ``m`` outside.

    .. math::

        u = \\begin{cases} m (x - d_2) & x > d_2 \\\\ 0 & -d_1 \\le x \\le d_2 \\\\
            m (x + d_1) & x < -d_1 \\end{cases}

    This is a *dead zone* (a static map). Valve papers sometimes say "deadband" for backlash;
    here backlash is :class:`Backlash`.

    Parameters
    ----------
    d1, d2 : float, default 0.05
        Widths of the band below and above zero (>= 0).
    slope : float, default 1.0
        Slope ``m`` outside the band (finite, non-zero).

    References
    ----------
    G. Tao and P. V. Kokotović, *Adaptive Control of Systems with Actuator and Sensor
    Nonlinearities*, Wiley, 1996 (dead-zone model).
    """

    name: ClassVar[str] = "deadband"

    def __init__(self, *, d1: float = 0.05, d2: float = 0.05, slope: float = 1.0) -> None:
        self.d1 = _positive("deadband: d1", d1)
        self.d2 = _positive("deadband: d2", d2)
        self.slope = _number("deadband: slope", slope)
        if self.slope == 0:
            raise InputError("deadband: slope must be non-zero, got 0.0")

    def params(self) -> dict[str, Any]:
        """``{"d1": d1, "d2": d2, "slope": m}``."""
        return {"d1": self.d1, "d2": self.d2, "slope": self.slope}

    def _map(self, x: np.ndarray) -> np.ndarray:
        # x - clip(x) is x - d2 above the band, exactly 0 inside and x + d1 below.
        return self.slope * (x - np.clip(x, -self.d1, self.d2))


class Saturation(_Static):
    """A range limit, ``u = min(max(x, u_min), u_max)``.

    Parameters
    ----------
    u_min, u_max : float, default -0.2 and 0.2
        Limits, ``u_min < u_max``; either may be infinite for a one-sided limit.

    References
    ----------
    K. J. Åström and T. Hägglund, *Advanced PID Control*, ISA, 2006 (actuator saturation
    and integrator windup).
    """

    name: ClassVar[str] = "saturation"

    def __init__(self, *, u_min: float = -0.2, u_max: float = 0.2) -> None:
        self.u_min = _number("saturation: u_min", u_min, finite=False)
        self.u_max = _number("saturation: u_max", u_max, finite=False)
        if not self.u_min < self.u_max:
            raise InputError(
                f"saturation: u_min must be < u_max, got u_min={self.u_min}, u_max={self.u_max}"
            )

    def params(self) -> dict[str, Any]:
        """``{"u_min": u_min, "u_max": u_max}``."""
        return {"u_min": self.u_min, "u_max": self.u_max}

    def _map(self, x: np.ndarray) -> np.ndarray:
        return np.clip(x, self.u_min, self.u_max)


# --------------------------------------------------------------------------- models with memory


class Backlash(Nonlinearity):
    """Backlash (play operator) of total width ``d``.

    .. math:: u(k) = \\max\\bigl(x(k) - d/2,\\ \\min(x(k) + d/2,\\ u(k-1))\\bigr)

    The output stays put while the input moves inside a band of width ``d`` around it and is
    dragged along, ``d/2`` behind the input, once the input pushes at either edge. The paper's
    "dead-band 0.1" is ``d = 0.1``.

    Parameters
    ----------
    d : float, default 0.1
        Total width of the play (>= 0; ``d = 0`` is the identity).
    u0 : float or None, default 0.0
        Output before the first sample, ``u(-1)``. If None: the first input ``x0`` when
        :meth:`initial_state` is given it (``apply`` without a state passes ``x[:, 0]``), so
        the valve starts centred on its first input; else 0.

    Notes
    -----
    State: ``{"u_prev": u(k-1)}``. The first output is ``u0`` clipped into
    ``[x(0) - d/2, x(0) + d/2]``.

    References
    ----------
    M. A. Krasnosel'skiĭ and A. V. Pokrovskiĭ, *Systems with Hysteresis*, Springer, 1989
    (the play operator); G. Tao and P. V. Kokotović, *Adaptive Control of Systems with Actuator
    and Sensor Nonlinearities*, Wiley, 1996 (backlash).
    """

    name: ClassVar[str] = "backlash"
    has_memory: ClassVar[bool] = True

    def __init__(self, *, d: float = 0.1, u0: float | None = 0.0) -> None:
        self.d = _positive("backlash: width d", d)
        self.u0 = _optional("backlash: u0", u0)

    def params(self) -> dict[str, Any]:
        """``{"d": d, "u0": u0}`` (``u0`` may be None)."""
        return {"d": self.d, "u0": self.u0}

    def initial_state(self, runs: int, x0: np.ndarray | None = None) -> State:
        """``{"u_prev": u0}`` (or ``x0``, see ``u0``), shape ``(runs,)``."""
        return {"u_prev": _start_output(self.u0, runs, x0)}

    def step(self, x: np.ndarray, state: State) -> tuple[np.ndarray, State]:
        """``u(k) = max(x - d/2, min(x + d/2, u(k-1)))``."""
        x = np.asarray(x, dtype=float)
        half = self.d / 2
        u = np.maximum(x - half, np.minimum(x + half, state["u_prev"]))
        return u, {"u_prev": u.copy()}


class Stiction(Nonlinearity):
    """Valve stiction: the two-parameter data-driven model of Choudhury, Thornhill and Shah.

    Parameters
    ----------
    S : float, default 0.1
        Deadband plus stickband, in units of the input (>= 0).
    J : float, default 0.02
        Slip jump, ``0 <= J <= S``. ``J = 0`` is backlash of width ``S`` (see
        :class:`Backlash`); ``J = S`` gives no offset while the valve moves.
    u0 : float or None, default 0.0
        Valve position before the first sample. If None: the first input ``x0`` when
        :meth:`initial_state` is given it (``apply`` without a state passes ``x[:, 0]``); else 0.

    Notes
    -----
    **Update rules** (per run, vectorised with boolean masks). State: ``x_prev = x(k-1)``,
    ``u_prev = u(k-1)``, ``x_ss`` (input at which the valve stuck), ``direction`` ``d`` in
    {-1, +1} (direction of the valve's last movement) and the flag ``stuck``. Let
    ``h = (S - J)/2`` and ``v = sign(x(k) - x(k-1))``.

    1. *Stick.* A moving valve whose input stops or reverses (``not stuck`` and ``v != d``,
       including ``v = 0``) sticks: ``x_ss = x(k-1)``, ``stuck = True``.
    2. *Slip after a reversal.* A stuck valve with ``-d (x(k) - x_ss) > S`` slips backwards:
       ``d = -d``, ``u(k) = x(k) - d h``, ``stuck = False``.
    3. *Slip in the same direction* (after a stop, or after the input turned back while the
       valve was stuck). A stuck valve with ``d (x(k) - x_ss) > J`` slips on:
       ``u(k) = x(k) - d h``, ``stuck = False``.
    4. Otherwise a stuck valve keeps ``u(k) = u(k-1)``; a moving valve gives
       ``u(k) = x(k) - d h``.

    The tests are strict: an input exactly on a threshold leaves the valve stuck. Rules 2 and
    3 are checked in the step where the valve sticks, so a single reversal step larger than
    ``S`` moves the valve at once. At a reversal the output jumps by ``J`` when the input
    crosses ``x_ss - d S``; after a stop it jumps by ``J`` when the input crosses
    ``x_ss + d J``.

    **Initial state.** The valve is at rest (stuck) at ``u(-1) = u_init`` (``u0``, or ``x0``
    if ``u0`` is None) with ``d = +1`` and ``x_ss = u_init + h``, which is the state a valve
    that moved up and stopped at ``u_init`` would have. It breaks away once
    ``|x - u_init| > (S + J)/2``, in either direction, with a jump ``J``. With ``J = 0`` this
    is exactly :class:`Backlash` of width ``S`` with the same ``u0``, from the first sample.

    **Sources.** The paper (Control Engineering Practice 13:641-658, 2005) was not available
    while this was written; its flowchart is reconstructed from memory. From the paper: the
    parameters ``S`` and ``J``; sticking when the input velocity changes sign or becomes
    zero, remembering ``x_ss = x(k-1)``; slipping past ``S`` after a reversal and past ``J``
    when moving on in the same direction after a stop; ``u = x - sign(v) (S - J)/2`` when
    slipping or moving, ``u(k) = u(k-1)`` when stuck; ``J = 0`` a pure deadband (backlash)
    and ``J = S`` no offset.

    Our choices: (i) ``x_ss`` is captured only when a *moving* valve sticks. A literal reading
    of the flowchart re-captures ``x_ss`` at every sign change of the input, also while the
    valve is already stuck, so that on a noisy input a stuck valve forgets where it stuck and
    ``J = 0`` is no longer backlash. As far as we recall, the rule used here is that of Kano
    et al. (2004) (their "stopped" flag), so no separate Kano model is provided;
    :class:`StictionHe`, whose friction state remembers where the valve stuck by construction,
    agrees with these rules at every stop and reversal. (ii) Reversal versus same direction is
    judged against ``d``, the direction in which the valve last moved, not the sign of the
    last input step (the two agree whenever the valve is moving). (iii) Strict thresholds;
    a stop is an exactly repeated input, ``v = 0``. (iv) The initial state above. (v) No
    0-100 % clipping of the input (the paper's chart clips to the valve range; use
    :class:`Saturation` for a range limit).

    References
    ----------
    M. A. A. S. Choudhury, N. F. Thornhill and S. L. Shah, "Modelling valve stiction",
    *Control Engineering Practice* 13(5):641-658, 2005.
    M. Kano, H. Maruta, H. Kugemoto and K. Shimizu, "Practical model and detection algorithm
    for valve stiction", IFAC Symposium on Dynamics and Control of Process Systems (DYCOPS),
    2004.
    """

    name: ClassVar[str] = "stiction"
    has_memory: ClassVar[bool] = True

    def __init__(self, *, S: float = 0.1, J: float = 0.02, u0: float | None = 0.0) -> None:
        self.S = _positive("stiction: S (deadband plus stickband)", S)
        self.J = _positive("stiction: J (slip jump)", J)
        if self.J > self.S:
            raise InputError(
                f"stiction: J (slip jump) must not exceed S (deadband plus stickband), "
                f"got J={self.J} > S={self.S}"
            )
        self.u0 = _optional("stiction: u0", u0)

    def params(self) -> dict[str, Any]:
        """``{"S": S, "J": J, "u0": u0}`` (``u0`` may be None)."""
        return {"S": self.S, "J": self.J, "u0": self.u0}

    def initial_state(self, runs: int, x0: np.ndarray | None = None) -> State:
        """At rest at ``u0`` (or ``x0``): stuck, ``d = +1``, ``x_ss = u0 + (S - J)/2``."""
        u = _start_output(self.u0, runs, x0)
        first = _first_input(runs, x0)
        return {
            # x_prev only sets the sign of the first step of a *moving* valve: unused at rest.
            "x_prev": u.copy() if first is None else first,
            "u_prev": u,
            "x_ss": u + (self.S - self.J) / 2,
            "direction": np.ones_like(u),
            "stuck": np.ones(u.shape, dtype=bool),
        }

    def step(self, x: np.ndarray, state: State) -> tuple[np.ndarray, State]:
        """One slow period of the rules in the class notes, for all runs at once."""
        x = np.asarray(x, dtype=float)
        d = state["direction"]
        stuck = state["stuck"]
        sticks = ~stuck & (np.sign(x - state["x_prev"]) != d)
        x_ss = np.where(sticks, state["x_prev"], state["x_ss"])
        stuck = stuck | sticks
        ahead = d * (x - x_ss)  # > 0: beyond x_ss in the direction of the last movement
        reverse = stuck & (-ahead > self.S)
        go_on = stuck & (ahead > self.J)
        d = np.where(reverse, -d, d)
        stuck = stuck & ~(reverse | go_on)
        u = np.where(stuck, state["u_prev"], x - d * ((self.S - self.J) / 2))
        return u, {
            "x_prev": x.copy(),
            "u_prev": u.copy(),
            "x_ss": x_ss,
            "direction": d,
            "stuck": stuck,
        }


class StictionHe(Nonlinearity):
    """Valve stiction: the semi-physical model of He, Wang, Pottmann and Qin (2007).

    With ``e = x(k) - u(k-1)`` (the force the actuator puts on the stem, in input units):

    .. math::

        u(k) = \\begin{cases} x(k) - \\operatorname{sign}(e)\\, f_d & |e| > f_s \\\\
            u(k-1) & |e| \\le f_s \\end{cases}

    Parameters
    ----------
    f_s : float, default 0.06
        Static friction (>= 0).
    f_d : float, default 0.04
        Dynamic (kinetic) friction, ``0 <= f_d <= f_s``.
    u0 : float or None, default 0.0
        Valve position before the first sample; None: the first input ``x0`` if given, else 0.

    Notes
    -----
    The paper writes the state as a residual force ``u_r = x - u`` and updates
    ``temp = u_r(k-1) + x(k) - x(k-1)``; since ``temp = e`` the two forms are the same. State:
    ``{"u_prev": u(k-1)}``. Rules reconstructed from memory (the paper was not available).

    ``f_d = f_s`` is exactly :class:`Backlash` of width ``2 f_s``. Reversals and stops behave
    as :class:`Stiction` with ``S = f_s + f_d`` and ``J = f_s - f_d`` (the defaults match
    ``Stiction()``), from the same initial state; the two differ only while the valve moves:
    here an input step of at most ``J`` in the direction of motion sticks the valve again
    (stick-slip on slow ramps), in :class:`Stiction` the valve keeps moving.

    References
    ----------
    Q. P. He, J. Wang, M. Pottmann and S. J. Qin, "A curve fitting method for detecting valve
    stiction in oscillating control loops", *Industrial & Engineering Chemistry Research*
    46(13):4549-4560, 2007.
    """

    name: ClassVar[str] = "stiction-he"
    has_memory: ClassVar[bool] = True

    def __init__(self, *, f_s: float = 0.06, f_d: float = 0.04, u0: float | None = 0.0) -> None:
        self.f_s = _positive("stiction-he: f_s (static friction)", f_s)
        self.f_d = _positive("stiction-he: f_d (dynamic friction)", f_d)
        if self.f_d > self.f_s:
            raise InputError(
                f"stiction-he: f_d (dynamic friction) must not exceed f_s (static friction), "
                f"got f_d={self.f_d} > f_s={self.f_s}"
            )
        self.u0 = _optional("stiction-he: u0", u0)

    def params(self) -> dict[str, Any]:
        """``{"f_s": f_s, "f_d": f_d, "u0": u0}`` (``u0`` may be None)."""
        return {"f_s": self.f_s, "f_d": self.f_d, "u0": self.u0}

    def initial_state(self, runs: int, x0: np.ndarray | None = None) -> State:
        """``{"u_prev": u0}`` (or ``x0``, see ``u0``), shape ``(runs,)``."""
        return {"u_prev": _start_output(self.u0, runs, x0)}

    def step(self, x: np.ndarray, state: State) -> tuple[np.ndarray, State]:
        """Slip to ``x - sign(e) f_d`` if ``|e| > f_s``, else stay."""
        x = np.asarray(x, dtype=float)
        e = x - state["u_prev"]
        u = np.where(np.abs(e) > self.f_s, x - np.sign(e) * self.f_d, state["u_prev"])
        return u, {"u_prev": u.copy()}


BUILTIN: tuple[type[Nonlinearity], ...] = (
    Linear,
    Backlash,
    Deadband,
    Saturation,
    Stiction,
    StictionHe,
)

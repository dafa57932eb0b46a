"""The closed loop's compiled kernel: which controllers and actuators it runs, and the call.

:func:`hbench.sim.simulate._run_loop` is the numpy loop this kernel stands for (the same
operations in the same order); the library and the backend switch are
:mod:`hbench.numerics.kernels`'.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from hbench.model import nonlinearities as nl
from hbench.model.controllers import Controller
from hbench.numerics.kernels import active_library, as_f64

#: Built-in actuators the closed-loop kernel knows: ``type -> (code, parameter names)``.
NONLINEARITY_CODES: dict[type[nl.Nonlinearity], tuple[int, tuple[str, ...]]] = {
    nl.Linear: (0, ("gain",)),
    nl.Deadband: (1, ("d1", "d2", "slope")),
    nl.Saturation: (2, ("u_min", "u_max")),
    nl.Backlash: (3, ("d",)),
    nl.Stiction: (4, ("S", "J")),
    nl.StictionHe: (5, ("f_s", "f_d")),
}


#: The actuator state's fields, in the columns the kernel reads and updates.
_STATE = ("x_prev", "u_prev", "x_ss", "direction", "stuck")


def supports_loop(controller: Controller, nonlinearity: nl.Nonlinearity) -> bool:
    """True when :func:`closed_loop` can run this controller and actuator compiled."""
    ctl = type(controller)
    return (
        type(nonlinearity) in NONLINEARITY_CODES
        and ctl.step is Controller.step
        and ctl.initial_state is Controller.initial_state
        and controller.A.shape[0] <= 64
    )


def closed_loop(
    lp: Any,
    controller: Controller,
    nonlinearity: nl.Nonlinearity,
    r: np.ndarray,
    v_slow: np.ndarray,
    p: int,
) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """``(y0, x, U)`` of the closed loop, compiled; ``None`` when the numpy loop must run.

    The arguments are those of :func:`hbench.sim.simulate._run_loop` but for ``v_slow``, the noise
    at the controller's samples (``v[:, ::p]``).
    """
    lib = active_library()
    L = lp.Fp.shape[0]
    if lib is None or not supports_loop(controller, nonlinearity) or L > 64:
        return None
    R, K = r.shape
    code, names = NONLINEARITY_CODES[type(nonlinearity)]
    prm = as_f64([getattr(nonlinearity, n) for n in names])
    init = nonlinearity.initial_state(R)
    state = np.zeros((R, len(_STATE)))
    for j, key in enumerate(_STATE):
        if key in init:
            state[:, j] = init[key]
    y0 = np.empty((R, K * p))
    X = np.empty((R, K))
    U = np.empty((R, K))
    c = controller
    rc = lib.hb_closed_loop(
        R,
        K,
        L,
        p,
        as_f64(lp.Fp),
        as_f64(lp.Gp),
        as_f64(lp.Ob),
        as_f64(lp.Db),
        c.A.shape[0],
        as_f64(c.A),
        as_f64(c.B),
        as_f64(c.C),
        float(c.D),
        int(c.delay),
        code,
        prm,
        state,
        as_f64(r),
        as_f64(v_slow),
        y0,
        X,
        U,
    )
    if rc != 0:
        raise RuntimeError(f"hb_closed_loop failed with code {rc}")
    return y0, X, U

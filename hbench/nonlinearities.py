"""Actuator (valve) models between the controller output x and the inner signal u.

Each model works on slow-rate sequences (one value per controller period), vectorised over runs:
``step(x, state)`` takes ``x`` of shape ``(runs,)`` and returns ``(u, state)``. Models with memory
(backlash, stiction) carry their state across calls, so a closed-loop simulation can call
``step`` once per slow period, and ``apply`` can continue from a previous state.
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

        Returns ``u`` of the same shape and the final state, so a later call can continue.
        """
        x = np.asarray(x, dtype=float)
        squeeze = x.ndim == 1
        x2 = np.atleast_2d(x)
        if state is None:
            state = self.initial_state(x2.shape[0])
        u = np.empty_like(x2)
        for n in range(x2.shape[1]):
            u[:, n], state = self.step(x2[:, n], state)
        return (u[0] if squeeze else u), state

    def __repr__(self) -> str:
        args = ", ".join(f"{k}={v!r}" for k, v in self.params().items())
        return f"{type(self).__name__}({args})"


def _positive(name: str, value: float, allow_zero: bool = True) -> float:
    value = float(value)
    if not np.isfinite(value) or value < 0 or (value == 0 and not allow_zero):
        raise InputError(f"{name} must be {'>=' if allow_zero else '>'} 0, got {value}")
    return value

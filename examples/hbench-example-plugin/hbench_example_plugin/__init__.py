"""An example hbench plugin: a blind identification method, a quantising actuator and a
double-lag plant.

Registered through the ``hbench`` entry-point group (see ``pyproject.toml``), or at run time
with :func:`hbench.plugins.register_module`.
"""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np

import hbench
from hbench.errors import InputError
from hbench.hookspecs import Register
from hbench.model.nonlinearities import Nonlinearity, State
from hbench.model.plants import ContinuousPlant
from hbench_example_plugin.plain_ls import PlainLS

__all__ = ["PlainLS", "Quantizer", "double_lag"]


class Quantizer(Nonlinearity):
    """A static quantiser, ``u = q round(x / q)``: the actuator moves in steps of ``q``.

    Parameters
    ----------
    q : float, default 0.05
        Quantisation step (finite, > 0).
    """

    name: ClassVar[str] = "quantizer"
    has_memory: ClassVar[bool] = False

    def __init__(self, *, q: float = 0.05) -> None:
        try:
            q = float(q)
        except (TypeError, ValueError):
            raise InputError(f"quantizer: q must be a number, got {q!r}") from None
        if not (np.isfinite(q) and q > 0):
            raise InputError(f"quantizer: q must be a finite number > 0, got {q}")
        self.q = q

    def params(self) -> dict[str, Any]:
        return {"q": self.q}

    def _map(self, x: np.ndarray) -> np.ndarray:
        return self.q * np.round(np.asarray(x, dtype=float) / self.q)

    def step(self, x: np.ndarray, state: State) -> tuple[np.ndarray, State]:
        return self._map(x), state

    def apply(self, x: np.ndarray, state: State | None = None) -> tuple[np.ndarray, State]:
        """Elementwise on ``x`` of any shape, without a loop over time."""
        return self._map(x), ({} if state is None else state)


def double_lag(
    gain: float = 1.0, t1: float = 2.0, t2: float = 0.5, delay: int = 1
) -> ContinuousPlant:
    """``gain / ((t1 s + 1)(t2 s + 1))`` with ``delay`` fast samples: na = nb = 2."""
    if not (t1 > 0 and t2 > 0):
        raise InputError(f"double-lag: time constants must be > 0, got t1={t1}, t2={t2}")
    den = np.polymul([t1, 1.0], [t2, 1.0])
    return ContinuousPlant((float(gain),), tuple(float(v) for v in den), delay, 0.0, "double-lag")


@hbench.hookimpl
def register_identifiers(register: Register) -> None:
    register(PlainLS.name, PlainLS)


@hbench.hookimpl
def register_nonlinearities(register: Register) -> None:
    register(Quantizer.name, Quantizer)


@hbench.hookimpl
def register_plants(register: Register) -> None:
    register("double-lag", double_lag)

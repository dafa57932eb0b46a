"""Discrete controllers at the slow period T, vectorised over runs.

Every controller is a discrete state-space system in the error ``e(n) = r(n) - y(p n)``:
``x(n) = Cc s(n) + Dc e(n)``, ``s(n+1) = Ac s(n) + Bc e(n)``. The plant is strictly proper at the
fast rate, so ``y(p n)`` does not depend on ``x(n)`` and the loop holds at least one sample of delay
without any extra; ``delay`` adds whole slow samples of computational delay.
"""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np
from scipy import signal

from hbench.errors import InputError
from hbench.numerics.ordered import ordered_products


class Controller:
    """A SISO discrete transfer function ``C(z) = num(z^-1)/den(z^-1)`` at the slow period."""

    name: ClassVar[str] = "tf"

    def __init__(self, num: Any = (1.0,), den: Any = (1.0,), delay: int = 0) -> None:
        num = np.atleast_1d(np.asarray(num, dtype=float))
        den = np.atleast_1d(np.asarray(den, dtype=float))
        if den.size == 0 or den[0] == 0:
            raise InputError("controller denominator must start with a non-zero coefficient")
        if int(delay) != delay or delay < 0:
            raise InputError(f"controller delay must be a non-negative integer, got {delay}")
        self.num, self.den, self.delay = num / den[0], den / den[0], int(delay)
        # z^-1 polynomials of equal length -> z polynomials for tf2ss
        L = max(num.size, den.size)
        n_z = np.zeros(L)
        n_z[: num.size] = self.num
        d_z = np.zeros(L)
        d_z[: den.size] = self.den
        if L == 1:
            self.A, self.B = np.zeros((0, 0)), np.zeros(0)
            self.C, self.D = np.zeros(0), float(self.num[0])
        else:
            A, B, C, D = signal.tf2ss(n_z, d_z)
            self.A, self.B, self.C, self.D = A, B[:, 0], C[0], float(D[0, 0])

    def params(self) -> dict[str, Any]:
        return {"num": self.num.tolist(), "den": self.den.tolist(), "delay": self.delay}

    @property
    def order(self) -> int:
        """Number of states, computational delay included."""
        return self.A.shape[0] + self.delay

    def initial_state(self, runs: int) -> dict[str, np.ndarray]:
        return {"s": np.zeros((runs, self.A.shape[0])), "buf": np.zeros((runs, self.delay))}

    def step(self, e: np.ndarray, state: dict[str, np.ndarray]) -> tuple[np.ndarray, dict]:
        """Controller output ``x(n)`` from ``e(n)`` (shape ``(runs,)``); returns the new state."""
        s = state["s"]
        x = self.D * e
        if s.shape[1]:
            # sums in a fixed order, not @ or einsum: the same on any machine and for any
            # batch, and the arithmetic the compiled loop (hbench.numerics.kernels) mirrors
            x = x + ordered_products(s, self.C[None, :])[:, 0]
            s = ordered_products(s, self.A) + e[:, None] * self.B[None, :]
        buf = state["buf"]
        if self.delay:
            x, buf = buf[:, 0].copy(), np.concatenate([buf[:, 1:], x[:, None]], axis=1)
        return x, {"s": s, "buf": buf}

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self.params()})"


class P(Controller):
    """Proportional controller ``C(z) = kp`` (the paper's example: kp = 0.1)."""

    name: ClassVar[str] = "p"

    def __init__(self, kp: float = 0.1, delay: int = 0) -> None:
        self.kp = float(kp)
        super().__init__((self.kp,), (1.0,), delay)

    def params(self) -> dict[str, Any]:
        return {"kp": self.kp, "delay": self.delay}


class PI(Controller):
    """PI controller, backward-Euler integral: ``C(z) = kp + ki T / (1 - z^-1)``.

    ``ki`` is in 1/s, ``T`` the slow period in seconds.
    """

    name: ClassVar[str] = "pi"

    def __init__(self, kp: float = 0.1, ki: float = 0.01, T: float = 0.6, delay: int = 0) -> None:
        self.kp, self.ki, self.T = float(kp), float(ki), float(T)
        num = (self.kp + self.ki * self.T, -self.kp)
        super().__init__(num, (1.0, -1.0), delay)

    def params(self) -> dict[str, Any]:
        return {"kp": self.kp, "ki": self.ki, "T": self.T, "delay": self.delay}


BUILTIN: tuple[type[Controller], ...] = (P, PI, Controller)

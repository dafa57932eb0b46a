"""hbench: a benchmark suite for blind identification of closed-loop Hammerstein systems.

Data flows one way::

    Scenario -> simulate() -> Record (+ Truth, held apart) -> Identifier.identify() -> Estimate
             -> metrics -> tidy rows -> tables -> report

Arrays are batched over Monte Carlo runs with time last, as in ``scipy.signal``:
a fast-rate signal has shape ``(runs, N)``, a slow-rate one ``(runs, K)`` with ``N = K p``.
"""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("hbench")
except PackageNotFoundError:  # pragma: no cover - running from a source tree
    __version__ = "0+unknown"

__all__ = ["__version__"]

from hbench.hookspecs import hookimpl

__all__ += ["hookimpl"]

"""``hbench diagnose``: what a nominal Hammerstein model gets wrong on a measured record.

The workflow, one submodule per step:

* :mod:`~hbench.diagnose.nominal` - the nominal model: blind identification of ``G`` and ``U``
  for ``p >= 2``, a non-blind output-error route for a plant log (``p = 1``); the actuator class
  among ``linear, backlash, deadband, saturation, stiction`` with its parameters.
* :mod:`~hbench.diagnose.effects` - the catalogue of effects (``colored-noise, drift, delay,
  outliers, time-varying, order``), each a detector plus a model extension, registered on the
  ``register_effects`` hook.
* :mod:`~hbench.diagnose.validate` - fit on the first part of the record, validate on the rest,
  name the cause; the JSON of the contract.
* :mod:`~hbench.diagnose.loop` - the ``closed-loop`` validation criterion of a record with r:
  the controller identified from ``(r - y, x)``, the loop re-simulated from r.
* :mod:`~hbench.diagnose.report` - the HTML and Markdown pages.
* :mod:`~hbench.diagnose.generator` - synthetic records with one hidden effect (tests).

Module-level imports stay light: the command line imports this module at start-up.
"""

from __future__ import annotations

import argparse
from typing import Any

__all__ = ["add_parser"]


def _run(args: argparse.Namespace) -> int:
    from hbench.diagnose.cli import run

    return run(args)


def add_parser(subparsers: Any) -> None:
    """Add the ``diagnose`` command to the ``hbench`` command line."""
    p = subparsers.add_parser(
        "diagnose",
        help="diagnose a measured record: nominal model, effects, cause, gain",
        description="Fit a nominal Hammerstein model to the first part of RECORD (blindly for "
        "p >= 2, through an output-error model for a plant log with p = 1), test what its "
        "simulation gets wrong, name the cause among the catalogued effects, and report the "
        "validation fits of the nominal and the extended model on the rest of the record.",
    )
    p.add_argument("record", help="CSV/Parquet record (t, x, y[, r]) or a plant log")
    p.add_argument("--p", type=int, default=None, help="fast-sampling ratio (inferred from x)")
    p.add_argument(
        "--json",
        metavar="OUT",
        default=None,
        help="write the diagnosis as JSON to OUT ('-' for stdout)",
    )
    p.add_argument(
        "--out",
        metavar="DIR",
        default=None,
        help="write the HTML and Markdown report (with figures) to DIR",
    )
    p.add_argument(
        "--method",
        default="wang-lsm",
        help="blind method of the nominal model for p >= 2 (default wang-lsm)",
    )
    p.add_argument(
        "--fit-fraction",
        type=float,
        default=2 / 3,
        metavar="F",
        help="share of the record used for fitting; the rest validates (default 2/3)",
    )
    p.add_argument(
        "--criterion",
        default="auto",
        metavar="C",
        help="validation criterion the cause is chosen on: auto (default: the calibrated "
        "choice for a record with r, simulation otherwise), simulation, closed-loop "
        "(re-simulation of the loop from r with the identified controller), prediction "
        "(K-step-ahead with K the nominal noise model's dominant time constant) or "
        "prediction-K",
    )
    p.add_argument(
        "--controller",
        default="auto",
        choices=("auto", "P", "PI"),
        help="structure of the controller the closed-loop criterion identifies from (r - y, x): "
        "P, PI, or auto (default: the smaller BIC)",
    )
    p.add_argument(
        "--rule",
        default="auto",
        choices=("auto", "validation", "detectors"),
        help="how the cause is chosen: validation (every effect's extension is fitted, the one "
        "that gains the most validation fit is named; with its detector quiet, it must gain on "
        "each half of the validation part too), detectors (only the extensions of the "
        "detectors that fired), or auto (default: validation for p >= 2, detectors for p = 1)",
    )
    p.add_argument(
        "--delay-multiple",
        type=int,
        default=0,
        metavar="M",
        help="known multiple of p in the plant delay (assumption A3, default 0)",
    )
    p.add_argument(
        "--progress",
        default="auto",
        choices=("auto", "on", "off"),
        help="a line on stderr as each step ends: on, off, or auto (default: when stderr is a "
        "terminal, as git does)",
    )
    p.set_defaults(func=_run)

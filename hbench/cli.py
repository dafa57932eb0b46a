"""The ``hbench`` command line.

Exit status: 0 on success; 2 with a one-line message on stderr (no traceback) for bad input or
configuration; 1 for an internal error.
"""

from __future__ import annotations

import argparse
import gc
import importlib
import json
import os
import sys
from collections.abc import Sequence
from typing import NoReturn

from hbench.errors import InputError, MethodError, one_line_warnings
from hbench.system.writable import check_output


class Parser(argparse.ArgumentParser):
    """An argument parser whose usage errors are one line on stderr, with exit status 2.

    argparse prints the usage block before the error; the contract wants one line, so this
    prints ``hbench CMD: error: MESSAGE (see 'hbench CMD --help')``. Subcommand parsers made
    through ``add_subparsers`` are of the same class. ``--help`` is unchanged.
    """

    def error(self, message: str) -> NoReturn:
        """Print ``message`` on one line with a pointer to ``--help``; exit with status 2.

        Parameters
        ----------
        message : str
            argparse's message.
        """
        self.exit(2, usage_error_line(self.prog, message))


def usage_error_line(prog: str, message: str) -> str:
    """``PROG: error: MESSAGE (see 'PROG --help')``, one line (the message's whitespace joined)."""
    msg = " ".join(message.split())
    return f"{prog}: error: {msg} (see '{prog} --help')\n"


def _cmd_plugins(args: argparse.Namespace) -> int:
    from hbench.plugins import registry

    listing = registry().as_dict()
    if args.json:
        json.dump(listing, sys.stdout, indent=2)
        sys.stdout.write("\n")
        return 0
    for kind, entries in listing.items():
        print(f"{kind.replace('_', ' ')}:")
        if not entries:
            print("  (none)")
        for e in entries:
            print(f"  {e['name']:<22} {e['source']:<24} {e['object']}")
    from hbench.bench import kernel_status

    print(f"kernels: {kernel_status.status()}")
    return 0


def _cmd_inspect(args: argparse.Namespace) -> int:
    from hbench.io.readers import read_record
    from hbench.plugins import registry

    readers = [registry().get("readers", n) for n in registry().names("readers")]
    rec = read_record(args.record, p=args.p, readers=readers)
    for notice in rec.meta.get("notices", []):
        print(f"notice: {notice}", file=sys.stderr)
    info = {
        "record": str(args.record),
        "runs": rec.runs,
        "p": rec.p,
        "h": rec.h,
        "T": rec.T,
        "n_fast": rec.n_fast,
        "n_slow": rec.n_slow,
        "has_r": rec.r is not None,
    }
    print(json.dumps(info, indent=2))
    return 0


def _cmd_simulate(args: argparse.Namespace) -> int:
    import copy

    import numpy as np

    from hbench.io.readers import writable_kind, write_record
    from hbench.sim import scenarios
    from hbench.sim.simulate import simulate

    out = check_output(args.out, "--out")
    writable_kind(out)  # before the simulation, not after it
    if args.seed < 0:  # numpy's seeds are non-negative
        raise InputError(f"--seed must be >= 0, got {args.seed}")
    spec = copy.deepcopy(scenarios.PAPER_SECTION6)
    keys = [item.split("=", 1)[0] for item in args.set or [] if "=" in item]
    if "noise.sigma2" in keys and "noise.snr" in keys:
        raise InputError(
            "--set noise.sigma2 and --set noise.snr are both given: give one (the noise level "
            "by variance or by signal-to-noise ratio)"
        )
    for item in args.set or []:
        if "=" not in item:
            raise InputError(f"--set takes KEY=VALUE, got {item!r}")
        key, value = item.split("=", 1)
        value = scenarios.parse_value(value)
        if key in ("noise.sigma2", "noise.snr"):
            spec["noise"].pop("sigma2", None)
            spec["noise"].pop("snr", None)
        if key.endswith(".name"):  # a new plugin: drop the old one's parameters (not the level)
            group = key.split(".")[0]
            spec[group] = {
                k: v
                for k, v in spec.get(group, {}).items()
                if group == "noise" and k in ("sigma2", "snr")
            }
        scenarios.set_dotted(spec, key, value)
    scenario = scenarios.build(spec)
    record, truth = simulate(scenario, 1, np.random.default_rng(args.seed))
    out.parent.mkdir(parents=True, exist_ok=True)
    path = write_record(record, out)
    print(
        f"wrote {path} ({record.n_fast} fast samples, p = {record.p}, h = {record.h:g} s, "
        f"SNR = {truth.snr[0]:.3g})",
        file=sys.stderr,
    )
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = Parser(
        prog="hbench",
        description="Blind identification of closed-loop Hammerstein systems: a benchmark suite.",
    )
    from hbench import __version__

    parser.add_argument("--version", action="version", version=f"hbench {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")

    p = sub.add_parser("plugins", help="list registered methods, models and readers")
    p.add_argument("--json", action="store_true", help="machine-readable listing")
    p.set_defaults(func=_cmd_plugins)

    p = sub.add_parser("inspect", help="read and validate a record; print its layout")
    p.add_argument("record", help="CSV/Parquet record (t, x, y[, r]) or a plant log")
    p.add_argument("--p", type=int, default=None, help="fast-sampling ratio (inferred from x)")
    p.set_defaults(func=_cmd_inspect)

    p = sub.add_parser(
        "simulate",
        help="simulate one record of a scenario (the paper's example by default) to a file",
        description="Simulate one closed-loop record and write it as CSV or Parquet (t, x, y, r). "
        "Change the scenario with --set, e.g. --set nonlinearity.name=stiction "
        "--set nonlinearity.S=0.2 --set noise.snr=5 --set p=4.",
    )
    p.add_argument("--out", required=True, help="output file (.csv or .parquet)")
    p.add_argument("--seed", type=int, default=0, help="seed of the run (default 0)")
    p.add_argument(
        "--set",
        action="append",
        metavar="KEY=VALUE",
        help="override a scenario key (dotted), repeatable",
    )
    p.set_defaults(func=_cmd_simulate)

    for module_name in COMMAND_MODULES:
        importlib.import_module(module_name).add_parser(sub)
    return parser


#: Modules that each add one command through ``add_parser(subparsers)``; the parser sets
#: ``func(args) -> int``. Their module-level imports must stay light (start-up time).
COMMAND_MODULES: tuple[str, ...] = (
    "hbench.sweep.app",
    "hbench.paper.reproduce",
    "hbench.report.build",
    "hbench.diagnose",
)


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``hbench`` console script.

    A command runs with glibc's allocator tuned for the process
    (:func:`hbench.system.runtime.tune_allocator`; ``HBENCH_TUNE_MALLOC=0`` leaves it alone).
    """
    argv = list(sys.argv[1:] if argv is None else argv)
    parser = build_parser()
    args, extra = parser.parse_known_args(argv)
    if extra:  # name the command in the message, as its own errors do (its prog: "hbench CMD")
        command = getattr(args, "command", None)
        prog = f"{parser.prog} {command}" if command else parser.prog
        parser.exit(2, usage_error_line(prog, f"unrecognized arguments: {' '.join(extra)}"))
    if not getattr(args, "func", None):
        parser.print_help()
        return 0
    from hbench.system.runtime import tune_allocator

    tune_allocator()  # the command's own process (and the workers it forks): hbench.system.runtime
    try:
        with one_line_warnings(args.command):
            return int(args.func(args) or 0)
    except InputError as exc:
        msg = " ".join(str(exc).split())
        print(f"hbench {args.command}: error: {msg}", file=sys.stderr)
        return 2
    except MethodError as exc:  # a plugin broke its interface: internal, but not ours to trace
        msg = " ".join(str(exc).split())
        print(f"hbench {args.command}: error: {msg}", file=sys.stderr)
        return 1
    except FileNotFoundError as exc:
        print(f"hbench {args.command}: error: no such file: {exc.filename}", file=sys.stderr)
        return 2
    except (IsADirectoryError, NotADirectoryError, PermissionError, FileExistsError) as exc:
        if exc.filename is None:  # not about a path the user gave
            raise
        print(f"hbench {args.command}: error: {exc.filename}: {exc.strerror}", file=sys.stderr)
        return 2
    except BrokenPipeError:  # the reader went away (``hbench plugins | head``): stop quietly
        devnull = os.open(os.devnull, os.O_WRONLY)  # no second error when stdout is flushed
        os.dup2(devnull, sys.stdout.fileno())
        return 141  # as a command killed by SIGPIPE
    except KeyboardInterrupt:  # pragma: no cover
        print("interrupted", file=sys.stderr)
        return 130


def console() -> NoReturn:
    """The ``hbench`` console script (and ``python -m hbench.cli``): :func:`main`, then the
    process exits with what it holds left out of the garbage collector's passes
    (``gc.freeze``). The interpreter's shutdown otherwise runs full collections over every
    object of numpy, scipy, pandas and matplotlib while it clears their modules: ~0.3 s, a tenth
    of ``hbench reproduce``'s. Objects are still released, files closed and ``atexit``
    handlers run; only objects that nothing but a reference cycle keeps are not finalized (the
    collector would have found them; hbench closes its files in ``with`` blocks). Not in
    :func:`main`, which tests and programs call in their own process."""
    status = main()
    gc.freeze()
    sys.exit(status)


if __name__ == "__main__":  # pragma: no cover
    console()

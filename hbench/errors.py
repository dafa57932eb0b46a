"""Exceptions that the command line maps to exit statuses, and their one-line descriptions.

``InputError`` (and its subclasses) mean bad input or configuration: the command line prints its
message on one line and exits with status 2; ``OutputError`` (an output that cannot be written:
disk full, a read-only or pseudo file system) is one of them. ``MethodError`` (a plugin that
broke its interface) and ``AggregationError`` (finished jobs whose rows cannot be read) are
printed on one line with status 1. Anything else is an internal error (status 1, traceback).
"""

import contextlib
import sys
import traceback
import warnings
from collections.abc import Iterator
from typing import Any


class InputError(ValueError):
    """Bad input: a malformed record, an unknown plugin name, an invalid option."""


class RecordError(InputError):
    """A record file or array that cannot be used (missing column, NaN, non-uniform time ...)."""


class PluginNotFoundError(InputError, KeyError):
    """A plugin name that no registered plugin provides."""

    def __str__(self) -> str:  # KeyError would quote the message
        return str(self.args[0]) if self.args else ""


class UnstableError(InputError):
    """An unstable plant, controller or closed loop; the message says which."""


class OutputError(InputError):
    """An output file that cannot be written (no space left, a read-only file system, a folder
    that takes no files); nothing is left under its name (:mod:`hbench.system.atomic`)."""


class AggregationError(RuntimeError):
    """A sweep's tables cannot be written: a finished job's rows cannot be read. The message
    names the job's folder; the tables are left as they were."""


class MethodError(RuntimeError):
    """A method (an identifier plugin) broke its interface: it returned something that is not
    a valid :class:`hbench.ident.identifiers.Estimate` for the record, or raised where the command
    line calls it directly. The message names the method. Not bad input: the command line
    prints it on one line and exits with status 1; a benchmark cell records failed rows for
    that method only."""


def describe(exc: BaseException) -> str:
    """One line for a method's exception: its type, message and the file and line that raised
    it (a :class:`MethodError`, which names the method, as it is). Benchmark cells record it as
    the reason of the method's failed rows."""
    if isinstance(exc, MethodError):
        return " ".join(str(exc).split())
    where = ""
    if exc.__traceback__ is not None:
        last = traceback.extract_tb(exc.__traceback__)[-1]
        where = f" ({last.filename.rsplit('/', 1)[-1]}:{last.lineno})"
    return " ".join(f"{type(exc).__name__}: {exc}{where}".split())


@contextlib.contextmanager
def one_line_warnings(command: str) -> Iterator[None]:
    """Show warnings as ``hbench COMMAND: warning: MESSAGE (Category)`` on one line of stderr
    (Python's default adds the file, line and source line of the call) while inside.

    Only ``warnings.showwarning`` is swapped and restored: the filters stay as they are (a
    module imported inside may add its own, which must outlive the block). The command line
    wraps every command in it, and a sweep's task too (a launcher's worker process runs it
    outside the command line's block).
    """
    previous = warnings.showwarning

    def show(message: Warning | str, category: type[Warning], *args: Any, **kwargs: Any) -> None:
        text = " ".join(str(message).split())
        print(f"hbench {command}: warning: {text} ({category.__name__})", file=sys.stderr)

    warnings.showwarning = show
    try:
        yield
    finally:
        warnings.showwarning = previous


def tell(text: str, file: Any = None) -> None:
    """Print ``text`` (a progress or summary line) on ``file`` (stderr by default). Such lines
    are advisory: a closed stream (``hbench sweep ... 2>&1 | head``) is ignored, never an error
    that stops the work."""
    stream = sys.stderr if file is None else file
    if stream is None:  # no stderr (pythonw, a daemon): print(file=None) would go to stdout
        return
    try:
        print(text, file=stream, flush=True)
    except (OSError, ValueError):  # BrokenPipeError, a closed file
        pass

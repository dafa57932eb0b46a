"""Hydra, as the sweep uses it: the app run through the public ``hydra.main``, and the one hook
into Hydra's internals that no public API offers.

:func:`run_app` runs a task function exactly as a script decorated with ``@hydra.main`` would,
with ``argv`` as its command line. :func:`report_errors` is the only private access: Hydra
reports an exception raised during a run (the task's, or one of its own writes such as
``.hydra/config.yaml``) through ``hydra._internal.utils.run_and_report``, which prints a traceback
and exits with status 1 before a caller can see the exception; while inside the block that
function is wrapped so that ``handle`` sees the call first. Supported Hydra versions:
:data:`SUPPORTED` (``tests/test_hydra_adapter.py`` checks the installed one and the hook).
"""

from __future__ import annotations

import contextlib
import sys
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Any

#: Hydra release series whose internals :func:`report_errors` is written against.
SUPPORTED = ("1.3",)


def run_app(
    task: Callable[[Any], Any], argv: Sequence[str], config_dir: str | Path, config_name: str
) -> None:
    """Run ``task`` as ``@hydra.main`` does, with ``argv`` as Hydra's command line.

    Parameters
    ----------
    task : callable
        The task function, called with each job's config.
    argv : sequence of str
        Hydra's command line (overrides, ``--multirun``, ``--cfg job`` ...), without the program.
    config_dir : str or Path
        The primary config folder (absolute).
    config_name : str
        The primary config's name.
    """
    import hydra

    app = hydra.main(version_base="1.3", config_path=str(config_dir), config_name=config_name)
    saved = sys.argv
    sys.argv = [saved[0] if saved else "hbench", *argv]  # what hydra.main parses
    try:
        app(task)()
    finally:
        sys.argv = saved


@contextlib.contextmanager
def report_errors(handle: Callable[[Callable[[], Any]], Any]) -> Iterator[None]:
    """While inside, every call Hydra makes to report a run's exception goes through
    ``handle(func)`` first (``handle`` calls ``func`` and may turn its exception into another,
    e.g. ``SystemExit(2)`` after one line on stderr); restored when the block ends.

    Parameters
    ----------
    handle : callable
        ``handle(func) -> func()``'s value.
    """
    from hydra._internal import utils as hydra_utils

    original = hydra_utils.run_and_report
    hydra_utils.run_and_report = lambda func: original(lambda: handle(func))
    try:
        yield
    finally:
        hydra_utils.run_and_report = original

"""The ``hbench`` command run from the shell by the benchmarks, from this tree or from another
revision's source tree (``HBENCH_BENCH_BASELINE``), and the CPU seconds its processes took."""

from __future__ import annotations

import os
import resource
import subprocess
import sys

import pytest

#: Another revision's source tree (with its compiled kernels), run beside this one.
BASELINE = os.environ.get("HBENCH_BENCH_BASELINE")


def cpu_children() -> float:
    """CPU seconds (user + system) of the finished child processes of this one."""
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def tree_of(which: str) -> str | None:
    """The source tree of a ``this`` / ``baseline`` case: ``None`` for this tree,
    :data:`BASELINE` for the baseline (the case skips when it is not set)."""
    if which == "baseline" and not BASELINE:
        pytest.skip("HBENCH_BENCH_BASELINE (another revision's source tree) is not set")
    return BASELINE if which == "baseline" else None


def hbench(
    *args: str,
    tree: str | None = None,
    cpu: list[float] | None = None,
    module: str = "hbench.cli",
) -> subprocess.CompletedProcess[str]:
    """``python -m hbench.cli ARGS`` with this environment's interpreter; ``tree``: another
    revision's sources (and plugins) ahead of this one's; ``cpu``: the CPU seconds of the
    command's processes are appended to it; ``module``: another module that runs the command
    (e.g. ``benchmarks.without_figures``, from the working directory). Fails on a non-zero
    exit."""
    before = cpu_children()
    env = dict(os.environ)
    if tree is not None:  # another revision's sources ahead of this one's
        env["PYTHONPATH"] = os.pathsep.join([tree, os.path.join(tree, "plugins")])
    proc = subprocess.run(  # from the tree: ``-m`` puts the working directory first
        [sys.executable, "-m", module, *args],
        capture_output=True,
        text=True,
        env=env,
        cwd=tree,
    )
    assert proc.returncode == 0, proc.stderr[-2000:]
    if cpu is not None:
        cpu.append(cpu_children() - before)
    return proc

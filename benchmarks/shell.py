"""The ``hbench`` command run from the shell by the benchmarks, from this tree or from another
revision's source tree (``HBENCH_BENCH_BASELINE``), and the CPU seconds its processes took."""

from __future__ import annotations

import os
import resource
import subprocess
import sys


def cpu_children() -> float:
    """CPU seconds (user + system) of the finished child processes of this one."""
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def hbench(*args: str, tree: str | None = None) -> subprocess.CompletedProcess[str]:
    """``python -m hbench.cli ARGS`` with this environment's interpreter; ``tree``: another
    revision's sources (and plugins) ahead of this one's. Fails on a non-zero exit."""
    env = dict(os.environ)
    if tree is not None:  # another revision's sources ahead of this one's
        env["PYTHONPATH"] = os.pathsep.join([tree, os.path.join(tree, "plugins")])
    proc = subprocess.run(  # from the tree: ``-m`` puts the working directory first
        [sys.executable, "-m", "hbench.cli", *args],
        capture_output=True,
        text=True,
        env=env,
        cwd=tree,
    )
    assert proc.returncode == 0, proc.stderr[-2000:]
    return proc

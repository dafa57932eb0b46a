"""hbench.system.runtime: the process settings under which run_cell computes."""

from __future__ import annotations

import platform
import subprocess
import sys

import pytest
from threadpoolctl import threadpool_info

from hbench.system import runtime


def _blas_threads() -> list[int]:
    return [i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas"]


def test_batch_settings_use_one_blas_thread_and_restore_the_count():
    import numpy  # noqa: F401 - loads the BLAS library threadpoolctl inspects

    before = _blas_threads()
    assert before, "no BLAS library found"
    if max(before) == 1:
        pytest.skip("BLAS runs one thread here already: nothing to limit")
    for _ in range(2):  # the second time from the pools found the first time
        with runtime.batch_settings():
            assert all(n == 1 for n in _blas_threads())
        assert _blas_threads() == before


def test_the_allocator_is_tuned_once_and_only_on_glibc():
    first = runtime.tune_allocator()
    assert runtime.tune_allocator() is first  # decided once per process
    if platform.system() != "Linux" or platform.libc_ver()[0] != "glibc":
        assert first is False


def _allocator_tuned_after(code: str) -> bool:
    """Whether ``code``, run in a fresh interpreter, leaves the allocator tuned."""
    probe = (
        f"{code}\nfrom hbench.system import runtime\n"
        "print(runtime.tune_allocator.cache_info().currsize)"
    )
    out = subprocess.run(
        [sys.executable, "-c", probe], capture_output=True, text=True, check=True, timeout=120
    )
    return out.stdout.strip().splitlines()[-1] == "1"


def test_run_cell_leaves_the_process_allocator_alone():
    code = (
        "from hbench.sim import scenarios\n"
        "from hbench.bench.runner import methods_from_names, run_cell\n"
        "sc = scenarios.build(scenarios.PAPER_SECTION6)\n"
        "run_cell(sc, methods_from_names(['wang-lsm']), 2, 0)"
    )
    assert not _allocator_tuned_after(code)


def test_the_hbench_command_opts_in():
    assert _allocator_tuned_after("from hbench.cli import main\nmain(['plugins'])")


def test_collector_paused_restores_the_collector():
    import gc

    from hbench.system.runtime import collector_paused

    assert gc.isenabled()
    with collector_paused():
        assert not gc.isenabled()
    assert gc.isenabled()
    gc.disable()
    try:
        with collector_paused():
            pass
        assert not gc.isenabled()  # as it was
    finally:
        gc.enable()

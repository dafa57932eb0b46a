"""hbench.runtime: the process settings under which run_cell computes (issue 7)."""

from __future__ import annotations

import platform

import pytest
from threadpoolctl import threadpool_info

from hbench import runtime


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

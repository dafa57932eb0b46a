"""The reproduction's figures shared between two processes: ``hbench.report.figures``'s scheduler
(``render_many`` with ``_share``: a feeder thread hands the worker its next figure only when the
worker is free, this process renders what is left, costliest first) against the executor's own
queue (``queue``: every figure submitted at once, costliest first, this process taking back the
cheapest still waiting with ``Future.cancel``), in the same run.

The work is what ``hbench reproduce --runs 20`` renders, recorded from one run: Figures 4 and 5
and the x-U graphs submitted early to a worker forked after ``figures.warm_up`` (as
``reproduce`` does while the levels compute), then the report's figures rendered by
``render_many(specs, 2, workers=..., ready=...)``. Each round times the report's batch and the
wait for the early figures. ``test_share[queue]``, the later of the pair, records
``speedup_over_queue`` (the queue's wall over ``_share``'s): the bespoke scheduler is kept only
while it pays at least 1.3x (``docs/performance.md``).
"""

from __future__ import annotations

import contextlib
import shutil
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import pytest
from pytest_benchmark.fixture import BenchmarkFixture

from hbench.bench import parallel
from hbench.report import figures

_seconds: dict[str, float] = {}


def queue_share(
    specs: Sequence[figures.FigureSpec], todo: list[int], out: list[bytes], workers: Any
) -> None:
    """The baseline: every figure of ``todo`` (costliest first) submitted to ``workers`` at once;
    this process takes back the cheapest one no worker has taken (``Future.cancel``) and renders
    it, until none is left waiting."""
    futures = {i: workers.submit(figures._render, specs[i]) for i in todo}
    for i in reversed(todo):
        if not futures[i].cancel():
            break
        out[i] = figures._render(specs[i])
        del futures[i]
    for i, future in futures.items():
        out[i] = future.result()


@pytest.fixture(scope="module")
def recorded(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    """The specs ``hbench reproduce --runs 20`` submits early and renders in its report batch."""
    from hbench.paper.reproduce import reproduce

    early: list[figures.FigureSpec] = []
    batch: list[figures.FigureSpec] = []
    submit, render_many = figures.submit, figures.render_many

    def recording_submit(workers: Any, spec: figures.FigureSpec) -> Any:
        early.append(spec)
        return submit(workers, spec)

    def recording_render_many(specs: Sequence[figures.FigureSpec], *args: Any, **kw: Any) -> Any:
        batch.extend(specs)
        return render_many(specs, *args, **kw)

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(figures, "submit", recording_submit)
        mp.setattr(figures, "render_many", recording_render_many)
        reproduce(runs=20, out=tmp_path_factory.mktemp("reproduce"), jobs=2)
    assert early and batch, "reproduce rendered no figures"
    return {"early": early, "batch": batch}


def _moved(specs: Sequence[figures.FigureSpec], to: Path) -> list[figures.FigureSpec]:
    """``specs`` writing under ``to`` (kept apart from the recorded run's files)."""
    return [
        (None if s[0] is None else to / Path(s[0]).parent.name / Path(s[0]).name, *s[1:])
        for s in specs
    ]


@pytest.mark.parametrize("how", ["share", "queue"])
def test_share(
    benchmark: BenchmarkFixture, recorded: dict[str, Any], tmp_path: Path, how: str
) -> None:
    figures.warm_up()
    counter = iter(range(100))

    def setup() -> tuple[tuple[Any, ...], dict[str, Any]]:
        to = tmp_path / f"r{next(counter)}"
        early, batch = _moved(recorded["early"], to), _moved(recorded["batch"], to)
        for spec in (*early, *batch):
            if spec[0] is not None:
                Path(spec[0]).parent.mkdir(parents=True, exist_ok=True)
        return (early, batch), {}

    def run(early: list[figures.FigureSpec], batch: list[figures.FigureSpec]) -> list[bytes]:
        with contextlib.ExitStack() as stack:
            workers = stack.enter_context(parallel.pool(1))
            futures = [figures.submit(workers, spec) for spec in early]
            stems = {Path(b[0]) for b in batch if b[0] is not None}
            ready = {
                Path(s[0]): f
                for s, f in zip(early, futures, strict=True)
                if s[0] is not None and Path(s[0]) in stems
            }
            if how == "queue":
                stack.enter_context(_patched_share(queue_share))
            pngs = figures.render_many(batch, 2, workers=workers, ready=ready)
            for future in futures:
                future.result()
        return pngs

    pngs = benchmark.pedantic(run, setup=setup, rounds=5, iterations=1, warmup_rounds=1)
    assert all(pngs), "a figure rendered no PNG"
    _seconds[how] = benchmark.stats.stats.mean
    if {"share", "queue"} <= _seconds.keys():
        speedup = _seconds["queue"] / _seconds["share"]
        benchmark.extra_info["speedup_over_queue"] = speedup
        print(
            f"\nreport figures, two processes: _share {_seconds['share']:.2f} s, executor's "
            f"queue {_seconds['queue']:.2f} s (_share {speedup:.2f}x)"
        )
    shutil.rmtree(tmp_path, ignore_errors=True)


@contextlib.contextmanager
def _patched_share(share: Any) -> Any:
    """``render_many`` with ``share`` in place of ``figures._share`` (same arguments: the
    scheduler's extra ones ignored)."""

    def adapter(specs, todo, out, processes, workers, busy, stack):
        share(specs, todo, out, workers)

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(figures, "_share", adapter)
        yield

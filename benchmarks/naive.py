"""The naive baseline: the same work written plainly, one run at a time.

Each run is simulated alone (a batch of one), every method identifies it alone, the inner
signal of eq. (27) is solved by a dense least-squares solve, and the fitness is scored per run,
all on the pure-numpy path (no compiled kernels: ``hbench.numerics.kernels.use("numpy")``).
It computes the same estimates as the batched path (checked in ``bench_end_to_end.py``), so
every throughput figure of hbench can be quoted as a ratio against it, measured in the same
run. Not part of the package: a benchmark's yardstick only.
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping
from contextlib import contextmanager

import numpy as np

from hbench.bench.metrics import fitness
from hbench.ident import polyphase as pp
from hbench.ident.identifiers import Identifier, IdentifyOptions, identify
from hbench.numerics import kernels
from hbench.sim.simulate import Scenario, simulate


@contextmanager
def dense_inner_signal() -> Iterator[None]:
    """Route eq. (27) through :func:`hbench.ident.polyphase.inner_signal_dense` while active."""
    saved = pp.inner_signal_ls
    pp.inner_signal_ls = pp.inner_signal_dense
    try:
        yield
    finally:
        pp.inner_signal_ls = saved


def run_naive(
    scenario: Scenario,
    methods: Mapping[str, Identifier],
    runs: int,
    seed: int,
    *,
    dense: bool = True,
) -> dict[str, np.ndarray]:
    """Fitness per method and run, one run at a time (``dense``: eq. 27 by dense lstsq)."""
    options = IdentifyOptions(delay_multiple=scenario.discrete_plant.delay_multiple(scenario.p))
    out = {name: np.empty(runs) for name in methods}
    rng_seed = np.random.SeedSequence(seed)
    with kernels.use("numpy"), dense_inner_signal() if dense else _nothing():
        for i in range(runs):
            record, truth = simulate(scenario, 1, np.random.default_rng(rng_seed), start=i)
            for name, method in methods.items():
                est = identify(method, record, options, truth)
                out[name][i] = fitness(est.U, truth.U, "gain", truth.plant.gain)[0]
    return out


@contextmanager
def _nothing() -> Iterator[None]:
    yield

"""Seeding (Scientific Python SPEC 7): every random function takes a ``numpy.random.Generator``.

Runs are independent streams spawned from one parent through ``SeedSequence`` spawning, so run
``i`` draws the same numbers whether 10 or 10 000 runs are simulated, and whether they are
simulated in one batch or in chunks. Sweep cells derive their seed from the experiment axes, so a
cell's numbers do not depend on which other cells ran or in which order.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Mapping
from typing import Any

import numpy as np


def as_generator(rng: np.random.Generator | int | None) -> np.random.Generator:
    """Return ``rng`` if it is a Generator, else a new one seeded with it.

    ``None`` is refused: hbench never draws from an unseeded source.
    """
    if isinstance(rng, np.random.Generator):
        return rng
    if rng is None:
        raise TypeError("a seed or numpy.random.Generator is required (hbench never seeds itself)")
    return np.random.default_rng(rng)


def spawn_runs(rng: np.random.Generator, runs: int, start: int = 0) -> list[np.random.Generator]:
    """Independent child generators for runs ``start .. start + runs - 1``.

    Children are derived from the parent's ``SeedSequence`` by index, so the stream of run ``i``
    does not depend on how many runs are drawn or on chunking. The parent is not advanced.
    """
    seq = rng.bit_generator.seed_seq
    if not isinstance(seq, np.random.SeedSequence):  # pragma: no cover - exotic bit generators
        raise TypeError("the generator must be seeded through a numpy.random.SeedSequence")
    bitgen = type(rng.bit_generator)
    return [
        np.random.Generator(
            bitgen(
                np.random.SeedSequence(
                    seq.entropy, spawn_key=(*seq.spawn_key, i), pool_size=seq.pool_size
                )
            )
        )
        for i in range(start, start + runs)
    ]


def run_streams(
    rng: np.random.Generator, runs: int, names: tuple[str, ...], start: int = 0
) -> dict[str, list[np.random.Generator]]:
    """Per-run generators, one independent stream per named use (``"reference"``, ``"noise"``).

    Stream ``names[j]`` of run ``i`` is the child ``(i, j)`` of the parent's ``SeedSequence``, so
    adding a use, or withholding one (a reference shared by all runs), leaves the others unchanged.
    """
    seq = rng.bit_generator.seed_seq
    if not isinstance(seq, np.random.SeedSequence):  # pragma: no cover
        raise TypeError("the generator must be seeded through a numpy.random.SeedSequence")
    bitgen = type(rng.bit_generator)
    return {
        name: [
            np.random.Generator(
                bitgen(
                    np.random.SeedSequence(
                        seq.entropy, spawn_key=(*seq.spawn_key, i, j), pool_size=seq.pool_size
                    )
                )
            )
            for i in range(start, start + runs)
        ]
        for j, name in enumerate(names)
    }


def cell_seed(base_seed: int, axes: Mapping[str, Any]) -> np.random.SeedSequence:
    """A ``SeedSequence`` for one sweep cell, derived from the base seed and the cell's axes.

    The axes are serialised canonically (sorted keys) and hashed, so the seed of a cell depends
    only on its own coordinates.
    """
    blob = json.dumps(dict(axes), sort_keys=True, default=str).encode()
    digest = hashlib.sha256(blob).digest()
    words = [int.from_bytes(digest[i : i + 4], "little") for i in range(0, 16, 4)]
    return np.random.SeedSequence([int(base_seed), *words])

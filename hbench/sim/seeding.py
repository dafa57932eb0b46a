"""Seeding (Scientific Python SPEC 7): every random function takes a ``numpy.random.Generator``.

Runs are independent streams spawned from one parent through ``SeedSequence`` spawning, so run
``i`` draws the same numbers whether 10 or 10 000 runs are simulated, and whether they are
simulated in one batch or in chunks. Sweep cells derive their seed from the experiment axes, so a
cell's numbers do not depend on which other cells ran or in which order.
"""

from __future__ import annotations

import functools
import hashlib
import json
from collections.abc import Mapping
from typing import Any

import numpy as np
from numpy.random.bit_generator import ISpawnableSeedSequence


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
    seq = _seed_sequence(rng)
    return _children(seq, type(rng.bit_generator), [(i,) for i in range(start, start + runs)])


def run_streams(
    rng: np.random.Generator, runs: int, names: tuple[str, ...], start: int = 0
) -> dict[str, list[np.random.Generator]]:
    """Per-run generators, one independent stream per named use (``"reference"``, ``"noise"``).

    Stream ``names[j]`` of run ``i`` is the child ``(i, j)`` of the parent's ``SeedSequence``, so
    adding a use, or withholding one (a reference shared by all runs), leaves the others unchanged.
    """
    seq = _seed_sequence(rng)
    bitgen = type(rng.bit_generator)
    return {
        name: _children(seq, bitgen, [(i, j) for i in range(start, start + runs)])
        for j, name in enumerate(names)
    }


def _seed_sequence(rng: np.random.Generator) -> np.random.SeedSequence:
    seq = rng.bit_generator.seed_seq
    if isinstance(seq, _Seeded):  # a stream of hbench's, parent in its turn
        seq = seq._sequence()
    if not isinstance(seq, np.random.SeedSequence):
        raise TypeError("the generator must be seeded through a numpy.random.SeedSequence")
    return seq


def _child_sequence(seq: np.random.SeedSequence, key: tuple[int, ...]) -> np.random.SeedSequence:
    """The child of ``seq`` with spawn key ``seq.spawn_key + key`` (what ``seq.spawn`` makes)."""
    return np.random.SeedSequence(
        seq.entropy, spawn_key=(*seq.spawn_key, *key), pool_size=seq.pool_size
    )


def _children(
    seq: np.random.SeedSequence, bitgen: type, keys: list[tuple[int, ...]]
) -> list[np.random.Generator]:
    """``Generator(bitgen(child))`` for the children of ``seq`` with the given spawn-key suffixes.

    For PCG64 (``default_rng``'s) the children's seeds are computed for all of them at once by
    :func:`_pcg64_seeds`, which evaluates ``SeedSequence``'s hash on arrays: the same words as
    numpy's (checked against it once per process, and by the tests), ~20x faster than building
    one ``SeedSequence`` per stream. Other bit generators, and keys numpy would spread over
    several 32-bit words, take numpy's own route.
    """
    if bitgen is np.random.PCG64 and keys and _fast_seeding_agrees():
        words = _pcg64_seeds(seq, keys)
        if words is not None:
            return [
                np.random.Generator(np.random.PCG64(_Seeded(seq, key, w)))
                for key, w in zip(keys, words, strict=True)
            ]
    return [np.random.Generator(bitgen(_child_sequence(seq, key))) for key in keys]


# SeedSequence's constants (numpy/random/bit_generator.pyx, after M. E. O'Neill's seed_seq_fe)
_INIT_A, _MULT_A = 0x43B0D7E5, 0x931E8875
_INIT_B, _MULT_B = 0x8B51F9DD, 0x58F38DED
_MIX_L, _MIX_R = 0xCA01F9DD, 0x4973F715
_MASK32 = 0xFFFFFFFF


def _int_words(value: Any) -> list[int] | None:
    """The 32-bit words numpy's SeedSequence makes of an entropy or key value (least
    significant first), or None for values this module leaves to numpy."""
    if isinstance(value, (int, np.integer)) and not isinstance(value, bool) and value >= 0:
        n = int(value)
        out = [n & _MASK32]
        n >>= 32
        while n:
            out.append(n & _MASK32)
            n >>= 32
        return out
    if isinstance(value, (list, tuple)):
        words: list[int] = []
        for v in value:
            w = _int_words(v)
            if w is None:
                return None
            words.extend(w)
        return words
    return None


def _pcg64_seeds(seq: np.random.SeedSequence, keys: list[tuple[int, ...]]) -> np.ndarray | None:
    """``child.generate_state(4, np.uint64)`` of every child ``seq.spawn_key + key``, as one
    ``(len(keys), 4)`` array, or None when the keys do not all assemble to equally long entropy.

    The pool of each child is ``mix_entropy`` of its assembled entropy (the run entropy padded
    to the pool size, then the spawn key's words); the hash constants advance the same way for
    every child, so the children are the rows of uint32 arrays (wrapping products).
    """
    run = _int_words(seq.entropy) if seq.entropy is not None else None
    prefix = _int_words(tuple(seq.spawn_key))
    if run is None or prefix is None or not keys:
        return None
    if len(run) < seq.pool_size:
        run = run + [0] * (seq.pool_size - len(run))
    width = len(keys[0])
    try:
        suffix = np.array(keys, dtype=np.int64)
    except (OverflowError, ValueError):  # keys beyond int64, or of unequal lengths
        return None
    if suffix.ndim != 2 or suffix.shape[1] != width or suffix.min() < 0 or suffix.max() > _MASK32:
        return None  # a key word beyond 32 bits spreads over several words: numpy's route
    n = len(keys)
    entropy = np.empty((n, len(run) + len(prefix) + width), dtype=np.uint32)
    entropy[:, : len(run)] = run
    entropy[:, len(run) : len(run) + len(prefix)] = prefix
    entropy[:, len(run) + len(prefix) :] = suffix
    pool_size = seq.pool_size
    h = _INIT_A

    def hashmix(value: np.ndarray) -> np.ndarray:
        nonlocal h
        value = value ^ np.uint32(h)
        h = (h * _MULT_A) & _MASK32
        value = value * np.uint32(h)
        return value ^ (value >> np.uint32(16))

    def mix(x: np.ndarray, y: np.ndarray) -> np.ndarray:
        result = np.uint32(_MIX_L) * x - np.uint32(_MIX_R) * y
        return result ^ (result >> np.uint32(16))

    zero = np.zeros(n, dtype=np.uint32)
    pool = [hashmix(entropy[:, i] if i < entropy.shape[1] else zero) for i in range(pool_size)]
    for i_src in range(pool_size):
        for i_dst in range(pool_size):
            if i_src != i_dst:
                pool[i_dst] = mix(pool[i_dst], hashmix(pool[i_src]))
    for i_src in range(pool_size, entropy.shape[1]):
        for i_dst in range(pool_size):
            pool[i_dst] = mix(pool[i_dst], hashmix(entropy[:, i_src]))
    # generate_state(4, np.uint64): 8 words cycling through the pool, paired little-endian
    h = _INIT_B
    state = np.empty((n, 8), dtype=np.uint32)
    for i in range(8):
        value = pool[i % pool_size] ^ np.uint32(h)
        h = (h * _MULT_B) & _MASK32
        value = value * np.uint32(h)
        state[:, i] = value ^ (value >> np.uint32(16))
    return state[:, 0::2].astype(np.uint64) | (state[:, 1::2].astype(np.uint64) << np.uint64(32))


class _Seeded(ISpawnableSeedSequence):
    """A child ``SeedSequence`` whose PCG64 seed words were computed in bulk.

    PCG64 asks it for ``generate_state(4, np.uint64)`` and gets the precomputed words; anything
    else (other requests, ``spawn``, ``entropy``, ``spawn_key``, ``pool``...) is answered by the
    equal ``numpy.random.SeedSequence``, built when first needed.
    """

    __slots__ = ("_key", "_parent", "_seq", "_words")

    def __init__(self, parent: np.random.SeedSequence, key: tuple[int, ...], words: np.ndarray):
        self._parent, self._key, self._words = parent, key, words
        self._seq: np.random.SeedSequence | None = None

    def _sequence(self) -> np.random.SeedSequence:
        if self._seq is None:
            self._seq = _child_sequence(self._parent, self._key)
        return self._seq

    def generate_state(self, n_words: int, dtype: Any = np.uint32) -> np.ndarray:
        if n_words == 4 and np.dtype(dtype) == np.dtype(np.uint64):
            return self._words.copy()
        return self._sequence().generate_state(n_words, dtype)

    def spawn(self, n_children: int) -> list[np.random.SeedSequence]:
        return self._sequence().spawn(n_children)

    def __getattr__(self, name: str) -> Any:
        if name.startswith("_"):  # own slots (unset only on a bare instance) and dunders
            raise AttributeError(name)
        return getattr(self._sequence(), name)

    def __reduce__(self) -> tuple[Any, ...]:
        """Pickled as the SeedSequence it stands for (any protocol)."""
        return (_child_sequence, (self._parent, self._key))

    def __repr__(self) -> str:
        return repr(self._sequence())


@functools.cache
def _fast_seeding_agrees() -> bool:
    """Whether :func:`_pcg64_seeds` gives numpy's words (checked once per process on keys that
    exercise every branch); if a future numpy changed SeedSequence, numpy's route is taken."""
    seq = np.random.SeedSequence([7, 2**40 + 3, 0], spawn_key=(5,), pool_size=4)
    keys = [(0, 0), (1, 1), (2**32 - 1, 3)]
    got = _pcg64_seeds(seq, keys)
    want = [_child_sequence(seq, key).generate_state(4, np.uint64) for key in keys]
    return got is not None and bool(np.array_equal(got, np.stack(want)))


def cell_seed(base_seed: int, axes: Mapping[str, Any]) -> np.random.SeedSequence:
    """A ``SeedSequence`` for one sweep cell, derived from the base seed and the cell's axes.

    The axes are serialised canonically (sorted keys) and hashed, so the seed of a cell depends
    only on its own coordinates.
    """
    blob = json.dumps(dict(axes), sort_keys=True, default=str).encode()
    digest = hashlib.sha256(blob).digest()
    words = [int.from_bytes(digest[i : i + 4], "little") for i in range(0, 16, 4)]
    return np.random.SeedSequence([int(base_seed), *words])

"""Per-run streams: the bulk PCG64 seeding gives numpy's own children, bit for bit.

Exact equality throughout: the children's seeds are integer hashes, so any difference is a bug.
"""

from __future__ import annotations

import numpy as np
import pytest

from hbench import seeding


def _numpy_child(seq: np.random.SeedSequence, key: tuple[int, ...], bitgen=np.random.PCG64):
    return np.random.Generator(
        bitgen(
            np.random.SeedSequence(
                seq.entropy, spawn_key=(*seq.spawn_key, *key), pool_size=seq.pool_size
            )
        )
    )


PARENTS = [
    np.random.SeedSequence(0),
    np.random.SeedSequence(2026),
    np.random.SeedSequence(2**64 + 12345),  # entropy of three 32-bit words
    np.random.SeedSequence([2026, 1, 2**33, 4]),  # a cell seed's shape (hbench.seeding.cell_seed)
    np.random.SeedSequence([1, 2, 3, 4, 5, 6, 7]),  # entropy longer than the pool
    np.random.SeedSequence(77, spawn_key=(3, 9)),  # a parent that is itself a child
    np.random.SeedSequence(5, pool_size=8),
    np.random.SeedSequence(2**127 + 1, spawn_key=(2**32 - 1,), pool_size=6),
]


@pytest.mark.parametrize("seq", PARENTS, ids=range(len(PARENTS)))
def test_streams_are_numpys_children(seq: np.random.SeedSequence) -> None:
    rng = np.random.Generator(np.random.PCG64(seq))
    starts = (0, 2**32 - 3)  # the last runs' keys are the largest a 32-bit word holds
    for start in starts:
        streams = seeding.run_streams(rng, 3, ("reference", "noise"), start=start)
        for j, name in enumerate(("reference", "noise")):
            for i, g in enumerate(streams[name]):
                want = _numpy_child(seq, (start + i, j))
                assert g.bit_generator.state == want.bit_generator.state
                np.testing.assert_array_equal(g.standard_normal(7), want.standard_normal(7))
        for i, g in enumerate(seeding.spawn_runs(rng, 3, start=start)):
            assert g.bit_generator.state == _numpy_child(seq, (start + i,)).bit_generator.state


def test_keys_beyond_32_bits_and_other_bit_generators_take_numpys_route() -> None:
    seq = np.random.SeedSequence(11)
    rng = np.random.Generator(np.random.PCG64(seq))
    for i, g in enumerate(seeding.spawn_runs(rng, 3, start=2**32 - 1)):  # 2**32 needs two words
        assert g.bit_generator.state == _numpy_child(seq, (2**32 - 1 + i,)).bit_generator.state
    philox = np.random.Generator(np.random.Philox(seq))
    for i, g in enumerate(seeding.spawn_runs(philox, 2)):
        want = _numpy_child(seq, (i,), np.random.Philox)
        assert isinstance(g.bit_generator, np.random.Philox)
        np.testing.assert_array_equal(g.integers(0, 2**63, 8), want.integers(0, 2**63, 8))


def test_a_stream_keeps_its_seed_sequence() -> None:
    """The child answers as the SeedSequence it stands for: spawning, entropy, other states."""
    seq = np.random.SeedSequence(2026)
    g = seeding.spawn_runs(np.random.Generator(np.random.PCG64(seq)), 2)[1]
    want = np.random.SeedSequence(2026, spawn_key=(1,))
    child = g.bit_generator.seed_seq
    assert child.entropy == want.entropy and child.spawn_key == want.spawn_key
    np.testing.assert_array_equal(child.generate_state(5), want.generate_state(5))
    np.testing.assert_array_equal(child.pool, want.pool)
    a, b = g.spawn(2), np.random.Generator(np.random.PCG64(want)).spawn(2)
    for x, y in zip(a, b, strict=True):
        assert x.bit_generator.state == y.bit_generator.state
    assert child.n_children_spawned == 2
    # a generator spawned from it is an hbench parent like any other
    assert len(seeding.spawn_runs(a[0], 2)) == 2


def test_the_bulk_hash_is_checked_against_numpy() -> None:
    assert seeding._fast_seeding_agrees()

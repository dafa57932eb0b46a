"""Per-run streams: the bulk PCG64 seeding gives numpy's own children, bit for bit.

Exact equality throughout: the children's seeds are integer hashes, so any difference is a bug.
"""

from __future__ import annotations

import numpy as np
import pytest

from hbench.sim import seeding


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
    np.random.SeedSequence(
        [2026, 1, 2**33, 4]
    ),  # a cell seed's shape (hbench.sim.seeding.cell_seed)
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


def test_a_stream_is_a_parent_in_its_turn_and_pickles_as_its_seed_sequence() -> None:
    """A run's stream spawns runs (and seeds a simulation) like the generator numpy would have
    made; it pickles with any protocol, as the SeedSequence it stands for."""
    import pickle

    from hbench.sim import scenarios
    from hbench.sim.simulate import simulate

    seq = np.random.SeedSequence(2026)
    child = seeding.spawn_runs(np.random.Generator(np.random.PCG64(seq)), 2)[1]
    want = _numpy_child(seq, (1,))
    for a, b in zip(seeding.spawn_runs(child, 3), seeding.spawn_runs(want, 3), strict=True):
        assert a.bit_generator.state == b.bit_generator.state
    sc = scenarios.build({**scenarios.PAPER_SECTION6, "duration": 30.0})
    np.testing.assert_array_equal(simulate(sc, 2, child)[0].y, simulate(sc, 2, want)[0].y)
    for protocol in range(pickle.HIGHEST_PROTOCOL + 1):
        seq_back = pickle.loads(pickle.dumps(child.bit_generator.seed_seq, protocol))
        assert isinstance(seq_back, np.random.SeedSequence)
        assert seq_back.spawn_key == (1,) and seq_back.entropy == 2026
        g = pickle.loads(pickle.dumps(child, protocol))
        assert g.bit_generator.state == child.bit_generator.state
    bare = object.__new__(seeding._Seeded)
    with pytest.raises(AttributeError):
        bare.entropy  # noqa: B018 - no recursion on an instance without its slots


def test_keys_beyond_int64_take_numpys_route() -> None:
    seq = np.random.SeedSequence(3)
    assert seeding._pcg64_seeds(seq, [(2**63,), (2**63 + 1,)]) is None
    g = seeding.spawn_runs(np.random.Generator(np.random.PCG64(seq)), 1, start=2**64)[0]
    assert g.bit_generator.state == _numpy_child(seq, (2**64,)).bit_generator.state

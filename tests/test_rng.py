"""Tests of hortishape._rng: random states and seeds for every stochastic step."""

import numpy as np

from hortishape._rng import as_generator, spawn_seeds


def test_as_generator_takes_every_form_of_random_state():
    g = np.random.default_rng(5)
    assert as_generator(g) is g  # a generator is used as it is, not copied
    assert as_generator(11).integers(1 << 30) == np.random.default_rng(11).integers(1 << 30)
    seq = np.random.SeedSequence(3)
    assert as_generator(seq).integers(1 << 30) == np.random.default_rng(np.random.SeedSequence(3)).integers(1 << 30)
    assert isinstance(as_generator(None), np.random.Generator)


def test_spawned_seeds_do_not_depend_on_the_count_or_on_earlier_use():
    first = [s.generate_state(2).tolist() for s in spawn_seeds(7, 3)]
    more = [s.generate_state(2).tolist() for s in spawn_seeds(7, 10)]
    assert more[:3] == first
    assert len({tuple(x) for x in more}) == 10  # independent children
    seq = np.random.SeedSequence(7)
    seq.spawn(4)  # used before: the children are the same
    assert [s.generate_state(2).tolist() for s in spawn_seeds(seq, 3)] == first
    assert spawn_seeds(8, 1)[0].generate_state(2).tolist() != first[0]


def test_spawned_seeds_from_a_generator_follow_the_generator():
    a = [s.generate_state(1)[0] for s in spawn_seeds(np.random.default_rng(1), 2)]
    b = [s.generate_state(1)[0] for s in spawn_seeds(np.random.default_rng(1), 2)]
    c = [s.generate_state(1)[0] for s in spawn_seeds(np.random.default_rng(2), 2)]
    assert a == b and a != c

"""Random-state handling shared by every stochastic step.

Every public function that draws random numbers takes ``random_state``: an
int seed, ``None`` (fresh entropy), a :class:`numpy.random.SeedSequence` or a
:class:`numpy.random.Generator`. Nothing uses numpy's global random state.
"""

from __future__ import annotations

import numpy as np

RandomState = int | np.random.Generator | np.random.SeedSequence | None


def as_generator(random_state: RandomState) -> np.random.Generator:
    """A :class:`numpy.random.Generator` for ``random_state``.

    Examples
    --------
    >>> bool(as_generator(3).integers(10) == as_generator(3).integers(10))
    True
    """
    if isinstance(random_state, np.random.Generator):
        return random_state
    return np.random.default_rng(random_state)


def spawn_seeds(random_state: RandomState, n: int) -> list[np.random.SeedSequence]:
    """``n`` independent seeds derived from ``random_state``.

    Child ``i`` depends only on ``random_state`` and ``i`` (not on ``n``), so
    item ``i`` of a population is the same whatever the population size and
    whether the items are made in parallel.

    Examples
    --------
    >>> a = spawn_seeds(7, 3)[1].generate_state(1)
    >>> b = spawn_seeds(7, 10)[1].generate_state(1)
    >>> bool((a == b).all())
    True
    """
    if isinstance(random_state, np.random.SeedSequence):
        seq = random_state
    elif isinstance(random_state, np.random.Generator):
        seq = np.random.SeedSequence(random_state.integers(0, 2**63 - 1, size=4))
    else:
        seq = np.random.SeedSequence(random_state)
    # Built by hand rather than with ``seq.spawn`` so the caller's SeedSequence
    # is not advanced (spawn counts its children) and results do not depend on
    # how often it was used before.
    return [
        np.random.SeedSequence(seq.entropy, spawn_key=(*seq.spawn_key, i), pool_size=seq.pool_size)
        for i in range(n)
    ]

"""Random draws the layout makes by the ten thousand, without ``Generator.choice``'s per-call cost.

Each function draws exactly what the ``rng.choice`` call it names would, from the same numbers of the
generator, so the streams (and every city) stay as they were; ``tests/sim/layout_pinned_test.py``
holds them to it.
"""

from __future__ import annotations

import bisect
import functools
from collections.abc import Mapping

import numpy as np


@functools.lru_cache(maxsize=None)
def _table(items: tuple) -> tuple[tuple, list[float]]:
    """The names and the cumulative distribution ``rng.choice`` builds from the weights."""
    cdf = np.cumsum(np.array([weight for _, weight in items], dtype=float))
    cdf /= cdf[-1]
    return tuple(name for name, _ in items), cdf.tolist()


def pick(rng: np.random.Generator, weights: Mapping) -> object:
    """A key of `weights` drawn with its probability: ``names[rng.choice(len(names), p=probabilities)]``,
    which searches the cumulative distribution for one ``rng.random()``."""
    names, cdf = _table(tuple(weights.items()))
    return names[bisect.bisect_right(cdf, rng.random())]


def sign(rng: np.random.Generator) -> int:
    """-1 or 1: ``rng.choice((-1, 1))``, which draws its index with ``rng.integers(2)``."""
    return -1 if rng.integers(2) == 0 else 1

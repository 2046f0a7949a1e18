"""The uniform and diversify-with-rejection samplers' numpy streams, pinned bit for bit.

Training sets, target sets and population renders are cached by their designs, and published figures
were made from them: the same seed must give the same designs (values and key order) for ever. The
digests were taken from the samplers as they were before the twins were merged into
``DesignSpace.sample`` and ``sim.design.diversify``. The torch streams are pinned in
``tests/nams/uniform_pinned_test.py``.
"""

import hashlib
import json

import numpy as np
import pytest

from meta_sim.render.jobs import sample_designs, sample_population
from meta_sim.sim.design import DesignSpace

SPACES = {"rooftops-v1": 0, "rooftops-flat-v1": 7, "overhead-towns-v5": 1}  # space -> seed
COUNTS = [3, 1, 2, 5]


def digest(value) -> str:
    return hashlib.sha256(json.dumps(value).encode()).hexdigest()[:16]


def drawn(case: str, name: str, seed: int):
    """What the caller ``case`` draws for the space and seed, with the generator's next number where the
    caller hands the generator on."""
    space = DesignSpace.load(name)
    if case == "sample":
        rng = np.random.default_rng(seed)
        return [space.sample(rng, 50), rng.random()]
    if case == "sample_designs":
        return sample_designs(space, 30, seed)
    base = space.sample(np.random.default_rng([seed, 9]), len(COUNTS))
    return [sample_population(space, base, COUNTS, 40, r, seed) for r in (0.0, 0.25, 1.0)]


PINNED = {
    ("sample", "rooftops-v1"): "eba04f9392aa61aa",
    ("sample", "rooftops-flat-v1"): "81b39203ab5f0800",
    ("sample", "overhead-towns-v5"): "b32103ae10bd6879",
    ("sample_designs", "rooftops-v1"): "c1026e12b0d21c24",
    ("sample_designs", "rooftops-flat-v1"): "7800bbf6018415d7",
    ("sample_designs", "overhead-towns-v5"): "0af78f5021f5cbb6",
    ("sample_population", "rooftops-v1"): "52f32a56a4a136e8",
    ("sample_population", "rooftops-flat-v1"): "93e98c1582f60090",
    ("sample_population", "overhead-towns-v5"): "61eb170d4d153a13",
}


@pytest.mark.parametrize(("case", "name"), list(PINNED))
def test_the_numpy_sampling_streams_are_pinned(case, name):
    assert digest(drawn(case, name, SPACES[name])) == PINNED[case, name]


def test_population_designs_do_not_depend_on_n():
    space = DesignSpace.load("overhead-towns-v5")
    base = space.sample(np.random.default_rng(3), 3)
    assert sample_population(space, base, [1, 2, 3], 12, 0.5, 4) == sample_population(space, base, [1, 2, 3], 30,
                                                                                       0.5, 4)[:12]

"""The searches' torch streams of the one uniform sampler, pinned bit for bit.

``uniform_predict`` (the Uniform baseline) and the searches' diversify-with-rejection draw through
``nams.search.TorchDraws`` into ``DesignSpace.sample`` / ``sim.design.diversify``; the digests were taken
before those twins were merged, and published figures rest on them. The numpy streams are pinned in
``tests/sim/sampling_pinned_test.py``.
"""

import hashlib
import json

import pytest
import torch

from meta_sim.nams import uniform_predict
from meta_sim.nams.search import SearchResult, _diversify
from meta_sim.sim.design import DesignSpace

SPACES = {"rooftops-v1": 0, "rooftops-flat-v1": 7, "overhead-towns-v5": 1}  # space -> seed


def digest(value) -> str:
    return hashlib.sha256(json.dumps(value).encode()).hexdigest()[:16]


def drawn(case: str, name: str, seed: int):
    """What ``case`` draws for the space and seed, with the generator's next numbers (where it stops)."""
    space = DesignSpace.load(name)
    generator = torch.Generator().manual_seed(seed)
    if case == "uniform_predict":
        out = uniform_predict(space, 40, generator)
    else:
        base = uniform_predict(space, 4, torch.Generator().manual_seed(seed + 100))
        out = []
        for r in (0.0, 0.25, 1.0):
            results = [SearchResult(design=dict(d), votes={}, best_loss=None, mean_loss=None, method="pinned",
                                    searched_design=dict(d)) for d in base * 5]
            out.append([[result.design, result.rejected] for result in _diversify(results, space, r, generator)])
    return [out, torch.rand(2, generator=generator, dtype=torch.float64).tolist()]


PINNED = {
    ("uniform_predict", "rooftops-v1"): "9b62a932da26d91c",
    ("uniform_predict", "rooftops-flat-v1"): "ddc2049024e77f70",
    ("uniform_predict", "overhead-towns-v5"): "6644b264d33474e1",
    ("diversify", "rooftops-v1"): "d0d2e98580bd359b",
    ("diversify", "rooftops-flat-v1"): "510318ac1616ff10",
    ("diversify", "overhead-towns-v5"): "4136d67c8f0a272d",
}


@pytest.mark.parametrize(("case", "name"), list(PINNED))
def test_the_torch_sampling_streams_are_pinned(case, name):
    assert digest(drawn(case, name, SPACES[name])) == PINNED[case, name]

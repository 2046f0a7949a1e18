"""Fixtures the pipeline tests share."""

import numpy as np
import pytest
import torch
from toys import toy_space

from meta_sim.nams import NAMSConfig, TrainConfig, train_nams


@pytest.fixture(scope="module")
def coloured():
    """A 6 x 7 space whose features are 12 linear ones plus two 8-bin histograms, peaked at each
    parameter's choice; NAMS trained on them (once per test module)."""
    space = toy_space(6, 7)
    generator = torch.Generator().manual_seed(0)
    weights = torch.randn(space.dim, 12, generator=generator)

    def simulate(designs):
        encoded = torch.stack([torch.from_numpy(space.encode(d)) for d in designs])
        hists = []
        for d in designs:
            for param, _width in (("p0", 6), ("p1", 7)):
                h = torch.full((8,), 0.02)
                h[space.parameters[int(param[1])].choices.index(d[param])] = 1.0
                hists.append(h)
        colour = torch.stack(hists).reshape(len(designs), 16) * (0.5 + torch.rand(len(designs), 1, generator=generator))
        lead = encoded @ weights + 0.05 * torch.randn(len(designs), 12, generator=generator)
        return encoded, torch.cat([lead, colour], 1)

    rng = np.random.default_rng(0)
    designs, features = simulate(space.sample(rng, 800))
    fit = train_nams(designs, features, NAMSConfig(space.dim, 28, hidden=(64, 128)),
                     TrainConfig(max_epochs=60, patience=10, lr=3e-3, whiten=0), hist_blocks=(8, 8))
    truth = space.sample(rng, 30)
    _, targets = simulate(truth)
    return {"space": space, "fit": fit, "truth": truth, "targets": targets}

"""NAMS architectures: the paper's joint networks, factorised E/D, and the additive predictor."""

import math

import numpy as np
import pytest
import torch
from toys import toy_space as _space

from meta_sim.cli.base import ARCHITECTURE_NAMES
from meta_sim.core.errors import MetaSimError
from meta_sim.nams import (
    ARCHITECTURES,
    NAMS,
    FeatureNorm,
    NAMSConfig,
    TrainConfig,
    adjoint_search,
    architecture_options,
    exhaustive_search,
    load_checkpoint,
    save_checkpoint,
    train_nams,
)
from meta_sim.pipeline.workflow import ModelSettings
from meta_sim.sim.design import DesignSpace

FEATURES = 24


def _config(space, architecture, **kw):
    return NAMSConfig(space.dim, FEATURES, **{"hidden": (32, 64), **architecture_options(architecture,
                                                                                           space.widths()), **kw})


def test_architectures_build_what_they_name():
    space = _space(3, 5, continuous=True)
    assert space.widths() == [3, 5, 1] and tuple(ARCHITECTURES) == ARCHITECTURE_NAMES
    for name in ARCHITECTURES:
        config = _config(space, name)
        assert config.architecture == name and NAMSConfig.from_dict(config.to_dict()) == config
        model = NAMS(config).eval()
        designs = torch.from_numpy(np.stack([space.encode(d) for d in space.sample(np.random.default_rng(0), 6)]))
        out = model(designs.float())
        z = config.z_dim  # 10 (the paper's) for a joint z; 5 per parameter for a factorised one
        assert z == (10 if name == "paper" else 15)
        assert out.mu.shape == out.z.shape == (6, z) and out.design_logits.shape == (6, 9)
        assert model.predict(torch.randn(2, 3, z)).shape == (2, 3, FEATURES)  # the search's leading dims
    assert _config(space, "additive").z_blocks == (5, 5, 5)
    assert _config(space, "additive", z_dim=10).z_blocks == (4, 3, 3)  # an explicit z_dim wins
    assert NAMSConfig(space.dim, FEATURES).architecture == "paper"  # the paper's networks by default


def test_factorised_encoder_gives_each_parameter_its_own_slice_of_z():
    space = _space(3, 4)
    model = NAMS(_config(space, "additive")).eval()
    a, b = torch.zeros(2, 7), torch.zeros(2, 7)
    a[:, 0] = b[:, 1] = 1  # p0 differs ...
    a[:, 3] = b[:, 3] = 1  # ... p1 is the same
    mu_a, mu_b = model.encode(a)[0], model.encode(b)[0]
    assert not torch.allclose(mu_a[:, :5], mu_b[:, :5]) and torch.equal(mu_a[:, 5:], mu_b[:, 5:])
    # Additive P: changing p0's slice of z moves the prediction by the same amount whatever p1's slice is.
    z = torch.randn(4, 10, generator=torch.Generator().manual_seed(0))
    moved = z.clone()
    moved[:, :5] += 1.0
    delta = model.predict(moved) - model.predict(z)
    swapped = z.clone()
    swapped[:, 5:] = z[0, 5:]
    swapped_moved = swapped.clone()
    swapped_moved[:, :5] += 1.0
    torch.testing.assert_close(delta, model.predict(swapped_moved) - model.predict(swapped), atol=1e-5, rtol=1e-4)


@pytest.mark.parametrize("bad, message", [
    ({"blocks": (3, 3)}, "summing to design_dim"),
    ({"blocks": (7, 0)}, "positive widths"),
    ({"blocks": (3, 4), "z_dim": 1}, "z_dim >= the number of parameters"),
    ({"predictor": "additive"}, "needs the design's parameter blocks"),
    ({"blocks": (3, 4), "predictor": "sum"}, "predictor must be one of"),
])
def test_bad_architecture_settings_are_clear_errors(bad, message):
    with pytest.raises(MetaSimError, match=message):
        NAMSConfig(7, FEATURES, **bad)


def test_unknown_architecture_is_an_error_before_anything_runs():
    with pytest.raises(MetaSimError, match="unknown architecture 'deep'"):
        architecture_options("deep", [3, 4])
    with pytest.raises(MetaSimError, match="unknown architecture"):
        ModelSettings(architecture="deep").key(None, "x")


def test_a_space_of_many_parameters_gives_each_its_share_of_z():
    from meta_sim.sim.design import DesignSpace

    assert "z_dim" not in architecture_options("additive", [40, 44])  # the default space: z of 10, 5 each
    widths = DesignSpace.load("overhead-v1").widths()
    options = architecture_options("additive", widths)
    config = NAMSConfig(sum(widths), FEATURES, **{**options, "hidden": (8, 8)})
    assert config.z_blocks == (5,) * len(widths)
    assert "z_dim" not in architecture_options("paper", widths)  # one joint z: no blocks to share it


def test_model_cache_keys_tell_architectures_apart():
    from meta_sim.pipeline.dataset import DatasetConfig

    keys = {ModelSettings(architecture=name).key(DatasetConfig(), "colour-texture-v1") for name in ARCHITECTURES}
    assert len(keys) == len(ARCHITECTURES)


class AdditiveSimulator:
    """Features = a flat contribution + a sloped contribution + noise, as a tile's roofs add up."""

    def __init__(self, space, seed=0):
        g = torch.Generator().manual_seed(seed)
        self.space, self.generator = space, g
        self.weights = torch.randn(space.dim, FEATURES, generator=g)

    def __call__(self, designs, noise=0.1):
        encoded = torch.stack([torch.from_numpy(self.space.encode(d)) for d in designs]).float()
        return encoded, encoded @ self.weights + noise * torch.randn(len(designs), FEATURES,
                                                                    generator=self.generator)


def _seen_and_unseen(space, rng, n):
    """Training designs pair choice i of p0 only with choices i, i+1, i+2 of p1 (24 of 64 pairings);
    held-out targets use the other pairings, each choice of which the training set has shown apart."""
    seen = [(i, (i + k) % 8) for i in range(8) for k in range(3)]
    unseen = [(i, j) for i in range(8) for j in range(8) if (i, j) not in seen]
    def pick(pairs, m):
        return [{"p0": f"p0c{pairs[t][0]}", "p1": f"p1c{pairs[t][1]}"}
                                 for t in rng.integers(len(pairs), size=m)]
    return pick(seen, n), pick(unseen, 40)


@pytest.fixture(scope="module")
def composed():
    space = _space(8, 8)
    simulate = AdditiveSimulator(space)
    train, held_out = _seen_and_unseen(space, np.random.default_rng(0), 480)
    designs, features = simulate(train)
    _, targets = simulate(held_out)
    config = TrainConfig(max_epochs=80, patience=15, lr=3e-3, whiten=0, seed=0)
    fits = {name: train_nams(designs, features, _config(space, name, hidden=(64, 128)), config)
            for name in ("paper", "additive")}
    return space, fits, targets, held_out


def test_additive_predictor_composes_parameters_it_saw_only_apart(composed):
    """The point of the additive architecture: pairings the training set never rendered."""
    space, fits, targets, truth = composed
    accuracy = {}
    for name, fit in fits.items():
        results = exhaustive_search(fit.model, fit.norm.apply(targets), space)
        accuracy[name] = np.mean([r.design == d for r, d in zip(results, truth)])
    assert accuracy["additive"] >= 0.9
    assert accuracy["additive"] >= accuracy["paper"]


def test_additive_model_adjoint_search_and_checkpoint_round_trip(composed, tmp_path):
    space, fits, targets, truth = composed
    fit = fits["additive"]
    results = adjoint_search(fit.model, fit.norm.apply(targets), space, M=64, S=8, iterations=80,
                             generator=torch.Generator().manual_seed(0))
    assert np.mean([r.design == d for r, d in zip(results, truth)]) >= 0.8
    assert all(math.isfinite(r.best_loss) for r in results)
    path = tmp_path / "nams.pt"
    save_checkpoint(path, "nams", fit.model, fit.model.config, space.to_dict(), fit.norm, "toy-v1")
    ckpt = load_checkpoint(path, "nams")
    assert ckpt.model.config.architecture == "additive"
    probe = torch.eye(space.dim)
    with torch.no_grad():
        torch.testing.assert_close(ckpt.model(probe).features, fit.model(probe).features, rtol=0, atol=0)
    # A checkpoint whose blocks do not match its space is refused, not searched.
    other = DesignSpace.from_dict({**space.to_dict(), "parameters": [
        {"name": "p0", "type": "categorical", "choices": [f"p0c{j}" for j in range(6)]},
        {"name": "p1", "type": "categorical", "choices": [f"p1c{j}" for j in range(10)]}]})
    save_checkpoint(tmp_path / "bad.pt", "nams", fit.model, fit.model.config, other.to_dict(), fit.norm, "toy-v1")
    with pytest.raises(MetaSimError, match="parameter blocks do not match"):
        load_checkpoint(tmp_path / "bad.pt", "nams")


@pytest.mark.parametrize("factor", [1e6, 1e-6])
def test_factorised_losses_stay_finite_with_weights_at_extreme_scales(factor):
    space = _space(3, 4)
    model = NAMS(_config(space, "additive")).train()
    with torch.no_grad():
        for layer in model.encoder.modules():
            if isinstance(layer, torch.nn.Linear):
                layer.weight.mul_(factor)
                layer.bias.mul_(factor)
    designs = torch.zeros(16, 7)
    designs[torch.arange(16), torch.arange(16) % 3] = 1
    designs[torch.arange(16), 3 + torch.arange(16) % 4] = 1
    loss, terms = model.loss(designs, torch.randn(16, FEATURES), torch.Generator().manual_seed(0))
    assert math.isfinite(loss.item()) and all(math.isfinite(v) for v in terms.values())
    loss.backward()
    assert all(torch.isfinite(p.grad).all() for p in model.parameters() if p.grad is not None)


def test_one_parameter_of_one_choice_with_the_factorised_model():
    space = _space(1)
    fit = train_nams(torch.ones(20, 1), torch.randn(20, 4, generator=torch.Generator().manual_seed(0)),
                     NAMSConfig(1, 4, **{**architecture_options("additive", [1]), "hidden": (8, 8)}),
                     TrainConfig(max_epochs=3))
    results = exhaustive_search(fit.model, fit.norm.apply(torch.randn(2, 4)), space)
    assert [r.design for r in results] == [{"p0": "p0c0"}] * 2
    assert isinstance(fit.norm, FeatureNorm)

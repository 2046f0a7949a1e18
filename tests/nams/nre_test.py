"""The sbi baseline (neural ratio estimation over the design grid) on a toy simulator: recovery, determinism,
the checkpoint, and clear errors for what it does not support."""

import math
import sys

import numpy as np
import pytest
import torch
from toys import toy_space

from meta_sim.core.errors import MetaSimError
from meta_sim.nams import (
    NREConfig,
    NRETrainConfig,
    RatioClassifier,
    load_checkpoint,
    nre_predict,
    save_checkpoint,
    train_nre,
    uniform_predict,
)
from meta_sim.nams.norm import FeatureNorm
from meta_sim.nams.nre import log_ratios

FEATURES = 12
# Smaller and shorter than the defaults, which are sized for the default training set.
SMALL = {"classifier": "resnet", "hidden": 64}
QUICK = NRETrainConfig(batch_size=200, num_classes=5, patience=20, max_epochs=60, seed=0)


def _simulate(space, designs, noise, generator, effects):
    """Features: the sum of one fixed random effect per chosen choice, plus noise (separable by design)."""
    encoded = torch.stack([torch.from_numpy(space.encode(d)).float() for d in designs])
    return encoded, encoded @ effects + noise * torch.randn(len(designs), FEATURES, generator=generator)


@pytest.fixture(scope="module")
def toy():
    """A 4 x 5 space; 240 training designs; 30 targets with less noise (group means, as targets are)."""
    space = toy_space(4, 5)
    generator = torch.Generator().manual_seed(0)
    effects = 2.0 * torch.randn(space.dim, FEATURES, generator=generator)
    rng = np.random.default_rng(0)
    designs, features = _simulate(space, space.sample(rng, 240), 0.5, generator, effects)
    truth = space.sample(rng, 30)
    _, targets = _simulate(space, truth, 0.2, generator, effects)
    fit = train_nre(designs, features, space, _small(space), QUICK)
    return {"space": space, "designs": designs, "features": features, "truth": truth, "targets": targets,
            "fit": fit}


def _small(space):
    return NREConfig(design_dim=space.dim, feature_dim=FEATURES, **SMALL)


def _hit_rate(designs, truth):
    return float(np.mean([[d[name] == t[name] for name in t] for d, t in zip(designs, truth)]))


def test_nre_recovers_separable_designs_and_beats_uniform(toy):
    space, truth = toy["space"], toy["truth"]
    results = nre_predict(toy["fit"].model, toy["targets"], space)
    assert len(results) == len(truth)
    for r in results:
        assert space.validate(r.design) == r.design and r.method == "sbi_nre" and r.searched_design == r.design
        assert len(r.ranked) == 10 and r.ranked[0][0] == r.design and math.isfinite(r.best_loss)
        assert [loss for _, loss in r.ranked] == sorted(loss for _, loss in r.ranked) and r.best_loss >= 0
        for p in space.parameters:  # each parameter's posterior marginal, largest first
            shares = r.votes[p.name]
            assert sum(shares.values()) == pytest.approx(1.0) and set(shares) <= set(p.choices)
            assert list(shares.values()) == sorted(shares.values(), reverse=True)
    recovered = _hit_rate([r.design for r in results], truth)
    chance = _hit_rate(uniform_predict(space, len(truth), torch.Generator().manual_seed(0)), truth)
    assert recovered >= 0.8 and recovered > chance + 0.4
    history = toy["fit"].history
    assert history["epochs"] == len(history["val_loss"]) <= QUICK.max_epochs and history["n_rows"] == 240


def test_nre_scores_every_design_and_its_posterior_marginals_agree(toy):
    space = toy["space"]
    log_r = log_ratios(toy["fit"].model, toy["targets"][:3], space)
    assert log_r.shape == (3, 20) and log_r.dtype == torch.float64 and torch.isfinite(log_r).all()
    result = nre_predict(toy["fit"].model, toy["targets"][:1], space, top=3)[0]
    assert len(result.ranked) == 3
    posterior = torch.softmax(log_r[0], dim=0).reshape(4, 5)
    first = space.parameters[0]
    assert [result.votes[first.name].get(c, 0.0) for c in first.choices] == pytest.approx(
        posterior.sum(dim=1).tolist())
    best = int(log_r[0].argmax())
    assert result.design == {first.name: first.choices[best // 5], space.parameters[1].name: f"p1c{best % 5}"}


def test_nre_is_deterministic_for_a_seed(toy):
    space, designs, features = toy["space"], toy["designs"], toy["features"]
    short = NRETrainConfig(max_epochs=8, seed=0)
    state = torch.random.get_rng_state()
    epochs = []
    first = train_nre(designs, features, space, _small(space), short, on_epoch=epochs.append)
    assert torch.equal(torch.random.get_rng_state(), state)  # the caller's RNG is left alone
    assert epochs == [1] * 8
    again = train_nre(designs, features, space, _small(space), short)
    assert first.history["epochs"] == 8 and not first.history["stopped_early"]
    for a, b in zip(first.model.state_dict().values(), again.model.state_dict().values()):
        assert torch.equal(a, b)
    assert torch.equal(log_ratios(first.model, toy["targets"], space), log_ratios(again.model, toy["targets"], space))
    other = train_nre(designs, features, space, _small(space), NRETrainConfig(max_epochs=2, seed=1))
    assert not all(torch.equal(a, b) for a, b in zip(first.model.state_dict().values(),
                                                      other.model.state_dict().values()))


def test_nre_checkpoint_round_trip(toy, tmp_path):
    space, model = toy["space"], toy["fit"].model
    norm = FeatureNorm.fit(toy["features"])
    path = tmp_path / "sbi_nre.pt"
    save_checkpoint(path, "sbi_nre", model, model.config, space.to_dict(), norm, "toy",
                    extra={"seconds": 1.5}, history=toy["fit"].history)
    loaded = load_checkpoint(path, "sbi_nre")
    assert isinstance(loaded.model, RatioClassifier) and loaded.extra["seconds"] == 1.5
    assert torch.equal(log_ratios(loaded.model, toy["targets"], space), log_ratios(model, toy["targets"], space))
    with pytest.raises(MetaSimError, match="'sbi_nre' checkpoint"):
        load_checkpoint(path, "nams")


def test_nre_refuses_what_it_cannot_enumerate_or_learn(toy):
    continuous = toy_space(3, continuous=True)
    with pytest.raises(MetaSimError, match="continuous parameter.*density"):
        train_nre(torch.zeros(10, continuous.dim), torch.randn(10, 4), continuous)
    with pytest.raises(MetaSimError, match="continuous"):
        nre_predict(toy["fit"].model, toy["targets"], continuous)
    space = toy["space"]
    with pytest.raises(MetaSimError, match="at least 6 simulations"):
        train_nre(toy["designs"][:5], toy["features"][:5], space, config=QUICK)
    with pytest.raises(MetaSimError, match="encodes to 9"):
        train_nre(toy["designs"][:, :8], toy["features"], space, config=QUICK)
    with pytest.raises(MetaSimError, match="targets must be"):
        nre_predict(toy["fit"].model, torch.zeros(2, FEATURES + 1), space)
    with pytest.raises(MetaSimError, match="NaN or Inf"):
        nre_predict(toy["fit"].model, torch.full((1, FEATURES), math.nan), space)
    with pytest.raises(MetaSimError, match="unknown sbi classifier"):
        NREConfig(design_dim=9, feature_dim=FEATURES, classifier="forest")
    with pytest.raises(MetaSimError, match="val_fraction"):
        NRETrainConfig(val_fraction=0.0)


def test_nre_drops_non_finite_simulations_and_trains_on_a_tiny_set(toy):
    space = toy["space"]
    designs, features = toy["designs"][:7].clone(), toy["features"][:7].clone()
    features[3, 0] = math.nan
    with pytest.warns(UserWarning, match="dropped 1 of 7"):
        fit = train_nre(designs, features, space, config=NRETrainConfig(max_epochs=3))
    # 3 of the 6 rows left validate (not a tenth), and each pair is contrasted with 2 others, not 5.
    assert fit.history["n_dropped"] == 1 and fit.history["num_classes"] == 2 and fit.history["val_fraction"] == 0.5
    assert len(nre_predict(fit.model, toy["targets"][:2], space)) == 2


def test_without_sbi_the_baseline_names_the_extra(monkeypatch):
    from meta_sim.experiments.evaluate import EvalSettings

    monkeypatch.setitem(sys.modules, "sbi", None)
    with pytest.raises(MetaSimError, match=r"pip install 'meta-sim\[sbi\]'"):
        RatioClassifier(NREConfig(design_dim=9, feature_dim=FEATURES))
    with pytest.raises(MetaSimError, match="--no-sbi"):
        EvalSettings().check()
    EvalSettings(sbi=False).check()

"""NAMS / DR networks, their losses at the extremes, feature normalisation and training."""

import math
import warnings

import pytest
import torch

from meta_sim.core.errors import MetaSimError
from meta_sim.nams import NAMS, DRConfig, FeatureNorm, NAMSConfig, TrainConfig, build_model, train_dr, train_nams
from meta_sim.nams.model import kl_to_standard_normal
from meta_sim.nams.train import FEATURE_SCALE_MIN

SMALL = (32, 64)


def _toy(n=256, design_dim=8, feature_dim=12, seed=0):
    """One-hot designs of two blocks (3 + 5) and features linear in them plus noise."""
    g = torch.Generator().manual_seed(seed)
    designs = torch.zeros(n, design_dim)
    designs[torch.arange(n), torch.randint(3, (n,), generator=g)] = 1
    designs[torch.arange(n), 3 + torch.randint(5, (n,), generator=g)] = 1
    weights = torch.randn(design_dim, feature_dim, generator=g)
    return designs, designs @ weights + 0.05 * torch.randn(n, feature_dim, generator=g)


def test_paper_sizes_are_the_defaults():
    config = NAMSConfig(design_dim=84, feature_dim=1000)
    assert (config.z_dim, config.hidden, config.dropout, config.negative_slope) == (10, (1024, 2048), 0.5, 0.2)
    assert (config.lambda_d, config.lambda_kld, config.lambda_p) == (1.0, 0.0005, 0.005)
    model = NAMS(config)
    linear = [m.out_features for m in model.encoder if isinstance(m, torch.nn.Linear)]
    assert linear == [1024, 2048, 20]
    assert [m.negative_slope for m in model.encoder if isinstance(m, torch.nn.LeakyReLU)] == [0.2, 0.2]
    assert [m.p for m in model.decoder if isinstance(m, torch.nn.Dropout)] == [0.5, 0.5]
    assert [m.out_features for m in model.predictor if isinstance(m, torch.nn.Linear)][-1] == 1000
    dr = build_model("dr", DRConfig(feature_dim=1000, design_dim=84))
    assert [m.out_features for m in dr.net if isinstance(m, torch.nn.Linear)] == [500] * 5 + [84]
    assert sum(isinstance(m, torch.nn.BatchNorm1d) for m in dr.net) == 5


def test_shapes_and_leading_dimensions():
    model = NAMS(NAMSConfig(design_dim=8, feature_dim=12, hidden=SMALL))
    designs, _ = _toy(16)
    out = model(designs)
    assert out.mu.shape == out.logvar.shape == out.z.shape == (16, 10)
    assert out.design_logits.shape == (16, 8) and out.features.shape == (16, 12)
    model.eval()
    assert model.predict(torch.randn(3, 5, 10)).shape == (3, 5, 12)  # the search's (targets, starts, z)
    assert model.decode(torch.randn(3, 5, 10)).shape == (3, 5, 8)
    assert torch.equal(model(designs).z, model(designs).mu)  # eval mode: z = mu


def test_reparameterisation_noise_follows_the_generator():
    # No dropout: its masks come from the global RNG, which training scopes with a fork.
    model = NAMS(NAMSConfig(design_dim=8, feature_dim=12, hidden=SMALL, dropout=0.0)).train()
    designs, _ = _toy(16)
    with torch.no_grad():
        first = model(designs, torch.Generator().manual_seed(3))
        again = model(designs, torch.Generator().manual_seed(3))
    torch.testing.assert_close(first.z, again.z)
    assert not torch.equal(first.z, first.mu)  # training mode samples z around mu


def test_configs_round_trip_and_reject_bad_values():
    config = NAMSConfig(design_dim=8, feature_dim=12, hidden=[16, 32], lambda_kld=0.01)
    assert config.hidden == (16, 32)
    assert NAMSConfig.from_dict(config.to_dict()) == config
    assert DRConfig.from_dict(DRConfig(12, 8).to_dict()) == DRConfig(12, 8)
    with pytest.raises(MetaSimError, match="unknown NAMSConfig"):
        NAMSConfig.from_dict({**config.to_dict(), "zdim": 3})
    for bad in ({"z_dim": 0}, {"hidden": (0,)}, {"dropout": 1.0}, {"lambda_p": -1.0}):
        with pytest.raises(MetaSimError):
            NAMSConfig(design_dim=8, feature_dim=12, **bad)
    with pytest.raises(MetaSimError, match="unknown model kind"):
        build_model("gan", {})


def test_kl_matches_torch_distributions_and_stays_finite_at_extremes():
    mu, logvar = torch.randn(5, 10), torch.randn(5, 10)
    q = torch.distributions.Normal(mu, torch.exp(0.5 * logvar))
    p = torch.distributions.Normal(torch.zeros(10), torch.ones(10))
    torch.testing.assert_close(kl_to_standard_normal(mu, logvar), torch.distributions.kl_divergence(q, p).sum(-1))
    model = NAMS(NAMSConfig(design_dim=8, feature_dim=12, hidden=SMALL))
    huge = torch.full((2, 8), 1e30)
    mu, logvar = model.encode(huge)  # soft clamps bound both, whatever the encoder produces
    assert torch.isfinite(kl_to_standard_normal(mu, logvar)).all()
    assert mu.abs().max() <= model.config.mu_bound and logvar.abs().max() <= model.config.logvar_bound


@pytest.mark.parametrize("factor", [1e6, 1e-6])
@pytest.mark.parametrize("training", [True, False])
def test_loss_is_finite_with_encoder_weights_at_huge_and_tiny_scales(factor, training):
    model = NAMS(NAMSConfig(design_dim=8, feature_dim=12, hidden=SMALL))
    with torch.no_grad():
        for layer in model.encoder:
            if isinstance(layer, torch.nn.Linear):
                layer.weight.mul_(factor)
                layer.bias.mul_(factor)
    model.train(training)
    designs, features = _toy(32)
    loss, terms = model.loss(designs, features, torch.Generator().manual_seed(0))
    assert math.isfinite(loss.item()) and all(math.isfinite(v) for v in terms.values())
    if training:
        loss.backward()
        assert all(torch.isfinite(p.grad).all() for p in model.parameters() if p.grad is not None)


def test_feature_norm_handles_constant_and_near_constant_dimensions():
    features = torch.randn(50, 4)
    features[:, 1] = 7.0  # zero variance
    features[:, 2] = 1e6 + 1e-9 * torch.randn(50).double().float()  # float32 noise only
    norm = FeatureNorm.fit(features, eps=1e-6)
    assert norm.std[1] == 1.0
    normalised = norm.apply(features)
    assert torch.isfinite(normalised).all()
    assert torch.all(normalised[:, 1] == 0)
    target = torch.tensor([[0.0, 1e30, -1e30, 3.0]])
    assert torch.isfinite(norm.apply(target)).all()
    torch.testing.assert_close(normalised * norm.std + norm.mean, features, rtol=1e-5, atol=1e-3)
    again = FeatureNorm.from_dict(norm.to_dict())
    assert torch.equal(again.mean, norm.mean) and torch.equal(again.std, norm.std)
    with pytest.raises(MetaSimError, match="dimensions"):
        norm.apply(torch.zeros(2, 5))
    with pytest.raises(MetaSimError):
        FeatureNorm.from_dict({"mean": torch.zeros(3), "std": torch.zeros(3)})


def test_whitening_gives_uncorrelated_unit_variance_components():
    g = torch.Generator().manual_seed(0)
    features = torch.randn(200, 3, generator=g) @ torch.randn(3, 8, generator=g)  # rank 3 in 8 dims
    norm = FeatureNorm.fit(features, whiten=5)
    assert norm.dim == 3  # only the directions the training set spans
    white = norm.apply(features).double()
    torch.testing.assert_close(white.T @ white / len(white), torch.eye(3, dtype=torch.float64),
                               rtol=0, atol=1e-3)
    again = FeatureNorm.from_dict(norm.to_dict())
    assert torch.equal(again.components, norm.components)
    fit = train_nams(*_toy(), NAMSConfig(8, 12, hidden=SMALL), _quick(max_epochs=2, whiten=4))
    assert fit.model.config.feature_dim == fit.norm.dim == 4


def test_noise_whitening_makes_the_design_residual_white_and_finds_the_design():
    """Features = design effect + noise that is loud along a few directions: whitened by the
    total spread those directions still blur the distance, whitened by the noise they do not."""
    g = torch.Generator().manual_seed(0)
    designs, _ = _toy(n=400, seed=0)
    weights = torch.randn(8, 12, generator=g)
    loud = torch.linalg.qr(torch.randn(12, 12, generator=g))[0][:, :4]

    def noise(n):
        return 0.3 * torch.randn(n, 12, generator=g) + 3.0 * torch.randn(n, 4, generator=g) @ loud.T

    features = designs @ weights + noise(400)
    noisy = FeatureNorm.fit(features, whiten=8, designs=designs, shrink=0.0)
    total = FeatureNorm.fit(features, whiten=8)
    assert noisy.noise_whitened and not total.noise_whitened
    again = FeatureNorm.from_dict(noisy.to_dict())
    assert again.noise_whitened and torch.equal(again.components, noisy.components)
    # What the designs leave unexplained is white: unit covariance over the residual degrees of freedom.
    a = torch.cat([designs, torch.ones(400, 1)], 1).double()
    white = noisy.apply(features).double()
    residual = white - a @ torch.linalg.lstsq(a, white, driver="gelsd").solution
    dof = 400 - int(torch.linalg.matrix_rank(a))
    torch.testing.assert_close(residual.T @ residual / dof, torch.eye(8, dtype=torch.float64), rtol=0, atol=1e-3)
    # Nearest design under each metric, for fresh noisy renders of every design.
    table = torch.unique(designs, dim=0)
    draws = table.repeat(20, 1)
    probe, truth = draws @ weights + noise(len(draws)), torch.arange(len(table)).repeat(20)

    def hits(norm):
        nearest = torch.cdist(norm.apply(probe), norm.apply(table @ weights)).argmin(1)
        return float((nearest == truth).float().mean())

    assert hits(noisy) > 0.97 and hits(noisy) > hits(total) + 0.1
    # Fewer residual degrees of freedom (12 rows - rank 7 = 5) than components: half as many components.
    few = FeatureNorm.fit(features[:12], whiten=6, designs=designs[:12])
    assert few.noise_whitened and few.dim == 2
    # Fewer than 2 (3 rows, rank 3): the total spread, over the 2 directions 3 rows span.
    fewer = FeatureNorm.fit(features[:3], whiten=6, designs=designs[:3])
    assert not fewer.noise_whitened and fewer.dim == 2
    with pytest.raises(MetaSimError, match="noise_shrink"):
        TrainConfig(noise_shrink=1.5)


def _quick(**overrides):
    return TrainConfig(**{"max_epochs": 12, "patience": 50, "batch_size": 32, "lr": 3e-3, **overrides})


def test_training_loss_is_finite_and_decreases():
    designs, features = _toy()
    fit = train_nams(designs, features, NAMSConfig(8, 12, hidden=SMALL), _quick())
    history = fit.history
    assert len(history["train_loss"]) == history["epochs"] == 12
    assert all(math.isfinite(v) for v in history["train_loss"] + history["val_loss"])
    assert history["val_loss"][-1] < 0.5 * history["val_loss"][0]
    assert set(history["val_terms"]) == {"bce", "kld", "mse"}
    assert (history["n_train"], history["n_val"], history["n_dropped"]) == (230, 26, 0)
    assert not fit.model.training
    assert torch.all(fit.model.z_std > 0) and torch.isfinite(fit.model.z_mean).all()
    # feature_scale is P's RMS error per feature over all rows, floored.
    with torch.no_grad():
        error = fit.model.predict(fit.model.encode(designs)[0]) - fit.norm.apply(features)
    expected = error.square().mean(dim=0).sqrt().clamp_min(FEATURE_SCALE_MIN)
    torch.testing.assert_close(fit.model.feature_scale, expected)


def test_early_stopping_can_watch_one_term_of_the_loss():
    designs, features = _toy()
    fit = train_nams(designs, features, NAMSConfig(8, 12, hidden=SMALL), _quick(max_epochs=20, monitor="mse"))
    mse = fit.history["val_terms"]["mse"]
    assert fit.history["best_val_loss"] == min(mse) == mse[fit.history["best_epoch"] - 1]
    with pytest.raises(MetaSimError, match="monitor"):
        TrainConfig(monitor="accuracy")


def test_training_is_deterministic_and_leaves_the_global_rng_alone():
    designs, features = _toy()
    torch.manual_seed(123)
    before = torch.get_rng_state()
    a = train_nams(designs, features, NAMSConfig(8, 12, hidden=SMALL), _quick(max_epochs=3))
    assert torch.equal(torch.get_rng_state(), before)
    b = train_nams(designs, features, NAMSConfig(8, 12, hidden=SMALL), _quick(max_epochs=3))
    assert a.history["train_loss"] == b.history["train_loss"]
    for (name, x), (_, y) in zip(a.model.state_dict().items(), b.model.state_dict().items()):
        assert torch.equal(x, y), name
    c = train_nams(designs, features, NAMSConfig(8, 12, hidden=SMALL), _quick(max_epochs=3, seed=1))
    assert c.history["train_loss"] != a.history["train_loss"]


def test_early_stopping_restores_the_best_weights():
    designs, features = _toy()
    reports = []
    # A learning rate this high makes the validation loss bounce, so patience runs out.
    fit = train_dr(designs, features, DRConfig(12, 8, hidden=SMALL),
                   _quick(max_epochs=200, patience=3, lr=0.3), on_epoch=reports.append)
    history = fit.history
    assert history["stopped_early"] and history["epochs"] == history["best_epoch"] + 3
    assert [r.epoch for r in reports] == list(range(1, history["epochs"] + 1))
    assert reports[-1].best_epoch == history["best_epoch"]
    assert history["best_val_loss"] == min(history["val_loss"])
    # The returned weights reproduce the best epoch's validation loss.
    generator = torch.Generator().manual_seed(0)
    val_rows = torch.randperm(len(designs), generator=generator)[:history["n_val"]]
    with torch.no_grad():
        loss, _ = fit.model.loss(designs[val_rows], fit.norm.apply(features[val_rows]))
    assert loss.item() == pytest.approx(history["best_val_loss"], rel=1e-5)


def test_plateau_schedule_lowers_the_learning_rate():
    designs, features = _toy()
    reports = []
    train_dr(designs, features, DRConfig(12, 8, hidden=SMALL),
             _quick(max_epochs=40, lr=0.3, plateau_factor=0.5, plateau_patience=1), on_epoch=reports.append)
    assert reports[-1].lr < 0.3


def test_non_finite_simulations_are_dropped_with_one_warning():
    designs, features = _toy()
    features[3, 0] = float("nan")
    features[7, 2] = float("inf")
    designs[9, 1] = float("nan")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        fit = train_dr(designs, features, DRConfig(12, 8, hidden=SMALL), _quick(max_epochs=2))
    assert [str(w.message) for w in caught] == ["dropped 3 of 256 simulations with NaN/Inf features or designs"]
    assert fit.history["n_dropped"] == 3 and fit.history["n_train"] + fit.history["n_val"] == 253
    with pytest.raises(MetaSimError, match="no simulation has finite"), warnings.catch_warnings():
        warnings.simplefilter("ignore")
        train_nams(designs, torch.full_like(features, float("nan")), NAMSConfig(8, 12, hidden=SMALL))


def test_bad_training_inputs_raise_clear_errors():
    designs, features = _toy(8)
    with pytest.raises(MetaSimError, match="one N"):
        train_nams(designs, features[:5])
    with pytest.raises(MetaSimError, match="at least 2 training"):
        train_nams(designs[:2], features[:2], config=TrainConfig(val_fraction=0.5))
    with pytest.raises(MetaSimError, match="val_fraction"):
        TrainConfig(val_fraction=1.0)
    assert TrainConfig.from_dict(TrainConfig(lr=0.1).to_dict()) == TrainConfig(lr=0.1)


def test_zero_variance_features_train_to_a_finite_model():
    designs, features = _toy()
    features[:, :4] = 3.0
    fit = train_nams(designs, features, NAMSConfig(8, 12, hidden=SMALL), _quick(max_epochs=3))
    assert all(math.isfinite(v) for v in fit.history["train_loss"])
    assert torch.all(fit.norm.std[:4] == 1.0)


def test_features_that_never_vary_are_a_clear_error_unless_the_histograms_do():
    """`make bench-stability` found this: with every feature constant the whitening had no component
    and failed on an empty eigenvalue list (an IndexError, not a message)."""
    designs, features = _toy()
    with pytest.raises(MetaSimError, match="all the same: no feature tells one design from another"):
        train_nams(designs, torch.full_like(features, 3.0), NAMSConfig(8, 12, hidden=SMALL), _quick(max_epochs=1))
    # The leading features constant, a histogram block that varies: nothing to whiten, a finite model.
    varied = torch.cat([torch.full((len(designs), 8), 3.0), designs[:, 3:7] + 0.1], dim=1)
    fit = train_nams(designs, varied, NAMSConfig(8, 12, hidden=SMALL), _quick(max_epochs=2), hist_blocks=(4,))
    assert fit.norm.components is None and all(math.isfinite(v) for v in fit.history["train_loss"])
    assert torch.isfinite(fit.norm.apply(varied)).all()


_IN_A_FRESH_PROCESS = """
import hashlib, sys
import torch
torch.set_num_threads({threads})
sys.path.insert(0, {tests!r})
from meta_sim.pipeline.features import ColourTexture
from meta_sim.nams import NAMSConfig, train_nams
from nams_model_test import SMALL, _quick, _toy

designs, features = _toy()
fit = train_nams(designs, features, NAMSConfig(8, 12, hidden=SMALL), _quick(max_epochs=3))
digest = hashlib.sha256()
for value in fit.model.state_dict().values():
    digest.update(value.numpy().tobytes())
tiles = torch.rand(4, 3, 64, 64, generator=torch.Generator().manual_seed(0))
digest.update(ColourTexture()(tiles).numpy().tobytes())
print(digest.hexdigest())
"""


@pytest.mark.parametrize("threads", [1, 2])
def test_a_fresh_process_trains_the_same_model_and_features(threads):
    """The same seed and thread count give bit-identical weights and features in any process (no
    state carried over from import order, hashing or the allocator); thread counts may differ."""
    import os
    import subprocess
    import sys
    from pathlib import Path

    script = _IN_A_FRESH_PROCESS.format(threads=threads, tests=str(Path(__file__).parent))
    digests = {subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, check=True,
                              env={**os.environ, "PYTHONHASHSEED": str(seed)}).stdout.strip()
               for seed in (1, 2)}
    assert len(digests) == 1, digests

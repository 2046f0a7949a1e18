"""Design inference on a fake simulator: recoverability, baselines, and every edge case of the search."""

import copy
import math

import numpy as np
import pytest
import torch
from toys import toy_space as _space

from meta_sim.core.errors import MetaSimError
from meta_sim.nams import (
    NAMS,
    DRConfig,
    NAMSConfig,
    TrainConfig,
    adjoint_search,
    design_table,
    dr_predict,
    exhaustive_search,
    near_designs,
    search,
    time_search,
    train_dr,
    train_nams,
    uniform_predict,
)
from meta_sim.nams.search import resolve_method
from meta_sim.sim.design import DesignSpace

FEATURES = 32
FAST = {"M": 64, "S": 8, "iterations": 60}


class FakeSimulator:
    """Features = a fixed random linear map of the encoded design + small noise."""

    def __init__(self, space, seed=0):
        self.space = space
        self.generator = torch.Generator().manual_seed(seed)
        self.weights = torch.randn(space.dim, FEATURES, generator=self.generator)

    def __call__(self, designs, noise=0.05):
        encoded = torch.stack([torch.from_numpy(self.space.encode(d)) for d in designs])
        return encoded, encoded @ self.weights + noise * torch.randn(len(designs), FEATURES,
                                                                    generator=self.generator)


@pytest.fixture(scope="module")
def toy():
    """A 6 x 7 space, NAMS and DR trained on 800 simulations, and 40 held-out noisy targets."""
    space = _space(6, 7)
    simulate = FakeSimulator(space)
    rng = np.random.default_rng(0)
    designs, features = simulate(space.sample(rng, 800))
    # No whitening: the tests address the simulator's feature dimensions one by one.
    config = TrainConfig(max_epochs=60, patience=10, lr=3e-3, whiten=0)
    nams = train_nams(designs, features, NAMSConfig(space.dim, FEATURES, hidden=(64, 128)), config)
    dr = train_dr(designs, features, DRConfig(FEATURES, space.dim, hidden=(64,) * 3), config)
    truth = space.sample(rng, 40)
    _, target_features = simulate(truth)
    return {"space": space, "nams": nams.model, "dr": dr.model, "truth": truth,
            "targets": nams.norm.apply(target_features), "dr_targets": dr.norm.apply(target_features)}


def _accuracy(results, truth):
    return np.mean([r.design == d for r, d in zip(results, truth)])


def _gen(seed=0):
    return torch.Generator().manual_seed(seed)


def _assert_finite(results, space):
    for r in results:
        assert space.validate(r.design) == r.design
        for loss in (r.best_loss, r.mean_loss):
            assert loss is None or math.isfinite(loss)
        for shares in r.votes.values():
            assert math.isclose(sum(shares.values()), 1.0) and all(0 < s <= 1 for s in shares.values())


# --- recoverability -----------------------------------------------------------------------------
def test_adjoint_search_recovers_held_out_designs(toy):
    results = adjoint_search(toy["nams"], toy["targets"], toy["space"], M=200, S=20, iterations=100,
                             generator=_gen())
    assert _accuracy(results, toy["truth"]) >= 0.9
    _assert_finite(results, toy["space"])
    first = results[0]
    assert first.method == "adjoint" and first.searched_design == first.design and not first.rejected
    assert first.best_loss <= first.mean_loss
    # The winner of each parameter has the largest share, listed first.
    for name, shares in first.votes.items():
        assert next(iter(shares)) == first.design[name] and shares[first.design[name]] == max(shares.values())


def test_exhaustive_search_recovers_held_out_designs(toy):
    results = exhaustive_search(toy["nams"], toy["targets"], toy["space"], S=5, top=3)
    assert _accuracy(results, toy["truth"]) >= 0.9
    _assert_finite(results, toy["space"])
    first = results[0]
    assert first.method == "exhaustive" and len(first.ranked) == 3
    assert first.ranked[0] == (first.design, first.best_loss)
    assert [loss for _, loss in first.ranked] == sorted(loss for _, loss in first.ranked)


def test_direct_regression_recovers_held_out_designs(toy):
    results = dr_predict(toy["dr"], toy["dr_targets"], toy["space"])
    assert _accuracy(results, toy["truth"]) >= 0.9
    _assert_finite(results, toy["space"])
    assert results[0].method == "dr" and results[0].best_loss is None
    with pytest.raises(MetaSimError, match="needs a DirectRegression"):
        dr_predict(toy["nams"], toy["targets"], toy["space"])
    with pytest.raises(MetaSimError, match="needs a NAMS"):
        adjoint_search(toy["dr"], toy["targets"], toy["space"])


def test_bfloat16_search_is_finite_and_still_recovers(toy):
    results = adjoint_search(toy["nams"], toy["targets"][:10], toy["space"], dtype=torch.bfloat16,
                             generator=_gen(), **FAST)
    _assert_finite(results, toy["space"])
    assert _accuracy(results, toy["truth"][:10]) >= 0.8
    assert next(toy["nams"].parameters()).dtype == torch.float32  # the caller's model is untouched


def test_search_measures_errors_in_units_of_the_feature_scale(toy):
    # Half the features of the targets drowned in noise: with a scale that says so, the
    # clean half decides; with unit scales the noise does.
    model = copy.deepcopy(toy["nams"])
    noisy = toy["targets"].clone()
    noisy[:, :FEATURES // 2] += 5 * torch.randn(len(noisy), FEATURES // 2, generator=_gen(3))
    plain = _accuracy(exhaustive_search(model, noisy, toy["space"]), toy["truth"])
    model.feature_scale[:FEATURES // 2] = 5.0
    model.train()  # drops the cached design table, which holds scaled predictions
    model.eval()
    assert _accuracy(exhaustive_search(model, noisy, toy["space"]), toy["truth"]) >= 0.9 > plain
    results = adjoint_search(model, noisy[:10], toy["space"], generator=_gen(), **FAST)
    assert _accuracy(results, toy["truth"][:10]) >= 0.8


# --- determinism, grouping, caching -------------------------------------------------------------
def test_search_is_deterministic_and_independent_of_grouping(toy):
    targets = toy["targets"][:5]
    a = adjoint_search(toy["nams"], targets, toy["space"], generator=_gen(7), **FAST)
    b = adjoint_search(toy["nams"], targets, toy["space"], generator=_gen(7), max_rows=FAST["M"], **FAST)
    assert [r.to_dict() for r in a] == [r.to_dict() for r in b]
    one = adjoint_search(toy["nams"], targets[3], toy["space"], generator=_gen(7), **FAST)
    assert len(one) == 1


def test_design_table_is_cached_until_the_weights_may_change(toy):
    model = toy["nams"]
    table = design_table(model, toy["space"])
    assert table.designs.shape == (42, toy["space"].dim) and table.features.shape == (42, FEATURES)
    assert design_table(model, toy["space"]) is table
    model.train()
    model.eval()
    assert design_table(model, toy["space"]) is not table


# --- the options' edge cases --------------------------------------------------------------------
@pytest.mark.parametrize("options", [
    {"M": 1, "S": 1}, {"M": 16, "S": 16}, {"k": 0.0}, {"iterations": 0}, {"r": 0.0}, {"r": 1.0}])
def test_edge_options_give_finite_answers(toy, options):
    kw = {**FAST, **options}
    results = adjoint_search(toy["nams"], toy["targets"][:4], toy["space"], generator=_gen(), **kw)
    _assert_finite(results, toy["space"])
    assert all(r.rejected == (kw.get("r", 0.0) == 1.0) for r in results)


def test_k_zero_starts_every_run_at_the_latent_mean(toy):
    results = adjoint_search(toy["nams"], toy["targets"][:2], toy["space"], k=0.0, generator=_gen(), **FAST)
    for r in results:  # identical starts follow identical paths: a unanimous vote
        assert all(len(shares) == 1 for shares in r.votes.values())
        assert r.best_loss == pytest.approx(r.mean_loss)


@pytest.mark.parametrize("options, message", [
    ({"M": 0}, "M"), ({"S": 0}, "S"), ({"M": 4, "S": 5}, "S must not exceed M"), ({"k": -1.0}, "k"),
    ({"k": math.inf}, "k"), ({"r": -0.1}, "r"), ({"r": 1.5}, "r"), ({"iterations": -1}, "iterations")])
def test_invalid_options_raise(toy, options, message):
    with pytest.raises(MetaSimError, match=message):
        adjoint_search(toy["nams"], toy["targets"][:1], toy["space"], **options)


def test_diversify_with_rejection_replaces_about_r_of_the_designs(toy):
    targets = toy["targets"].repeat(5, 1)  # 200 targets
    results = exhaustive_search(toy["nams"], targets, toy["space"], r=0.25, generator=_gen(3))
    rejected = [r for r in results if r.rejected]
    assert 0.15 <= len(rejected) / len(results) <= 0.35
    assert all(r.design == r.searched_design for r in results if not r.rejected)
    assert len({toy["space"].format(r.design) for r in rejected}) > 10  # uniform draws, not the search answer
    _assert_finite(results, toy["space"])


def test_targets_at_the_extremes(toy):
    space, model = toy["space"], toy["nams"]
    for targets in (torch.zeros(2, FEATURES), torch.full((2, FEATURES), 1e30), torch.full((2, FEATURES), -3e38)):
        _assert_finite(adjoint_search(model, targets, space, generator=_gen(), **FAST), space)
        _assert_finite(exhaustive_search(model, targets, space), space)
    bad = toy["targets"][:3].clone()
    bad[1, 4] = float("nan")
    for method in ("adjoint", "exhaustive"):
        with pytest.raises(MetaSimError, match=r"row\(s\) \[1\] contain NaN or Inf"):
            search(model, bad, space, method)
    with pytest.raises(MetaSimError, match="beyond float32"):
        search(model, torch.full((1, FEATURES), 1e300, dtype=torch.float64), space)
    with pytest.raises(MetaSimError, match=rf"\(T, {FEATURES}\)"):
        search(model, torch.zeros(2, FEATURES + 1), space)
    with pytest.raises(MetaSimError, match="encodes to"):
        search(model, toy["targets"][:1], _space(6, 6))


def test_one_parameter_with_one_choice():
    """A bank of one texture: every embedding is the same, sigma collapses, every answer is that texture."""
    space = _space(1)
    designs = torch.ones(20, 1)
    features = torch.randn(20, 4, generator=_gen())
    fit = train_nams(designs, features, NAMSConfig(1, 4, hidden=(8, 8)), TrainConfig(max_epochs=3))
    assert torch.all(fit.model.z_std > 0)
    targets = fit.norm.apply(torch.randn(3, 4, generator=_gen(1)))
    for method, kw in (("adjoint", {"M": 1, "S": 1, "iterations": 5}), ("adjoint", FAST), ("exhaustive", {})):
        results = search(fit.model, targets, space, method, generator=_gen(), **kw)
        assert [r.design for r in results] == [{"p0": "p0c0"}] * 3
        assert all(r.votes == {"p0": {"p0c0": 1.0}} for r in results)
        _assert_finite(results, space)


def _continuous_toy(epochs: int):
    """A 3-choice space with a continuous "density", 200 simulations and a small NAMS trained for ``epochs``."""
    space = _space(3, continuous=True)
    simulate = FakeSimulator(space, seed=2)
    designs, features = simulate(space.sample(np.random.default_rng(1), 200))
    fit = train_nams(designs, features, NAMSConfig(space.dim, FEATURES, hidden=(16, 16)),
                     TrainConfig(max_epochs=epochs))
    return space, designs, features, fit


def test_continuous_parameters_use_the_adjoint_search():
    space, _, _, fit = _continuous_toy(2)
    assert resolve_method(space, "auto") == "adjoint"
    with pytest.raises(MetaSimError, match="continuous"):
        exhaustive_search(fit.model, torch.zeros(1, FEATURES), space)
    results = search(fit.model, torch.zeros(2, FEATURES), space, generator=_gen(), **FAST)
    _assert_finite(results, space)
    assert all(0.3 <= r.design["density"] <= 0.9 for r in results)
    assert set(results[0].votes) == {"p0"}  # continuous parameters have a mean, not a vote


def test_the_adjoint_ranks_its_kept_starts_and_near_designs_keep_their_spread():
    space, designs, features, fit = _continuous_toy(5)
    results = adjoint_search(fit.model, torch.zeros(2, FEATURES), space, generator=_gen(), **FAST)
    for r in results:
        assert len(r.ranked) == FAST["S"] and r.ranked[0][1] == r.best_loss
        losses = [loss for _, loss in r.ranked]
        assert losses == sorted(losses) and math.isclose(np.mean(losses), r.mean_loss, rel_tol=1e-9)
        assert all(space.validate(d) == d for d, _ in r.ranked)
        # The answer summarises its starts: the mean of their continuous value, the vote's share of each choice.
        assert math.isclose(np.mean([d["density"] for d, _ in r.ranked]), r.design["density"], rel_tol=1e-6)
        picks = [d["p0"] for d, _ in r.ranked]
        assert r.votes["p0"] == {c: picks.count(c) / len(picks) for c in r.votes["p0"]}
    near = near_designs(results, 3)
    assert near == [d for r in results for d, _ in r.ranked[:3]] and len(near) == 6
    assert near_designs(results, 100) == [d for r in results for d, _ in r.ranked]  # all there are
    dr = train_dr(designs, features, DRConfig(FEATURES, space.dim, hidden=(16,)), TrainConfig(max_epochs=2))
    regressed = dr_predict(dr.model, torch.zeros(2, FEATURES), space)
    assert near_designs(regressed, 5) == [r.design for r in regressed]  # nothing ranked: the answer alone
    with pytest.raises(MetaSimError, match="at least 1"):
        near_designs(results, 0)


def test_auto_prefers_exhaustive_for_small_discrete_spaces_and_refuses_huge_ones(toy):
    assert resolve_method(toy["space"], "auto") == "exhaustive"
    assert search(toy["nams"], toy["targets"][:1], toy["space"])[0].method == "exhaustive"
    assert resolve_method(_space(100, 100, 100), "auto") == "adjoint"
    with pytest.raises(MetaSimError, match="at most 10"):
        design_table(toy["nams"], toy["space"], limit=10)
    with pytest.raises(MetaSimError, match="unknown search method"):
        search(toy["nams"], toy["targets"][:1], toy["space"], "grid")


def test_uniform_baseline_is_seeded_and_valid():
    space = _space(6, 7, continuous=True)
    a, b = uniform_predict(space, 300, _gen(4)), uniform_predict(space, 300, _gen(4))
    assert a == b and all(space.validate(d) == d for d in a)
    assert {d["p1"] for d in a} == set(space.parameter("p1").choices)


# --- the default space ---------------------------------------------------------------------------
def test_exhaustive_search_over_the_default_1760_designs():
    """The default 40 x 44 space with F = 500: searches after the first reuse its table and agree with it (how
    fast a search is: bench-nams' seconds per target)."""
    space = DesignSpace.load()
    torch.manual_seed(0)
    model = NAMS(NAMSConfig(space.dim, 500, hidden=(64, 128))).eval()
    targets = torch.randn(9, 500, generator=_gen())
    first = exhaustive_search(model, targets, space)  # builds the table
    table = design_table(model, space)
    results = exhaustive_search(model, targets, space)
    assert design_table(model, space) is table and len(table.designs) == 1760
    _assert_finite(results, space)
    assert [r.design for r in results] == [r.design for r in first]
    assert time_search(model, space, "exhaustive", n_targets=9, repeats=3) > 0

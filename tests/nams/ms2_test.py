"""The MS2 baseline on a toy simulator (recovery, determinism, edge cases) and the per-tile feature cache."""

import math
import warnings

import numpy as np
import pytest
import torch
from toys import toy_space as _space

from meta_sim.core.errors import MetaSimError
from meta_sim.nams import MS2Config, ms2_search
from meta_sim.pipeline.dataset import DatasetConfig, build_features, build_tile_features
from meta_sim.sim.design import DesignSpace

FEATURES = 16
FAST = MS2Config(samples=200, iterations=100)


class ToySimulator:
    """A tile's features: the sum of one random effect per chosen choice, plus noise."""

    def __init__(self, space, noise=0.5, seed=0):
        self.space, self.noise = space, noise
        self.generator = torch.Generator().manual_seed(seed)
        self.effects = torch.randn(space.dim, FEATURES, generator=self.generator)

    def __call__(self, designs):
        encoded = torch.stack([torch.from_numpy(self.space.encode(d)) for d in designs])
        return encoded, encoded @ self.effects + self.noise * torch.randn(len(designs), FEATURES,
                                                                          generator=self.generator)


def _every_design(space):
    first, second = space.parameters
    return [{first.name: a, second.name: b} for a in first.choices for b in second.choices]


@pytest.fixture(scope="module")
def toy():
    """A 4 x 5 space; a pool of 3 tiles of every design; 10 targets of 4-9 tiles each."""
    space = _space(4, 5)
    simulate = ToySimulator(space)
    pool_designs, pool_features = simulate([d for d in _every_design(space) for _ in range(3)])
    rng = np.random.default_rng(0)
    truth = space.sample(rng, 10)
    groups = [simulate([d] * int(rng.integers(4, 10)))[1] for d in truth]
    return {"space": space, "simulate": simulate, "pool": (pool_features, pool_designs), "truth": truth,
            "groups": groups}


def _gen(seed=0):
    return torch.Generator().manual_seed(seed)


def _assert_valid(results, space, n):
    assert len(results) == n
    for r in results:
        assert space.validate(r.design) == r.design and r.method == "ms2" and r.searched_design == r.design
        assert math.isfinite(r.best_loss)
        for name, shares in r.votes.items():
            assert math.isclose(sum(shares.values()), 1.0) and all(0 < s <= 1 for s in shares.values())
            assert next(iter(shares)) == r.design[name] and shares[r.design[name]] == max(shares.values())


def _true_share(results, truth):
    return np.mean([[r.votes[name].get(d[name], 0.0) for name in d] for r, d in zip(results, truth)])


# --- recovery -----------------------------------------------------------------------------------
def test_ms2_recovers_designs_and_beats_its_uniform_start(toy):
    space = toy["space"]
    results = ms2_search(*toy["pool"], toy["groups"], space, generator=_gen())
    _assert_valid(results, space, 10)
    assert np.mean([r.design == d for r, d in zip(results, toy["truth"])]) >= 0.8  # chance is 1 in 20
    start = ms2_search(*toy["pool"], toy["groups"], space, MS2Config(iterations=0), generator=_gen())
    _assert_valid(start, space, 10)
    assert all(len(shares) == p.width and max(shares.values()) == pytest.approx(1 / p.width)
               for r in start for p, shares in zip(space.parameters, r.votes.values()))
    assert _true_share(results, toy["truth"]) >= 0.6 > 2 * _true_share(start, toy["truth"])
    assert np.mean([r.best_loss < s.best_loss for r, s in zip(results, start)]) >= 0.9


def test_ms2_combines_parameters_of_designs_the_pool_lacks():
    # The pool holds 8 of the 20 designs, every choice at least once; no target design is among them.
    space = _space(4, 5)
    simulate = ToySimulator(space, seed=1)
    held = [{"p0": f"p0c{i}", "p1": f"p1c{j}"} for i in range(4) for j in (i, i + 1)]
    pool_designs, pool_features = simulate([d for d in held for _ in range(3)])
    assert (pool_designs.sum(dim=0) > 0).all()
    truth = [d for d in _every_design(space) if d not in held][:10]
    groups = [simulate([d] * 6)[1] for d in truth]
    results = ms2_search(pool_features, pool_designs, groups, space, generator=_gen())
    _assert_valid(results, space, 10)
    hits = [r.design[name] == d[name] for r, d in zip(results, truth) for name in d]
    assert np.mean(hits) >= 0.7  # right parameter by parameter; chance is about 1 in 4.5


def test_choices_absent_from_the_pool_are_never_chosen(toy):
    features, designs = toy["pool"]
    keep = designs[:, 0] == 0  # no tile with p0c0
    results = ms2_search(features[keep], designs[keep], toy["groups"], toy["space"], FAST, generator=_gen())
    _assert_valid(results, toy["space"], 10)
    assert all(r.design["p0"] != "p0c0" and "p0c0" not in r.votes["p0"] for r in results)
    assert all(len(r.votes["p1"]) == 5 for r in results)


def test_median_bandwidth_rule_also_recovers(toy):
    results = ms2_search(*toy["pool"], toy["groups"], toy["space"], MS2Config(bandwidth="median",
                                                                              bandwidth_scale=0.5),
                         generator=_gen())
    _assert_valid(results, toy["space"], 10)
    assert np.mean([r.design == d for r, d in zip(results, toy["truth"])]) >= 0.8


# --- determinism --------------------------------------------------------------------------------
def test_same_seed_same_results_and_progress(toy):
    steps = []
    a = ms2_search(*toy["pool"], toy["groups"], toy["space"], FAST, generator=_gen(5),
                   bars=lambda label, total: steps.append((label, total)) or steps.append)
    b = ms2_search(*toy["pool"], toy["groups"], toy["space"], FAST, generator=_gen(5))
    c = ms2_search(*toy["pool"], toy["groups"], toy["space"], FAST, generator=_gen(6))
    assert [r.to_dict() for r in a] == [r.to_dict() for r in b]
    assert [r.to_dict() for r in a] != [r.to_dict() for r in c]
    assert steps == [("MS2 search", FAST.iterations)] + [1] * FAST.iterations


# --- edge cases ---------------------------------------------------------------------------------
def test_one_tile_and_identical_tiles(toy):
    space, group = toy["space"], toy["groups"][0]
    for groups in ([group[0]], [group[:1]], [group[:1].repeat(6, 1)], [torch.zeros(3, FEATURES)]):
        _assert_valid(ms2_search(*toy["pool"], groups, space, FAST, generator=_gen()), space, 1)


def test_a_pool_of_one_tile_answers_its_design(toy):
    features, designs = toy["pool"]
    results = ms2_search(features[7:8], designs[7:8], toy["groups"][:3], toy["space"], FAST, generator=_gen())
    _assert_valid(results, toy["space"], 3)
    assert all(r.design == toy["space"].decode(designs[7].numpy()) for r in results)
    assert all(shares == {r.design[name]: 1.0} for r in results for name, shares in r.votes.items())


def test_results_do_not_depend_on_the_feature_scale(toy):
    features, designs = toy["pool"]
    plain = ms2_search(features, designs, toy["groups"], toy["space"], FAST, generator=_gen())
    huge = ms2_search(features * 1e30, designs, [g * 1e30 for g in toy["groups"]], toy["space"], FAST,
                      generator=_gen())
    _assert_valid(huge, toy["space"], 10)
    assert [r.design for r in huge] == [r.design for r in plain]
    assert [r.best_loss for r in huge] == pytest.approx([r.best_loss for r in plain], rel=1e-6)


def test_targets_far_from_the_pool_and_a_pool_without_spread(toy):
    features, designs = toy["pool"]
    space = toy["space"]
    far = [torch.full((2, FEATURES), 3e38), torch.full((1, FEATURES), -3e38), torch.full((4, FEATURES), 1e-30)]
    _assert_valid(ms2_search(features, designs, far, space, FAST, generator=_gen()), space, 3)
    flat = torch.ones_like(features)
    for rule in ("scott", "median"):
        results = ms2_search(flat, designs, toy["groups"][:2], space, MS2Config(bandwidth=rule, iterations=20),
                             generator=_gen())
        _assert_valid(results, space, 2)


def test_nan_pool_rows_are_dropped_with_a_warning(toy):
    features, designs = toy["pool"]
    bad_features, bad_designs = features.clone(), designs.clone()
    bad_features[3, 2] = math.nan
    bad_designs[7, 0] = math.inf
    with pytest.warns(UserWarning, match="dropped 2 of 60 pool tiles"):
        dropped = ms2_search(bad_features, bad_designs, toy["groups"], toy["space"], FAST, generator=_gen())
    keep = torch.ones(len(features), dtype=torch.bool)
    keep[[3, 7]] = False
    clean = ms2_search(features[keep], designs[keep], toy["groups"], toy["space"], FAST, generator=_gen())
    assert [r.to_dict() for r in dropped] == [r.to_dict() for r in clean]
    with pytest.warns(UserWarning), pytest.raises(MetaSimError, match="no tile with finite"):
        ms2_search(torch.full_like(features, math.nan), designs, toy["groups"], toy["space"])


def test_a_pool_beyond_max_pool_is_thinned_with_a_warning(toy):
    with pytest.warns(UserWarning, match="random 40 of the 60 pool tiles"):
        results = ms2_search(*toy["pool"], toy["groups"], toy["space"], MS2Config(iterations=20, max_pool=40),
                             generator=_gen())
    _assert_valid(results, toy["space"], 10)


def test_bad_inputs_raise(toy):
    features, designs = toy["pool"]
    space, groups = toy["space"], toy["groups"]
    cases = [
        ((features, designs, groups, _space(4, 5, continuous=True)), "categorical design parameters only"),
        ((features, designs, [torch.zeros(3, FEATURES + 1)], space), r"target group 0 must be \(tiles, 16\)"),
        ((features, designs, [torch.zeros(0, FEATURES)], space), "target group 0 must be"),
        ((features, designs, [], space), "non-empty list of target groups"),
        ((features, designs, groups[0], space), "non-empty list of target groups"),
        ((features, designs, [groups[0], torch.full((2, FEATURES), math.nan)], space), "target group 1 .*NaN"),
        ((features[:0], designs[:0], groups, space), "no tile with finite"),
        ((features[:5], designs, groups, space), "with one P"),
        ((features, designs[:, :-1], groups, space), "encodes to 9"),
        ((features, designs * 0.5, groups, space), "one-hot"),
    ]
    for args, message in cases:
        with pytest.raises(MetaSimError, match=message):
            ms2_search(*args, config=FAST)


@pytest.mark.parametrize("options, message", [
    ({"samples": 0}, "samples"), ({"samples": 2.5}, "samples"), ({"iterations": -1}, "iterations"),
    ({"lr": 0.0}, "lr"), ({"lr": math.nan}, "lr"), ({"lr": math.inf}, "lr"),
    ({"baseline_alpha": 1.0}, "baseline_alpha"), ({"baseline_alpha": -0.1}, "baseline_alpha"),
    ({"bandwidth": "silverman"}, "bandwidth rule"), ({"bandwidth_scale": 0.0}, "bandwidth_scale"),
    ({"bandwidth_scale": math.inf}, "bandwidth_scale"), ({"max_pool": 0}, "max_pool")])
def test_bad_configs_raise(options, message):
    with pytest.raises(MetaSimError, match=message):
        MS2Config(**options)


# --- the per-tile feature cache -----------------------------------------------------------------
class CountingExtractor:
    """Mean colour and its square per tile (dihedral invariant), counting the images it sees."""

    id = "test-mean-colour"
    dim = 6
    dihedral_invariant = True

    def __init__(self):
        self.images = 0

    def __call__(self, batch):
        self.images += len(batch)
        mean = batch.mean(dim=(2, 3))
        return torch.cat([mean, mean.square()], dim=1)


def _fake_training_set(folder, config):
    """Tiles of random colours for ``config``'s designs, written as the renderer names them."""
    from meta_sim.render.jobs import sample_designs
    from meta_sim.sim import tiles

    space = DesignSpace.load(config.space)
    designs = sample_designs(space, config.designs, config.seed)
    rng = np.random.default_rng(0)
    zeros = np.zeros((24, 24), np.uint32)
    (folder / "tiles").mkdir()
    for k, design in enumerate(designs):
        for j in range(config.tiles):
            meta = tiles.tile_metadata(design=design, space=space.name, city_seed=k, tile_index=j, origin_m=(0, 0),
                                       size_px=(24, 24), pixel_size_m=0.3, preset="fast")
            rgb = (rng.random((24, 24, 3)) * rng.random(3)).astype(np.float32)
            tiles.write_tile(folder / "tiles" / f"d{k:05d}_t{j:02d}.exr", rgb, zeros, zeros, meta)
    return space, designs


def test_design_features_are_the_means_of_the_cached_tile_features(tmp_path):
    config = DatasetConfig(designs=3, tiles=2, seed=4, space="rooftops-v1")
    space, designs = _fake_training_set(tmp_path, config)

    extractor = CountingExtractor()
    counted = []
    per_design = build_features(tmp_path, config, extractor, progress=counted.append)
    assert extractor.images == 6 and counted == [1, 1, 1]  # invariant: one view per tile
    out = build_tile_features(tmp_path, config, extractor)  # computed once: the design features' pass
    assert extractor.images == 6
    assert out.designs == designs and out.encoded.shape == (3, space.dim)
    assert out.features.shape == (3, 2, 6) and torch.isfinite(out.features).all()
    assert torch.allclose(per_design.features, out.features.mean(dim=1), atol=1e-6)
    assert torch.equal(per_design.encoded, out.encoded)
    assert len(list(tmp_path.glob("tile-features-*.pt"))) == 1 and len(list(tmp_path.glob("features-*.pt"))) == 1

    extractor.images = 0
    for tile in (tmp_path / "tiles").glob("*.exr"):
        tile.unlink()
    again = build_tile_features(tmp_path, config, extractor)
    assert extractor.images == 0 and torch.equal(again.features, out.features)
    with pytest.raises(MetaSimError, match="d00003_t00.exr is missing"):
        build_tile_features(tmp_path, DatasetConfig(designs=4, tiles=2, seed=4, space="rooftops-v1"), extractor)
    with pytest.raises(MetaSimError, match="d00000_t00.exr is missing"):  # more tiles per design: not cached
        build_tile_features(tmp_path, DatasetConfig(designs=3, tiles=3, seed=4, space="rooftops-v1"), extractor)
    other = CountingExtractor()
    other.id = "another-extractor"
    with pytest.raises(MetaSimError, match="is missing"):
        build_tile_features(tmp_path, config, other)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert build_tile_features(tmp_path, config, extractor).features.shape == (3, 2, 6)


def test_a_killed_feature_pass_resumes_where_its_cache_was_last_saved(tmp_path, monkeypatch):
    from meta_sim.pipeline import dataset

    config = DatasetConfig(designs=5, tiles=1, seed=4, space="rooftops-v1")
    _fake_training_set(tmp_path, config)
    monkeypatch.setattr(dataset, "SAVE_SECONDS", 0.0)  # save after every design

    def killed_after_three(n):
        done.append(n)
        if len(done) == 3:
            raise KeyboardInterrupt  # as a kill would stop it, after the third design's features

    done, extractor = [], CountingExtractor()
    with pytest.raises(KeyboardInterrupt):
        build_tile_features(tmp_path, config, extractor, progress=killed_after_three)
    assert extractor.images == 3 and not list(tmp_path.glob(".*tmp*"))
    extractor.images = 0
    again = build_tile_features(tmp_path, config, extractor)
    assert extractor.images == 2  # only the two designs the killed pass had not reached
    assert again.features.shape == (5, 1, 6)

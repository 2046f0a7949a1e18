"""Roof colour: the likelihood counted on labelled tiles, the weighted histograms, their normalisation,
and the search's geometric mean of the two feature parts."""

import math

import numpy as np
import pytest
import torch
from toys import toy_space

from meta_sim.core.errors import MetaSimError
from meta_sim.nams import (
    ColourComparison,
    FeatureNorm,
    adjoint_search,
    design_table,
    exhaustive_search,
)
from meta_sim.pipeline.features import ColourTexture
from meta_sim.pipeline.roofcolour import (
    BINS,
    PRIOR,
    WEIGHT_POWER,
    RoofColourExtractor,
    RoofLikelihood,
    checkpoint_extractor,
    colour_blur,
    colour_comparison,
    ensure_roof_finder,
    evidence_reference,
    finder_agreement,
    roof_evidence,
    training_evidence,
)
from meta_sim.sim.imageio import linear_to_srgb
from meta_sim.sim.tiles import write_tile

# Linear colours: ground green, flat roofs red, sloped roofs blue.
GROUND, FLAT, SLOPED = (0.05, 0.3, 0.05), (0.6, 0.05, 0.05), (0.05, 0.05, 0.6)


def _scene(size=32):
    """(linear RGB, roof classes): ground with a flat roof on the left and a sloped one on the right."""
    rgb = np.empty((size, size, 3), np.float32)
    rgb[:] = GROUND
    roof = np.zeros((size, size), np.uint32)
    rgb[4:20, 2:14], roof[4:20, 2:14] = FLAT, 1
    rgb[8:28, 18:30], roof[8:28, 18:30] = SLOPED, 2
    return rgb, roof


def _bin(linear_rgb):
    srgb = linear_to_srgb(np.array(linear_rgb))
    q = np.minimum((srgb * BINS).astype(int), BINS - 1)
    return (q[0] * BINS + q[1]) * BINS + q[2]


@pytest.fixture(scope="module")
def tiles(tmp_path_factory):
    folder = tmp_path_factory.mktemp("roof-tiles")
    paths = []
    for k in range(3):
        rgb, roof = _scene()
        path = folder / f"t{k}.exr"
        write_tile(path, rgb, np.zeros(roof.shape, np.uint32), roof, {"k": k})
        paths.append(path)
    return paths


def test_likelihood_is_counted_on_the_roof_labels(tiles, tmp_path):
    likelihood = ensure_roof_finder(tmp_path, tiles, "colour")
    flat, sloped = likelihood.tables
    red, blue, green = _bin(FLAT), _bin(SLOPED), _bin(GROUND)
    assert flat[red] > 0.9 and sloped[red] < 0.05
    assert sloped[blue] > 0.9 and flat[blue] < 0.05
    assert flat[green] < 0.05 and sloped[green] < 0.05
    assert flat[_bin((1.0, 1.0, 0.0))] == pytest.approx(PRIOR)  # a colour no tile showed
    assert likelihood.pixels == 3 * 16 * 16
    # Cached in the folder: the same tables, not counted again (the tiles may be gone).
    again = ensure_roof_finder(tmp_path, [tmp_path / "missing.exr"] * len(tiles), "colour")
    assert again.id == likelihood.id and torch.equal(again.tables, likelihood.tables)


def test_histograms_follow_the_likely_roofs(tiles, tmp_path):
    extractor = RoofColourExtractor(ColourTexture(), ensure_roof_finder(tmp_path, tiles, "colour"), power=1.0)
    rgb, _ = _scene()
    batch = torch.from_numpy(linear_to_srgb(rgb).astype(np.float32)).permute(2, 0, 1)[None]
    out = extractor(batch)
    assert out.shape == (1, extractor.dim) and extractor.dim == ColourTexture().dim + sum(extractor.hist_blocks)
    assert torch.equal(out[:, :extractor.base_dim], ColourTexture()(batch))
    flat, sloped = out[0, extractor.base_dim:].split(list(extractor.hist_blocks))
    # Each histogram holds its kind's share of the pixels (the likelihood-weighted pixel count).
    assert float(flat.sum()) == pytest.approx(12 * 16 / 32 ** 2, rel=0.1)
    assert float(sloped.sum()) == pytest.approx(12 * 20 / 32 ** 2, rel=0.1)
    # Red and blue fall into different colour bins.
    assert float((flat / flat.sum() * sloped / sloped.sum()).sum()) < 0.05
    # The same under the dihedral views, as the extractor claims.
    assert extractor.dihedral_invariant
    assert torch.allclose(extractor(torch.rot90(batch, 1, (2, 3)).flip(-1)), out, atol=1e-6)
    # Black, white and NaN images give finite histograms.
    extremes = torch.stack([torch.zeros(3, 32, 32), torch.ones(3, 32, 32), torch.full((3, 32, 32), float("nan"))])
    assert torch.isfinite(extractor(extremes)).all()


def test_roof_evidence_is_the_share_of_pixels_the_finder_counts_as_each_roof(tiles, tmp_path):
    """What `meta-sim infer` reports beside each design: a scene with both roofs gives each kind its share of
    the pixels, one without roofs next to nothing, and an extractor without roof colour gives None."""
    extractor = RoofColourExtractor(ColourTexture(), ensure_roof_finder(tmp_path, tiles, "colour"), power=1.0)
    rgb, _ = _scene()
    ground = np.empty_like(rgb)
    ground[:] = GROUND
    batch = torch.from_numpy(linear_to_srgb(np.stack([rgb, ground])).astype(np.float32)).permute(0, 3, 1, 2)
    evidence = roof_evidence(extractor(batch), extractor)
    assert set(evidence) == {"flat", "sloped"}
    assert float(evidence["flat"][0]) == pytest.approx(12 * 16 / 32 ** 2, rel=0.1)
    assert float(evidence["sloped"][0]) == pytest.approx(12 * 20 / 32 ** 2, rel=0.1)
    assert float(evidence["flat"][1]) < 0.05 and float(evidence["sloped"][1]) < 0.05
    assert roof_evidence(ColourTexture()(batch), ColourTexture()) is None


def test_finder_agreement_scores_the_roof_finder_against_building_masks(tiles, tmp_path):
    """bench-realism's roof-finder table: on a scene whose roofs the finder knows, its building map matches
    the mask and its roof pixels the roofs' share; against a mask of other ground, it matches nothing."""
    extractor = RoofColourExtractor(ColourTexture(), ensure_roof_finder(tmp_path, tiles, "colour"), power=1.0)
    rgb, roof = _scene()
    image = linear_to_srgb(rgb).astype(np.float32)
    scored = finder_agreement(extractor, [image, image], [roof > 0, roof > 0])
    assert scored["building_share"] == pytest.approx((12 * 16 + 12 * 20) / 32 ** 2)
    assert scored["iou"] > 0.9 and scored["precision"] > 0.9 and scored["recall"] > 0.9
    assert scored["roof_pixels"]["flat"] == pytest.approx(12 * 16 / 32 ** 2, rel=0.15)
    assert scored["roof_pixels"]["sloped"] == pytest.approx(12 * 20 / 32 ** 2, rel=0.15)
    elsewhere = np.zeros((32, 32), bool)
    elsewhere[28:, :] = True  # ground only
    assert finder_agreement(extractor, [image], [elsewhere])["iou"] == 0.0


def test_the_training_range_spans_the_designs_roof_evidence_but_for_5_percent_at_either_end():
    """The checkpoint keeps, per roof kind, the 5% and 95% quantiles of its training designs' roof evidence
    (the range a target group is held against) and the median; a damaged entry is an error, a missing one
    none."""
    lead = torch.zeros(101, 3)
    flat = torch.linspace(0, 0.2, 101)[:, None].expand(101, 4) / 4  # design k: share 0.002 k in 4 bins
    sloped = torch.full((101, 2), 0.05)
    kept = training_evidence(torch.cat([lead, flat, sloped], 1), (4, 2))
    assert kept["quantile"] == 0.05
    assert kept["flat"] == {"low": pytest.approx(0.01, abs=1e-6), "median": pytest.approx(0.1),
                            "high": pytest.approx(0.19, abs=1e-6)}
    assert kept["sloped"] == {"low": pytest.approx(0.1), "median": pytest.approx(0.1), "high": pytest.approx(0.1)}
    assert training_evidence(lead, ()) is None
    assert evidence_reference({"roof_evidence": kept}) == {"flat": pytest.approx((0.01, 0.19)),
                                                           "sloped": pytest.approx((0.1, 0.1))}
    assert evidence_reference({}) == {}
    good = {"low": 0.1, "high": 0.2}
    for damaged in ({"flat": {"low": 2.0, "high": 3.0}, "sloped": good}, {"flat": {"low": True, "high": 0.1}},
                    {"flat": {"low": 0.3, "high": 0.2}, "sloped": good}, {"flat": 0.1}, {"flat": good}, "x"):
        with pytest.raises(MetaSimError, match="roof_evidence"):
            evidence_reference({"roof_evidence": damaged})


def test_feature_norm_makes_unit_histograms_with_the_leading_parts_spread():
    generator = torch.Generator().manual_seed(0)
    lead = torch.randn(200, 6, generator=generator) * 3
    counts = torch.rand(200, 10, generator=generator) * 0.01  # two histograms of 5 bins, unnormalised
    norm = FeatureNorm.fit(torch.cat([lead, counts], 1), hist_blocks=(5, 5))
    out = norm.apply(torch.cat([lead, counts], 1))
    assert norm.dim == 16 and norm.hist_dim == 10 and out.shape == (200, 16)
    hists = out[:, 6:] / norm.hist_scale
    for block in hists.split([5, 5], dim=1):
        assert torch.allclose(block.square().sum(1), torch.ones(200), atol=1e-5)
    assert float(out[:, 6:].var(0, unbiased=False).sum()) == pytest.approx(
        float(out[:, :6].var(0, unbiased=False).sum()), rel=1e-3)
    # Empty, NaN and infinite counts give finite (zero) histograms, never NaN.
    odd = torch.cat([torch.zeros(3, 6), torch.tensor([[0.0] * 10, [float("nan")] * 10, [float("inf")] * 10])], 1)
    assert torch.isfinite(norm.apply(odd)).all()
    restored = FeatureNorm.from_dict(norm.to_dict())
    assert torch.equal(restored.apply(odd), norm.apply(odd))
    with pytest.raises(MetaSimError, match="dimensions"):
        norm.apply(torch.zeros(1, 15))
    with pytest.raises(MetaSimError, match="do not fit"):
        FeatureNorm.fit(torch.zeros(10, 4), hist_blocks=(4,))


def _accuracy(results, truth, param):
    return np.mean([r.design[param] == d[param] for r, d in zip(results, truth)])


def test_search_takes_the_geometric_mean_of_the_two_parts(coloured):
    space, fit = coloured["space"], coloured["fit"]
    model = fit.model
    assert model.config.colour_dims == 16 and model.config.feature_dim == 28
    # One error scale over the histograms.
    assert torch.unique(model.feature_scale[-16:]).numel() == 1
    targets = fit.norm.apply(coloured["targets"])
    results = exhaustive_search(model, targets, space)
    assert _accuracy(results, coloured["truth"], "p0") >= 0.9 and _accuracy(results, coloured["truth"], "p1") >= 0.9
    table = design_table(model, space)
    errors = (targets[:, None].double() / model.feature_scale.double() - table.features[None].double()).square()
    expected = (errors[..., :12].mean(-1) * errors[..., 12:].mean(-1)).sqrt().min(dim=1).values
    assert torch.allclose(torch.tensor([r.best_loss for r in results], dtype=torch.float64), expected, rtol=1e-6)
    adjoint = adjoint_search(model, targets[:10], space, M=64, S=8, iterations=60,
                             generator=torch.Generator().manual_seed(0))
    assert _accuracy(adjoint, coloured["truth"][:10], "p0") >= 0.8


def test_colour_decides_when_the_other_features_are_far_off(coloured):
    # A target unlike every simulation in the other features (a texture the bank lacks): their error
    # is huge for every design, and the product still ranks designs by the colour histograms.
    space, fit = coloured["space"], coloured["fit"]
    shifted = coloured["targets"].clone()
    shifted[:, :12] += 40.0 * torch.randn(12, generator=torch.Generator().manual_seed(5))
    targets = fit.norm.apply(shifted)
    results = exhaustive_search(fit.model, targets, space)
    assert _accuracy(results, coloured["truth"], "p0") >= 0.9 and _accuracy(results, coloured["truth"], "p1") >= 0.9
    for dtype in (torch.float32, torch.bfloat16):
        out = adjoint_search(fit.model, targets[:5], space, M=32, S=4, iterations=20, dtype=dtype,
                             generator=torch.Generator().manual_seed(0))
        assert all(math.isfinite(r.best_loss) for r in out)


def test_search_is_finite_at_the_extremes_with_colour(coloured):
    space, fit = coloured["space"], coloured["fit"]
    exact = design_table(fit.model, space).features[:2] * fit.model.feature_scale  # a target P predicts exactly
    for targets in (torch.zeros(2, 28), torch.full((2, 28), 1e30), exact):
        for result in exhaustive_search(fit.model, targets, space) + adjoint_search(
                fit.model, targets, space, M=16, S=4, iterations=10, generator=torch.Generator().manual_seed(0)):
            assert math.isfinite(result.best_loss) and result.best_loss >= 0


def _line_blur(bins: int = 8, sigma: float = 1.0) -> torch.Tensor:
    """A Gaussian blur over bins in a line, each column summing to 1 (the toy histograms' neighbours)."""
    i = torch.arange(bins, dtype=torch.float64)
    weights = torch.exp(-(i[:, None] - i[None, :]).square() / (2 * sigma ** 2))
    return weights / weights.sum(dim=0, keepdim=True)


def test_the_colour_comparison_weighs_the_colour_error_by_its_exponent(coloured):
    space, fit = coloured["space"], coloured["fit"]
    model, targets = fit.model, fit.norm.apply(coloured["targets"])
    plain = exhaustive_search(model, targets, space)
    assert [r.ranked for r in exhaustive_search(model, targets, space, colour=colour_comparison())] == \
        [r.ranked for r in plain]
    table = design_table(model, space)
    errors = (targets[:, None].double() / model.feature_scale.double() - table.features[None].double()).square()
    rest, colour = errors[..., :12].mean(-1), errors[..., 12:].mean(-1)
    found = exhaustive_search(model, targets, space, colour=ColourComparison(exponent=0.3))
    expected = (rest ** 0.7 * colour ** 0.3).min(dim=1).values
    assert torch.allclose(torch.tensor([r.best_loss for r in found], dtype=torch.float64), expected, rtol=1e-6)
    assert _accuracy(found, coloured["truth"], "p0") >= 0.9


def test_a_blurred_comparison_names_the_nearest_colour_for_one_the_bank_lacks(coloured):
    # p0's six choices peak in bins 0-5 of its histogram; the targets' p0 roofs peak in bin 7, a colour no
    # choice has, and their other features are far off. Plain, every choice shares nothing with bin 7 and the
    # answer is whichever the other features favour; blurred, bin 7 overlaps bin 6's neighbour 5: choice 5.
    space, fit = coloured["space"], coloured["fit"]
    lacking = coloured["targets"].clone()
    lacking[:, :12] += 40.0 * torch.randn(12, generator=torch.Generator().manual_seed(5))
    lacking[:, 12:20] = torch.full((8,), 0.02)
    lacking[:, 19] = 1.0
    targets = fit.norm.apply(lacking)
    nearest = space.parameters[0].choices[5]
    blurred = ColourComparison(exponent=0.5, blur=_line_blur(), blur_weight=30.0)

    def share(results):
        return np.mean([r.design["p0"] == nearest for r in results])

    assert share(exhaustive_search(fit.model, targets, space, colour=blurred)) == 1.0
    assert share(exhaustive_search(fit.model, targets, space)) <= 0.5
    adjoint = adjoint_search(fit.model, targets[:8], space, M=64, S=8, iterations=60, colour=blurred,
                             generator=torch.Generator().manual_seed(0))
    assert share(adjoint) >= 0.75
    # p1's answers still follow the targets' own p1 histograms.
    assert _accuracy(exhaustive_search(fit.model, targets, space, colour=blurred), coloured["truth"], "p1") >= 0.9


def test_a_grid_of_comparisons_keeps_a_bounded_cache_and_the_same_answers(coloured):
    """Each comparison's blurred and kept tables are cached on the model for the searches that reuse it; a grid of
    hundreds of comparisons (bench-objective's) keeps only the most recent few, and a comparison whose tables were
    dropped ranks as it did when they were kept."""
    from meta_sim.nams.search import DERIVED_TABLES_KEPT

    space, fit = coloured["space"], coloured["fit"]
    targets = fit.norm.apply(coloured["targets"])[:6]
    grid = [ColourComparison(exponent=0.3, blur=_line_blur(sigma=0.5 + k / 10), blur_weight=30.0,
                             far=ColourComparison(keep=_p0_only(), blur=_line_blur(sigma=0.5 + k / 10),
                                                  blur_weight=10.0), far_loss=1e-12)
             for k in range(3 * DERIVED_TABLES_KEPT)]
    first = [r.ranked for r in exhaustive_search(fit.model, targets, space, colour=grid[0])]
    for colour in grid[1:]:
        exhaustive_search(fit.model, targets, space, colour=colour)
        derived = [k for k in fit.model._design_tables if isinstance(k, tuple)]
        assert len(derived) <= DERIVED_TABLES_KEPT
    assert any(not isinstance(k, tuple) for k in fit.model._design_tables)  # the design table stays
    assert [r.ranked for r in exhaustive_search(fit.model, targets, space, colour=grid[0])] == first


def test_a_blurred_search_is_finite_at_the_extremes(coloured):
    space, fit = coloured["space"], coloured["fit"]
    blurred = ColourComparison(exponent=0.3, blur=_line_blur(), blur_weight=30.0)
    exact = design_table(fit.model, space).features[:2] * fit.model.feature_scale
    for targets in (torch.zeros(2, 28), torch.full((2, 28), 1e30), exact):
        for dtype in (torch.float32, torch.bfloat16):
            results = exhaustive_search(fit.model, targets, space, colour=blurred) + adjoint_search(
                fit.model, targets, space, M=16, S=4, iterations=10, dtype=dtype, colour=blurred,
                generator=torch.Generator().manual_seed(0))
            assert all(math.isfinite(r.best_loss) and r.best_loss >= 0 for r in results)


@pytest.mark.parametrize("kwargs, message", [
    ({"exponent": 0.0}, "between 0 and 1"), ({"exponent": 1.0}, "between 0 and 1"),
    ({"blur_weight": -1.0}, "at least 0"), ({"blur_weight": math.inf}, "finite"),
    ({"blur": torch.ones(8, 8)}, "columns sum to 1"), ({"blur": -_line_blur()}, "non-negative"),
    ({"blur": torch.ones(1, 8) / 8}, "square"),
])
def test_bad_colour_comparisons_are_refused(kwargs, message):
    with pytest.raises(MetaSimError, match=message):
        ColourComparison(**kwargs)


def test_a_blur_must_fit_the_models_histograms(coloured):
    space, fit = coloured["space"], coloured["fit"]
    targets = fit.norm.apply(coloured["targets"][:2])
    wrong = ColourComparison(blur=_line_blur(bins=5), blur_weight=1.0)
    for search in (exhaustive_search, lambda *a, **k: adjoint_search(*a, M=8, S=2, iterations=1, **k)):
        with pytest.raises(MetaSimError, match="5 bins per histogram"):
            search(fit.model, targets, space, colour=wrong)


def test_the_colour_blur_spreads_each_bin_over_its_neighbours_in_the_cone():
    blur = colour_blur(1.5)
    assert blur.shape == (488, 488) and blur.dtype == torch.float64
    assert (blur >= 0).all() and torch.allclose(blur.sum(dim=0), torch.ones(488, dtype=torch.float64))
    assert bool((blur.diagonal() >= blur.max(dim=0).values - 1e-12).all())  # a bin keeps most of itself
    wider = colour_blur(3.0)
    assert float(wider.diagonal().mean()) < float(blur.diagonal().mean())  # a wider blur keeps less
    for sigma in (0.0, -1.0, math.nan):
        with pytest.raises(MetaSimError, match="sigma"):
            colour_blur(sigma)
    assert colour_comparison(0.3).blur is None and colour_comparison(0.3, 1.5, 0.0).blur is None
    assert colour_comparison(0.3, 1.5, 30.0).blur.shape == (488, 488)


def test_pixels_count_their_roof_probability_to_a_power(tiles, tmp_path):
    likelihood = ensure_roof_finder(tmp_path, tiles, "colour")
    rgb, _ = _scene()
    batch = torch.from_numpy(linear_to_srgb(rgb).astype(np.float32)).permute(2, 0, 1)[None]
    plain = RoofColourExtractor(ColourTexture(), likelihood, power=1.0)
    sharp = RoofColourExtractor(ColourTexture(), likelihood)  # the default power, WEIGHT_POWER
    assert sharp.power == WEIGHT_POWER > 1 and plain.id == f"{ColourTexture().id}+{likelihood.id}"
    assert sharp.id == f"{plain.id}^{WEIGHT_POWER:g}"

    class Squared:  # the likelihood's probabilities squared: power 2 of it is power 4 of the likelihood
        id = "squared"

        def weights(self, level1):
            return likelihood.weights(level1) ** 2

    assert torch.allclose(sharp.roof_histograms(batch),
                          RoofColourExtractor(ColourTexture(), Squared(), power=2.0).roof_histograms(batch))
    # Doubtful pixels (the prior's 0.25 for a colour never seen) all but vanish; sure ones stay.
    odd = batch.clone()
    odd[..., :4, :] = torch.tensor([1.0, 1.0, 0.0])[:, None, None]  # yellow: no training tile had it
    for extractor, doubt in ((plain, PRIOR), (sharp, PRIOR ** WEIGHT_POWER)):
        grown = extractor.roof_histograms(odd) - extractor.roof_histograms(batch)
        assert float(grown[0, :extractor.hist_blocks[0]].sum()) == pytest.approx(doubt * 4 * 32 / 32 ** 2, rel=0.2)
    for bad in (0.0, -1.0, float("nan"), float("inf")):
        with pytest.raises(MetaSimError, match="weight power"):
            RoofColourExtractor(ColourTexture(), likelihood, power=bad)


def test_checkpoint_extractor_needs_the_same_likelihood(tiles, tmp_path):
    likelihood = ensure_roof_finder(tmp_path, tiles, "colour")

    class Ckpt:
        extractor = RoofColourExtractor(ColourTexture(), likelihood, power=3.0)
        extra = {"extractor_spec": "colour-texture", "roof_likelihood": extractor.to_dict()}
        extractor_id = extractor.id

    assert checkpoint_extractor(Ckpt()).id == Ckpt.extractor_id
    assert checkpoint_extractor(Ckpt()).power == 3.0
    # Checkpoints from before the power was kept counted the plain probability.
    Ckpt.extra = {"extractor_spec": "colour-texture", "roof_likelihood": likelihood.to_dict()}
    Ckpt.extractor_id = RoofColourExtractor(ColourTexture(), likelihood, power=1.0).id
    assert checkpoint_extractor(Ckpt()).id == Ckpt.extractor_id
    Ckpt.extra = {"extractor_spec": "colour-texture",
                  "roof_likelihood": RoofLikelihood(likelihood.tables * 0.5, 1).to_dict()}
    with pytest.raises(MetaSimError, match="trained on features"):
        checkpoint_extractor(Ckpt())
    with pytest.raises(MetaSimError, match="version"):
        RoofLikelihood.from_dict({"version": 99})


class _Stub:
    """A roof finder that calls the given 2x2 blocks (None: all) flat roofs (probability 1), nothing sloped."""

    id = "stub"

    def __init__(self, flat_blocks):
        self.flat_blocks = flat_blocks

    def weights(self, level1):
        out = torch.zeros(level1.shape[0], 2, *level1.shape[-2:])
        out[:, 0] = 1.0 if self.flat_blocks is None else self.flat_blocks
        return out

    def to_dict(self):
        return {"kind": "stub"}


def test_score_cone_histograms_count_full_resolution_roof_pixels_as_the_score_does():
    from meta_sim.pipeline.roofcolour import score_cone_bins
    from meta_sim.sim.textures import hsv_cone_histogram

    # A flat roof of a one-pixel checkerboard of two colours on grey ground: its 2x2 means are one third colour.
    size = 16
    srgb = np.full((size, size, 3), 0.5, np.float32)
    checker = (np.add.outer(np.arange(8), np.arange(8)) % 2).astype(bool)
    roof = np.where(checker[..., None], np.float32([0.85, 0.2, 0.15]), np.float32([0.2, 0.3, 0.8]))
    srgb[4:12, 4:12] = roof
    blocks = torch.zeros(size // 2, size // 2)
    blocks[2:6, 2:6] = 1.0
    batch = torch.from_numpy(srgb).permute(2, 0, 1)[None]
    extractor = RoofColourExtractor(ColourTexture(), _Stub(blocks), power=1.0, score_cone=True)
    keep = score_cone_bins()
    assert extractor.hist_blocks == (488, 488, 220, 220) and int(keep.sum()) == 220
    assert extractor.dim == ColourTexture().dim + 1416 and extractor.id.endswith("+score-cone8")
    out = extractor(batch)
    stretched_flat, _, score_flat, score_sloped = out[0, extractor.base_dim:].split(list(extractor.hist_blocks))
    # The score's own histogram of the roof's pixels: the two colours, half each, none of their mean.
    expected = torch.from_numpy(hsv_cone_histogram(np.round(roof * 255).astype(np.uint8)))[keep].float()
    assert torch.allclose(score_flat / score_flat.sum(), expected, atol=1e-6)
    assert int((expected > 0).sum()) == 2 and float(score_sloped.sum()) == 0.0
    assert float(score_flat.sum()) == pytest.approx(64 / size ** 2)  # the roof's share of the tile's pixels
    # The stretched histogram of 2x2 means sees the blend instead (one colour, in neither of the two bins).
    without = RoofColourExtractor(ColourTexture(), _Stub(blocks), power=1.0)
    assert torch.equal(without(batch), out[:, :without.dim])
    assert extractor.dihedral_invariant
    assert torch.allclose(extractor(torch.rot90(batch, 1, (2, 3)).flip(-1)), out, atol=1e-6)
    extremes = torch.stack([torch.zeros(3, size, size), torch.ones(3, size, size),
                            torch.full((3, size, size), float("nan"))])
    assert torch.isfinite(extractor(extremes)).all()
    everywhere = RoofColourExtractor(ColourTexture(), _Stub(None), power=1.0, score_cone=True)
    odd = everywhere.roof_histograms(torch.rand(1, 3, 17, 17))  # the last odd row and column are left out
    assert odd.shape == (1, 1416) and float(odd[0, 976:1196].sum()) == pytest.approx(1.0)  # of the pixels counted


def test_the_score_cone_is_kept_by_the_checkpoint_and_off_for_older_ones(tiles, tmp_path):
    likelihood = ensure_roof_finder(tmp_path, tiles, "colour")
    extractor = RoofColourExtractor(ColourTexture(), likelihood, score_cone=True)

    class Ckpt:
        extra = {"extractor_spec": "colour-texture", "roof_likelihood": extractor.to_dict()}
        extractor_id = extractor.id

    back = checkpoint_extractor(Ckpt())
    assert back.score_cone and back.id == extractor.id and back.hist_blocks == extractor.hist_blocks
    older = {k: v for k, v in extractor.to_dict().items() if k != "score_cone"}  # from before it existed
    Ckpt.extra = {"extractor_spec": "colour-texture", "roof_likelihood": older}
    Ckpt.extractor_id = RoofColourExtractor(ColourTexture(), likelihood).id
    assert not checkpoint_extractor(Ckpt()).score_cone
    Ckpt.extra = {"extractor_spec": "colour-texture", "roof_likelihood": {**older, "score_cone": "yes"}}
    with pytest.raises(MetaSimError, match="score_cone"):
        checkpoint_extractor(Ckpt())


def test_the_colour_blur_covers_both_cones_block_by_block():
    blur = colour_blur(1.5, (488, 488, 220, 220))
    assert blur.shape == (1416, 1416) and torch.allclose(blur.sum(dim=0), torch.ones(1416, dtype=torch.float64))
    assert torch.equal(blur[:488, :488], colour_blur(1.5)) and torch.equal(blur[488:976, 488:976], colour_blur(1.5))
    assert float(blur[:976, 976:].abs().sum()) == 0.0 and float(blur[976:, :976].abs().sum()) == 0.0
    assert torch.equal(blur[976:1196, 976:1196], blur[1196:, 1196:])
    assert colour_comparison(0.3, 1.5, 30.0, (488, 488, 220, 220)).blur.shape == (1416, 1416)
    with pytest.raises(MetaSimError, match="no colour cone has 100 bins"):
        colour_blur(1.5, (100,))


def test_the_blurred_design_table_is_kept_per_comparison_and_gives_the_same_answers(coloured):
    space, fit = coloured["space"], coloured["fit"]
    targets = fit.norm.apply(coloured["targets"])
    blurred = ColourComparison(exponent=0.3, blur=_line_blur(), blur_weight=30.0)
    fit.model.train()  # drops what the other tests' searches kept
    fit.model.eval()
    first = exhaustive_search(fit.model, targets, space, colour=blurred)
    kept = [k for k in fit.model._design_tables if k[0] == "blurred"]
    assert len(kept) == 1
    again = exhaustive_search(fit.model, targets, space, colour=blurred)  # from the kept table
    assert [r.ranked for r in again] == [r.ranked for r in first]
    other = ColourComparison(exponent=0.3, blur=_line_blur() * 0 + torch.eye(8, dtype=torch.float64),
                             blur_weight=30.0)  # another comparison: its own table, never the first's
    exhaustive_search(fit.model, targets, space, colour=other)
    assert len([k for k in fit.model._design_tables if k[0] == "blurred"]) == 2
    fit.model.train()  # new weights to come: every kept table goes
    assert not fit.model._design_tables
    fit.model.eval()
    assert [r.ranked for r in exhaustive_search(fit.model, targets, space, colour=blurred)] == \
        [r.ranked for r in first]


def test_the_search_colour_is_the_chosen_comparison_for_a_model_with_roof_colours(coloured):
    from meta_sim.nams import PLAIN_COLOUR
    from meta_sim.pipeline.roofcolour import SEARCH_COLOUR, search_colour

    class Ckpt:  # a space without roof materials: no roof match
        feature_norm = FeatureNorm(torch.zeros(4), torch.ones(4), hist_blocks=(488, 488, 220, 220))
        space, model_id = toy_space(2, 2), "no-roofs"

    colour = search_colour(Ckpt())
    assert (colour.exponent, colour.blur_weight) == (SEARCH_COLOUR[0], SEARCH_COLOUR[2])
    assert colour.blur.shape == (1416, 1416) and torch.equal(colour.blur, colour_blur(SEARCH_COLOUR[1],
                                                                                       (488, 488, 220, 220)))
    assert search_colour(Ckpt()) is colour  # one object per layout: the search blurs a design table once
    Ckpt.feature_norm = FeatureNorm(torch.zeros(4), torch.ones(4))
    assert search_colour(Ckpt()) is PLAIN_COLOUR


def _p0_only() -> torch.Tensor:
    """Keeps the toy model's first histogram (p0's, the first 8 of its 16 histogram values)."""
    return torch.arange(16) < 8


def test_a_target_far_from_every_design_is_searched_again_by_the_kept_histograms(coloured):
    space, fit = coloured["space"], coloured["fit"]
    model, targets = fit.model, fit.norm.apply(coloured["targets"])
    shifted = coloured["targets"].clone()
    shifted[:, :12] += 40.0 * torch.randn(12, generator=torch.Generator().manual_seed(5))
    targets = torch.cat([targets[:10], fit.norm.apply(shifted)[:10]])  # ten near, ten far off
    plain = exhaustive_search(model, targets, space)
    threshold = float(np.median([r.best_loss for r in plain]))
    colour = ColourComparison(far=ColourComparison(keep=_p0_only()), far_loss=threshold)
    found = exhaustive_search(model, targets, space, colour=colour)
    far = [r.best_loss > threshold for r in plain]
    assert 0 < sum(far) < len(far) and [r.far for r in found] == far
    for near, result in zip(plain, found):  # a target near some design is searched as before
        if not result.far:
            assert result.ranked == near.ranked
    table = design_table(model, space)
    errors = (targets[:, None].double() / model.feature_scale.double() - table.features[None].double()).square()
    expected = (errors[..., :12].mean(-1) * errors[..., 12:20].mean(-1)).sqrt().min(dim=1).values
    got = torch.tensor([r.best_loss for r in found], dtype=torch.float64)
    assert torch.allclose(got[torch.tensor(far)], expected[torch.tensor(far)], rtol=1e-6)
    # Without a threshold, or with one no target exceeds, nothing is searched again.
    for unused in (ColourComparison(far=ColourComparison(keep=_p0_only())),
                   ColourComparison(far=ColourComparison(keep=_p0_only()), far_loss=1e30)):
        assert [r.ranked for r in exhaustive_search(model, targets, space, colour=unused)] == \
            [r.ranked for r in plain]
    # The adjoint search too: every target beyond a tiny threshold, none beyond a huge one.
    for loss, expect in ((1e-12, True), (1e30, False)):
        out = adjoint_search(model, targets[:4], space, M=16, S=4, iterations=10,
                             colour=ColourComparison(far=ColourComparison(keep=_p0_only()), far_loss=loss),
                             generator=torch.Generator().manual_seed(0))
        assert all(r.far is expect and math.isfinite(r.best_loss) for r in out)
        assert all(r.to_dict()["far"] is expect for r in out)


def test_a_far_margin_keeps_the_first_answer_where_the_far_comparison_finds_it_plausible(coloured):
    from meta_sim.nams import design_losses

    space, fit = coloured["space"], coloured["fit"]
    model = fit.model
    shifted = coloured["targets"].clone()
    shifted[:, :12] += 40.0 * torch.randn(12, generator=torch.Generator().manual_seed(5))
    targets = torch.cat([fit.norm.apply(coloured["targets"])[:10], fit.norm.apply(shifted)[:10]])
    plain = exhaustive_search(model, targets, space)
    far_only = exhaustive_search(model, targets, space, colour=ColourComparison(keep=_p0_only()))
    # The loss of a named design is the search's own: the best design's is the best loss.
    assert torch.allclose(design_losses(model, space, [r.design for r in plain], targets),
                          torch.tensor([r.best_loss for r in plain], dtype=torch.float64), rtol=1e-6)
    # Far for every target; each first answer's far loss against the far search's best.
    ratio = (design_losses(model, space, [r.design for r in plain], targets, ColourComparison(keep=_p0_only()))
             / torch.tensor([r.best_loss for r in far_only], dtype=torch.float64))
    assert (ratio >= 1 - 1e-9).all()
    ordered = ratio.sort().values
    gap = max(range(len(ordered) // 4, 3 * len(ordered) // 4), key=lambda i: ordered[i + 1] - ordered[i])
    margin = float(ordered[gap] + ordered[gap + 1]) / 2 - 1  # in the widest gap between two middle ratios
    for m in (0.0, margin, 1e9):
        found = exhaustive_search(model, targets, space, colour=ColourComparison(
            far=ColourComparison(keep=_p0_only()), far_loss=1e-12, far_margin=m))
        # A margin of 0 ranks again where the far search's best is another design.
        again = ([a.design != b.design for a, b in zip(plain, far_only)] if m == 0 else (ratio > 1 + m).tolist())
        assert [r.far for r in found] == again
        for result, first, other, a in zip(found, plain, far_only, again):
            assert result.ranked == (other.ranked if a else first.ranked)
    assert 0 < sum(ratio > 1 + margin) < len(ratio)  # the median margin keeps some and ranks some again
    # The adjoint search: a huge margin keeps every first answer; without a margin every target is ranked again.
    for m, expect in ((1e9, False), (None, True)):
        out = adjoint_search(model, targets[:4], space, M=16, S=4, iterations=10,
                             colour=ColourComparison(far=ColourComparison(keep=_p0_only()), far_loss=1e-12,
                                                     far_margin=m),
                             generator=torch.Generator().manual_seed(0))
        assert all(r.far is expect for r in out)
    with pytest.raises(MetaSimError, match="2 designs for 4 targets"):
        design_losses(model, space, [r.design for r in plain[:2]], targets[:4])


def test_a_far_search_is_deterministic(coloured):
    space, fit = coloured["space"], coloured["fit"]
    targets = fit.norm.apply(coloured["targets"][:4])
    colour = ColourComparison(far=ColourComparison(keep=_p0_only()), far_loss=1e-12)

    def run():
        return [(r.design, r.best_loss) for r in adjoint_search(
            fit.model, targets, space, M=16, S=4, iterations=10, colour=colour, r=0.5,
            generator=torch.Generator().manual_seed(3))]

    assert run() == run()


@pytest.mark.parametrize("kwargs, message", [
    ({"keep": torch.ones(16)}, "boolean mask"), ({"keep": torch.zeros(16, dtype=torch.bool)}, "keeping some"),
    ({"far_loss": 0.0}, "positive"), ({"far_loss": math.nan}, "positive"),
    ({"far": ColourComparison(far=ColourComparison()), "far_loss": 1.0}, "without a far comparison"),
    ({"far_margin": -0.1}, "margin"), ({"far_margin": math.inf}, "margin"), ({"far_margin": math.nan}, "margin"),
])
def test_bad_far_comparisons_are_refused(kwargs, message):
    with pytest.raises(MetaSimError, match=message):
        ColourComparison(**kwargs)


def test_a_mask_must_fit_the_models_histograms(coloured):
    space, fit = coloured["space"], coloured["fit"]
    targets = fit.norm.apply(coloured["targets"][:2])
    for wrong in (ColourComparison(keep=torch.ones(5, dtype=torch.bool)),
                  ColourComparison(far=ColourComparison(keep=torch.ones(5, dtype=torch.bool)), far_loss=1.0)):
        for search in (exhaustive_search, lambda *a, **k: adjoint_search(*a, M=8, S=2, iterations=1, **k)):
            with pytest.raises(MetaSimError, match="keeps 5 histogram values; the model has 16"):
                search(fit.model, targets, space, colour=wrong)


def test_the_far_comparison_keeps_the_score_cones_histograms_and_shares_the_blur():
    from meta_sim.pipeline.roofcolour import SEARCH_FAR

    blocks = (488, 488, 220, 220)
    colour = colour_comparison(0.3, 1.0, 30.0, blocks, far=(4.0, 0.5, 1.0, 10.0))
    assert colour.searches_far and colour.far_loss == 4.0 and colour.far.exponent == 0.5
    assert colour.far.keep.tolist() == [False] * 976 + [True] * 440
    assert colour.far.blur is colour.blur and colour.far.blur_weight == 10.0  # one blurred table for both
    assert colour_comparison(0.3, 1.0, 30.0, blocks, far=(4.0, 0.5, 1.5, 10.0)).far.blur is not None
    assert colour_comparison(0.3, 1.0, 30.0, blocks, far=(4.0, 0.5, 1.0, 0.0)).far.blur is None
    assert colour.to_dict() == {"exponent": 0.3, "blurred": True, "blur_weight": 30.0, "far_loss": 4.0,
                                "far": {"exponent": 0.5, "blurred": True, "blur_weight": 10.0, "kept_values": 440}}
    with pytest.raises(MetaSimError, match="score's cone"):
        colour_comparison(0.3, 1.0, 30.0, (488, 488), far=SEARCH_FAR)


def test_the_search_colour_searches_far_targets_only_for_a_model_with_the_score_cone():
    from meta_sim.pipeline.roofcolour import SEARCH_FAR, search_colour

    class Ckpt:  # a space without roof materials: no roof match
        feature_norm = FeatureNorm(torch.zeros(4), torch.ones(4), hist_blocks=(488, 488, 220, 220))
        space, model_id = toy_space(2, 2), "no-roofs"

    colour = search_colour(Ckpt())
    assert colour.searches_far and (colour.far_loss, colour.far.exponent, colour.far.blur_weight) == \
        (SEARCH_FAR[0], SEARCH_FAR[1], SEARCH_FAR[3])
    Ckpt.feature_norm = FeatureNorm(torch.zeros(4), torch.ones(4), hist_blocks=(488, 488))
    assert not search_colour(Ckpt()).searches_far

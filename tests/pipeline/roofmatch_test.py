"""Far targets ranked by their roof colours under the score's own measure: ``nams.RoofMatch`` and the search's
use of it, and ``pipeline.roofcolour.roof_match``, which builds one for a checkpoint."""

from types import SimpleNamespace

import numpy as np
import pytest
import torch
from toys import toy_space

from meta_sim.core.errors import MetaSimError
from meta_sim.nams import (
    ColourComparison,
    FeatureNorm,
    NAMSConfig,
    RoofMatch,
    TrainConfig,
    adjoint_search,
    exhaustive_search,
    train_nams,
)
from meta_sim.pipeline.roofcolour import (
    SEARCH_FAR,
    colour_comparison,
    roof_match,
    score_cone_bins,
    search_colour,
    swatch_histograms,
    value_shift,
)
from meta_sim.sim.design import DesignSpace
from meta_sim.sim.textures.similarity import BINS

WIDTH = int(score_cone_bins().sum())


def _one_hot(index: int, width: int = 8) -> torch.Tensor:
    return torch.nn.functional.one_hot(torch.tensor(index), width).double()


def test_the_match_loss_is_one_minus_the_mean_intersection():
    space = toy_space(3, 2)
    vectors = torch.stack([torch.from_numpy(space.encode({"p0": f"p0c{a}", "p1": f"p1c{b}"}))
                           for a in range(3) for b in range(2)]).double()
    generator = torch.Generator().manual_seed(0)
    predicted = torch.rand(6, 8, generator=generator, dtype=torch.float64)  # square roots, not normalised
    target = torch.rand(1, 8, generator=generator, dtype=torch.float64)
    swatches = torch.rand(3, 4, generator=generator, dtype=torch.float64)
    swatches /= swatches.sum(dim=1, keepdim=True)
    roll = torch.roll(torch.eye(4, dtype=torch.float64), 1, dims=0)  # bin j's mass to bin j + 1

    def hist(v):
        return v.square() / v.square().sum(dim=-1, keepdim=True)

    for weight in (0.0, 0.4, 1.0):
        match = RoofMatch(((0, 4), (4, 4)), ("p0", "p1"), (swatches, None), (roll, torch.eye(4)), weight)
        got = match.losses(space, vectors, predicted, target)
        assert got.shape == (1, 6) and got.dtype == torch.float64
        for n in range(6):
            flat = torch.minimum(hist(target[0, :4]), hist(predicted[n, :4])).sum()
            own = torch.minimum(hist(target[0, :4]) @ roll.T, swatches[n // 2]).sum()
            sloped = torch.minimum(hist(target[0, 4:]), hist(predicted[n, 4:])).sum()  # no swatches: rendered only
            expected = 1 - ((1 - weight) * flat + weight * own + sloped) / 2
            assert abs(float(got[0, n]) - float(expected)) < 1e-12
    # Unmixed: before the swatch part, the histogram less a share of the other kind's (cut at 0).
    match = RoofMatch(((0, 4), (4, 4)), ("p0", "p1"), (swatches, None), (roll, torch.eye(4)), 1.0, unmix=0.5)
    got = match.losses(space, vectors, predicted, target)
    rest = (hist(target[0, :4]) - 0.5 * hist(target[0, 4:])).clamp_min(0)
    for n in range(6):
        own = torch.minimum((rest / rest.sum()) @ roll.T, swatches[n // 2]).sum()
        sloped = torch.minimum(hist(target[0, 4:]), hist(predicted[n, 4:])).sum()
        assert abs(float(got[0, n]) - float(1 - (own + sloped) / 2)) < 1e-12
    # With a render share, that share of the swatch part compares the unmixed, unshifted histogram with each
    # choice's rendered one.
    renders = torch.rand(3, 4, generator=generator, dtype=torch.float64)
    renders /= renders.sum(dim=1, keepdim=True)
    match = RoofMatch(((0, 4), (4, 4)), ("p0", "p1"), (swatches, None), (roll, torch.eye(4)), 0.8, unmix=0.5,
                      renders=(renders, None), render_share=0.3)
    got = match.losses(space, vectors, predicted, target)
    unmixed = rest / rest.sum()
    for n in range(6):
        flat = torch.minimum(hist(target[0, :4]), hist(predicted[n, :4])).sum()
        own = torch.minimum(unmixed @ roll.T, swatches[n // 2]).sum()
        as_rendered = torch.minimum(unmixed, renders[n // 2]).sum()
        sloped = torch.minimum(hist(target[0, 4:]), hist(predicted[n, 4:])).sum()
        expected = 1 - (0.2 * flat + 0.8 * (0.7 * own + 0.3 * as_rendered) + sloped) / 2
        assert abs(float(got[0, n]) - float(expected)) < 1e-12
    assert match.to_dict()["render_share"] == 0.3
    # A target whose colours are exactly a design's scores 0 for it.
    match = RoofMatch(((0, 4), (4, 4)), ("p0", "p1"), (None, None), (torch.eye(4), torch.eye(4)))
    assert float(match.losses(space, vectors, predicted, predicted[3:4])[0, 3]) < 1e-12


def _far_targets(coloured, count=10):
    """The fixture's first ``count`` targets, then the same with their other features far off (a texture the
    bank lacks): ten near, ten far."""
    fit = coloured["fit"]
    shifted = coloured["targets"].clone()
    shifted[:, :12] += 40.0 * torch.randn(12, generator=torch.Generator().manual_seed(5))
    return torch.cat([fit.norm.apply(coloured["targets"])[:count], fit.norm.apply(shifted)[:count]])


def _toy_match(swatch_weight=0.5, roll_p0=0):
    """The coloured fixture's two 8-bin histograms, each choice's own colour its bin (p0's moved ``roll_p0``
    bins)."""
    eye = torch.eye(8, dtype=torch.float64)
    return RoofMatch(((0, 8), (8, 8)), ("p0", "p1"), (torch.roll(eye, roll_p0, dims=1)[:6], eye[:7]),
                     (eye, eye), swatch_weight)


def test_far_targets_are_ranked_by_the_roof_match_in_both_searches(coloured):
    space, fit = coloured["space"], coloured["fit"]
    model, targets, truth = fit.model, _far_targets(coloured), coloured["truth"][:10] * 2
    plain = exhaustive_search(model, targets, space)
    threshold = float(np.median([r.best_loss for r in plain]))
    far = [r.best_loss > threshold for r in plain]
    assert far == [False] * 10 + [True] * 10
    found = exhaustive_search(model, targets, space, colour=ColourComparison(far_loss=threshold, match=_toy_match()))
    assert [r.far for r in found] == far
    assert [r.ranked for r in found[:10]] == [r.ranked for r in plain[:10]]  # near targets searched as before
    for result, design in zip(found[10:], truth[10:]):  # far ones named by their roof colours
        assert result.design == design and result.best_loss == result.ranked[0][1] < 0.3
    adjoint = adjoint_search(model, targets, space, M=32, S=8, iterations=20,
                             generator=torch.Generator().manual_seed(0),
                             colour=ColourComparison(far_loss=threshold, match=_toy_match()))
    assert [r.design for r in adjoint[10:]] == truth[10:] and all(r.far for r in adjoint[10:])
    assert all(r.method == "adjoint" and r.votes for r in adjoint[10:])
    # The swatches count: with them alone, p0 moved by a bin in its swatches names the choice before the truth.
    moved = exhaustive_search(model, targets, space,
                              colour=ColourComparison(far_loss=threshold, match=_toy_match(1.0, roll_p0=1)))
    for result, design in zip(moved[10:], truth[10:]):
        index = space.parameters[0].choices.index(design["p0"])
        if index > 0:
            assert result.design["p0"] == f"p0c{index - 1}"


def test_a_margin_keeps_the_first_answer_the_match_finds_plausible(coloured):
    space, fit = coloured["space"], coloured["fit"]
    targets = _far_targets(coloured)
    plain = exhaustive_search(fit.model, targets, space)
    for search in (exhaustive_search, lambda *a, **k: adjoint_search(*a, M=16, S=4, iterations=5,
                                                                     generator=torch.Generator().manual_seed(0), **k)):
        first = search(fit.model, targets, space)
        kept = search(fit.model, targets, space,
                      colour=ColourComparison(far_loss=1e-12, far_margin=1e9, match=_toy_match()))
        assert [r.design for r in kept] == [r.design for r in first] and not any(r.far for r in kept)
    assert plain  # the first search ran


@pytest.mark.parametrize("kwargs, message", [
    ({"blocks": ()}, "per roof kind"),
    ({"params": ("p0",)}, "per roof kind"),
    ({"swatch_weight": 1.5}, "between 0 and 1"),
    ({"blocks": ((0, 8), (8, 0))}, "not a block"),
    ({"shifts": (torch.eye(8), torch.eye(7))}, "non-negative matrix"),
    ({"shifts": (torch.eye(8), 2 * torch.eye(8))}, "sum to at most 1"),
    ({"swatches": (-torch.eye(8)[:6], None)}, "non-negative histograms"),
    ({"unmix": -0.1}, "unmixing"), ({"unmix": 2.0}, "unmixing"),
    ({"unmix": 0.5, "blocks": ((0, 8), (8, 7)), "shifts": (torch.eye(8), torch.eye(7))}, "one width"),
    ({"render_share": 1.5, "renders": (torch.eye(8)[:6], None)}, "render share"),
    ({"render_share": 0.5}, "rendered histograms"),
    ({"render_share": 0.5, "renders": (torch.eye(8)[:6],)}, "rendered histograms"),
    ({"render_share": 0.5, "renders": (torch.eye(8)[:5], None)}, "one per swatch"),
    ({"render_share": 0.5, "renders": (None, torch.eye(8)[:6])}, "one per swatch"),
    ({"render_share": 0.5, "renders": (-torch.eye(8)[:6], None)}, "non-negative"),
])
def test_bad_roof_matches_are_refused(kwargs, message):
    fields = {"blocks": ((0, 8), (8, 8)), "params": ("p0", "p1"), "swatches": (torch.eye(8)[:6], None),
              "shifts": (torch.eye(8), torch.eye(8)), "swatch_weight": 0.5, "unmix": 0.0, **kwargs}
    with pytest.raises(MetaSimError, match=message):
        RoofMatch(**fields)


def test_a_match_must_fit_the_model_and_its_space(coloured):
    space, fit = coloured["space"], coloured["fit"]
    targets = fit.norm.apply(coloured["targets"][:2])
    eye = torch.eye(8)
    for wrong, message in (
            (RoofMatch(((0, 8), (12, 8)), ("p0", "p1"), (None, None), (eye, eye)), "does not fit"),
            (RoofMatch(((0, 8), (8, 8)), ("p0", "p9"), (None, None), (eye, eye)), "no categorical parameter"),
            (RoofMatch(((0, 8), (8, 8)), ("p0", "p1"), (eye[:5], None), (eye, eye)), "has 6 choices")):
        for search in (exhaustive_search, lambda *a, **k: adjoint_search(*a, M=8, S=2, iterations=1, **k)):
            with pytest.raises(MetaSimError, match=message):
                search(fit.model, targets, space, colour=ColourComparison(far_loss=1.0, match=wrong))
    with pytest.raises(MetaSimError, match="not both"):
        ColourComparison(far=ColourComparison(), far_loss=1.0, match=_toy_match())
    with pytest.raises(MetaSimError, match="not both"):
        colour_comparison(0.3, blocks=(488, 488, 220, 220), far=SEARCH_FAR, match=_toy_match())
    colour = colour_comparison(0.3, blocks=(488, 488, 220, 220), far_margin=0.05, match=_toy_match(), match_loss=4.0)
    assert colour.searches_far and colour.far is None and colour.far_loss == 4.0 and colour.far_margin == 0.05
    assert colour.to_dict()["far"] == {"match": {"kinds": 2, "params": ["p0", "p1"], "swatch_weight": 0.5,
                                                 "swatches": [True, True]}}


def test_the_value_shift_moves_mass_along_the_value_axis():
    keep = score_cone_bins()
    assert torch.equal(value_shift(0.0), torch.eye(WIDTH, dtype=torch.float64))
    full = torch.zeros(BINS ** 3, dtype=torch.float64)
    grey = (4 * BINS + 4) * BINS  # the grey column's bins, value 0 to 7
    full[grey + 5] = 1.0
    for delta, expected in ((-1.0, {4: 1.0}), (-0.5, {4: 0.5, 5: 0.5}), (1.0, {6: 1.0}), (-9.0, {0: 1.0}),
                            (3.0, {7: 1.0})):
        moved = torch.zeros(BINS ** 3, dtype=torch.float64)
        moved[keep] = value_shift(delta) @ full[keep]
        assert {int(i) - grey: round(float(moved[i]), 6) for i in moved.nonzero()[:, 0]} == expected
    assert (value_shift(-0.75).sum(dim=0) <= 1 + 1e-12).all()


def _roof_space(flat, sloped) -> DesignSpace:
    return DesignSpace.from_dict({"format": "meta-sim-design-space", "version": 1, "name": "roofs", "parameters": [
        {"name": "flat_roof", "type": "categorical", "texture_kind": "flat", "choices": flat},
        {"name": "sloped_roof", "type": "categorical", "texture_kind": "sloped", "choices": sloped}]})


def test_a_roof_match_is_fitted_for_a_checkpoint_whose_space_chooses_roof_materials(bank):
    flat, sloped = bank.ids("flat")[:4], bank.ids("sloped")[:3]
    space = _roof_space(flat, sloped)
    swatches = {kind: swatch_histograms(tuple(ids)) for kind, ids in (("flat", flat), ("sloped", sloped))}
    assert swatches["flat"].shape == (4, WIDTH) and torch.allclose(swatches["flat"].sum(dim=1),
                                                                   torch.ones(4, dtype=torch.float64))
    assert swatch_histograms(("no-such-texture",)) is None
    # "Renders": each texture's own histogram a bin brighter, after four other features.
    brighter = value_shift(1.0)
    rng = np.random.default_rng(0)
    designs = [dict(zip(("flat_roof", "sloped_roof"), pair)) for pair in
               zip(rng.choice(flat, 600), rng.choice(sloped, 600))]
    encoded = torch.stack([torch.from_numpy(space.encode(d)) for d in designs])
    features = torch.cat([encoded @ torch.randn(space.dim, 4, generator=torch.Generator().manual_seed(1)),
                          torch.stack([swatches["flat"][flat.index(d["flat_roof"])] @ brighter.T for d in designs]),
                          torch.stack([swatches["sloped"][sloped.index(d["sloped_roof"])] @ brighter.T
                                       for d in designs])], dim=1).float()
    fit = train_nams(encoded, features, NAMSConfig(space.dim, features.shape[1], hidden=(64, 128)),
                     TrainConfig(max_epochs=40, patience=10, lr=3e-3, whiten=0), hist_blocks=(WIDTH, WIDTH))
    ckpt = SimpleNamespace(model=fit.model, space=space, feature_norm=fit.norm, model_id="toy-roofs")
    match = roof_match(ckpt, 0.6)
    assert match.params == ("flat_roof", "sloped_roof") and match.blocks == ((0, WIDTH), (WIDTH, WIDTH))
    assert match.swatch_weight == 0.6 and all(torch.equal(a, b) for a, b in zip(match.swatches, swatches.values()))
    assert all(torch.equal(shift, value_shift(-1.0)) for shift in match.shifts)  # the renders' brightening undone
    # Each choice's rendered histogram: the model's predictions for its designs, about its texture a bin brighter.
    for renders, own in zip(match.renders, swatches.values()):
        assert renders.shape == own.shape
        assert torch.allclose(renders.sum(dim=1), torch.ones(len(own), dtype=torch.float64))
        brightened = own.double() @ brighter.T.double()
        assert (torch.minimum(renders, brightened).sum(dim=1) > 0.8).all()
    # A far target with one texture's colours (rendered) and others far off is named by them.
    target = torch.cat([torch.full((1, 4), 500.0), features[:1, 4:]], dim=1)
    for as_rendered in (0.0, 1.0):  # by the textures' own colours, or as they render
        found = exhaustive_search(fit.model, fit.norm.apply(target), space,
                                  colour=ColourComparison(far_loss=1e-9, match=roof_match(ckpt, 1.0, 0.0, as_rendered)))
        assert found[0].far and found[0].design == designs[0]
    # The search's default uses the match for such a model, the far comparison for one whose space has no roofs.
    colour = search_colour(ckpt)
    assert colour.match is not None and colour.far is None and search_colour(ckpt).match is colour.match
    plain = SimpleNamespace(model=fit.model, space=toy_space(4, 3), feature_norm=fit.norm, model_id="toy-plain")
    assert roof_match(plain, 0.5) is None
    assert search_colour(plain).far is not None and search_colour(plain).match is None
    without = SimpleNamespace(model=fit.model, space=space, model_id="toy-no-cone",
                              feature_norm=FeatureNorm(torch.zeros(4), torch.ones(4), hist_blocks=(488, 488)))
    assert roof_match(without, 0.5) is None

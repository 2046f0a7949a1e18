"""Roof segmenter: learnt on labelled tiles, it finds roofs by their shape and shading, also in colours
it never saw; cached, deterministic, and stored in checkpoints."""

import numpy as np
import pytest
import torch

from meta_sim.core.errors import MetaSimError
from meta_sim.pipeline.features import ColourTexture, _half
from meta_sim.pipeline.roofcolour import (
    RoofColourExtractor,
    checkpoint_extractor,
    ensure_roof_finder,
    roof_finder_seconds,
)
from meta_sim.pipeline.roofsegment import RoofSegmenter
from meta_sim.sim.imageio import linear_to_srgb
from meta_sim.sim.tiles import write_tile

GROUND = (0.05, 0.3, 0.05)


def _scene(flat_colour, sloped_colour, shift=0, size=64):
    """(linear RGB, roof classes): ground, a uniform flat roof and a sloped roof whose two halves are
    lit and shaded, as the renders' facets are."""
    rgb = np.empty((size, size, 3), np.float32)
    rgb[:] = GROUND
    roof = np.zeros((size, size), np.uint32)
    rows, cols = slice(8 + shift, 30 + shift), slice(6, 26)
    rgb[rows, cols], roof[rows, cols] = flat_colour, 1
    top, left = 34 - shift, 36
    rgb[top:top + 22, left:left + 10] = np.array(sloped_colour) * 1.6
    rgb[top:top + 22, left + 10:left + 20] = np.array(sloped_colour) * 0.4
    roof[top:top + 22, left:left + 20] = 2
    return rgb, roof


@pytest.fixture(scope="module")
def tiles(tmp_path_factory):
    folder = tmp_path_factory.mktemp("segmenter-tiles")
    paths = []
    for k, (flat, sloped) in enumerate([((0.6, 0.05, 0.05), (0.05, 0.05, 0.4)), ((0.3, 0.3, 0.3), (0.3, 0.1, 0.05)),
                                        ((0.05, 0.05, 0.5), (0.4, 0.05, 0.05)), ((0.5, 0.5, 0.1), (0.2, 0.2, 0.2))]):
        rgb, roof = _scene(flat, sloped, shift=k)
        path = folder / f"t{k}.exr"
        write_tile(path, rgb, np.zeros(roof.shape, np.uint32), roof, {"k": k})
        paths.append(path)
    return paths


@pytest.fixture(scope="module")
def segmenter(tiles):
    return RoofSegmenter.fit(tiles, seed=0, steps=1000)


def _weights(segmenter, rgb):
    batch = torch.from_numpy(linear_to_srgb(rgb).astype(np.float32)).permute(2, 0, 1)[None]
    return segmenter.weights(_half(batch))[0]


def test_it_finds_roofs_in_colours_it_was_not_trained_on(segmenter):
    rgb, roof = _scene((0.1, 0.5, 0.5), (0.5, 0.3, 0.5), shift=2)  # cyan and violet: no training roof had them
    flat, sloped = _weights(segmenter, rgb)
    labels = _half(torch.from_numpy(np.stack([roof == 1, roof == 2]).astype(np.float32)))
    inside_flat, inside_sloped, ground = labels[0] == 1, labels[1] == 1, labels.sum(0) == 0
    assert float(flat[inside_flat].mean()) > 0.6 and float(sloped[inside_sloped].mean()) > 0.6
    assert float(flat[ground].mean()) < 0.2 and float(sloped[ground].mean()) < 0.2
    assert float(sloped[inside_flat].mean()) < 0.3 and float(flat[inside_sloped].mean()) < 0.3


def _found(segmenter, ground, gain):
    """Mean p(flat) on the flat roof and p(any roof) on the ground of a scene with unseen roof colours,
    its ground painted ``ground`` and the whole image scaled by ``gain`` (exposure)."""
    rgb, roof = _scene((0.1, 0.5, 0.5), (0.5, 0.3, 0.5), shift=2)
    rgb[roof == 0] = ground
    weights = _weights(segmenter, rgb * gain)
    labels = _half(torch.from_numpy(np.stack([roof == 1, roof == 2]).astype(np.float32)))
    return float(weights[0][labels[0] == 1].mean()), float(weights.sum(0)[labels.sum(0) == 0].mean())


def test_jittering_the_scene_keeps_roofs_found_on_ground_and_exposure_it_never_saw(tiles, segmenter):
    """Trained on one ground colour, the roofs-only segmenter loses the roofs or takes the ground for roof when the
    ground or the exposure changes (real imagery has ground colours no render has); trained with the scene
    jittered, it keeps them and still leaves the ground alone."""
    jittered = RoofSegmenter.fit(tiles, seed=0, steps=1000, augment="scene")
    conditions = [(ground, gain) for ground in (GROUND, (0.35, 0.25, 0.12), (0.5, 0.5, 0.5), (0.15, 0.15, 0.15))
                  for gain in (1.0, 0.6)]
    plain = [_found(segmenter, *c) for c in conditions]
    scene = [_found(jittered, *c) for c in conditions]
    # Where and how the plain one fails depends on the CPU's rounding (on one CPU it keeps under 0.2 of a roof, on
    # another it keeps 0.29 of one and takes a grey ground for roof); that it fails far worse than the jittered
    # one, which keeps roofs and ground apart in every condition, does not.
    def worst(found):  # the roof missed plus the ground taken for roof, in the worst condition
        return max((1.0 - flat) + ground for flat, ground in found)

    assert worst(plain) > worst(scene) + 0.3  # lost somewhere, kept when jittered
    assert min(flat for flat, _ in scene) > 0.3 and max(ground for _, ground in scene) < 0.25
    with pytest.raises(MetaSimError, match="augmentation"):
        RoofSegmenter.fit(tiles, steps=1, augment="everything")


def test_fit_is_deterministic_and_cached(tiles, tmp_path, monkeypatch):
    fitted = RoofSegmenter.fit(tiles, seed=0, steps=50)
    assert RoofSegmenter.fit(tiles, seed=0, steps=50).id == fitted.id
    assert RoofSegmenter.fit(tiles, seed=1, steps=50).id != fitted.id
    monkeypatch.setattr("meta_sim.pipeline.roofsegment.STEPS", 20)
    first = ensure_roof_finder(tmp_path, tiles, "segmenter", seed=0)
    again = ensure_roof_finder(tmp_path, [tmp_path / "missing.exr"] * len(tiles), "segmenter", seed=0)
    assert again.id == first.id  # read from the cache: the tiles may be gone
    jittered = ensure_roof_finder(tmp_path, tiles, "segmenter-jitter", seed=0)  # cached under its own name
    assert jittered.id != first.id and len(list(tmp_path.glob("roof-segmenter-*.pt"))) == 2
    with pytest.raises(MetaSimError, match="unknown roof finder"):
        ensure_roof_finder(tmp_path, tiles, "labels")
    with pytest.raises(MetaSimError, match="no training tiles"):
        RoofSegmenter.fit([], steps=1)


def test_a_segmenter_learnt_in_fewer_steps_is_cached_under_its_own_name_with_its_time(tiles, tmp_path, monkeypatch):
    """The trade study's knob for the segmenter's cost: another number of steps is another finder, cached beside
    the default one (never mistaken for it) with the seconds it took; steps that are not a whole number of at
    least 1 are refused before any work."""
    monkeypatch.setattr("meta_sim.pipeline.roofsegment.STEPS", 20)
    default = ensure_roof_finder(tmp_path, tiles, "segmenter", seed=0)
    fewer = ensure_roof_finder(tmp_path, tiles, "segmenter", seed=0, steps=8)
    assert fewer.id != default.id and len(list(tmp_path.glob("roof-segmenter-*.pt"))) == 2
    assert fewer.id == RoofSegmenter.fit(tiles, seed=0, steps=8).id
    assert ensure_roof_finder(tmp_path, tiles, "segmenter", seed=0, steps=20).id == default.id  # the default's own
    missing = [tmp_path / "missing.exr"] * len(tiles)
    assert ensure_roof_finder(tmp_path, missing, "segmenter", seed=0, steps=8).id == fewer.id  # from the cache
    assert roof_finder_seconds(tmp_path, "segmenter", 0, steps=8) > 0
    assert roof_finder_seconds(tmp_path, "segmenter", 0, steps=9) is None
    for bad in (0, -3, True, 2.5):
        with pytest.raises(MetaSimError, match="training steps"):
            RoofSegmenter.fit(tiles, steps=bad)


def test_checkpoints_carry_the_segmenter(segmenter):
    made = RoofColourExtractor(ColourTexture(), segmenter)

    class Ckpt:
        extra = {"extractor_spec": "colour-texture", "roof_likelihood": made.to_dict()}
        extractor_id = made.id

    extractor = checkpoint_extractor(Ckpt())
    assert extractor.id == Ckpt.extractor_id
    rgb, _ = _scene((0.6, 0.05, 0.05), (0.05, 0.05, 0.4))
    batch = torch.from_numpy(linear_to_srgb(rgb).astype(np.float32)).permute(2, 0, 1)[None]
    assert torch.equal(extractor(batch), RoofColourExtractor(ColourTexture(), segmenter)(batch))
    with pytest.raises(MetaSimError, match="version"):
        RoofSegmenter.from_dict({**segmenter.to_dict(), "version": 99})
    with pytest.raises(MetaSimError, match="do not fit"):
        RoofSegmenter({"0.weight": torch.zeros(1)})


def test_weights_are_finite_at_the_extremes(segmenter):
    for value in (0.0, 1.0, 1e6):
        batch = torch.full((1, 3, 16, 16), value)
        w = segmenter.weights(batch.clamp(0.0, 1.0))
        assert torch.isfinite(w).all() and float(w.sum(1).max()) <= 1.0 + 1e-6

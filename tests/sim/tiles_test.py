import dataclasses
import os

import numpy as np
import OpenImageIO as oiio
import pytest

from meta_sim.core.errors import MetaSimError
from meta_sim.sim import tiles
from meta_sim.sim.design import DesignSpace


def _meta(**kw):
    base = dict(design={"flat_roof": "flat-a", "sloped_roof": "sloped-b"}, space="rooftops-v1", city_seed=7,
                tile_index=3, origin_m=(115.2, 0.0), size_px=(32, 24), pixel_size_m=0.3, preset="fast")
    base.update(kw)
    return tiles.tile_metadata(**base)


def _pixels(rng):
    rgb = (rng.random((24, 32, 3)) * 4).astype(np.float32)  # HDR values survive as half floats
    instance = rng.integers(0, 70000, (24, 32)).astype(np.uint32)
    instance[:5] = 0
    roof_class = np.where(instance > 0, 1 + instance % 2, 0).astype(np.uint32)
    return rgb, instance, roof_class


def test_round_trip_channels_dtypes_and_metadata(tmp_path):
    rgb, instance, roof_class = _pixels(np.random.default_rng(0))
    path = tmp_path / "t.exr"
    tiles.write_tile(path, rgb, instance, roof_class, _meta())
    tile = tiles.read_tile(path)
    assert np.array_equal(tile.instance, instance) and tile.instance.dtype == np.uint32
    assert np.array_equal(tile.roof_class, roof_class)
    assert np.array_equal(tile.building, (instance > 0).astype(np.uint32))
    assert np.allclose(tile.rgb, rgb, rtol=1e-3)
    assert tile.meta["design"] == {"flat_roof": "flat-a", "sloped_roof": "sloped-b"}
    assert tile.meta["pixel_size_m"] == 0.3 and tile.meta["tile_origin_m"] == [115.2, 0.0]
    assert tile.meta["city_seed"] == 7 and tile.meta["preset"] == "fast"
    assert {"meta_sim", "openimageio", "python"} <= set(tile.meta["software"])

    # What any OpenImageIO/OpenEXR reader sees: two parts, half RGB and uint labels.
    image = oiio.ImageInput.open(str(path))
    assert image.spec().channelnames == ("R", "G", "B") and image.spec().format == "half"
    assert image.seek_subimage(1, 0)
    assert image.spec().channelnames == ("label.building", "label.instance", "label.roof_class")
    assert image.spec().format == "uint"
    image.close()


def test_validity_checks_metadata_and_completeness(tmp_path):
    rgb, instance, roof_class = _pixels(np.random.default_rng(1))
    path = tmp_path / "t.exr"
    tiles.write_tile(path, rgb, instance, roof_class, _meta())
    assert tiles.is_valid_tile(path, {"city_seed": 7, "tile_size_px": [32, 24]})
    assert not tiles.is_valid_tile(path, {"city_seed": 8})
    assert not tiles.is_valid_tile(path, {"tile_size_px": [64, 64]})
    assert not tiles.is_valid_tile(tmp_path / "missing.exr", {})
    truncated = tmp_path / "truncated.exr"
    truncated.write_bytes(path.read_bytes()[: os.path.getsize(path) // 2])
    assert not tiles.is_valid_tile(truncated, {})
    empty = tmp_path / "empty.exr"
    empty.write_bytes(b"")
    assert not tiles.is_valid_tile(empty, {})
    with pytest.raises(MetaSimError, match="empty.exr"):
        tiles.read_tile(empty)


def test_write_is_atomic_and_leaves_nothing_on_failure(tmp_path):
    rgb, instance, roof_class = _pixels(np.random.default_rng(2))
    path = tmp_path / "t.exr"
    tiles.write_tile(path, rgb, instance, roof_class, _meta())
    assert sorted(os.listdir(tmp_path)) == ["t.exr"]
    before = path.read_bytes()
    with pytest.raises((MetaSimError, ValueError)):
        tiles.write_tile(path, rgb[:, :5], instance, roof_class, _meta())  # shape mismatch
    assert path.read_bytes() == before
    assert sorted(os.listdir(tmp_path)) == ["t.exr"]


def test_tiles_rendered_before_an_exposure_or_tone_change_are_rendered_again(tmp_path):
    """A preset whose exposure is not 1, or that has a tone curve, names them in the tiles it expects,
    the training set's key and the models' key; a preset at exposure 1 without a curve keeps the keys
    of earlier caches."""
    from meta_sim.pipeline.dataset import DatasetConfig
    from meta_sim.render.jobs import RenderSettings, expected_meta, single_job
    from meta_sim.sim.quality import get_preset

    rgb, instance, roof_class = _pixels(np.random.default_rng(1))
    path = tmp_path / "t.exr"
    old = {key: value for key, value in _meta().items() if key not in ("exposure", "render", "tone")}
    tiles.write_tile(path, rgb, instance, roof_class, old)
    fast = get_preset("fast")
    assert fast.exposure != 1.0 and fast.cache_fields() == {"exposure": fast.exposure, "tone": list(fast.tone)}
    assert not tiles.is_valid_tile(path, {"city_seed": 7, **fast.cache_fields()})
    tiles.write_tile(path, rgb, instance, roof_class, _meta())
    assert tiles.is_valid_tile(path, {"city_seed": 7, **fast.cache_fields()})
    assert tiles.read_tile(path).meta["render"] == fast.to_dict()

    space = DesignSpace.load()
    settings = RenderSettings(space=space, banks=[], preset=fast, out_dir=tmp_path, n_tiles=1)
    assert expected_meta(settings, single_job(space, space.sample(np.random.default_rng(0), 1)[0], 1), 0)[
        "exposure"] == fast.exposure
    balanced = get_preset("balanced")
    assert balanced.cache_fields() == {"tone": list(balanced.tone)}
    config = DatasetConfig(preset="balanced")
    assert config.identity() == {**dataclasses.asdict(config), "tone": list(balanced.tone)}
    assert {"exposure", "tone"} <= set(DatasetConfig(preset="fast").identity())
    untoned = dataclasses.replace(balanced, tone=None)
    assert untoned.cache_fields() == {}  # the key of sets cached before exposures and tone curves

"""Per-building roof variation: each roof its own, the ground and labels untouched, deterministic per city."""

import numpy as np
import pytest

from meta_sim.core.errors import MetaSimError
from meta_sim.sim.jitter import roof_jitter


def _tile():
    rgb = np.full((40, 40, 3), 0.4, np.float32)
    instance = np.zeros((40, 40), np.uint32)
    for k, (y, x) in enumerate([(2, 2), (2, 22), (22, 2), (22, 22)], start=1):
        instance[y:y + 14, x:x + 14] = k
    roof_class = (instance > 0).astype(np.uint32)
    rgb[instance > 0] = 0.6
    return rgb, instance, roof_class


def test_each_roof_varies_alone_and_the_ground_is_untouched():
    rgb, instance, roof_class = _tile()
    assert roof_jitter(rgb, instance, roof_class, 5, 0.0) is rgb
    out = roof_jitter(rgb, instance, roof_class, 5, 1.0)
    assert np.array_equal(out[instance == 0], rgb[instance == 0])
    colours = [out[instance == k] for k in range(1, 5)]
    assert all(np.ptp(c, axis=0).max() < 1e-6 for c in colours)  # one change per building
    means = np.array([c.mean(axis=0) for c in colours])
    assert np.unique(means.round(4), axis=0).shape[0] == 4  # no two buildings alike
    assert np.array_equal(out, roof_jitter(rgb, instance, roof_class, 5, 1.0))
    assert not np.array_equal(out, roof_jitter(rgb, instance, roof_class, 6, 1.0))
    milder = roof_jitter(rgb, instance, roof_class, 5, 0.2)
    assert np.abs(milder - rgb).max() < np.abs(out - rgb).max()


def test_a_building_looks_the_same_in_every_tile_of_its_city():
    rgb, instance, roof_class = _tile()
    whole = roof_jitter(rgb, instance, roof_class, 9, 0.7)
    half = roof_jitter(rgb[:, 20:], instance[:, 20:], roof_class[:, 20:], 9, 0.7)
    assert np.array_equal(whole[:, 20:], half)


@pytest.mark.parametrize("bad", [-0.1, 1.5, True, "1", float("nan")])
def test_bad_strength_is_refused(bad):
    rgb, instance, roof_class = _tile()
    with pytest.raises(MetaSimError, match="--roof-jitter"):
        roof_jitter(rgb, instance, roof_class, 1, bad)


def test_a_share_of_the_roofs_is_painted_keeping_each_pixels_shading_and_the_ground():
    from meta_sim.sim.jitter import LUMA, roof_paint

    rgb, instance, roof_class = _tile()
    rng = np.random.default_rng(0)
    rgb = rgb * (0.8 + 0.4 * rng.random((40, 40, 1))).astype(np.float32)  # a textured roof
    assert roof_paint(rgb, instance, roof_class, 5, 0.0) is rgb
    out = roof_paint(rgb, instance, roof_class, 5, 1.0)
    assert np.array_equal(out[instance == 0], rgb[instance == 0])
    for k in range(1, 5):
        before, after = rgb[instance == k], out[instance == k]
        assert np.ptp(before, axis=1).max() < 1e-6 and np.ptp(after, axis=1).min() > 0.01  # grey becomes a colour
        ratio = (after @ LUMA) / (before @ LUMA)
        assert np.ptp(ratio) < 1e-4  # the texture's shading survives: one gain per roof
    assert np.array_equal(out, roof_paint(rgb, instance, roof_class, 5, 1.0))
    assert not np.array_equal(out, roof_paint(rgb, instance, roof_class, 6, 1.0))


def test_a_larger_paint_share_paints_the_same_roofs_and_more_alike_in_every_tile():
    from meta_sim.sim.jitter import roof_paint

    rgb, instance, roof_class = _tile()
    painted = {}
    for share in (0.3, 0.6, 0.9):
        out = roof_paint(rgb, instance, roof_class, 11, share)
        painted[share] = {k for k in range(1, 5) if not np.allclose(out[instance == k], rgb[instance == k])}
        for k in painted[share]:
            assert np.allclose(out[instance == k], roof_paint(rgb, instance, roof_class, 11, 1.0)[instance == k])
    assert painted[0.3] <= painted[0.6] <= painted[0.9]
    row = np.full((1, 40, 3), 0.4, np.float32)  # 40 one-pixel buildings
    ids, roofs = np.arange(1, 41, dtype=np.uint32)[None], np.ones((1, 40), np.uint32)
    many = [int((roof_paint(row, ids, roofs, seed, 0.5) != row).any(axis=2).sum()) for seed in range(5)]
    assert 10 <= np.mean(many) <= 30  # about half of 40 buildings
    half = roof_paint(rgb[:, 20:], instance[:, 20:], roof_class[:, 20:], 11, 0.6)
    assert np.array_equal(roof_paint(rgb, instance, roof_class, 11, 0.6)[:, 20:], half)


@pytest.mark.parametrize("bad", [-0.1, 1.5, True, "1", float("nan")])
def test_a_bad_paint_share_is_refused(bad):
    from meta_sim.sim.jitter import roof_paint

    rgb, instance, roof_class = _tile()
    with pytest.raises(MetaSimError, match="roof_paint"):
        roof_paint(rgb, instance, roof_class, 1, bad)


def test_each_roof_is_changed_as_a_mask_per_building_would_change_it():
    """The roof pixels are grouped by building in one sort; each building must still get its own generator and
    its pixels in raster order, so the result is the one a boolean mask per building gives."""
    from meta_sim.sim.jitter import _each_roof

    rng = np.random.default_rng(4)
    instance = rng.integers(0, 40, (48, 64)).astype(np.uint32)
    roof_class = rng.integers(0, 3, (48, 64)).astype(np.uint32)
    rgb = rng.random((48, 64, 3)).astype(np.float32)

    def change(generator, pixels):  # depends on the generator, the pixels' order and their number
        if generator.random() < 0.2:
            return None
        return pixels * generator.random() + np.cumsum(pixels, axis=0) / (1.0 + len(pixels))

    expected = rgb.copy()
    roofs = (roof_class > 0) & (instance > 0)
    for building in np.unique(instance[roofs]):
        where = roofs & (instance == building)
        changed = change(np.random.default_rng([9, int(building), 3]), expected[where])
        if changed is not None:
            expected[where] = changed
    out = _each_roof(rgb, instance, roof_class, 9, 3, change)
    assert np.array_equal(out, expected) and not np.array_equal(out, rgb)
    assert np.array_equal(_each_roof(rgb, instance * 0, roof_class, 9, 3, change), rgb)  # no roof: a copy

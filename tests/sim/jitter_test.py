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

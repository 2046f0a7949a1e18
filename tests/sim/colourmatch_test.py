"""Colour matching: a render brought to a target's channel means and spreads, labels untouched."""

import numpy as np
import pytest

from meta_sim.core.errors import MetaSimError
from meta_sim.sim.colourmatch import ColourStats, match_colours


def _image(seed: int, mean, std, size=(48, 40)) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return np.clip(rng.normal(mean, std, (*size, 3)), 0, 1).astype(np.float32)


def test_statistics_weigh_every_pixel_alike():
    small, large = np.full((2, 2, 3), 0.2, np.float32), np.full((4, 4, 3), 0.8, np.float32)
    stats = ColourStats.of_images([small, large])
    assert np.allclose(stats.mean, (0.2 * 4 + 0.8 * 16) / 20)
    assert np.allclose(stats.std, np.sqrt(4 * 16 / 400) * 0.6)
    assert stats.to_dict() == {"mean": list(stats.mean), "std": list(stats.std)}


def test_a_render_takes_the_targets_channel_means_and_spreads():
    target = ColourStats.of_images([_image(1, (0.6, 0.5, 0.4), (0.2, 0.18, 0.15))])
    render = _image(2, (0.3, 0.3, 0.28), (0.1, 0.1, 0.1))
    matched = match_colours(render, target)
    assert matched.dtype == render.dtype and matched.shape == render.shape
    got = ColourStats.of_images([matched])
    assert np.allclose(got.mean, target.mean, atol=0.01) and np.allclose(got.std, target.std, atol=0.01)
    for c in range(3):  # an increasing map per channel: brighter pixels stay brighter
        order = np.argsort(render[..., c], axis=None)
        assert np.all(np.diff(matched[..., c].ravel()[order]) >= -1e-6)
    assert np.allclose(match_colours(matched, got), matched, atol=1e-4)  # its own statistics change nothing


def test_a_flat_render_moves_to_the_targets_mean_and_the_result_stays_in_range():
    flat = np.full((8, 8, 3), 0.3, np.float32)
    out = match_colours(flat, ColourStats((0.7, 0.6, 0.5), (0.2, 0.2, 0.2)))
    assert np.allclose(out, np.array([0.7, 0.6, 0.5], np.float32))
    bright = match_colours(_image(3, 0.5, 0.3), ColourStats((0.95, 0.95, 0.95), (0.5, 0.5, 0.5)))
    assert bright.min() >= 0.0 and bright.max() <= 1.0


@pytest.mark.parametrize("stats", [
    ColourStats((0.5, 0.5), (0.1, 0.1, 0.1)), ColourStats((0.5, 0.5, 1.5), (0.1,) * 3),
    ColourStats((0.5,) * 3, (0.1, float("nan"), 0.1)), ColourStats((0.5,) * 3, (-0.1,) * 3),
    ColourStats((0.5, True, 0.5), (0.1,) * 3)])
def test_bad_statistics_are_refused(stats):
    with pytest.raises(MetaSimError, match="colour statistics"):
        stats.check()


def test_bad_images_are_refused():
    with pytest.raises(MetaSimError, match=r"\(H, W, 3\)"):
        match_colours(np.zeros((4, 4)), ColourStats((0.5,) * 3, (0.1,) * 3))
    with pytest.raises(MetaSimError, match="NaN"):
        ColourStats.of_images([np.full((2, 2, 3), np.nan)])
    with pytest.raises(MetaSimError, match="at least one pixel"):
        ColourStats.of_images([])

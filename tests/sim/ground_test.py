"""Ground cover: patches in the declared proportions, deterministic, bad mixes refused."""

import numpy as np
import pytest

from meta_sim.core.errors import MetaSimError
from meta_sim.sim.ground import COVERS, MIXES, PIXEL_M, get_mix, ground_image


def _share(image, cover):
    """Share of pixels nearest in hue (colour normalised by brightness) to a cover's colour."""
    colours = np.array(list(COVERS.values()), np.float32)
    norm = lambda x: x / np.linalg.norm(x, axis=-1, keepdims=True)  # noqa: E731
    nearest = np.argmax(norm(image) @ norm(colours).T, axis=-1)
    return float((nearest == list(COVERS).index(cover)).mean())


def test_covers_take_their_shares_in_patches():
    mix = {"lawn": 0.5, "soil": 0.3, "pavement": 0.2}
    image = ground_image(300, 200, 4, mix)
    assert image.shape == (round(200 / PIXEL_M), round(300 / PIXEL_M), 3) and image.dtype == np.float32
    for cover, share in mix.items():
        assert abs(_share(image, cover) - share) < 0.1, cover
    # patches, not salt and pepper: neighbouring pixels mostly share a cover
    green = image[..., 1] > image[..., 0]
    assert float((green[:, 1:] == green[:, :-1]).mean()) > 0.9
    assert np.array_equal(image, ground_image(300, 200, 4, mix))
    assert not np.array_equal(image, ground_image(300, 200, 5, mix))


def test_named_mixes_and_bad_ones():
    assert get_mix("plain") is None and get_mix(None) is None
    for name, mix in MIXES.items():
        if mix:
            assert abs(sum(mix.values()) - 1.0) < 1e-9 and set(mix) <= set(COVERS), name
    with pytest.raises(MetaSimError, match="plain, suburban"):
        get_mix("lunar")
    for bad in ({"lava": 1.0}, {}, {"lawn": -1.0}, {"lawn": 0.0}):
        with pytest.raises(MetaSimError, match="ground mix"):
            ground_image(50, 50, 1, bad)


def _busyness(grey):
    """Median absolute Laplacian: how much a surface changes from pixel to pixel."""
    lap = 4 * grey[1:-1, 1:-1] - grey[:-2, 1:-1] - grey[2:, 1:-1] - grey[1:-1, :-2] - grey[1:-1, 2:]
    return float(np.median(np.abs(lap)))


def test_grain_adds_fine_texture_at_a_finer_pixel_and_keeps_the_covers_and_their_light():
    from meta_sim.sim.ground import GRAIN_PIXEL_M, grain_field
    from meta_sim.sim.imageio import resize

    mix = MIXES["arid"]
    plain = ground_image(120, 80, 4, mix)
    assert np.array_equal(plain, ground_image(120, 80, 4, mix, grain=0.0))  # no grain: today's ground
    grainy = ground_image(120, 80, 4, mix, grain=1.0)
    assert grainy.shape == (round(80 / GRAIN_PIXEL_M), round(120 / GRAIN_PIXEL_M), 3)
    assert np.array_equal(grainy, ground_image(120, 80, 4, mix, grain=1.0))
    assert not np.array_equal(grainy, ground_image(120, 80, 5, mix, grain=1.0))
    # The same covers in the same places, about as bright, and busier where a pixel meets its neighbours
    back = resize(grainy, *plain.shape[:2])
    assert np.mean(back) == pytest.approx(np.mean(plain), rel=0.05)
    hue = lambda x: x / np.linalg.norm(x, axis=-1, keepdims=True)  # noqa: E731
    assert float(np.mean(np.sum(hue(back) * hue(plain), axis=-1))) > 0.99
    coarse = resize(plain, *grainy.shape[:2])
    assert _busyness(grainy.mean(-1)) > 3 * _busyness(coarse.mean(-1))
    assert _busyness(ground_image(120, 80, 4, mix, grain=0.3).mean(-1)) < _busyness(grainy.mean(-1))
    field = grain_field(400, 300, 4, 1.0)
    assert field.mean() == pytest.approx(1.0, abs=0.03) and field.min() > 0
    for bad in (-0.1, 1.5):
        with pytest.raises(MetaSimError, match="grain"):
            ground_image(50, 50, 1, mix, grain=bad)

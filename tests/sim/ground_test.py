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

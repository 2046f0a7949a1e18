"""The render presets' light: pure Python, no Blender."""

import math

import pytest

from meta_sim.core.errors import MetaSimError
from meta_sim.sim.quality import SKY_COLOUR, SKY_STRENGTH, SUN_ENERGY, cycles_light


def test_cycles_light_keeps_todays_sun_and_sky_by_default_and_gives_the_sky_one_minus_the_shadow_depth():
    def flat(sun, sky, elevation):  # what a flat diffuse surface receives from each, per unit albedo
        return sun * math.sin(elevation) / math.pi, sky * sum(SKY_COLOUR) / 3

    for elevation in (math.radians(20), math.radians(45), math.radians(85)):
        assert cycles_light(elevation) == (SUN_ENERGY, SKY_STRENGTH)
        before = sum(flat(*cycles_light(elevation), elevation))
        for depth in (0.0, 0.3, 0.9):
            sun, sky = flat(*cycles_light(elevation, depth), elevation)
            assert sun + sky == pytest.approx(before) and sky / (sun + sky) == pytest.approx(1 - depth)
    for bad in (1.0, -0.1, float("nan")):
        with pytest.raises(MetaSimError, match="depth"):
            cycles_light(math.radians(45), bad)
    with pytest.raises(MetaSimError, match="above the horizon"):
        cycles_light(0.0, 0.5)

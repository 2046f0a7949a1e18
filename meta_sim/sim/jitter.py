"""Per-building roof variation: no two roofs of one texture alike, as in real cities (and Synthinel-1).

In a render every roof of one texture has the same brightness and hue; real roofs of one material
differ with age, dirt, paint and sun. ``roof_jitter`` changes each building's roof pixels in the
linear render after the fact, using the exact instance labels: a brightness gain (log-normal), a tint
(a gain per channel around 1) and weathering (a blend towards a dusty grey). Each building's draw comes
from a generator seeded by the city and the building's id, so a building looks the same in every
tile and with every design's texture. ``strength`` 0 leaves the render untouched; 1 is the strongest
setting (brightness x/÷ 1.3, tint +-8%, up to 30% weathering, one standard deviation or maximum).
Labels are never touched.
"""

from __future__ import annotations

import numpy as np

from ..core.errors import MetaSimError

BRIGHTNESS = 0.25  # standard deviation of the log gain at strength 1
TINT = 0.08  # standard deviation of each channel's gain at strength 1
WEATHERING = 0.3  # largest blend towards DUST at strength 1
DUST = np.array([0.32, 0.30, 0.27], np.float32)  # linear grey-brown of dirt and faded paint


def check_strength(strength) -> float:
    if isinstance(strength, bool) or not isinstance(strength, (int, float)) or not 0.0 <= strength <= 1.0:
        raise MetaSimError(f"--roof-jitter must be a number from 0 to 1, not {strength!r}")
    return float(strength)


def roof_jitter(rgb: np.ndarray, instance: np.ndarray, roof_class: np.ndarray, city_seed: int,
                strength: float) -> np.ndarray:
    """The linear render ``rgb`` (H, W, 3) with each building's roof pixels varied (see the module)."""
    strength = check_strength(strength)
    if strength == 0.0:
        return rgb
    out = rgb.astype(np.float32).copy()
    roofs = (roof_class > 0) & (instance > 0)
    for building in np.unique(instance[roofs]):
        rng = np.random.default_rng([int(city_seed), int(building), 7])
        gain = np.exp(BRIGHTNESS * strength * rng.standard_normal())
        tint = 1.0 + TINT * strength * rng.standard_normal(3)
        weathering = WEATHERING * strength * rng.random()
        where = roofs & (instance == building)
        pixels = out[where] * (gain * tint).astype(np.float32)
        out[where] = (1.0 - weathering) * pixels + weathering * DUST * gain
    return out

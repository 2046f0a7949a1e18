"""Per-building roof variation: no two roofs of one texture alike, as in real cities (and Synthinel-1).

In a render every roof of one texture has the same brightness and hue; real roofs of one material
differ with age, dirt, paint and sun. ``roof_jitter`` changes each building's roof pixels in the
linear render after the fact, using the exact instance labels: a brightness gain (log-normal), a tint
(a gain per channel around 1) and weathering (a blend towards a dusty grey). Each building's draw comes
from a generator seeded by the city and the building's id, so a building looks the same in every
tile and with every design's texture. ``strength`` 0 leaves the render untouched; 1 is the strongest
setting (brightness x/÷ 1.3, tint +-8%, up to 30% weathering, one standard deviation or maximum).
Labels are never touched.

``roof_paint`` goes further: real towns mix materials, and most of all paints (the blue, red and green
tin roofs of Kampala and Banepa beside bare metal and concrete), so a share of the buildings get a
painted roof in place of the design's texture: the roof keeps its shading and texture (each pixel's
luminance), takes the chromaticity of a colour from ``PAINTS`` faded by sun and age (a random part of
the way back to grey), and its brightness moves halfway (in log) towards that paint's lightness against
a mid-grey roof. Which buildings are painted, and with
what, is drawn per building from the city seed, so a larger share paints the same buildings and more.
"""

from __future__ import annotations

import numpy as np

from ..core.errors import MetaSimError

BRIGHTNESS = 0.25  # standard deviation of the log gain at strength 1
TINT = 0.08  # standard deviation of each channel's gain at strength 1
WEATHERING = 0.3  # largest blend towards DUST at strength 1
DUST = np.array([0.32, 0.30, 0.27], np.float32)  # linear grey-brown of dirt and faded paint
# Linear albedo of roof paints common in real towns: blues, reds, greens, white, greys, rust and orange.
PAINTS = np.array([
    (0.02, 0.10, 0.40), (0.10, 0.30, 0.58), (0.03, 0.22, 0.30),  # blue, sky blue, teal
    (0.40, 0.02, 0.02), (0.19, 0.02, 0.02), (0.58, 0.13, 0.05),  # red, maroon, orange
    (0.02, 0.16, 0.06), (0.72, 0.72, 0.68), (0.30, 0.33, 0.33),  # green, white, galvanised grey
    (0.30, 0.08, 0.03),  # rust
], np.float32)
FADED = (0.35, 0.8)  # range of the share of a paint's colour left after fading
MID_GREY = 0.25  # the albedo a roof of unknown texture is taken to have
LUMA = np.array([0.2126, 0.7152, 0.0722], np.float32)  # Rec. 709 luminance weights (linear RGB)


def _check_unit(value, message: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not 0.0 <= value <= 1.0:
        raise MetaSimError(f"{message}, not {value!r}")
    return float(value)


def check_strength(strength) -> float:
    return _check_unit(strength, "--roof-jitter must be a number from 0 to 1")


def check_share(share) -> float:
    return _check_unit(share, "roof_paint must be a share from 0 to 1")


def _each_roof(rgb: np.ndarray, instance: np.ndarray, roof_class: np.ndarray, city_seed: int, stream: int,
               change) -> np.ndarray:
    """A copy of ``rgb`` with ``change(rng, pixels)`` applied to each building's roof pixels; ``rng`` is
    seeded by the city, the building and ``stream``, and a change that returns None leaves its roof."""
    out = rgb.astype(np.float32).copy()
    pixels = out.reshape(-1, out.shape[-1])  # a view: the copy is contiguous
    roofs = np.flatnonzero((roof_class > 0) & (instance > 0))
    if not roofs.size:
        return out
    # The roof pixels grouped by building in one sort, not one pass over the tile per building; the stable
    # sort keeps each building's pixels in raster order, as a mask would list them.
    ids = instance.reshape(-1)[roofs]
    order = np.argsort(ids, kind="stable")
    ids, roofs = ids[order], roofs[order]
    starts = np.flatnonzero(np.concatenate([[True], ids[1:] != ids[:-1]]))
    for start, end in zip(starts, np.append(starts[1:], len(ids))):
        where = roofs[start:end]
        changed = change(np.random.default_rng([int(city_seed), int(ids[start]), stream]), pixels[where])
        if changed is not None:
            pixels[where] = changed
    return out


def roof_paint(rgb: np.ndarray, instance: np.ndarray, roof_class: np.ndarray, city_seed: int,
               share: float) -> np.ndarray:
    """The linear render ``rgb`` (H, W, 3) with ``share`` of the buildings' roofs painted (see the module)."""
    share = check_share(share)
    if share == 0.0:
        return rgb

    def paint_roof(rng, pixels):
        if rng.random() >= share:  # one draw decides, so a larger share keeps these buildings painted
            return None
        paint = PAINTS[rng.integers(len(PAINTS))] * (1.0 + 0.1 * rng.standard_normal(3)).astype(np.float32)
        paint = np.clip(paint, 0.005, 1.0)
        lightness = float(paint @ LUMA)
        chroma = 1.0 + rng.uniform(*FADED) * (paint / lightness - 1.0)  # per channel; grey is 1, 1, 1
        gain = np.float32(np.sqrt(lightness / MID_GREY))
        return (pixels @ LUMA)[:, None] * chroma[None, :].astype(np.float32) * gain

    return _each_roof(rgb, instance, roof_class, city_seed, 8, paint_roof)


def roof_jitter(rgb: np.ndarray, instance: np.ndarray, roof_class: np.ndarray, city_seed: int,
                strength: float) -> np.ndarray:
    """The linear render ``rgb`` (H, W, 3) with each building's roof pixels varied (see the module)."""
    strength = check_strength(strength)
    if strength == 0.0:
        return rgb

    def vary_roof(rng, pixels):
        gain = np.exp(BRIGHTNESS * strength * rng.standard_normal())
        tint = 1.0 + TINT * strength * rng.standard_normal(3)
        weathering = WEATHERING * strength * rng.random()
        pixels = pixels * (gain * tint).astype(np.float32)
        return (1.0 - weathering) * pixels + weathering * DUST * gain

    return _each_roof(rgb, instance, roof_class, city_seed, 7, vary_roof)

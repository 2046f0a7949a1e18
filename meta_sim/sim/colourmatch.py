"""Colour matching to a target: each render's colours brought to the target imagery's statistics.

A real image's colours depend on its camera's exposure and white balance and on the product's
radiometric processing, all of which the renderer's sensor model (``sensor.py``) sets only roughly. The
target folder itself says what its images look like: ``ColourStats`` are the mean and standard deviation
of each channel of its display (sRGB) values, and ``match_colours`` maps a rendered image so that its own
channel means and spreads become those, like a camera's automatic exposure and white balance calibrated
on the target. Only the beauty image changes; labels never do. Numpy only: the add-on may import it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..core.errors import MetaSimError

# A render whose channel hardly varies (a flat colour) is shifted to the target's mean, not stretched.
MIN_SPREAD = 1e-3


@dataclass(frozen=True)
class ColourStats:
    """Per-channel mean and standard deviation of display (sRGB, 0-1) values."""

    mean: tuple[float, float, float]
    std: tuple[float, float, float]

    def check(self) -> ColourStats:
        for name, triple, low, high in (("mean", self.mean, 0.0, 1.0), ("std", self.std, 0.0, 0.5)):
            if not isinstance(triple, (tuple, list)) or len(triple) != 3 or not all(
                    isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) and low <= v <= high
                    for v in triple):
                raise MetaSimError(f"colour statistics: {name} must be three numbers between {low} and {high}, "
                                   f"not {triple!r}")
        return self

    @classmethod
    def of_images(cls, images) -> ColourStats:
        """The statistics over every pixel of ``images`` ((H, W, 3) display values in 0-1), weighing each
        pixel alike."""
        total, squares, count = np.zeros(3), np.zeros(3), 0
        for image in images:
            pixels = np.asarray(image, dtype=np.float64).reshape(-1, 3)
            if not np.isfinite(pixels).all():
                raise MetaSimError("colour statistics: an image holds NaN or infinite values")
            total += pixels.sum(axis=0)
            squares += np.square(pixels).sum(axis=0)
            count += len(pixels)
        if not count:
            raise MetaSimError("colour statistics need at least one pixel")
        mean = total / count
        std = np.sqrt(np.maximum(squares / count - np.square(mean), 0.0))
        return cls(tuple(float(v) for v in np.clip(mean, 0, 1)), tuple(float(v) for v in np.clip(std, 0, 0.5)))

    def to_dict(self) -> dict:
        return {"mean": list(self.mean), "std": list(self.std)}


def match_colours(display: np.ndarray, target: ColourStats) -> np.ndarray:
    """``display`` ((H, W, 3) display values in 0-1) with each channel's mean and standard deviation made
    ``target``'s (clipped to 0-1, so a saturated image lands a little off); the dtype is kept."""
    image = np.asarray(display)
    if image.ndim != 3 or image.shape[-1] != 3:
        raise MetaSimError(f"colour matching needs an (H, W, 3) image, not shape {image.shape}")
    pixels = image.reshape(-1, 3).astype(np.float64)
    mean, std = pixels.mean(axis=0), pixels.std(axis=0)
    scale = np.where(std > MIN_SPREAD, np.asarray(target.std) / np.maximum(std, MIN_SPREAD), 1.0)
    out = (image.astype(np.float64) - mean) * scale + np.asarray(target.mean)
    return np.clip(out, 0.0, 1.0).astype(image.dtype)

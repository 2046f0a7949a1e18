"""PNG previews of a tile, for a person to look at: the RGB and a colour-coded label image."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .imageio import linear_to_srgb
from .textures.pngio import write_png


def to_srgb8(linear: np.ndarray) -> np.ndarray:
    """Linear RGB -> 8-bit sRGB (the standard transfer curve, values clipped to [0, 1])."""
    return np.floor(linear_to_srgb(linear) * 255.0 + 0.5).astype(np.uint8)


def label_image(instance: np.ndarray, roof_class: np.ndarray) -> np.ndarray:
    """Flat roofs in cool colours, sloped roofs in warm ones, one shade per building; edges dark."""
    ids = instance.astype(np.uint64)
    shade = ((ids * np.uint64(2654435761)) >> np.uint64(8)) % np.uint64(97)
    t = (shade.astype(np.float64) / 96.0)[..., None]
    cool = np.array([40, 110, 230]) * (1 - t) + np.array([60, 210, 200]) * t
    warm = np.array([230, 90, 40]) * (1 - t) + np.array([250, 200, 60]) * t
    out = np.zeros(instance.shape + (3,), dtype=np.float64)
    out[roof_class == 1] = cool[roof_class == 1]
    out[roof_class == 2] = warm[roof_class == 2]
    edge = np.zeros(instance.shape, dtype=bool)
    edge[:-1] |= instance[:-1] != instance[1:]
    edge[:, :-1] |= instance[:, :-1] != instance[:, 1:]
    out[edge & (instance > 0)] *= 0.45
    return out.astype(np.uint8)


def write_previews(tile_path: Path, rgb: np.ndarray, instance: np.ndarray, roof_class: np.ndarray) -> None:
    """``<tile>.png`` (RGB) and ``<tile>_labels.png`` beside an EXR tile."""
    tile_path = Path(tile_path)
    write_png(tile_path.with_suffix(".png"), to_srgb8(rgb))
    write_png(tile_path.with_name(tile_path.stem + "_labels.png"), label_image(instance, roof_class))


def write_mosaic(path: Path, images: list[np.ndarray], rects, pixel_size_m: float, max_px: int = 1536) -> None:
    """The tiles of one design placed where they lie in the city (north up), as one sRGB PNG."""
    x0 = min(r[0] for r in rects)
    y1 = max(r[3] for r in rects)
    width = max(int(round((r[2] - x0) / pixel_size_m)) for r in rects)
    height = max(int(round((y1 - r[1]) / pixel_size_m)) for r in rects)
    canvas = np.zeros((height, width, 3), dtype=np.float32)
    for image, rect in zip(images, rects):
        col = int(round((rect[0] - x0) / pixel_size_m))
        row = int(round((y1 - rect[3]) / pixel_size_m))
        canvas[row:row + image.shape[0], col:col + image.shape[1]] = image
    step = max(1, -(-max(width, height) // max_px))
    write_png(path, to_srgb8(canvas[::step, ::step]))

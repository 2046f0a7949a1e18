"""Ground cover with spatial variation: patches of lawn, dry grass, bare soil, sand, gravel and pavement.

Today's city lies on one lawn colour; real ground is a patchwork. ``ground_image`` paints the city's
ground as patches of covers in the proportions a mix declares: a smooth random field (value noise at
scales of about 15 to 60 m) is ranked, and its quantiles are cut at the mix's cumulative shares, so
each cover takes its share of the ground in contiguous patches; a second field shifts the cuts, so
covers do not always border in the same order. Each cover's colour varies within a patch (fine
noise and a slow brightness drift). Deterministic for a seed; pure numpy, so testable without
Blender. Colours are linear RGB (albedo-like, as the renderer's materials take them).
"""

from __future__ import annotations

import numpy as np

from ..core.errors import MetaSimError
from .imageio import resize

COVERS = {  # linear RGB
    "lawn": (0.20, 0.26, 0.12),
    "dry_grass": (0.34, 0.31, 0.18),
    "soil": (0.36, 0.25, 0.16),
    "sand": (0.52, 0.45, 0.34),
    "gravel": (0.33, 0.32, 0.30),
    "pavement": (0.40, 0.40, 0.39),
}
DIRT = (0.30, 0.22, 0.15)  # linear RGB of the unpaved tracks' bare earth (not a cover of the mixes)
MIXES = {
    "plain": None,  # the lawn of today's cities
    "suburban": {"lawn": 0.6, "dry_grass": 0.2, "soil": 0.1, "pavement": 0.1},
    "mixed": {"lawn": 0.35, "dry_grass": 0.2, "soil": 0.2, "gravel": 0.1, "pavement": 0.15},
    "arid": {"dry_grass": 0.25, "soil": 0.35, "sand": 0.25, "gravel": 0.15},
}
PIXEL_M = 0.5  # ground image resolution
# Grain (``ground_image``'s ``grain``): the fine texture of real bare ground (clods, stones, tufts, litter),
# multiplied into the covers at GRAIN_PIXEL_M, in log light: white noise per pixel and blobs of about 1 m and
# 3 m, with these standard deviations at grain 1.
GRAIN_PIXEL_M = 0.25
GRAIN_SIGMAS = (0.35, 0.2, 0.15)
GRAIN_SCALES_M = (1.0, 3.0)


def get_mix(name: str | None) -> dict | None:
    """The named ground mix (None for "plain": the lawn); MetaSimError listing the names for another."""
    if name is None:
        return None
    try:
        return MIXES[name]
    except KeyError:
        raise MetaSimError(f"unknown ground {name!r}; choose one of {', '.join(MIXES)}") from None


def _field(rng: np.random.Generator, h: int, w: int, scales_px) -> np.ndarray:
    """Smooth noise: bilinearly upsampled random grids, one per scale, summed."""
    total = np.zeros((h, w), np.float32)
    for scale in scales_px:
        gh, gw = max(2, int(np.ceil(h / scale)) + 1), max(2, int(np.ceil(w / scale)) + 1)
        grid = rng.standard_normal((gh, gw, 1)).astype(np.float32)
        total += resize(grid, h, w)[:, :, 0]
    return total


def ground_image(width_m: float, height_m: float, seed: int, mix: dict, colours: dict | None = None,
                 grain: float = 0.0) -> np.ndarray:
    """Linear RGB (H, W, 3) of the ground of a ``width_m`` x ``height_m`` region at ``PIXEL_M``;
    ``colours`` replaces the colours of some covers (a greener or drier lawn). With ``grain`` (0 to 1)
    the same ground at ``GRAIN_PIXEL_M`` with fine texture multiplied in (``grain_field``)."""
    if not 0.0 <= grain <= 1.0:
        raise MetaSimError(f"a ground's grain must be from 0 to 1, not {grain!r}")
    image = _covers(width_m, height_m, seed, mix, colours)
    if not grain:
        return image
    h, w = (max(2, int(round(m / GRAIN_PIXEL_M))) for m in (height_m, width_m))
    return np.clip(resize(image, h, w) * grain_field(h, w, seed, grain)[:, :, None], 0.0, 1.0).astype(np.float32)


def grain_field(h: int, w: int, seed: int, grain: float) -> np.ndarray:
    """Multiplicative fine texture (H, W) at ``GRAIN_PIXEL_M``: lognormal, of mean about 1, its log the sum
    of white noise and smooth noise at ``GRAIN_SCALES_M``, each with its ``GRAIN_SIGMAS`` times ``grain``."""
    rng = np.random.default_rng([int(seed), 12])
    fine, *smooth = GRAIN_SIGMAS
    log = fine * rng.standard_normal((h, w)).astype(np.float32)
    for sigma, scale_m in zip(smooth, GRAIN_SCALES_M):
        field = _field(rng, h, w, (scale_m / GRAIN_PIXEL_M,))
        log += sigma * field / max(float(field.std()), 1e-6)
    variance = sum(sigma * sigma for sigma in GRAIN_SIGMAS) * grain * grain
    return np.exp(grain * log - variance / 2.0).astype(np.float32)


def _covers(width_m: float, height_m: float, seed: int, mix: dict, colours: dict | None) -> np.ndarray:
    """``ground_image`` without grain."""
    unknown = [c for c in mix if c not in COVERS]
    if unknown or not mix or any(not 0 <= v for v in mix.values()) or sum(mix.values()) <= 0:
        raise MetaSimError(f"a ground mix gives shares (at least one positive) of {', '.join(COVERS)}; "
                           f"not {mix!r}")
    h, w = max(2, int(round(height_m / PIXEL_M))), max(2, int(round(width_m / PIXEL_M)))
    rng = np.random.default_rng([int(seed), 11])
    patches = _field(rng, h, w, (120, 60, 30))
    shift = _field(rng, h, w, (160,))
    order = np.argsort(patches.ravel())
    ranks = np.empty(order.size, np.int64)
    ranks[order] = np.arange(order.size)  # each pixel's place in the order: one sort, not two
    ranks = ranks.reshape(h, w) / float(h * w)
    ranks = np.clip(ranks + 0.08 * shift / (np.abs(shift).max() + 1e-6), 0.0, 0.999999)
    names = list(mix)
    edges = np.cumsum([mix[n] for n in names]) / sum(mix.values())
    cover = np.searchsorted(edges, ranks, side="right")
    palette = np.array([{**COVERS, **(colours or {})}[n] for n in names], np.float32)
    image = palette[np.minimum(cover, len(names) - 1)]
    drift = 1.0 + 0.12 * _field(rng, h, w, (80,))[:, :, None] / 2.0
    speckle = 1.0 + 0.15 * rng.standard_normal((h, w, 1)).astype(np.float32)
    return np.clip(image * drift * speckle, 0.0, 1.0).astype(np.float32)

"""Baked images of the clutter's surfaces: foliage, asphalt, concrete, pool water. Pure numpy.

The fast preset (Workbench) shows a material's image texture and nothing of
procedural shader nodes, so every pattern is baked here into an image the
renderer wraps in a plain image material. Images are linear RGB, float32,
row 0 at v = 0 (Blender's order). Asphalt, concrete and water tile seamlessly
(their noise is filtered in the Fourier domain, which is periodic); each
repeats every ``*_REPEAT_M`` metres of the metre UVs of ``meshes``. Every city
uses the images of seed 0 (cached, read-only); per-tree variety comes from the
atlas cells.

The foliage atlas is a grid of ``ATLAS_CELLS`` x ``ATLAS_CELLS`` cells, each
``CELL_M`` metres of leaf clumps (cellular noise: bright domes, dark gaps) in
its own tint; the first `TREE_CELLS` are tree greens, the rest lighter shrub
greens. A crown maps a window of one cell, so its clumps keep their size in
metres and neighbouring trees differ in shade.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from ..core.errors import MetaSimError

ATLAS_CELLS = 4
CELL_PX = 64
CELL_M = 16.0
TREE_CELLS = 12
ASPHALT_REPEAT_M = 25.6
CONCRETE_REPEAT_M = 6.4
WATER_REPEAT_M = 4.8
LAKE_REPEAT_M = 76.8  # open water (sim/water.py): 256 px at 0.3 m

_TREE_GREENS = ((0.060, 0.13, 0.035), (0.080, 0.15, 0.040), (0.105, 0.16, 0.045), (0.045, 0.11, 0.040),
                (0.120, 0.145, 0.050), (0.065, 0.125, 0.060))
_SHRUB_GREENS = ((0.085, 0.15, 0.045), (0.11, 0.16, 0.055), (0.07, 0.13, 0.05))


def _frozen(make):
    """Cache an image maker and hand out read-only arrays: a render worker builds many cities with the same images."""
    @lru_cache(maxsize=8)
    def cached(*args, **kwargs):
        image = make(*args, **kwargs)
        image.flags.writeable = False
        return image
    cached.__doc__ = make.__doc__
    return cached


def _periodic_field(rng: np.random.Generator, n: int, wavelength_px: float) -> np.ndarray:
    """Tileable smooth noise of unit standard deviation: white noise low-passed in the Fourier domain."""
    white = rng.standard_normal((n, n))
    f = np.fft.fftfreq(n)
    radius = np.hypot(f[:, None], f[None, :])
    field = np.real(np.fft.ifft2(np.fft.fft2(white) * np.exp(-(radius * wavelength_px) ** 2)))
    return field / (field.std() + 1e-9)


def _cellular(rng: np.random.Generator, h: int, w: int, spacing: float) -> tuple[np.ndarray, np.ndarray]:
    """Distances (F1, F2) of each pixel to its nearest and second-nearest jittered grid point."""
    gh, gw = int(np.ceil(h / spacing)) + 2, int(np.ceil(w / spacing)) + 2
    points = (np.stack(np.meshgrid(np.arange(gh), np.arange(gw), indexing="ij"), -1)
              + rng.uniform(0.0, 1.0, (gh, gw, 2)) - 1.0) * spacing
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64) + 0.5
    ci, cj = (yy // spacing).astype(int) + 1, (xx // spacing).astype(int) + 1
    dists = []
    for di in (-1, 0, 1):
        for dj in (-1, 0, 1):
            p = points[np.clip(ci + di, 0, gh - 1), np.clip(cj + dj, 0, gw - 1)]
            dists.append(np.hypot(p[..., 0] - yy, p[..., 1] - xx))
    d = np.sort(np.stack(dists), axis=0)
    return d[0], d[1]


def _clumps(rng: np.random.Generator, n: int, spacing: float) -> np.ndarray:
    """Leaf-clump shading around 1: domes bright in the middle, dark in the gaps between them."""
    f1, f2 = _cellular(rng, n, n, spacing)
    dome = np.sqrt(np.clip(1.0 - f1 / (0.9 * spacing), 0.0, 1.0))
    gap = np.clip((f2 - f1) / (0.35 * spacing), 0.0, 1.0)
    return 0.3 + 1.1 * dome * (0.6 + 0.4 * gap)


@_frozen
def foliage_atlas(seed: int = 0) -> np.ndarray:
    """The foliage atlas (see the module docstring): (ATLAS_CELLS * CELL_PX) square, linear RGB."""
    rng = np.random.default_rng([int(seed), 31])
    size = ATLAS_CELLS * CELL_PX
    out = np.zeros((size, size, 3), np.float32)
    px_m = CELL_PX / CELL_M
    for cell in range(ATLAS_CELLS * ATLAS_CELLS):
        row, col = divmod(cell, ATLAS_CELLS)
        tree = cell < TREE_CELLS
        palette = _TREE_GREENS if tree else _SHRUB_GREENS
        tint = np.asarray(palette[cell % len(palette)]) * rng.uniform(0.8, 1.2)
        tint = tint * (1.0 + rng.normal(0.0, 0.06, 3))  # a slight hue shift per cell
        shade = (0.5 * _clumps(rng, CELL_PX, (1.8 if tree else 0.8) * px_m) + 0.3 * _clumps(rng, CELL_PX, 0.9 * px_m)
                 + 0.2 * _clumps(rng, CELL_PX, 0.5 * px_m))
        drift = 1.0 + 0.12 * _periodic_field(rng, CELL_PX, 24.0)
        grain = 1.0 + 0.08 * rng.standard_normal((CELL_PX, CELL_PX))
        rgb = tint[None, None, :] * (shade * drift * grain)[..., None]
        out[row * CELL_PX:(row + 1) * CELL_PX, col * CELL_PX:(col + 1) * CELL_PX] = np.clip(rgb, 0.0, 1.0)
    return out


@_frozen
def asphalt_image(seed: int = 0, n: int = 256) -> np.ndarray:
    """Tileable asphalt of ``ASPHALT_REPEAT_M``: fine grain, darker repair patches, faded areas, cracks."""
    rng = np.random.default_rng([int(seed), 37])
    px_m = n / ASPHALT_REPEAT_M
    value = np.full((n, n), 0.105)
    value *= 1.0 + 0.10 * rng.standard_normal((n, n))  # aggregate grain
    value *= 1.0 + 0.06 * _periodic_field(rng, n, 0.6 * px_m)
    patches = _periodic_field(rng, n, 4.0 * px_m)
    value *= np.where(patches > 1.2, 0.8, 1.0)  # patched repairs: fresher, darker
    value *= 1.0 + 0.06 * np.clip(_periodic_field(rng, n, 6.0 * px_m), -1.5, 1.5)  # wear and fading
    cracks = np.abs(_periodic_field(rng, n, 1.2 * px_m)) < 0.05
    cracked = _periodic_field(rng, n, 5.0 * px_m) > 0.5
    value *= np.where(cracks & cracked, 0.55, 1.0)
    tint = np.array([1.0, 1.0, 1.06])
    return np.clip(value[..., None] * tint, 0.0, 1.0).astype(np.float32)


@_frozen
def concrete_image(seed: int = 0, n: int = 128) -> np.ndarray:
    """Tileable light concrete of ``CONCRETE_REPEAT_M``: grain, stains and joints every 1.6 m."""
    rng = np.random.default_rng([int(seed), 41])
    px_m = n / CONCRETE_REPEAT_M
    value = np.full((n, n), 0.36)
    value *= 1.0 + 0.05 * rng.standard_normal((n, n))
    value *= 1.0 + 0.07 * _periodic_field(rng, n, 1.5 * px_m)
    joint = int(round(1.6 * px_m))
    lines = (np.arange(n) % joint) == 0
    value *= np.where(lines[:, None] | lines[None, :], 0.8, 1.0)
    tint = np.array([1.0, 0.98, 0.94])
    return np.clip(value[..., None] * tint, 0.0, 1.0).astype(np.float32)


@_frozen
def water_image(seed: int = 0, n: int = 64) -> np.ndarray:
    """Tileable pool water of ``WATER_REPEAT_M``: turquoise with bright caustic ripples."""
    rng = np.random.default_rng([int(seed), 43])
    ripple = np.abs(_periodic_field(rng, n, 0.08 * n)) < 0.25
    depth = 1.0 + 0.08 * _periodic_field(rng, n, 0.3 * n)
    base = np.array([0.06, 0.36, 0.52])
    rgb = base * depth[..., None] * np.where(ripple, 1.25, 1.0)[..., None]
    return np.clip(rgb, 0.0, 1.0).astype(np.float32)


@_frozen
def lake_image(colour: tuple[float, float, float], n: int = 256) -> np.ndarray:
    """Tileable open water of ``LAKE_REPEAT_M`` in ``colour`` (linear RGB): broad patches of turbidity and
    depth (+-7%) with faint wind ripples (+-3%), no caustics (too deep and too far for them)."""
    rng = np.random.default_rng(47)
    broad = 0.07 * _periodic_field(rng, n, 0.2 * n)
    ripple = 0.03 * _periodic_field(rng, n, 0.02 * n)
    rgb = np.asarray(colour, np.float32) * (1.0 + broad + ripple)[..., None]
    return np.clip(rgb, 0.0, 1.0).astype(np.float32)


# Flat colours (linear RGB) of the clutter materials without a pattern of their own.
CAR_PAINT = {"white": (0.72, 0.72, 0.70), "silver": (0.42, 0.43, 0.44), "grey": (0.17, 0.17, 0.18),
             "black": (0.025, 0.025, 0.03), "red": (0.42, 0.035, 0.03), "blue": (0.04, 0.08, 0.28)}
GLASS = (0.02, 0.025, 0.03)
ROAD_PAINT = (0.62, 0.62, 0.60)
COPING = (0.55, 0.53, 0.50)
YARD_SHADE = 0.6  # paved commercial and industrial lots: concrete, weathered darker than sidewalks
# The light grey-beige (linear RGB) of a road under dust, as in towns on dry ground (``dusty``).
ROAD_DUST = (0.30, 0.285, 0.26)


def dusty(rgb, dust: float) -> np.ndarray:
    """A road surface (linear RGB, an image or one colour) under ``dust`` (0 to 1): its mean colour moved
    that far towards `ROAD_DUST`, its texture (each pixel over the mean) kept."""
    if not 0.0 <= dust <= 1.0:
        raise MetaSimError(f"a road's dust must be from 0 to 1, not {dust!r}")
    rgb = np.asarray(rgb, np.float32)
    mean = rgb.reshape(-1, 3).mean(axis=0)
    target = (1.0 - dust) * mean + dust * np.asarray(ROAD_DUST, np.float32)
    return np.clip(rgb * (target / np.maximum(mean, 1e-6)), 0.0, 1.0).astype(np.float32)


# Roof furniture (sim/furniture.py): colours (linear RGB) and roughness of its surfaces; "solar" panels and
# HVAC lids are images (below).
FURNITURE = {"coping": COPING, "metal": (0.50, 0.51, 0.52), "dark": (0.09, 0.09, 0.10), "dome": (0.62, 0.66, 0.68),
             "glass": (0.025, 0.035, 0.05), "brick": (0.25, 0.085, 0.055), "render": (0.44, 0.42, 0.39),
             "tank-black": (0.03, 0.03, 0.032), "tank-blue": (0.03, 0.11, 0.33), "tank-white": (0.66, 0.66, 0.63),
             "tank-beige": (0.52, 0.40, 0.19)}
FURNITURE_ROUGHNESS = {"metal": 0.5, "dome": 0.3, "glass": 0.1, "solar": 0.2, "tank-black": 0.5, "tank-blue": 0.5,
                       "tank-white": 0.5, "tank-beige": 0.5}


@_frozen
def solar_image(seed: int = 0) -> np.ndarray:
    """One solar module (``furniture.PANEL_M``, portrait): dark blue cells in a light frame, faint lines
    between the cells, a slight sheen across it."""
    rng = np.random.default_rng([int(seed), 47])
    h, w = 60, 36  # rows up the module, columns across it
    rows, cols = np.arange(h)[:, None], np.arange(w)[None, :]
    rgb = np.empty((h, w, 3))
    rgb[:] = (0.018, 0.03, 0.07)
    rgb *= (1.0 + 0.15 * (rows / h) + 0.04 * rng.standard_normal((h, w)))[..., None]
    lines = (rows % 6 == 0) | (cols % 6 == 0)
    rgb[lines] = (0.05, 0.06, 0.09)
    frame = (rows < 1) | (rows >= h - 1) | (cols < 1) | (cols >= w - 1)
    rgb[frame] = (0.30, 0.31, 0.32)
    return np.clip(rgb, 0.0, 1.0).astype(np.float32)


@_frozen
def fan_lid_image(seed: int = 0, n: int = 32) -> np.ndarray:
    """The lid of an HVAC unit, spanning it: light sheet metal, a dark fan grille with a hub towards one
    end, louvres at the other."""
    rng = np.random.default_rng([int(seed), 53])
    yy, xx = (np.mgrid[0:n, 0:n] + 0.5) / n
    value = np.asarray(FURNITURE["metal"])[None, None, :] * (1.0 + 0.03 * rng.standard_normal((n, n)))[..., None]
    r = np.hypot(xx - 0.3, yy - 0.5)
    value[(r < 0.24) & (r > 0.06)] *= 0.18
    louvres = (xx > 0.62) & (xx < 0.92) & (yy > 0.15) & (yy < 0.85) & ((np.arange(n)[:, None] % 4) < 2)
    value[louvres] *= 0.6
    return np.clip(value, 0.0, 1.0).astype(np.float32)

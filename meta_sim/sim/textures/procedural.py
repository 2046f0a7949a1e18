"""Procedural roof textures for the default bank, numpy only.

Every texture is a *recipe*: a stable id, a human name, its kind (``flat`` or
``sloped``), the physical size of one repeat in metres, a generator family
and that family's parameters. ``generate(recipe, size)`` turns it into a
``size x size`` uint8 RGB image.

Rules that make the output identical on every run and every machine:

- Randomness is integer hashing only (a 32-bit avalanche hash of lattice or
  cell coordinates and a seed). A recipe's seed is ``crc32`` of its id.
- Arithmetic is float64 ``+ - * /``, ``sqrt``, ``floor``, ``min``/``max``,
  ``abs`` and polynomials: all correctly rounded in IEEE 754. No
  ``sin``/``cos``/``exp``/``log``/``power`` (their vectorised implementations
  differ by an ulp between CPUs) and no reductions (summation order).
  Periodic waves are polynomials of the fractional part.
- Quantisation is ``floor(clip(x, 0, 1) * 255 + 0.5)``.

Every texture tiles seamlessly: noise lattices have an integer period per
repeat and all structures (tiles, seams, stones) sit on periodic grids, so
the image is a function of the pixel's position modulo one repeat.

Orientation of sloped textures: courses run along the image x axis (parallel
to the eaves) and the down-slope direction is +y (image down); standing
seams, corrugations and shake grain run along y. Light comes from the
top-left (up-slope, left), at about 50 degrees elevation.
"""

from __future__ import annotations

import zlib
from dataclasses import dataclass, field
from typing import Any, Callable, Mapping

import numpy as np

RECIPE_VERSION = 1
KINDS = ("flat", "sloped")

# --- integer hashing ------------------------------------------------------

_MUL1 = np.uint32(0x7FEB352D)
_MUL2 = np.uint32(0x846CA68B)
_GOLDEN = np.uint32(0x9E3779B9)
_SHIFT15 = np.uint32(15)
_SHIFT16 = np.uint32(16)
_TO_UNIT = 1.0 / 4294967296.0


def _mix32(x: np.ndarray) -> np.ndarray:
    """32-bit avalanche hash (lowbias32); wraps modulo 2**32 by design."""
    x = x ^ (x >> _SHIFT16)
    x = x * _MUL1
    x = x ^ (x >> _SHIFT15)
    x = x * _MUL2
    return x ^ (x >> _SHIFT16)


def _hash(seed: int, *keys: Any) -> np.ndarray:
    """uint32 hash of a seed and non-negative integer keys (broadcast arrays)."""
    with np.errstate(over="ignore"):
        h = _mix32(np.array([seed & 0xFFFFFFFF], dtype=np.uint32))
        for key in keys:
            h = _mix32((h + _GOLDEN) ^ np.asarray(key, dtype=np.int64).astype(np.uint32))
    return h


def _rand(seed: int, *keys: Any) -> np.ndarray:
    """Uniform float64 in [0, 1) from a seed and integer keys."""
    return _hash(seed, *keys) * _TO_UNIT


def _subseed(seed: int, name: str) -> int:
    return int(_hash(seed, zlib.crc32(name.encode("ascii")))[0])


# --- polynomial helpers ---------------------------------------------------


def _smoothstep(a: float, b: float, x: np.ndarray) -> np.ndarray:
    t = np.clip((x - a) / (b - a), 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


def _frac(x: np.ndarray) -> np.ndarray:
    return x - np.floor(x)


def _pdist(t: np.ndarray) -> np.ndarray:
    """Distance from t to the nearest integer (a triangle wave in [0, 0.5])."""
    return np.abs(t - np.floor(t + 0.5))


def _coverage(dist: np.ndarray, width: float, pixel: float) -> np.ndarray:
    """Fraction of a pixel (box of size ``pixel``) covered by a line of
    ``width`` whose centre is ``dist`` away: exact box-filter antialiasing."""
    lo = np.maximum(dist - 0.5 * pixel, -0.5 * width)
    hi = np.minimum(dist + 0.5 * pixel, 0.5 * width)
    return np.clip((hi - lo) / pixel, 0.0, 1.0)


def _box(dx: np.ndarray, dy: np.ndarray, hw: float, hh: float, pixel: float) -> np.ndarray:
    """Antialiased coverage of an axis-aligned rectangle (half sizes hw, hh)."""
    return _coverage(np.abs(dx), 2.0 * hw, pixel) * _coverage(np.abs(dy), 2.0 * hh, pixel)


def _disc(dx: np.ndarray, dy: np.ndarray, radius: float, pixel: float) -> np.ndarray:
    d = np.sqrt(dx * dx + dy * dy)
    return np.clip((radius - d) / pixel + 0.5, 0.0, 1.0)


# Direction towards the light (top-left, ~50 degrees up), normalised.
_LIGHT = np.array([0.45, 0.45, 0.771], dtype=np.float64)
_LIGHT = _LIGHT / np.sqrt(_LIGHT[0] * _LIGHT[0] + _LIGHT[1] * _LIGHT[1] + _LIGHT[2] * _LIGHT[2])


def _lambert(hx: np.ndarray, hy: np.ndarray) -> np.ndarray:
    """Diffuse shading of a height field with slopes (hx, hy), 1 when flat.
    A surface rising towards +x faces the light (which is at -x, -y)."""
    dot = _LIGHT[0] * hx + _LIGHT[1] * hy + _LIGHT[2]
    return np.maximum(dot, 0.0) / np.sqrt(1.0 + hx * hx + hy * hy) / _LIGHT[2]


# --- colours --------------------------------------------------------------


def _hex(colour: str) -> np.ndarray:
    value = int(colour.lstrip("#"), 16)
    return np.array([(value >> 16) & 255, (value >> 8) & 255, value & 255], dtype=np.float64) / 255.0


def _palette(entries) -> tuple[np.ndarray, np.ndarray]:
    """Colours (K, 3) and cumulative weights (K,) from ``[(hex, weight), ...]``."""
    colours = np.stack([_hex(c) for c, _ in entries])
    weights = np.array([w for _, w in entries], dtype=np.float64)
    cumulative = np.cumsum(weights)
    return colours, cumulative / cumulative[-1]


def _pick(entries, t: np.ndarray) -> np.ndarray:
    """Palette colour chosen by t in [0, 1) with the palette's weights."""
    colours, cumulative = _palette(entries)
    idx = np.minimum(np.searchsorted(cumulative, t, side="right"), len(colours) - 1)
    return colours[idx]


def _ramp(entries, t: np.ndarray) -> np.ndarray:
    """Colour ramp: piecewise-linear through the palette's colours (weights
    ignored) as t goes from 0 to 1."""
    colours, _ = _palette(entries)
    if len(colours) == 1:
        return np.broadcast_to(colours[0], np.shape(t) + (3,))
    x = np.clip(t, 0.0, 1.0) * (len(colours) - 1)
    i = np.minimum(np.floor(x).astype(np.int64), len(colours) - 2)
    return _mix(colours[i], colours[i + 1], x - i)


def _mix(a: np.ndarray, b: np.ndarray, t: np.ndarray) -> np.ndarray:
    t = np.asarray(t)
    if t.ndim == 2:
        t = t[:, :, None]
    return a + (b - a) * t


def _scale(rgb: np.ndarray, factor: np.ndarray) -> np.ndarray:
    factor = np.asarray(factor)
    if factor.ndim == 2:
        factor = factor[:, :, None]
    return rgb * factor


# --- noise ----------------------------------------------------------------


def _value_noise(u, v, px: int, py: int, seed: int) -> np.ndarray:
    """Periodic value noise in [0, 1]: lattice of px x py cells per repeat."""
    x = u * px
    y = v * py
    xf = np.floor(x)
    yf = np.floor(y)
    sx = _smoothstep(0.0, 1.0, x - xf)
    sy = _smoothstep(0.0, 1.0, y - yf)
    x0 = xf.astype(np.int64) % px
    y0 = yf.astype(np.int64) % py
    x1 = (x0 + 1) % px
    y1 = (y0 + 1) % py
    a = _rand(seed, x0, y0)
    b = _rand(seed, x1, y0)
    c = _rand(seed, x0, y1)
    d = _rand(seed, x1, y1)
    return a + (b - a) * sx + (c - a) * sy + (a - b - c + d) * sx * sy


def _fbm(u, v, px: int, py: int, seed: int, octaves: int = 4, gain: float = 0.5) -> np.ndarray:
    """Sum of value-noise octaves (periods doubling), normalised to [0, 1]."""
    total = 0.0
    amplitude = 1.0
    norm = 0.0
    for k in range(octaves):
        total = total + amplitude * _value_noise(u, v, px << k, py << k, _subseed(seed, f"octave{k}"))
        norm += amplitude
        amplitude *= gain
    return total / norm


@dataclass
class _Cells:
    """Nearest and second-nearest feature points of a periodic jittered grid."""

    f1: np.ndarray  # distance to the nearest point, in repeats
    f2: np.ndarray  # distance to the second nearest point
    cell: np.ndarray  # wrapped id of the nearest point's cell
    dx: np.ndarray  # pixel minus nearest point, in repeats
    dy: np.ndarray


def _worley(u, v, nx: int, ny: int, seed: int, jitter: float = 0.9, stagger: bool = False) -> _Cells:
    """Cellular noise with nx x ny cells per repeat. ``stagger`` shifts odd
    rows by half a cell (with jitter 0 this gives a hexagonal pattern; ny
    must then be even)."""
    x = np.broadcast_to(u * nx, np.broadcast_shapes(np.shape(u), np.shape(v)))
    y = np.broadcast_to(v * ny, x.shape)
    cx = np.floor(x).astype(np.int64)
    cy = np.floor(y).astype(np.int64)
    f1 = np.full(x.shape, np.inf)
    f2 = np.full(x.shape, np.inf)
    cell = np.zeros(x.shape, dtype=np.int64)
    best_dx = np.zeros(x.shape)
    best_dy = np.zeros(x.shape)
    seed_x = _subseed(seed, "x")
    seed_y = _subseed(seed, "y")
    for oy in (-1, 0, 1):
        gy = cy + oy
        wy = gy % ny
        for ox in (-1, 0, 1):
            gx = cx + ox
            wx = gx % nx
            px = gx + 0.5 + jitter * (_rand(seed_x, wx, wy) - 0.5)
            if stagger:
                px = px + 0.5 * (wy % 2)
            py = gy + 0.5 + jitter * (_rand(seed_y, wx, wy) - 0.5)
            dx = (x - px) / nx
            dy = (y - py) / ny
            d = np.sqrt(dx * dx + dy * dy)
            closer = d < f1
            f2 = np.where(closer, f1, np.minimum(f2, d))
            f1 = np.where(closer, d, f1)
            cell = np.where(closer, wx * ny + wy, cell)
            best_dx = np.where(closer, dx, best_dx)
            best_dy = np.where(closer, dy, best_dy)
    return _Cells(f1, f2, cell, best_dx, best_dy)


def _row_cells(x: np.ndarray, row: np.ndarray, n: int, seed: int, jitter: float):
    """Split each row into n cells per repeat along x (x in cell units).

    With ``jitter`` > 0 (< 0.5) each boundary moves by up to +-jitter cells,
    per row, so widths vary. Returns (wrapped cell id, position in the cell
    0..1, cell width in cell units).
    """
    k = np.floor(x).astype(np.int64)
    if jitter == 0.0:
        return k % n, x - k, np.ones_like(x)

    def boundary(kk):
        return kk + jitter * (2.0 * _rand(seed, kk % n, row) - 1.0)

    b0 = boundary(k)
    b1 = boundary(k + 1)
    before = x < b0
    after = x >= b1
    cell = np.where(before, k - 1, np.where(after, k + 1, k))
    lo = np.where(before, boundary(k - 1), np.where(after, b1, b0))
    hi = np.where(before, b0, np.where(after, boundary(k + 2), b1))
    return cell % n, (x - lo) / (hi - lo), hi - lo


def _count(repeat_m: float, size_m: float, even: bool = False) -> int:
    """Whole number of structures of about size_m in one repeat."""
    n = max(1, int(np.floor(repeat_m / size_m + 0.5)))
    if even and n % 2:
        n += 1
    return n


class _Canvas:
    """Pixel-centre coordinates, in repeats (u, v), of ``size`` pixels per
    repeat over ``span`` repeats each way (span > 1 only to test periodicity)."""

    def __init__(self, size: int, repeat_m: float, seed: int, span: int = 1):
        self.shape = (size * span, size * span, 3)
        self.repeat_m = float(repeat_m)
        self.seed = seed
        centres = (np.arange(size * span, dtype=np.float64) + 0.5) / size
        self.u = centres[None, :]
        self.v = centres[:, None]
        pixels = np.arange(size * span, dtype=np.int64) % size
        self.col = pixels[None, :]
        self.row = pixels[:, None]
        self.pixel_m = self.repeat_m / size

    def seed_for(self, name: str) -> int:
        return _subseed(self.seed, name)

    def fbm(self, name: str, size_m: float, octaves: int = 4, stretch: tuple[float, float] = (1.0, 1.0)):
        """fBm whose largest features are about size_m, optionally stretched
        (stretch > 1 makes features that much longer along that axis)."""
        px = _count(self.repeat_m, size_m * stretch[0])
        py = _count(self.repeat_m, size_m * stretch[1])
        return _fbm(self.u, self.v, px, py, self.seed_for(name), octaves)

    def speckle(self, name: str) -> np.ndarray:
        """Independent uniform value per pixel (granules, grain)."""
        return _rand(self.seed_for(name), self.col, self.row)


# --- shared finishing touches ---------------------------------------------


def _weathering(c: _Canvas, rgb: np.ndarray, amount: float, size_m: float = 3.0) -> np.ndarray:
    """Large-scale brightness variation (dirt, sun-bleaching)."""
    if amount <= 0.0:
        return rgb
    return _scale(rgb, 1.0 + amount * (2.0 * c.fbm("weathering", size_m) - 1.0))


def _granules(c: _Canvas, rgb: np.ndarray, amount: float, flecks=None, fleck_share: float = 0.0):
    """Per-pixel brightness jitter, plus optional coloured flecks."""
    if amount > 0.0:
        rgb = _scale(rgb, 1.0 + amount * (2.0 * c.speckle("granules") - 1.0))
    if flecks:
        chosen = c.speckle("fleck-choice")
        share = c.speckle("fleck-share") < fleck_share
        rgb = np.where(share[:, :, None], _pick(flecks, chosen), rgb)
    return rgb


def _spots(c: _Canvas, rgb: np.ndarray, spec: Mapping | None) -> np.ndarray:
    """Sparse round spots (lichen, moss, rust pits) on a periodic grid."""
    if not spec:
        return rgb
    n = _count(c.repeat_m, spec["size_m"])
    cells = _worley(c.u, c.v, n, n, c.seed_for("spots"))
    # Spots cluster in colonies: dense where a coarse noise is high, absent elsewhere.
    colonies = _smoothstep(0.42, 0.62, c.fbm("spot-patches", spec.get("patch_m", 1.0)))
    alive = _rand(c.seed_for("spot-alive"), cells.cell) < spec["density"] * 2.0 * colonies
    radius = spec.get("radius", 0.35) / n * (0.5 + _rand(c.seed_for("spot-radius"), cells.cell))
    inside = np.clip((radius - cells.f1) / (c.pixel_m / c.repeat_m) + 0.5, 0.0, 1.0) * alive
    colour = _pick(spec["palette"], _rand(c.seed_for("spot-colour"), cells.cell))
    return _mix(rgb, colour, inside * spec.get("opacity", 0.7))


def _stains(c: _Canvas, rgb: np.ndarray, spec: Mapping | None) -> np.ndarray:
    """Soft blotches (ponding marks, dirt, moss) towards a colour."""
    if not spec:
        return rgb
    field_ = c.fbm("stains", spec.get("size_m", 3.0), octaves=5)
    lo = spec.get("threshold", 0.55)
    mask = _smoothstep(lo, lo + spec.get("softness", 0.2), field_) * spec["amount"]
    return _mix(rgb, _hex(spec["colour"]), mask)


# --- families -------------------------------------------------------------


def _gravel(c: _Canvas, p: Mapping) -> np.ndarray:
    """Loose stones: jittered cells, each a shaded dome of its own colour."""
    n = _count(c.repeat_m, p["stone_m"])
    cells = _worley(c.u, c.v, n, n, c.seed_for("stones"), jitter=0.95)
    colour = _pick(p["palette"], _rand(c.seed_for("stone-colour"), cells.cell))
    tone = 1.0 + p.get("tone", 0.15) * (2.0 * _rand(c.seed_for("stone-tone"), cells.cell) - 1.0)
    radius = 0.55 / n
    height = 0.7 * radius
    hx = -2.0 * cells.dx * height / (radius * radius)
    hy = -2.0 * cells.dy * height / (radius * radius)
    shade = np.clip(_lambert(hx, hy), 0.35, 1.35)
    crevice = 0.45 + 0.55 * _smoothstep(0.0, 0.22, (cells.f2 - cells.f1) * n)
    rgb = _scale(colour, tone * shade * crevice)
    rgb = _stains(c, rgb, p.get("stains"))
    return _weathering(c, rgb, p.get("weathering", 0.1), 1.5)


def _rect_patches(c: _Canvas, rgb: np.ndarray, spec: Mapping | None) -> np.ndarray:
    """Repair patches: at most one rectangle per cell of a coarse grid."""
    if not spec:
        return rgb
    g = _count(c.repeat_m, spec.get("cell_m", 4.0))
    cell_m = c.repeat_m / g
    a = np.floor(c.u * g).astype(np.int64) % g
    b = np.floor(c.v * g).astype(np.int64) % g
    lx = _frac(c.u * g) * cell_m
    ly = _frac(c.v * g) * cell_m
    seed = c.seed_for("patches")
    present = _rand(seed, a, b, 0) < spec["probability"]
    hw = cell_m * (0.08 + 0.17 * _rand(seed, a, b, 1))
    hh = cell_m * (0.08 + 0.17 * _rand(seed, a, b, 2))
    cx = cell_m * (0.3 + 0.4 * _rand(seed, a, b, 3))
    cy = cell_m * (0.3 + 0.4 * _rand(seed, a, b, 4))
    inside = _box(lx - cx, ly - cy, hw, hh, c.pixel_m) * present
    edge = np.clip(
        _box(lx - cx, ly - cy, hw + 0.015, hh + 0.015, c.pixel_m) * present - inside, 0.0, 1.0
    )
    rgb = _scale(rgb, 1.0 + inside * spec.get("tone", -0.06))
    return _scale(rgb, 1.0 - edge * spec.get("edge", 0.3))


def _sheet(c: _Canvas, p: Mapping) -> np.ndarray:
    """Rolled roofing (membranes, cap sheets): parallel sheets with lapped
    seams, end laps, mottling, stains, patches, optional walkway pads.
    Seams are vertical; ``horizontal: True`` turns the result a quarter."""
    base = _hex(p["colour"])
    n = _count(c.repeat_m, p["sheet_m"])
    sheet_w = c.repeat_m / n
    s = c.u * n
    k = np.floor(s).astype(np.int64) % n
    d = _frac(s) * sheet_w  # metres from the seam on the sheet's left
    lap = p.get("lap_m", 0.08)
    lap_strip = _coverage(_pdist((d - 0.5 * lap) / sheet_w) * sheet_w, lap, c.pixel_m)
    lap_edge = _coverage(_pdist((d - lap) / sheet_w) * sheet_w, p.get("edge_m", 0.01), c.pixel_m)
    ends_per_repeat = p.get("end_laps", 1)
    t = c.v * ends_per_repeat + _rand(c.seed_for("end-laps"), k)
    end_d = _pdist(t) * c.repeat_m / ends_per_repeat
    end_strip = _coverage(end_d, lap, c.pixel_m)
    shade = 1.0 + p.get("mottle", 0.03) * (2.0 * c.fbm("mottle", 1.5) - 1.0)
    shade = shade * (1.0 + p.get("sheet_tone", 0.015) * (2.0 * _rand(c.seed_for("sheet-tone"), k) - 1.0))
    lap_tone = p.get("lap_tone", 0.04)
    shade = shade * (1.0 + lap_tone * np.maximum(lap_strip, end_strip))
    shade = shade * (1.0 - p.get("edge_dark", 0.25) * np.maximum(lap_edge, end_strip * 0.5))
    rgb = _scale(np.broadcast_to(base, c.shape), shade)
    rgb = _granules(c, rgb, p.get("granules", 0.0), p.get("flecks"), p.get("fleck_share", 0.0))
    rgb = _stains(c, rgb, p.get("stains"))
    rgb = _rect_patches(c, rgb, p.get("patches"))
    if p.get("walkway"):
        rgb = _walkway(c, rgb, p["walkway"])
    rgb = _weathering(c, rgb, p.get("weathering", 0.03), 4.0)
    if p.get("horizontal"):
        rgb = np.ascontiguousarray(np.transpose(rgb, (1, 0, 2)))
    return rgb


def _walkway(c: _Canvas, rgb: np.ndarray, spec: Mapping) -> np.ndarray:
    """A line of square walkway pads across the repeat at height y."""
    pad = spec.get("pad_m", 0.76)
    n = _count(c.repeat_m, pad + spec.get("gap_m", 0.08))
    step = c.repeat_m / n
    x = _frac(c.u * n) * step - 0.5 * step
    y = (_frac(c.v - spec.get("y", 0.5) + 0.5) - 0.5) * c.repeat_m
    inside = _box(x, y, 0.5 * pad, 0.5 * pad, c.pixel_m)
    colour = _hex(spec["colour"])
    pads = _scale(np.broadcast_to(colour, rgb.shape), 1.0 + 0.25 * (c.speckle("walkway") - 0.5))
    return _mix(rgb, pads, inside)


def _tar(c: _Canvas, p: Mapping) -> np.ndarray:
    """Built-up bitumen roof: aged and fresh areas, patches, cracks, and
    optionally embedded gravel."""
    aged = _smoothstep(0.38, 0.62, c.fbm("aged", 3.0))
    rgb = _mix(_hex(p["colour"]), _hex(p["aged"]), aged)
    rgb = np.broadcast_to(rgb, c.shape)
    fresh = _smoothstep(0.6, 0.63, c.fbm("fresh", 1.2, octaves=5)) * p.get("fresh", 0.0)
    rgb = _mix(rgb, _hex(p.get("fresh_colour", "#1a1a1b")), fresh)
    if p.get("cracks"):
        n = _count(c.repeat_m, p["cracks"])
        cells = _worley(c.u, c.v, n, n, c.seed_for("cracks"))
        line = _coverage((cells.f2 - cells.f1) * c.repeat_m * 0.5, 0.012, c.pixel_m)
        rgb = _scale(rgb, 1.0 - 0.5 * line * aged)
    if p.get("gravel"):
        spec = p["gravel"]
        n = _count(c.repeat_m, spec["stone_m"])
        cells = _worley(c.u, c.v, n, n, c.seed_for("embedded"))
        alive = _rand(c.seed_for("embedded-alive"), cells.cell) < spec["density"]
        radius = 0.38 / n
        stone = np.clip((radius - cells.f1) / (c.pixel_m / c.repeat_m) + 0.5, 0.0, 1.0) * alive
        colour = _pick(spec["palette"], _rand(c.seed_for("embedded-colour"), cells.cell))
        hx = -cells.dx / radius
        hy = -cells.dy / radius
        colour = _scale(colour, np.clip(_lambert(hx, hy), 0.5, 1.3))
        rgb = _mix(rgb, colour, stone)
    rgb = _granules(c, rgb, p.get("granules", 0.06))
    rgb = _rect_patches(c, rgb, p.get("patches"))
    return _weathering(c, rgb, p.get("weathering", 0.06), 5.0)


def _pavers(c: _Canvas, p: Mapping) -> np.ndarray:
    """Unit pavers, slabs and tiles with joints: grid, running bond,
    hexagons or basket weave; per-unit colour; bevels; stains; cracks."""
    layout = p.get("layout", "grid")
    w_m, h_m = p["size_m"]
    if layout == "hex":
        nx = _count(c.repeat_m, w_m)
        ny = _count(c.repeat_m, w_m * 0.8660254037844386, even=True)
        cells = _worley(c.u, c.v, nx, ny, c.seed_for("hex"), jitter=0.0, stagger=True)
        unit = cells.cell
        edge = (cells.f2 - cells.f1) * 0.5 * c.repeat_m
        bevel = np.clip(-(cells.dx + cells.dy) * nx, -1.0, 1.0)  # lit towards the top-left
        parity = unit % 2
    else:
        if layout == "basket":
            nb = _count(c.repeat_m, w_m, even=True)
            bx = c.u * nb
            by = c.v * nb
            ix = np.floor(bx).astype(np.int64)
            iy = np.floor(by).astype(np.int64)
            fx = bx - ix
            fy = by - iy
            across = ((ix + iy) % 2) == 1
            half_x = np.floor(fx * 2.0)
            half_y = np.floor(fy * 2.0)
            fu = np.where(across, _frac(fx * 2.0), fx)
            fv = np.where(across, fy, _frac(fy * 2.0))
            unit = ((ix % nb) * nb + (iy % nb)) * 2 + np.where(across, half_x, half_y).astype(np.int64)
            parity = (ix + iy) % 2
            uw = c.repeat_m / nb * np.where(across, 0.5, 1.0)
            uh = c.repeat_m / nb * np.where(across, 1.0, 0.5)
        else:
            rows = _count(c.repeat_m, h_m, even=layout == "running")
            cols = _count(c.repeat_m, w_m)
            y = c.v * rows
            r = np.floor(y).astype(np.int64) % rows
            fv = _frac(y)
            x = c.u * cols + (0.5 * (r % 2) if layout == "running" else 0.0)
            col, fu, _ = _row_cells(x, r, cols, c.seed_for("columns"), 0.0)
            unit = col * rows + r
            parity = (col + r) % 2
            uw = c.repeat_m / cols
            uh = c.repeat_m / rows
        dist_x = np.minimum(fu, 1.0 - fu) * uw
        dist_y = np.minimum(fv, 1.0 - fv) * uh
        edge = np.minimum(dist_x, dist_y)
    colour = _pick(p["palette"], _rand(c.seed_for("unit-colour"), unit))
    if p.get("checker"):
        second = _pick(p["checker"], _rand(c.seed_for("unit-colour2"), unit))
        colour = np.where((parity == 1)[:, :, None], second, colour)
    tone = 1.0 + p.get("tone", 0.05) * (2.0 * _rand(c.seed_for("unit-tone"), unit) - 1.0)
    surface = 1.0 + p.get("texture", 0.05) * (2.0 * c.fbm("surface", 0.3, octaves=3) - 1.0)
    bevel_m = p.get("bevel_m", 0.01)
    joint = p.get("joint_m", 0.01)
    if layout == "hex":
        bevel = bevel * _smoothstep(0.5 * joint + bevel_m, 0.5 * joint, edge)
    else:  # lit along top and left edges, shaded along bottom and right ones
        bevel = np.clip(
            np.where(fu < 0.5, 1.0, -1.0) * _smoothstep(0.5 * joint + bevel_m, 0.5 * joint, dist_x)
            + np.where(fv < 0.5, 1.0, -1.0) * _smoothstep(0.5 * joint + bevel_m, 0.5 * joint, dist_y),
            -1.0, 1.0,
        )
    shade = tone * surface * (1.0 + p.get("bevel", 0.08) * bevel)
    rgb = _scale(colour, shade)
    rgb = _granules(c, rgb, p.get("granules", 0.04), p.get("flecks"), p.get("fleck_share", 0.0))
    rgb = _stains(c, rgb, p.get("stains"))
    if p.get("cracks"):
        n = _count(c.repeat_m, p["cracks"])
        cells = _worley(c.u, c.v, n, n, c.seed_for("cracks"))
        few = c.fbm("crack-mask", 2.0) > 0.55
        line = _coverage((cells.f2 - cells.f1) * c.repeat_m * 0.5, 0.006, c.pixel_m) * few
        rgb = _scale(rgb, 1.0 - 0.45 * line)
    rgb = _spots(c, rgb, p.get("spots"))
    joint_colour = _hex(p["joint_colour"])
    rgb = _mix(rgb, np.broadcast_to(joint_colour, rgb.shape), _coverage(edge, joint, c.pixel_m))
    return _weathering(c, rgb, p.get("weathering", 0.05), 3.0)


def _supersample(func, t: np.ndarray, dt: float, samples: int = 4) -> np.ndarray:
    """Mean of func over a pixel of width dt centred on t (in func's units)."""
    total = 0.0
    for k in range(samples):
        total = total + func(t + ((k + 0.5) / samples - 0.5) * dt)
    return total / samples


def _profile_height(profile: str, t: np.ndarray) -> np.ndarray:
    """Height (0..1) of a profiled sheet at t (in pitches, periodic)."""
    f = _frac(t)
    if profile == "corrugated":
        return 16.0 * f * f * (1.0 - f) * (1.0 - f)
    if profile == "trapezoid":  # wide pan, narrow rib: rise 0.55-0.65, top to 0.9, fall to 1
        rise = np.clip((f - 0.55) / 0.1, 0.0, 1.0)
        fall = np.clip((1.0 - f) / 0.1, 0.0, 1.0)
        return np.minimum(rise, fall)
    if profile == "seam":  # standing seam: narrow rib at f in [0, 0.055]
        up = np.clip(f / 0.012, 0.0, 1.0)
        down = np.clip((0.055 - f) / 0.012, 0.0, 1.0)
        return np.minimum(up, down)
    raise ValueError(f"unknown profile {profile!r}")


def _profiled(c: _Canvas, p: Mapping) -> np.ndarray:
    """Profiled metal or fibre-cement sheets (trapezoidal deck, corrugated,
    standing seam): ribs along y, sheets with side and end laps, paint or
    zinc, rust, per-sheet replacement colours."""
    # Sheets are a whole number of ribs wide; end laps at random heights.
    n_sheets = _count(c.repeat_m, p.get("sheet_m", 1.0))
    n_ribs = n_sheets * _count(c.repeat_m / n_sheets, p["pitch_m"])
    pitch = c.repeat_m / n_ribs
    t = c.u * n_ribs
    dt = c.pixel_m / pitch
    # Slope averaged over the pixel footprint: exact box-filtered shading.
    slope = (_profile_height(p["profile"], t + 0.5 * dt) - _profile_height(p["profile"], t - 0.5 * dt)) / dt
    hx = slope * p["depth_m"] / pitch
    shade = _lambert(hx, np.zeros_like(hx))
    height = _supersample(lambda tt: _profile_height(p["profile"], tt), t, dt)
    shade = shade * (1.0 + p.get("rib_light", 0.0) * height)
    if p.get("cast_m"):  # shadow of each rib on the pan beside it (down-light side)
        cast = p["cast_m"] / pitch
        rib = 0.055
        shade = shade * (1.0 - p.get("cast", 0.3) * _supersample(
            lambda tt: ((_frac(tt) > rib) & (_frac(tt) < rib + cast)).astype(np.float64), t, dt))
    sheet = np.floor(c.u * n_sheets).astype(np.int64) % n_sheets
    lengths = _count(c.repeat_m, p.get("sheet_len_m", c.repeat_m))
    sheet_row = np.floor(c.v * lengths + _rand(c.seed_for("sheet-offset"), sheet)).astype(np.int64) % lengths
    piece = sheet * lengths + sheet_row
    end_d = _pdist(c.v * lengths + _rand(c.seed_for("sheet-offset"), sheet)) * c.repeat_m / lengths
    end_line = _coverage(end_d, p.get("lap_m", 0.012), c.pixel_m)
    side_d = _pdist(c.u * n_sheets) * c.repeat_m / n_sheets
    side_line = _coverage(side_d, 0.012, c.pixel_m)
    paint = np.broadcast_to(_hex(p["colour"]), c.shape)
    if p.get("replaced"):
        spec = p["replaced"]
        other = _pick(spec["palette"], _rand(c.seed_for("replaced-colour"), piece))
        swap = _rand(c.seed_for("replaced"), piece) < spec["probability"]
        paint = np.where(swap[:, :, None], other, paint)
    tone = 1.0 + p.get("sheet_tone", 0.03) * (2.0 * _rand(c.seed_for("sheet-tone"), piece) - 1.0)
    rgb = _scale(paint, tone)
    if p.get("spangle"):
        mottle = c.fbm("spangle", 0.12, octaves=3)
        rgb = _scale(rgb, 1.0 + p["spangle"] * (2.0 * mottle - 1.0))
    if p.get("oilcan"):
        ripple = _fbm(c.u, c.v, n_ribs * 2, _count(c.repeat_m, 1.5), c.seed_for("oilcan"), 2)
        rgb = _scale(rgb, 1.0 + p["oilcan"] * (2.0 * ripple - 1.0))
    if p.get("rust"):
        spec = p["rust"]
        streak = c.fbm("rust-streak", 0.2, octaves=3, stretch=(1.0, 15.0))
        blotch = c.fbm("rust-blotch", 1.5, octaves=5)
        per_piece = _rand(c.seed_for("rust-piece"), piece) * spec.get("per_sheet", 0.0)
        level = 0.5 * blotch + 0.5 * streak + per_piece + spec.get("valleys", 0.1) * (1.0 - height)
        amount = _smoothstep(1.0 - spec["amount"], 1.0 - spec["amount"] + 0.35, level)
        rust = _ramp(spec["palette"], _smoothstep(0.25, 0.75, c.fbm("rust-colour", 0.5, octaves=4)))
        rgb = _mix(rgb, rust, amount)
    rgb = _scale(rgb, shade * (1.0 - 0.35 * end_line) * (1.0 - p.get("side_dark", 0.15) * side_line))
    rgb = _granules(c, rgb, p.get("granules", 0.02))
    rgb = _stains(c, rgb, p.get("stains"))
    rgb = _spots(c, rgb, p.get("spots"))
    return _weathering(c, rgb, p.get("weathering", 0.04), 3.0)


def _tiles(c: _Canvas, p: Mapping) -> np.ndarray:
    """Courses of overlapping units: clay and concrete tiles, shingles,
    slates, shakes, wood planks. Rows along x; the butt (lower) edge of each
    course overlaps the next course down (+y) and shadows it."""
    stagger = p.get("stagger", "half")
    profile = p.get("profile", "flat")
    rows = _count(c.repeat_m, p["course_m"], even=stagger == "half")
    cols = _count(c.repeat_m, p["width_m"], even=profile == "barrel")
    course_m = c.repeat_m / rows
    unit_m = c.repeat_m / cols
    y = c.v * rows
    r = np.floor(y).astype(np.int64) % rows
    fv = _frac(y)
    row_seed = c.seed_for("row-offset")
    col_seed = c.seed_for("columns")
    jitter = p.get("width_jitter", 0.0)

    def layout(rr):
        if stagger == "half":
            offset = 0.5 * (rr % 2)
        elif stagger == "random":
            offset = _rand(row_seed, rr)
        else:
            offset = 0.0
        return _row_cells(c.u * cols + offset, rr, cols, col_seed, jitter)

    col, fu, width = layout(r)
    cut = np.zeros_like(fu)
    if p.get("rag"):
        cut = cut + p["rag"] * _rand(c.seed_for("rag"), col, r)
    if profile == "round":
        t = 2.0 * fu - 1.0
        cut = cut + p.get("butt_depth", 0.3) * (1.0 - np.sqrt(np.maximum(0.0, 1.0 - t * t)))
    under = fv > 1.0 - cut
    below = (r + 1) % rows
    col2, fu2, width2 = layout(below)
    unit_col = np.where(under, col2, col)
    unit_row = np.where(under, below, r)
    fu = np.where(under, fu2, fu)
    width = np.where(under, width2, width)
    unit = unit_col * rows + unit_row

    colour = _pick(p["palette"], _rand(c.seed_for("unit-colour"), unit))
    shade = 1.0 + p.get("tone", 0.08) * (2.0 * _rand(c.seed_for("unit-tone"), unit) - 1.0)
    w_m = width * unit_m
    depth = p.get("relief_m", 0.0)
    if profile == "barrel":
        cap = (unit_col % 2) == 0
        amplitude = np.where(cap, 1.0, -0.5)
        hx = amplitude * 4.0 * (1.0 - 2.0 * fu) * depth / w_m
    elif profile == "double":
        t = _frac(fu * 2.0)
        hx = 0.5 * 8.0 * (1.0 - 2.0 * t) * depth / w_m
    elif profile == "wave":
        roll = np.clip((fu - 0.5) / 0.5, 0.0, 1.0)
        pan = np.clip(fu / 0.5, 0.0, 1.0)
        hx = np.where(fu >= 0.5, 4.0 * (1.0 - 2.0 * roll) / 0.5, -0.3 * 4.0 * (1.0 - 2.0 * pan) / 0.5) * depth / w_m
    else:
        hx = np.zeros_like(fu)
    shade = shade * np.clip(_lambert(hx, np.zeros_like(hx)), 0.3, 1.5)
    # Shadow of the course above along the top of each course; the part of
    # a lower unit that shows under a cut butt lies in that shadow too.
    shadow_frac = p.get("shadow_m", 0.03) / course_m
    shade = shade * (1.0 - p.get("shadow", 0.4) * (1.0 - _smoothstep(0.0, shadow_frac, fv)))
    shade = shade * np.where(under, 1.0 - p.get("under_dark", 0.45), 1.0)
    lip = p.get("lip", 0.0)
    if lip:
        lip_frac = p.get("lip_m", 0.02) / course_m
        near_butt = _smoothstep(1.0 - cut - lip_frac, 1.0 - cut, fv) * (1.0 - under)
        shade = shade * (1.0 + lip * near_butt)
    if p.get("laminate"):
        dark_tab = _rand(c.seed_for("laminate"), unit) < p["laminate"]
        band = fv < 0.25 + 0.35 * _rand(c.seed_for("laminate-depth"), unit)
        shade = shade * np.where(dark_tab & band & ~under, 0.62, 1.0)
    if p.get("grain"):
        along_y = p.get("grain_dir", "y") == "y"
        shift = _rand(c.seed_for("grain-shift"), unit)
        gu = c.u + (0.0 if along_y else shift)
        gv = c.v + (shift if along_y else 0.0)
        fine = _count(c.repeat_m, p.get("grain_m", 0.02))
        long = _count(c.repeat_m, p.get("grain_len_m", 0.6))
        px, py = (fine, long) if along_y else (long, fine)
        grain = _fbm(gu, gv, px, py, c.seed_for("grain"), 3)
        shade = shade * (1.0 + p["grain"] * (2.0 * grain - 1.0))
    rgb = _scale(colour, shade)
    gap = p.get("gap_m", 0.0)
    if gap:
        side = np.minimum(fu, 1.0 - fu) * w_m
        rgb = _mix(rgb, _scale(colour, p.get("gap_shade", 0.3)), _coverage(side, gap, c.pixel_m))
    if p.get("gloss"):
        glint = _smoothstep(0.75, 0.95, 1.0 - np.abs(fu - 0.35) * 4.0) * (1.0 - under)
        rgb = _mix(rgb, np.ones(3), glint * p["gloss"])
    rgb = _granules(c, rgb, p.get("granules", 0.05), p.get("flecks"), p.get("fleck_share", 0.0))
    rgb = _stains(c, rgb, p.get("stains"))
    rgb = _spots(c, rgb, p.get("spots"))
    return _weathering(c, rgb, p.get("weathering", 0.06), 3.0)


def _thatch(c: _Canvas, p: Mapping) -> np.ndarray:
    """Thatch: straw fibres down the slope in wavy courses."""
    rows = _count(c.repeat_m, p["course_m"])
    wave = _value_noise(c.u, c.v * 0.0, _count(c.repeat_m, 1.2), 1, c.seed_for("course-wave"))
    y = c.v * rows + 0.35 * (wave - 0.5)
    r = np.floor(y).astype(np.int64) % rows
    fv = _frac(y)
    shift = _rand(c.seed_for("course-shift"), r)
    fibre = _fbm(c.u + shift, c.v, _count(c.repeat_m, 0.03), _count(c.repeat_m, 0.5), c.seed_for("fibres"), 3)
    strands = _smoothstep(0.3, 0.7, fibre)
    rgb = _mix(_hex(p["dark"]), _hex(p["light"]), strands)
    shade = 1.0 - 0.45 * (1.0 - _smoothstep(0.0, 0.4, fv))
    rgb = _scale(rgb, shade * (1.0 + 0.12 * (2.0 * c.speckle("straw") - 1.0)))
    rgb = _stains(c, rgb, p.get("stains"))
    return _weathering(c, rgb, p.get("weathering", 0.1), 3.0)


def _vegetation(c: _Canvas, p: Mapping) -> np.ndarray:
    """Green roofs: plant rosettes whose species cluster in patches, bare
    substrate, and optional paver paths on a periodic grid."""
    n = _count(c.repeat_m, p["rosette_m"])
    cells = _worley(c.u, c.v, n, n, c.seed_for("rosettes"), jitter=0.95)
    species = (0.7 * c.fbm("species", p.get("patch_m", 1.5), octaves=3)
               + 0.3 * _rand(c.seed_for("rosette-pick"), cells.cell))
    species = _smoothstep(0.3, 0.7, species) * 0.999
    colour = _pick(p["palette"], species)
    radius = 0.6 / n
    hx = -1.4 * cells.dx / radius
    hy = -1.4 * cells.dy / radius
    shade = np.clip(_lambert(hx, hy), 0.45, 1.3)
    shade = shade * (0.55 + 0.45 * _smoothstep(0.0, 0.25, (cells.f2 - cells.f1) * n))
    rgb = _scale(colour, shade * (1.0 + 0.1 * (2.0 * c.speckle("leaves") - 1.0)))
    if p.get("bare"):
        bare = _smoothstep(1.0 - p["bare"], 1.0 - p["bare"] + 0.08, 1.0 - c.fbm("bare", 1.2, octaves=5))
        soil = _scale(np.broadcast_to(_hex(p["substrate"]), rgb.shape), 1.0 + 0.3 * (2.0 * c.speckle("soil") - 1.0))
        rgb = _mix(rgb, soil, bare)
    if p.get("paths"):
        spec = p["paths"]
        g = _count(c.repeat_m, spec["spacing_m"])
        dist = np.minimum(_pdist(c.u * g - 0.5), _pdist(c.v * g - 0.5)) * c.repeat_m / g
        path = _coverage(dist, spec["width_m"], c.pixel_m)
        slab = _count(c.repeat_m, spec["width_m"] / 2.0)
        joints = np.minimum(_pdist(c.u * slab), _pdist(c.v * slab)) * c.repeat_m / slab
        stone = _scale(np.broadcast_to(_hex(spec["colour"]), rgb.shape),
                       1.0 - 0.35 * _coverage(joints, 0.015, c.pixel_m))
        stone = _scale(stone, 1.0 + 0.06 * (2.0 * c.speckle("path") - 1.0))
        edge = _coverage(np.abs(dist - 0.5 * spec["width_m"]), 0.04, c.pixel_m)
        rgb = _mix(_scale(rgb, 1.0 - 0.35 * edge), stone, path)
    return _weathering(c, rgb, p.get("weathering", 0.08), 2.5)


def _coating(c: _Canvas, p: Mapping) -> np.ndarray:
    """Painted/elastomeric coating over concrete: roller strokes, peeling to
    the grey substrate, hairline cracks."""
    strokes = _fbm(c.u, c.v, 2, _count(c.repeat_m, 0.3), c.seed_for("roller"), 2)
    rgb = _scale(np.broadcast_to(_hex(p["colour"]), c.shape), 1.0 + p.get("roller", 0.05) * (2.0 * strokes - 1.0))
    peel = _smoothstep(1.0 - p.get("peel", 0.1), 1.0 - p.get("peel", 0.1) + 0.03, c.fbm("peel", 1.2, octaves=6))
    base = _scale(np.broadcast_to(_hex(p["substrate"]), rgb.shape), 1.0 + 0.15 * (2.0 * c.speckle("concrete") - 1.0))
    rgb = _mix(rgb, base, peel)
    if p.get("cracks"):
        n = _count(c.repeat_m, p["cracks"])
        cells = _worley(c.u, c.v, n, n, c.seed_for("cracks"))
        rgb = _scale(rgb, 1.0 - 0.4 * _coverage((cells.f2 - cells.f1) * 0.5 * c.repeat_m, 0.008, c.pixel_m))
    rgb = _granules(c, rgb, p.get("granules", 0.04))
    rgb = _stains(c, rgb, p.get("stains"))
    return _weathering(c, rgb, p.get("weathering", 0.08), 4.0)


def _equipment(c: _Canvas, p: Mapping) -> np.ndarray:
    """A base roof with rooftop objects on a periodic grid (skylights, HVAC
    units, solar panel rows) and their shadows."""
    rgb = _FAMILIES[p["base"]](c, p["base_params"])
    return _OVERLAYS[p["overlay"]](c, rgb, p)


def _grid_cell(c: _Canvas, spacing_m: float):
    g = _count(c.repeat_m, spacing_m)
    cell_m = c.repeat_m / g
    a = np.floor(c.u * g).astype(np.int64) % g
    b = np.floor(c.v * g).astype(np.int64) % g
    return a, b, _frac(c.u * g) * cell_m, _frac(c.v * g) * cell_m, cell_m


def _shadowed(c, rgb, dx, dy, hw, hh, offset_m, strength):
    shadow = _box(dx - offset_m, dy - offset_m, hw, hh, c.pixel_m)
    return _scale(rgb, 1.0 - strength * shadow)


def _skylights(c: _Canvas, rgb: np.ndarray, p: Mapping) -> np.ndarray:
    _, _, lx, ly, cell_m = _grid_cell(c, p["spacing_m"])
    hw, hh = 0.5 * p["size_m"][0], 0.5 * p["size_m"][1]
    dx = lx - 0.5 * cell_m
    dy = ly - 0.5 * cell_m
    rgb = _shadowed(c, rgb, dx, dy, hw, hh, 0.18, 0.45)
    frame = _box(dx, dy, hw, hh, c.pixel_m)
    glass = _box(dx, dy, hw - 0.08, hh - 0.08, c.pixel_m)
    highlight = _smoothstep(0.0, 1.0, 1.0 - (dx / hw + dy / hh + 2.0) * 0.25)
    pane = _mix(_hex(p["glass"]), _hex(p["glass_light"]), highlight)
    rgb = _mix(rgb, np.broadcast_to(_hex(p["frame"]), rgb.shape), frame)
    return _mix(rgb, pane, glass)


def _hvac(c: _Canvas, rgb: np.ndarray, p: Mapping) -> np.ndarray:
    a, b, lx, ly, cell_m = _grid_cell(c, p["spacing_m"])
    seed = c.seed_for("units")
    present = _rand(seed, a, b, 0) < p.get("probability", 0.8)
    hw, hh = 0.5 * p["size_m"][0], 0.5 * p["size_m"][1]
    margin = 0.5 * cell_m - max(hw, hh) - 0.4
    dx = lx - 0.5 * cell_m - margin * (2.0 * _rand(seed, a, b, 1) - 1.0)
    dy = ly - 0.5 * cell_m - margin * (2.0 * _rand(seed, a, b, 2) - 1.0)
    rgb = _scale(rgb, 1.0 - 0.5 * present * _box(dx - 0.35, dy - 0.35, hw, hh, c.pixel_m))
    body = _box(dx, dy, hw, hh, c.pixel_m) * present
    lid = _box(dx, dy, hw - 0.05, hh - 0.05, c.pixel_m)
    casing = _scale(np.broadcast_to(_hex(p["casing"]), rgb.shape), 1.0 + 0.12 * lid)
    rgb = _mix(rgb, casing, body)
    fan_r = 0.8 * min(hw, hh * 0.5) if hw < hh else 0.8 * min(hh, hw * 0.5)
    along_x = hw >= hh
    for sign in (-1.0, 1.0):
        fx = dx - (sign * 0.5 * hw if along_x else 0.0)
        fy = dy - (0.0 if along_x else sign * 0.5 * hh)
        fan = _disc(fx, fy, fan_r, c.pixel_m) * present
        ring = _disc(fx, fy, fan_r * 0.35, c.pixel_m)
        grille = _mix(_hex(p["fan"]), _hex(p["casing"]), ring * 0.6)
        rgb = _mix(rgb, grille, fan)
    return rgb


def _solar(c: _Canvas, rgb: np.ndarray, p: Mapping) -> np.ndarray:
    rows = _count(c.repeat_m, p["row_m"])
    row_m = c.repeat_m / rows
    panel_h = p["panel_m"][1]
    fy = _frac(c.v * rows) * row_m
    cols = _count(c.repeat_m, p["panel_m"][0])
    panel_w = c.repeat_m / cols
    fx = _frac(c.u * cols) * panel_w
    dx = fx - 0.5 * panel_w
    dy = fy - 0.5 * panel_h - 0.1
    rgb = _scale(rgb, 1.0 - 0.55 * _box(dx, dy - 0.5, 0.5 * panel_w, 0.5 * panel_h, c.pixel_m))
    panel = _box(dx, dy, 0.5 * panel_w - 0.015, 0.5 * panel_h, c.pixel_m)
    cells_x = _pdist((fx / panel_w) * 6.0) * panel_w / 6.0
    cells_y = _pdist((dy / panel_h + 0.5) * 10.0) * panel_h / 10.0
    cell_lines = np.maximum(_coverage(cells_x, 0.006, c.pixel_m), _coverage(cells_y, 0.006, c.pixel_m))
    sheen = _smoothstep(-0.6, 0.6, -dy / panel_h - dx / panel_w)
    glass = _mix(_hex(p["cell"]), _hex(p["cell_light"]), sheen * 0.6)
    glass = _mix(glass, _hex(p["frame"]), cell_lines * 0.5)
    frame = panel - _box(dx, dy, 0.5 * panel_w - 0.04, 0.5 * panel_h - 0.03, c.pixel_m)
    glass = _mix(glass, _hex(p["frame"]), np.clip(frame, 0.0, 1.0))
    return _mix(rgb, glass, panel)


_FAMILIES: dict[str, Callable[[_Canvas, Mapping], np.ndarray]] = {
    "gravel": _gravel,
    "sheet": _sheet,
    "tar": _tar,
    "pavers": _pavers,
    "profiled": _profiled,
    "tiles": _tiles,
    "thatch": _thatch,
    "vegetation": _vegetation,
    "coating": _coating,
    "equipment": _equipment,
}
_OVERLAYS = {"skylights": _skylights, "hvac": _hvac, "solar": _solar}


# --- recipes --------------------------------------------------------------


@dataclass(frozen=True)
class Recipe:
    """One procedural texture: what it is and how to draw it."""

    id: str
    name: str
    kind: str
    repeat_m: float
    family: str
    params: Mapping[str, Any] = field(default_factory=dict)

    @property
    def seed(self) -> int:
        return zlib.crc32(self.id.encode("ascii"))

    @property
    def source(self) -> str:
        return f"procedural:{self.id}@v{RECIPE_VERSION}"


def generate(recipe: Recipe, size: int = 256) -> np.ndarray:
    """Render a recipe to a ``size x size`` uint8 RGB array (tileable)."""
    return _render(recipe, size, span=1)


def _render(recipe: Recipe, size: int, span: int) -> np.ndarray:
    """Evaluate ``span x span`` repeats at ``size`` pixels per repeat."""
    if size < 8:
        raise ValueError(f"texture size must be at least 8 pixels, got {size}")
    canvas = _Canvas(size, recipe.repeat_m, recipe.seed, span)
    rgb = np.broadcast_to(_FAMILIES[recipe.family](canvas, recipe.params), canvas.shape)
    return np.floor(np.clip(rgb, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)


def _p(*colours) -> tuple:
    """Palette: hex strings, optionally ``(hex, weight)``; weight 1 by default."""
    return tuple((c, 1.0) if isinstance(c, str) else (c[0], float(c[1])) for c in colours)


def _flat(id_, name, repeat_m, family, **params) -> Recipe:
    return Recipe(f"flat-{id_}", name, "flat", repeat_m, family, params)


def _sloped(id_, name, repeat_m, family, **params) -> Recipe:
    return Recipe(f"sloped-{id_}", name, "sloped", repeat_m, family, params)


# Shared recipe parts (one definition each, varied per recipe).
def _membrane(colour, sheet_m=3.0, **extra):
    params = dict(colour=colour, sheet_m=sheet_m, lap_m=0.1, lap_tone=0.035, edge_dark=0.25,
                  mottle=0.03, end_laps=1)
    params.update(extra)
    return params


def _cap_sheet(colour, flecks, **extra):
    params = dict(colour=colour, sheet_m=1.0, lap_m=0.08, lap_tone=-0.08, edge_m=0.012, edge_dark=0.55,
                  granules=0.16, flecks=flecks, fleck_share=0.12, mottle=0.05, horizontal=True, end_laps=1)
    params.update(extra)
    return params


def _three_tab(palette, flecks, **extra):
    params = dict(course_m=0.143, width_m=0.333, stagger="half", gap_m=0.014, gap_shade=0.2, shadow=0.55,
                  shadow_m=0.018, palette=palette, tone=0.05, granules=0.15, flecks=flecks, fleck_share=0.07,
                  weathering=0.06)
    params.update(extra)
    return params


def _architectural(palette, flecks, **extra):
    params = dict(course_m=0.143, width_m=0.25, stagger="random", width_jitter=0.35, gap_m=0.006,
                  gap_shade=0.35, shadow=0.55, shadow_m=0.02, laminate=0.55, palette=palette, tone=0.1,
                  granules=0.15, flecks=flecks, fleck_share=0.06, weathering=0.06)
    params.update(extra)
    return params


def _barrel(palette, **extra):
    params = dict(course_m=0.33, width_m=0.21, stagger="none", profile="barrel", relief_m=0.05,
                  shadow=0.6, shadow_m=0.07, lip=0.12, lip_m=0.03, palette=palette, tone=0.1,
                  granules=0.05, weathering=0.08)
    params.update(extra)
    return params


def _slate(palette, **extra):
    params = dict(course_m=0.23, width_m=0.3, stagger="half", rag=0.06, gap_m=0.01, gap_shade=0.25,
                  shadow=0.5, shadow_m=0.02, palette=palette, tone=0.1, grain=0.05, grain_dir="x",
                  grain_m=0.03, grain_len_m=0.3, granules=0.05, weathering=0.05)
    params.update(extra)
    return params


def _seam(colour, **extra):
    params = dict(profile="seam", pitch_m=0.45, depth_m=0.04, colour=colour, sheet_m=0.45,
                  sheet_len_m=24.0, lap_m=0.0, side_dark=0.0, oilcan=0.05, granules=0.015,
                  rib_light=0.5, cast_m=0.035, cast=0.35, weathering=0.04)
    params.update(extra)
    return params


def _corrugated(colour, **extra):
    params = dict(profile="corrugated", pitch_m=0.076, depth_m=0.02, colour=colour, sheet_m=0.8,
                  sheet_len_m=2.0, lap_m=0.015, side_dark=0.2, granules=0.03, weathering=0.06)
    params.update(extra)
    return params


def _deck(colour, **extra):
    params = dict(profile="trapezoid", pitch_m=0.3, depth_m=0.05, colour=colour, sheet_m=0.9,
                  sheet_len_m=3.0, lap_m=0.012, side_dark=0.2, granules=0.02, weathering=0.04)
    params.update(extra)
    return params


def _shakes(palette, **extra):
    params = dict(course_m=0.25, width_m=0.18, stagger="random", width_jitter=0.4, rag=0.08, gap_m=0.01,
                  gap_shade=0.25, shadow=0.55, shadow_m=0.03, palette=palette, tone=0.14, grain=0.2,
                  grain_dir="y", grain_m=0.012, grain_len_m=0.5, granules=0.06, weathering=0.08)
    params.update(extra)
    return params


_RUST = _p("#6b3519", "#8a4a24", "#a55e2e", "#b87a45")
_LIGHT_GRAVEL = _p(("#c4c2bc", 3), ("#a9a7a1", 3), ("#d8d6d0", 2), ("#8e8c87", 1))

FLAT_RECIPES: tuple[Recipe, ...] = (
    # Gravel ballast.
    _flat("gravel-light", "Light grey gravel ballast", 3.0, "gravel", palette=_LIGHT_GRAVEL, stone_m=0.035),
    _flat("gravel-dark", "Dark basalt gravel", 3.0, "gravel", stone_m=0.035,
          palette=_p(("#5d5e60", 3), ("#47484a", 3), ("#76777a", 2), ("#333436", 1))),
    _flat("gravel-river", "Tan river gravel", 3.0, "gravel", stone_m=0.045,
          palette=_p(("#b49a78", 3), ("#9a7f5f", 2), ("#cbb797", 2), ("#7d6a55", 1), ("#a8a39a", 1))),
    _flat("gravel-marble", "White marble chippings", 3.0, "gravel", stone_m=0.03, tone=0.08,
          palette=_p(("#eeeeeb", 4), ("#dcdcd8", 3), ("#f7f6f2", 2), ("#c9cbcc", 1))),
    _flat("gravel-lava", "Red lava rock", 3.0, "gravel", stone_m=0.04,
          palette=_p(("#8c3b2a", 3), ("#6e2c20", 2), ("#a5503a", 2), ("#4a2219", 1))),
    _flat("gravel-mixed", "Mixed pebbles with dirt", 3.0, "gravel", stone_m=0.05, weathering=0.16,
          palette=_p(("#9b9b96", 2), ("#b8a58a", 2), ("#6f6a63", 2), ("#d2cfc7", 1), ("#8a5f48", 1)),
          stains=dict(colour="#5f5446", amount=0.5, size_m=1.5, threshold=0.58)),
    # Single-ply membranes.
    _flat("membrane-white-tpo", "White TPO membrane", 12.0, "sheet",
          **_membrane("#e6e8e6", stains=dict(colour="#bdb6a4", amount=0.35, size_m=4.0),
                      patches=dict(probability=0.35, tone=-0.04, edge=0.15))),
    _flat("membrane-tan-pvc", "Tan PVC membrane", 12.0, "sheet",
          **_membrane("#c8b48f", sheet_m=2.0, stains=dict(colour="#a28e6c", amount=0.35, size_m=3.0))),
    _flat("membrane-grey-pvc", "Light grey PVC membrane", 12.0, "sheet",
          **_membrane("#a3a7aa", sheet_m=2.0, patches=dict(probability=0.5, tone=0.05, edge=0.2))),
    _flat("membrane-black-epdm", "Black EPDM membrane", 12.0, "sheet",
          **_membrane("#252627", lap_tone=0.25, edge_dark=0.2, mottle=0.06,
                      stains=dict(colour="#4a4b4c", amount=0.5, size_m=3.0))),
    _flat("membrane-grey-epdm", "Weathered grey EPDM", 12.0, "sheet",
          **_membrane("#55585a", lap_tone=0.15, mottle=0.07, stains=dict(colour="#77797b", amount=0.55, size_m=2.5),
                      patches=dict(probability=0.7, tone=-0.18, edge=0.3))),
    _flat("membrane-white-walkway", "Aged white membrane with walkway pads", 12.0, "sheet",
          **_membrane("#d1d2cc", stains=dict(colour="#9f998a", amount=0.6, size_m=2.0, threshold=0.5),
                      walkway=dict(colour="#7d8082", y=0.3), weathering=0.05)),
    # Granulated cap sheets (modified bitumen), rolls 1 m wide.
    _flat("capsheet-white", "White granulated cap sheet", 8.0, "sheet",
          **_cap_sheet("#cfcdc5", _p("#f2f1ec", "#9f9d97", "#b9b4a6"))),
    _flat("capsheet-grey", "Grey granulated cap sheet", 8.0, "sheet",
          **_cap_sheet("#8d8e8b", _p("#c5c6c3", "#5a5b59", "#a9a295"))),
    _flat("capsheet-green", "Green mineral cap sheet", 8.0, "sheet",
          **_cap_sheet("#6f8066", _p("#9fae93", "#4c5a45", "#8a8f78"))),
    # Bitumen.
    _flat("tar-patched", "Patched tar roof", 8.0, "tar", colour="#2b2b2c", aged="#3e3d3b", fresh=0.5,
          patches=dict(probability=0.6, tone=-0.3, edge=0.3, cell_m=2.5)),
    _flat("tar-gravel", "Tar and gravel (built-up roof)", 4.0, "tar", colour="#242424", aged="#343331",
          gravel=dict(stone_m=0.022, density=0.45, palette=_p("#b3ab9c", "#8e877b", "#cdc6b8", "#6f6a61"))),
    _flat("bitumen-cracked", "Cracked aged bitumen", 8.0, "tar", colour="#3c3936", aged="#5a544c",
          cracks=0.25, fresh=0.3, granules=0.1),
    # Concrete and brick pavers.
    _flat("pavers-grey-60", "Grey concrete pavers 60 cm", 6.0, "pavers", size_m=(0.6, 0.6), joint_m=0.012,
          joint_colour="#55544f", palette=_p("#a09f9b", "#a8a7a2", "#979691"), tone=0.05, bevel=0.1,
          stains=dict(colour="#77756e", amount=0.4, size_m=2.0)),
    _flat("pavers-buff-50", "Buff concrete pavers 50 cm", 6.0, "pavers", size_m=(0.5, 0.5), joint_m=0.01,
          joint_colour="#86796a", palette=_p("#cdbb9b", "#c2b091", "#d6c6a8"), tone=0.05, bevel=0.1),
    _flat("pavers-brick", "Red brick pavers, running bond", 6.0, "pavers", layout="running", size_m=(0.2, 0.1),
          joint_m=0.01, joint_colour="#8d877c",
          palette=_p("#9c4a34", "#8a3f2c", "#a8563c", ("#74382a", 0.5)), tone=0.1, bevel=0.15),
    _flat("concrete-slab", "Poured concrete with control joints", 8.0, "pavers", size_m=(4.0, 4.0),
          joint_m=0.012, joint_colour="#6b6964", palette=_p("#b7b5ae", "#aeaca5"), tone=0.03, texture=0.08,
          cracks=1.0, stains=dict(colour="#8d8a82", amount=0.5, size_m=2.5), bevel=0.0),
    _flat("concrete-lichen", "Weathered concrete flags with lichen", 6.0, "pavers", size_m=(0.9, 0.9),
          joint_m=0.02, joint_colour="#3f3e3a", palette=_p("#7c7b76", "#85837d", "#72716c"), tone=0.08,
          texture=0.1, spots=dict(size_m=0.07, density=0.5, radius=0.4, palette=_p("#b5ad6f", "#3e453a", "#d2cfb8"))),
    # Trapezoidal metal deck.
    _flat("metal-deck-galvanised", "Galvanised metal deck", 6.0, "profiled", **_deck("#a7abae", spangle=0.05)),
    _flat("metal-deck-white", "White painted metal deck", 6.0, "profiled", **_deck("#dfe2e2")),
    _flat("metal-deck-blue", "Blue painted metal deck", 6.0, "profiled", **_deck("#3a6591")),
    _flat("metal-deck-rusty", "Rusty metal deck", 6.0, "profiled",
          **_deck("#9a9d9e", spangle=0.05, rust=dict(amount=0.6, palette=_RUST, valleys=0.3))),
    # Green roofs.
    _flat("green-sedum", "Sedum green roof", 6.0, "vegetation", rosette_m=0.06, patch_m=1.5,
          palette=_p("#4a6b2c", "#5b7f34", "#6f9440", "#8aa651"), bare=0.12, substrate="#6b5a47"),
    _flat("green-sedum-red", "Red and green sedum mat", 6.0, "vegetation", rosette_m=0.06, patch_m=1.2,
          palette=_p("#8a3f2e", "#a0533a", "#7a6a3a", "#6b7a34", "#4f6a30"), bare=0.08, substrate="#5e4d3c"),
    _flat("green-meadow-dry", "Dry extensive meadow roof", 6.0, "vegetation", rosette_m=0.08, patch_m=2.0,
          palette=_p("#6f7443", "#8a7d4c", "#a4945e", "#bcae7a"), bare=0.2, substrate="#7a6650"),
    _flat("green-lawn-paths", "Roof lawn with paver paths", 8.0, "vegetation", rosette_m=0.03, patch_m=2.5,
          palette=_p("#3f7526", "#4f8a2f", "#5d9a38"), paths=dict(spacing_m=8.0, width_m=1.2, colour="#c2bfb6")),
    # Rubber pavers.
    _flat("rubber-pavers-black", "Black rubber pavers", 5.0, "pavers", size_m=(0.5, 0.5), joint_m=0.014,
          joint_colour="#0e0e0f", palette=_p("#303032"), tone=0.04, granules=0.25, bevel=0.15,
          flecks=_p("#5a5a5c", "#1a1a1b"), fleck_share=0.2),
    _flat("rubber-pavers-red", "Red rubber pavers", 5.0, "pavers", size_m=(0.5, 0.5), joint_m=0.014,
          joint_colour="#2a100e", palette=_p("#7a2e26"), tone=0.04, granules=0.25, bevel=0.15,
          flecks=_p("#4a1a16", "#96463a"), fleck_share=0.2),
    _flat("rubber-pavers-green", "Green rubber pavers", 5.0, "pavers", size_m=(0.5, 0.5), joint_m=0.014,
          joint_colour="#141e14", palette=_p("#3c5a3a"), tone=0.04, granules=0.25, bevel=0.15,
          flecks=_p("#263a25", "#5a7a56"), fleck_share=0.2),
    # Roofs with equipment.
    _flat("skylights-white", "White membrane with skylights", 12.0, "equipment", overlay="skylights",
          base="sheet", base_params=_membrane("#dfe1df", sheet_m=3.0), spacing_m=4.0, size_m=(1.3, 2.5),
          frame="#b9bdbf", glass="#4d6272", glass_light="#8ea6b5"),
    _flat("hvac-grey", "Grey membrane with HVAC units", 12.0, "equipment", overlay="hvac",
          base="sheet", base_params=_membrane("#8f9396", sheet_m=2.0, stains=dict(colour="#6e7174", amount=0.4)),
          spacing_m=4.0, size_m=(2.0, 1.2), casing="#c9cbcb", fan="#2c2e30", probability=0.75),
    _flat("solar-gravel", "Solar panel rows on gravel", 8.0, "equipment", overlay="solar",
          base="gravel", base_params=dict(palette=_LIGHT_GRAVEL, stone_m=0.06), row_m=2.0, panel_m=(1.0, 1.1),
          cell="#1b2540", cell_light="#3a4d78", frame="#aeb4ba"),
    # Other finishes.
    _flat("wood-deck", "Wooden roof deck", 6.0, "tiles", course_m=0.145, width_m=2.0, stagger="random",
          width_jitter=0.3, gap_m=0.008, gap_shade=0.25, shadow=0.0,
          palette=_p("#8a5a3a", "#7a4e31", "#966644", "#6e4630"),
          tone=0.1, grain=0.25, grain_dir="x", grain_m=0.01, grain_len_m=0.8, granules=0.04),
    _flat("terrace-terracotta", "Terracotta terrace tiles", 6.0, "pavers", size_m=(0.3, 0.3), joint_m=0.012,
          joint_colour="#c9c2b6", palette=_p("#b5603b", "#a8573a", "#c26d45", "#9c4e33"), tone=0.07, bevel=0.08,
          texture=0.06),
    _flat("coating-red", "Red painted concrete roof", 8.0, "coating", colour="#8e3a2e", substrate="#9a9a96",
          peel=0.12, cracks=0.6, stains=dict(colour="#5e3a33", amount=0.35, size_m=3.0)),
)

SLOPED_RECIPES: tuple[Recipe, ...] = (
    # Clay barrel tiles.
    _sloped("clay-terracotta", "Terracotta barrel tiles", 6.0, "tiles",
            **_barrel(_p(("#b8613a", 3), ("#a95634", 2), ("#c4704a", 2), ("#9a4b2e", 1)))),
    _sloped("clay-red", "Red clay barrel tiles", 6.0, "tiles",
            **_barrel(_p("#a0372a", "#8f3024", "#b04434", ("#7e2a20", 0.5)))),
    _sloped("clay-brown", "Brown clay barrel tiles", 6.0, "tiles",
            **_barrel(_p("#6e4431", "#5e3a2a", "#7d5039", "#4f3124"))),
    _sloped("clay-blend", "Blended orange clay tiles", 6.0, "tiles",
            **_barrel(_p("#c98048", "#b55a36", "#d49a5e", "#8f4a30", "#a8663c"), tone=0.06)),
    _sloped("clay-glazed-green", "Glazed green clay tiles", 6.0, "tiles",
            **_barrel(_p("#2f5e3c", "#2a5436", "#3a6b46"), gloss=0.35, tone=0.05)),
    _sloped("clay-aged", "Aged clay tiles with lichen", 6.0, "tiles",
            **_barrel(_p("#9a6650", "#8a5a46", "#a87260"), weathering=0.12,
                      spots=dict(size_m=0.1, density=0.3, radius=0.45,
                                 palette=_p(("#2e2a26", 2), "#4d4a3a", "#c9c08a")),
                      stains=dict(colour="#4a4038", amount=0.45, size_m=2.0))),
    # Interlocking concrete and flat clay tiles.
    _sloped("concrete-tile-grey", "Grey concrete double-roman tiles", 6.0, "tiles", course_m=0.34, width_m=0.3,
            stagger="none", profile="double", relief_m=0.035, shadow=0.5, shadow_m=0.04, lip=0.1,
            palette=_p("#7f8082", "#8a8b8d", "#747577"), tone=0.04, granules=0.06),
    _sloped("concrete-tile-charcoal", "Charcoal concrete pantiles", 6.0, "tiles", course_m=0.34, width_m=0.3,
            stagger="none", profile="wave", relief_m=0.03, shadow=0.55, shadow_m=0.04, lip=0.1,
            palette=_p("#3c3d40", "#444548", "#35363a"), tone=0.05, granules=0.06),
    _sloped("concrete-tile-brown", "Brown concrete pantiles", 6.0, "tiles", course_m=0.34, width_m=0.3,
            stagger="none", profile="wave", relief_m=0.03, shadow=0.55, shadow_m=0.04, lip=0.1,
            palette=_p("#6a4a3a", "#5c4133", "#775342"), tone=0.05, granules=0.06),
    _sloped("clay-beavertail", "Beaver-tail plain clay tiles", 5.0, "tiles", course_m=0.16, width_m=0.18,
            stagger="half", profile="round", butt_depth=0.35, shadow=0.45, shadow_m=0.015,
            palette=_p("#a24a32", "#b2563a", "#8f4029", "#c0664a"), tone=0.1, granules=0.06, under_dark=0.5),
    # Asphalt shingles.
    _sloped("shingle-black", "Black 3-tab asphalt shingles", 5.0, "tiles",
            **_three_tab(_p("#242526", "#2c2d2f"), _p("#515355", "#121213"))),
    _sloped("shingle-charcoal", "Charcoal architectural shingles", 5.0, "tiles",
            **_architectural(_p("#44464a", "#4d4f53", "#3b3d40"), _p("#707276", "#1e1f21"))),
    _sloped("shingle-grey", "Weathered grey 3-tab shingles", 5.0, "tiles",
            **_three_tab(_p("#7b7d7f", "#86888a", "#6f7173"), _p("#a5a7a9", "#4c4e50"))),
    _sloped("shingle-brown", "Brown architectural shingles", 5.0, "tiles",
            **_architectural(_p("#5a4030", "#6a4c38", "#4d3628", "#7a5a42"), _p("#8d735a", "#2f2219"))),
    _sloped("shingle-green", "Green 3-tab shingles", 5.0, "tiles",
            **_three_tab(_p("#3f5b3e", "#476648", "#385238"), _p("#6b8269", "#222f22"))),
    _sloped("shingle-blue", "Blue 3-tab shingles", 5.0, "tiles",
            **_three_tab(_p("#3d5570", "#465f7a", "#35495f"), _p("#6c8099", "#1e2835"))),
    _sloped("shingle-red", "Red architectural shingles", 5.0, "tiles",
            **_architectural(_p("#7a3029", "#8a3a30", "#6b2a24"), _p("#a0584c", "#3a1714"))),
    _sloped("shingle-tan", "Desert tan 3-tab shingles", 5.0, "tiles",
            **_three_tab(_p("#a89478", "#b39f83", "#9c886e"), _p("#cdbb9f", "#6f604c"))),
    _sloped("shingle-white", "White 3-tab shingles", 5.0, "tiles",
            **_three_tab(_p("#c9c9c4", "#d4d4cf", "#bdbdb8"), _p("#efefea", "#8d8d88"), shadow=0.45)),
    # Slate.
    _sloped("slate-grey", "Grey slate", 6.0, "tiles", **_slate(_p("#5f6366", "#686c70", "#565a5d", "#72767a"))),
    _sloped("slate-dark", "Dark blue-black slate", 6.0, "tiles",
            **_slate(_p("#2e3136", "#33373c", "#292c30", "#3a3e44"))),
    _sloped("slate-purple", "Purple Welsh slate", 6.0, "tiles",
            **_slate(_p("#4d4250", "#574a5a", "#453b48", "#5f5262"))),
    _sloped("slate-green", "Green-grey slate", 6.0, "tiles", **_slate(_p("#5b6a5c", "#647363", "#526052", "#6d7a6a"))),
    # Standing-seam metal.
    _sloped("seam-red", "Red standing-seam metal", 8.0, "profiled", **_seam("#8e2a22")),
    _sloped("seam-green", "Green standing-seam metal", 8.0, "profiled", **_seam("#2f4f3a")),
    _sloped("seam-blue", "Blue standing-seam metal", 8.0, "profiled", **_seam("#2e4f78")),
    _sloped("seam-grey", "Grey standing-seam metal", 8.0, "profiled", **_seam("#7d8286")),
    _sloped("seam-white", "White standing-seam metal", 8.0, "profiled", **_seam("#d9dcdc")),
    _sloped("seam-copper-patina", "Patinated copper standing seam", 8.0, "profiled",
            **_seam("#5e9c86", oilcan=0.08, stains=dict(colour="#6c5a3c", amount=0.6, size_m=2.0, threshold=0.6))),
    _sloped("seam-bronze", "Bronze standing-seam metal", 8.0, "profiled", **_seam("#4a3a2c")),
    _sloped("seam-black", "Black standing-seam metal", 8.0, "profiled", **_seam("#1f2022")),
    # Wood shakes.
    _sloped("shakes-silver", "Silver-weathered wood shakes", 5.0, "tiles",
            **_shakes(_p("#8a8882", "#7d7b75", "#97948d"))),
    _sloped("shakes-cedar", "Cedar wood shakes", 5.0, "tiles", **_shakes(_p("#8b5e3c", "#7a5034", "#9b6b46"))),
    _sloped("shakes-mossy", "Dark mossy wood shakes", 5.0, "tiles",
            **_shakes(_p("#4d4338", "#574c3f", "#433a30"), stains=dict(colour="#4a5a2a", amount=0.6, size_m=1.5))),
    # Corrugated iron.
    _sloped("corrugated-rusty", "Rusty corrugated iron", 4.0, "profiled",
            **_corrugated("#9ea2a4", spangle=0.05, rust=dict(amount=0.75, palette=_RUST, per_sheet=0.2))),
    _sloped("corrugated-red", "Maroon painted corrugated iron", 4.0, "profiled",
            **_corrugated("#7d2420", rust=dict(amount=0.12, palette=_RUST))),
    _sloped("corrugated-green", "Green painted corrugated iron", 4.0, "profiled",
            **_corrugated("#3b6a45", rust=dict(amount=0.1, palette=_RUST))),
    _sloped("corrugated-blue", "Blue painted corrugated iron", 4.0, "profiled",
            **_corrugated("#2f5d8c", rust=dict(amount=0.1, palette=_RUST))),
    _sloped("corrugated-galvanised", "Galvanised corrugated iron", 4.0, "profiled",
            **_corrugated("#b4b8ba", spangle=0.06, rust=dict(amount=0.06, palette=_RUST))),
    _sloped("corrugated-patchwork", "Patchwork of old and new iron sheets", 4.0, "profiled",
            **_corrugated("#a9adaf", spangle=0.05,
                          replaced=dict(probability=0.45, palette=_p("#8a4a24", "#6b3519", "#7d2420", "#c4c8ca")),
                          rust=dict(amount=0.35, palette=_RUST, per_sheet=0.3))),
    # Others.
    _sloped("thatch-golden", "Golden straw thatch", 6.0, "thatch", course_m=0.4, light="#c9ab6e", dark="#7d6338"),
    _sloped("thatch-aged", "Aged grey thatch", 6.0, "thatch", course_m=0.4, light="#8a8070", dark="#3f382e",
            stains=dict(colour="#4b5532", amount=0.5, size_m=1.5)),
    _sloped("fibre-cement", "Fibre-cement corrugated sheets", 6.0, "profiled", profile="corrugated", pitch_m=0.146,
            depth_m=0.05, colour="#a3a29c", sheet_m=1.0, sheet_len_m=2.5, lap_m=0.02, side_dark=0.2, granules=0.05,
            spots=dict(size_m=0.2, density=0.15, radius=0.4, palette=_p(("#3e3f36", 3), "#d8b25a", "#c9c4a2")),
            stains=dict(colour="#6f6d63", amount=0.45, size_m=2.0)),
    _sloped("metal-tile-maroon", "Stone-coated metal tile, maroon", 6.0, "tiles", course_m=0.37, width_m=0.2,
            stagger="none", profile="wave", relief_m=0.035, shadow=0.6, shadow_m=0.05, lip=0.15,
            palette=_p("#5a2226", "#62272b"), tone=0.03, granules=0.2, flecks=_p("#7a3a3e", "#2a1012"),
            fleck_share=0.2),
)

HELDOUT_FLAT_RECIPES: tuple[Recipe, ...] = (
    _flat("pavers-hex-sand", "Sand hexagonal pavers", 6.0, "pavers", layout="hex", size_m=(0.35, 0.35),
          joint_m=0.012, joint_colour="#7a6c58", palette=_p("#c2ad8a", "#b8a27f", "#cbb896"), tone=0.06, bevel=0.1),
    _flat("brick-basketweave", "Brick pavers, basket weave", 6.0, "pavers", layout="basket", size_m=(0.24, 0.12),
          joint_m=0.01, joint_colour="#6d6259", palette=_p("#a85a3e", "#8a4530", "#b86a48"), tone=0.1, bevel=0.12),
    _flat("gravel-crushed-brick", "Crushed brick gravel", 3.0, "gravel", stone_m=0.04,
          palette=_p(("#b86a45", 3), ("#c47c55", 2), ("#9a5236", 2), ("#d49a72", 1))),
    _flat("membrane-light-blue", "Light blue PVC membrane", 12.0, "sheet",
          **_membrane("#9fb8c8", sheet_m=2.0, stains=dict(colour="#8a9aa2", amount=0.3, size_m=3.0))),
    _flat("metal-deck-green", "Green painted metal deck", 6.0, "profiled", **_deck("#4f7a55")),
    _flat("green-sedum-flowering", "Flowering yellow sedum", 6.0, "vegetation", rosette_m=0.05, patch_m=1.0,
          palette=_p("#c8b840", "#a7a33a", "#6f8a35", "#d8c850"), bare=0.05, substrate="#6b5a47"),
    _flat("coating-aluminium", "Aluminium roof coating", 8.0, "coating", colour="#c4c6c8", substrate="#3a3836",
          peel=0.08, roller=0.08, stains=dict(colour="#8c8e90", amount=0.4, size_m=2.5)),
    _flat("pavers-checker", "Checkerboard concrete pavers", 6.0, "pavers", size_m=(0.5, 0.5), joint_m=0.01,
          joint_colour="#4a4946", palette=_p("#d0cec8"), checker=_p("#6e6d69"), tone=0.04, bevel=0.08),
    _flat("capsheet-tan", "Tan granulated cap sheet", 8.0, "sheet",
          **_cap_sheet("#b7a582", _p("#d8ccb0", "#857659", "#a09a8a"))),
    _flat("solar-membrane", "Solar panels on white membrane", 12.0, "equipment", overlay="solar",
          base="sheet", base_params=_membrane("#e2e3e0"), row_m=2.5, panel_m=(1.7, 1.0),
          cell="#222a33", cell_light="#4a5866", frame="#c7cbce"),
)

HELDOUT_SLOPED_RECIPES: tuple[Recipe, ...] = (
    _sloped("slate-fishscale", "Blue-grey fish-scale slate", 5.0, "tiles", course_m=0.15, width_m=0.2,
            stagger="half", profile="round", butt_depth=0.55, shadow=0.4, shadow_m=0.015, gap_m=0.0,
            palette=_p("#5a6470", "#646e7a", "#505a66"), tone=0.08, granules=0.05, under_dark=0.55),
    _sloped("clay-ochre", "Ochre clay barrel tiles", 6.0, "tiles",
            **_barrel(_p("#c9a04f", "#b88e44", "#d6b062", "#a87c3c"))),
    _sloped("clay-glazed-blue", "Glazed blue clay tiles", 6.0, "tiles",
            **_barrel(_p("#2d4f8a", "#284680", "#355a96"), gloss=0.35, tone=0.05)),
    _sloped("shingle-plum", "Plum architectural shingles", 5.0, "tiles",
            **_architectural(_p("#5a4466", "#664e72", "#4e3a5a"), _p("#8a7494", "#2a1e30"))),
    _sloped("seam-terracotta", "Terracotta standing-seam metal", 8.0, "profiled", **_seam("#a4553a")),
    _sloped("seam-copper-new", "New copper standing seam", 8.0, "profiled",
            **_seam("#b06a3d", oilcan=0.1, spangle=0.06)),
    _sloped("corrugated-turquoise", "Turquoise painted corrugated iron", 4.0, "profiled",
            **_corrugated("#3a8a8c", rust=dict(amount=0.1, palette=_RUST))),
    _sloped("thatch-reed-dark", "Dark water-reed thatch with moss", 6.0, "thatch", course_m=0.3,
            light="#7a6a48", dark="#2e281e", stains=dict(colour="#3f5a2a", amount=0.6, size_m=1.2, threshold=0.5)),
    _sloped("shakes-fresh", "Fresh orange cedar shingles", 5.0, "tiles",
            **_shakes(_p("#c08a55", "#b07a48", "#cc9a62"), tone=0.1, rag=0.0, stagger="half", width_jitter=0.3)),
    _sloped("solar-tiles", "Black solar roof tiles", 5.0, "tiles", course_m=0.35, width_m=0.4, stagger="half",
            gap_m=0.01, gap_shade=0.5, shadow=0.4, shadow_m=0.02, lip=0.3, lip_m=0.01,
            palette=_p("#16181d", "#1b1e24"), tone=0.05, granules=0.03, gloss=0.08),
)


# The second held-out set: E2's test textures (meta_sim/experiments/splits.py), never looked at to choose
# anything. Its colours are those neither the bank nor the first held-out set has (lime, yellow, orange,
# pink, lavender, cobalt, sky blue, teal, cream), on the same families, each with enough grey or shadow
# that the HSV similarity still ranks the bank's textures for it: every one shares colours with at least
# ten bank textures of its kind, and none is as close to a bank or first held-out texture as a typical
# bank texture is to its nearest neighbour (tests/sim/textures_test.py measures both).
HELDOUT_V2_FLAT_RECIPES: tuple[Recipe, ...] = (
    _flat("deck-lime", "Lime-green painted metal deck", 6.0, "profiled", **_deck("#8ab83a")),
    _flat("deck-yellow", "Yellow painted metal deck", 6.0, "profiled", **_deck("#c8a830")),
    _flat("turf-artificial", "Artificial turf", 4.0, "vegetation", rosette_m=0.02, patch_m=2.0,
          palette=_p("#8ac040", "#7ab030", "#9ad050"), bare=0.0, substrate="#3a3a30"),
    _flat("gravel-blue-glass", "Blue glass gravel", 3.0, "gravel", stone_m=0.03,
          palette=_p(("#3a7ac0", 3), ("#2a5aa0", 2), ("#5a9ad8", 2))),
    _flat("coating-cream", "Cream roof coating", 8.0, "coating", colour="#f0e0a0", substrate="#6a6a66", peel=0.08),
    _flat("court-blue", "Blue sports-court coating", 10.0, "coating", colour="#3a62a8", substrate="#5a5a5a",
          peel=0.3, roller=0.04, cracks=0.6, stains=dict(colour="#606060", amount=0.6, size_m=2.0)),
    _flat("membrane-orange", "Safety-orange membrane", 12.0, "sheet",
          **_membrane("#d8692a", sheet_m=2.0, stains=dict(colour="#7a7070", amount=0.7, size_m=2.0, threshold=0.45),
                      patches=dict(probability=0.6, tone=-0.3, edge=0.3))),
    _flat("capsheet-red", "Bright red granulated cap sheet", 8.0, "sheet",
          **_cap_sheet("#b82a2a", _p("#d84a4a", "#7a1a1a", "#8a8a8a", "#5a5a5a"), fleck_share=0.25)),
    _flat("coating-yellow", "Yellow elastomeric coating", 8.0, "coating", colour="#d8b840", substrate="#707070",
          peel=0.35, cracks=0.8, stains=dict(colour="#808070", amount=0.6, size_m=2.0)),
    _flat("capsheet-purple", "Purple granulated cap sheet", 8.0, "sheet",
          **_cap_sheet("#7a5a8a", _p("#9a7aaa", "#4a3a5a", "#8a8a8a", "#5a5a5a"), fleck_share=0.3)),
    _flat("coating-teal", "Teal roof coating", 8.0, "coating", colour="#3a8a82", substrate="#707070", peel=0.35,
          stains=dict(colour="#606868", amount=0.6, size_m=2.0)),
)

HELDOUT_V2_SLOPED_RECIPES: tuple[Recipe, ...] = (
    _sloped("clay-glazed-yellow", "Glazed yellow clay tiles", 6.0, "tiles",
            **_barrel(_p("#e0b820", "#d0a818", "#e8c838"), gloss=0.3, tone=0.05)),
    _sloped("seam-sky", "Sky-blue standing-seam metal", 8.0, "profiled", **_seam("#6a9ac0")),
    _sloped("corrugated-orange", "Orange painted corrugated iron", 4.0, "profiled",
            **_corrugated("#e0782a", rust=dict(amount=0.08, palette=_RUST))),
    _sloped("clay-glazed-red", "Glazed bright red clay tiles", 6.0, "tiles",
            **_barrel(_p("#c81e1e", "#b81818", "#d82a2a"), gloss=0.3, tone=0.05)),
    _sloped("shingle-mustard", "Mustard 3-tab shingles", 5.0, "tiles",
            **_three_tab(_p("#b89a3a", "#c4a648", "#ac8e30"), _p("#d8c070", "#5a4a20"))),
    _sloped("corrugated-lime", "Lime painted corrugated iron", 4.0, "profiled",
            **_corrugated("#8ab040", rust=dict(amount=0.2, palette=_RUST))),
    _sloped("clay-glazed-cobalt", "Glazed cobalt clay tiles", 6.0, "tiles",
            **_barrel(_p("#2a40a8", "#3248b0", "#2238a0"), gloss=0.35, tone=0.05)),
    _sloped("shingle-lavender", "Lavender 3-tab shingles", 5.0, "tiles",
            **_three_tab(_p("#8a6ab0", "#9474ba", "#8060a6"), _p("#b09ad0", "#40304a"))),
    _sloped("corrugated-pink", "Pink painted corrugated iron", 4.0, "profiled",
            **_corrugated("#c07a8a", rust=dict(amount=0.4, palette=_RUST))),
    _sloped("shingle-coral", "Coral architectural shingles", 5.0, "tiles",
            **_architectural(_p("#d0607a", "#dc708a", "#c4506a"), _p("#8a8a8a", "#4a4a4a"), fleck_share=0.25,
                             stains=dict(colour="#606060", amount=0.5, size_m=1.5))),
    _sloped("shakes-painted-blue", "Blue-painted wood shakes", 5.0, "tiles",
            **_shakes(_p("#4a6ab0", "#5474ba", "#4060a6"))),
)

# The third held-out set: a check on textures no step of meta-sim looked at before it reported on them (made
# after `heldout-v2`'s figures had suggested a change to the search, docs/benchmarks.md). Colours none of the
# bank, `heldout-v1` or `heldout-v2` has (salmon, magenta, peach, mint, indigo, violet, apricot, emerald glass,
# cyan, lemon, sage), on the same families, under the same two conditions as `heldout-v2`, now against all
# three sets before it (tests/sim/textures_test.py).
_GREY_STAINS = dict(colour="#606060", amount=0.6, size_m=2.0)
HELDOUT_V3_FLAT_RECIPES: tuple[Recipe, ...] = (
    _flat("membrane-salmon", "Salmon PVC membrane", 12.0, "sheet",
          **_membrane("#d89080", sheet_m=2.0, stains=dict(colour="#7a7070", amount=0.6, size_m=2.0, threshold=0.45))),
    _flat("coating-magenta", "Magenta sports-court coating", 10.0, "coating", colour="#a03a7a", substrate="#5a5a5a",
          peel=0.3, roller=0.04, cracks=0.6, stains=_GREY_STAINS),
    _flat("coating-peach", "Peach elastomeric coating", 8.0, "coating", colour="#e8b890", substrate="#707070",
          peel=0.35, cracks=0.8, stains=dict(colour="#808070", amount=0.6, size_m=2.0)),
    _flat("coating-mint", "Mint roof coating", 8.0, "coating", colour="#9ad0b0", substrate="#6a6a66", peel=0.4,
          cracks=0.8, stains=dict(colour="#707a74", amount=0.7, size_m=2.0)),
    _flat("membrane-indigo", "Indigo PVC membrane", 12.0, "sheet",
          **_membrane("#4a4a9a", sheet_m=2.0, stains=dict(colour="#6a6a78", amount=0.7, size_m=2.0, threshold=0.45),
                      patches=dict(probability=0.6, tone=-0.3, edge=0.3))),
    _flat("deck-violet", "Violet painted metal deck", 6.0, "profiled", **_deck("#5a3a9a")),
    _flat("capsheet-apricot", "Apricot granulated cap sheet", 8.0, "sheet",
          **_cap_sheet("#e09050", _p("#f0b070", "#8a5a2a", "#8a8a8a", "#5a5a5a"), fleck_share=0.3)),
    _flat("gravel-emerald-glass", "Emerald glass gravel", 3.0, "gravel", stone_m=0.03,
          palette=_p(("#3a9a5a", 3), ("#2a7a4a", 2), ("#5ab87a", 2), ("#6a6a6a", 1))),
    _flat("deck-cyan", "Cyan painted metal deck", 6.0, "profiled", **_deck("#30a8d0")),
    _flat("membrane-lemon", "Lemon PVC membrane", 12.0, "sheet",
          **_membrane("#e8e070", sheet_m=2.0, stains=dict(colour="#7a7a70", amount=0.6, size_m=2.0, threshold=0.45))),
)

HELDOUT_V3_SLOPED_RECIPES: tuple[Recipe, ...] = (
    _sloped("clay-glazed-purple", "Glazed purple clay tiles", 6.0, "tiles",
            **_barrel(_p("#5a2a8a", "#522480", "#623294"), gloss=0.35, tone=0.05)),
    _sloped("corrugated-salmon", "Salmon painted corrugated iron", 4.0, "profiled",
            **_corrugated("#d88870", rust=dict(amount=0.25, palette=_RUST))),
    _sloped("shingle-peach", "Peach architectural shingles", 5.0, "tiles",
            **_architectural(_p("#e0a880", "#e8b48c", "#d49c74"), _p("#8a8a8a", "#4a4a4a"), fleck_share=0.25,
                             stains=dict(colour="#606060", amount=0.5, size_m=1.5))),
    _sloped("shingle-sage", "Sage 3-tab shingles", 5.0, "tiles",
            **_three_tab(_p("#8aa080", "#94aa8a", "#809676"), _p("#b0c0a0", "#3a4a34"))),
    _sloped("seam-violet", "Violet standing-seam metal", 8.0, "profiled", **_seam("#6a4aa0")),
    _sloped("seam-cyan", "Cyan standing-seam metal", 8.0, "profiled", **_seam("#30a0c8")),
    _sloped("clay-glazed-mint", "Glazed mint clay tiles", 6.0, "tiles",
            **_barrel(_p("#6ac0a0", "#60b696", "#74caaa"), gloss=0.3, tone=0.05)),
    _sloped("corrugated-cyan", "Cyan painted corrugated iron", 4.0, "profiled",
            **_corrugated("#30a0c8", rust=dict(amount=0.25, palette=_RUST))),
    _sloped("shingle-apricot", "Apricot 3-tab shingles", 5.0, "tiles",
            **_three_tab(_p("#e09050", "#e89a5a", "#d68646"), _p("#f0b070", "#5a3a1a"))),
    _sloped("clay-glazed-violet", "Glazed violet clay tiles", 6.0, "tiles",
            **_barrel(_p("#6a4aa0", "#64449a", "#7054a8"), gloss=0.3, tone=0.05)),
)

# The fourth held-out set: once E2's validation textures (meta_sim/experiments/splits.py). The
# first held-out set shares its colours with the bank, so a choice made on it never saw what the test and
# check splits show, a texture in a colour the bank lacks. This set is made under the same two conditions as
# `heldout-v2` and `heldout-v3`, now against all four sets before it (tests/sim/textures_test.py), in colours
# none of them has: olive, chartreuse, burgundy, crimson, fuchsia, amber, gold, spring green, azure, aqua,
# royal blue and forest green, on the same families.
HELDOUT_V4_FLAT_RECIPES: tuple[Recipe, ...] = (
    _flat("deck-olive", "Olive painted metal deck", 6.0, "profiled", **_deck("#7a7a30")),
    _flat("coating-chartreuse", "Chartreuse roof coating", 8.0, "coating", colour="#b0d030", substrate="#707070",
          peel=0.35, cracks=0.6, stains=dict(colour="#707868", amount=0.6, size_m=2.0)),
    _flat("capsheet-burgundy", "Burgundy granulated cap sheet", 8.0, "sheet",
          **_cap_sheet("#8a2236", _p("#a83a4e", "#4a1420", "#8a8a8a", "#5a5a5a"), fleck_share=0.35)),
    _flat("capsheet-crimson", "Crimson granulated cap sheet", 8.0, "sheet",
          **_cap_sheet("#c01840", _p("#d83a5a", "#6a1020", "#8a8a8a", "#5a5a5a"), fleck_share=0.3)),
    _flat("coating-fuchsia", "Fuchsia sports-court coating", 10.0, "coating", colour="#c8308a", substrate="#5a5a5a",
          peel=0.3, roller=0.04, cracks=0.6, stains=dict(colour="#606060", amount=0.6, size_m=2.0)),
    _flat("gravel-amber-glass", "Amber glass gravel", 3.0, "gravel", stone_m=0.03,
          palette=_p(("#c88a20", 3), ("#a86a10", 2), ("#e0a840", 2), ("#6a6a6a", 1))),
    _flat("coating-spring-green", "Spring-green roof coating", 8.0, "coating", colour="#30c060", substrate="#707070",
          peel=0.35, cracks=0.6, stains=dict(colour="#687068", amount=0.6, size_m=2.0)),
    _flat("coating-gold", "Gold elastomeric coating", 8.0, "coating", colour="#e8a800", substrate="#6a6a66",
          peel=0.4, cracks=0.8, stains=dict(colour="#7a7a70", amount=0.6, size_m=2.0)),
    _flat("membrane-azure", "Azure PVC membrane", 12.0, "sheet",
          **_membrane("#3080e0", sheet_m=2.0, stains=dict(colour="#6a7078", amount=0.7, size_m=2.0, threshold=0.45),
                      patches=dict(probability=0.6, tone=-0.3, edge=0.3))),
    _flat("deck-aqua", "Aqua painted metal deck", 6.0, "profiled", **_deck("#40c0c0")),
)

HELDOUT_V4_SLOPED_RECIPES: tuple[Recipe, ...] = (
    _sloped("corrugated-olive", "Olive painted corrugated iron", 4.0, "profiled",
            **_corrugated("#6a7020", rust=dict(amount=0.2, palette=_RUST))),
    _sloped("shingle-burgundy", "Burgundy architectural shingles", 5.0, "tiles",
            **_architectural(_p("#7a2a3a", "#862f42", "#6e2434"), _p("#8a8a8a", "#4a4a4a"), fleck_share=0.25,
                             stains=dict(colour="#606060", amount=0.5, size_m=1.5))),
    _sloped("seam-royal-blue", "Royal-blue standing-seam metal", 8.0, "profiled", **_seam("#3050d0")),
    _sloped("clay-glazed-forest", "Glazed forest-green clay tiles", 6.0, "tiles",
            **_barrel(_p("#2a7a3a", "#247034", "#308440"), gloss=0.3, tone=0.05)),
    _sloped("corrugated-fuchsia", "Fuchsia painted corrugated iron", 4.0, "profiled",
            **_corrugated("#c03a90", rust=dict(amount=0.5, palette=_RUST))),
    _sloped("shingle-spring-green", "Spring-green architectural shingles", 5.0, "tiles",
            **_architectural(_p("#40b060", "#4aba6a", "#36a656"), _p("#8a8a8a", "#4a4a4a"), fleck_share=0.25,
                             stains=dict(colour="#606060", amount=0.5, size_m=1.5))),
    _sloped("seam-azure", "Azure standing-seam metal", 8.0, "profiled", **_seam("#3a88e0")),
    _sloped("clay-glazed-amber", "Glazed amber clay tiles", 6.0, "tiles",
            **_barrel(_p("#d08a18", "#c48014", "#da961e"), gloss=0.3, tone=0.05)),
    _sloped("shakes-painted-chartreuse", "Chartreuse-painted wood shakes", 5.0, "tiles",
            **_shakes(_p("#a0c030", "#aaca3a", "#96b628"))),
    _sloped("corrugated-crimson", "Crimson painted corrugated iron", 4.0, "profiled",
            **_corrugated("#c02040", rust=dict(amount=0.6, palette=_RUST))),
)

# The fifth held-out set, E2's validation textures (meta_sim/experiments/splits.py): the fourth
# set's 10 + 10 and 20 + 20 drawn ones. Validation on 10 textures per kind chose a roof match that test (heldout-v2)
# did not confirm; settings that close are told apart only on more textures. Drawn, not picked: candidate
# ``index`` of a kind is a family of the kind and a colour (hue uniform, saturation and value in [0.3, 0.95])
# from integer hashing of (DRAWN_SEED, kind, index); the set keeps the first candidates that meet the held-out
# conditions against every set before it and the candidates kept before them (tests/sim/textures_test.py
# checks that HELDOUT_V5_DRAWN lists exactly those).
DRAWN_SEED = 5
_DRAWN_FAMILIES = {
    "flat": ("deck", "coating", "capsheet", "membrane", "gravel"),
    "sloped": ("corrugated", "seam", "clay", "shingle", "shakes"),
}
_DRAWN_NAMES = {"deck": "painted metal deck", "coating": "roof coating", "capsheet": "granulated cap sheet",
                "membrane": "PVC membrane", "gravel": "glass gravel", "corrugated": "painted corrugated iron",
                "seam": "standing-seam metal", "clay": "glazed clay tiles", "shingle": "architectural shingles",
                "shakes": "painted wood shakes"}


def _hsv_hex(h: float, s: float, v: float) -> str:
    """``#rrggbb`` of a colour in HSV (hue wrapped, saturation and value clipped to [0, 1])."""
    h = (h - np.floor(h)) * 6.0
    s, v = min(max(s, 0.0), 1.0), min(max(v, 0.0), 1.0)
    sector = int(h) % 6
    f = h - int(h)
    p, q, t = v * (1.0 - s), v * (1.0 - s * f), v * (1.0 - s * (1.0 - f))
    rgb = ((v, t, p), (q, v, p), (p, v, t), (p, q, v), (t, p, v), (v, p, q))[sector]
    return "#" + "".join(f"{int(np.floor(c * 255.0 + 0.5)):02x}" for c in rgb)


def drawn_recipe(kind: str, index: int, seed: int = DRAWN_SEED) -> Recipe:
    """Candidate ``index`` (from 0) of a drawn held-out set of ``kind``: one of the kind's families in a colour
    drawn by integer hashing (the same on every machine)."""
    if kind not in KINDS:
        raise ValueError(f"kind must be one of {KINDS}, got {kind!r}")
    u = [float(x) for x in _rand(seed, KINDS.index(kind), index, np.arange(4))]
    families = _DRAWN_FAMILIES[kind]
    family = families[min(int(u[0] * len(families)), len(families) - 1)]
    h, s, v = u[1], 0.3 + 0.65 * u[2], 0.3 + 0.65 * u[3]
    colour = _hsv_hex(h, s, v)
    shades = _p(*(_hsv_hex(h, s, v + dv) for dv in (-0.05, 0.0, 0.05)))
    id_, name = f"drawn{seed}-{index:03d}-{family}", f"{colour} {_DRAWN_NAMES[family]} (drawn)"
    stains = dict(colour="#686868", amount=0.6, size_m=2.0)
    if family == "deck":
        return _flat(id_, name, 6.0, "profiled", **_deck(colour))
    if family == "coating":
        return _flat(id_, name, 8.0, "coating", colour=colour, substrate="#707070", peel=0.35, cracks=0.6,
                     stains=stains)
    if family == "capsheet":
        flecks = _p(_hsv_hex(h, s, v + 0.12), _hsv_hex(h, s, v - 0.3), "#8a8a8a", "#5a5a5a")
        return _flat(id_, name, 8.0, "sheet", **_cap_sheet(colour, flecks, fleck_share=0.3))
    if family == "membrane":
        return _flat(id_, name, 12.0, "sheet",
                     **_membrane(colour, sheet_m=2.0, stains={**stains, "amount": 0.7, "threshold": 0.45},
                                 patches=dict(probability=0.6, tone=-0.3, edge=0.3)))
    if family == "gravel":
        return _flat(id_, name, 3.0, "gravel", stone_m=0.03,
                     palette=_p((colour, 3), (_hsv_hex(h, s, v - 0.12), 2), (_hsv_hex(h, 0.8 * s, v + 0.1), 2),
                                ("#6a6a6a", 1)))
    if family == "corrugated":
        return _sloped(id_, name, 4.0, "profiled", **_corrugated(colour, rust=dict(amount=0.3, palette=_RUST)))
    if family == "seam":
        return _sloped(id_, name, 8.0, "profiled", **_seam(colour))
    if family == "clay":
        return _sloped(id_, name, 6.0, "tiles", **_barrel(shades, gloss=0.3, tone=0.05))
    if family == "shingle":
        return _sloped(id_, name, 5.0, "tiles", **_architectural(shades, _p("#8a8a8a", "#4a4a4a"), fleck_share=0.25,
                                                                  stains={**stains, "amount": 0.5, "size_m": 1.5}))
    return _sloped(id_, name, 5.0, "tiles", **_shakes(shades))


# The candidates heldout-v5 keeps, per kind (indices of ``drawn_recipe``).
HELDOUT_V5_DRAWN: dict[str, tuple[int, ...]] = {
    "flat": (0, 1, 2, 4, 7, 8, 9, 10, 11, 12, 15, 16, 17, 19, 21, 22, 23, 24, 25, 26),
    "sloped": (2, 5, 7, 9, 10, 13, 14, 16, 20, 21, 24, 26, 30, 38, 43, 48, 50, 51, 54, 55),
}
HELDOUT_V5_FLAT_RECIPES = HELDOUT_V4_FLAT_RECIPES + tuple(drawn_recipe("flat", i) for i in HELDOUT_V5_DRAWN["flat"])
HELDOUT_V5_SLOPED_RECIPES = HELDOUT_V4_SLOPED_RECIPES + tuple(
    drawn_recipe("sloped", i) for i in HELDOUT_V5_DRAWN["sloped"])

# Held-out sets by name, in the order they were made (a name is not RECIPE_VERSION: see ``set_name``).
HELDOUT_SETS: dict[str, tuple[tuple[Recipe, ...], tuple[Recipe, ...]]] = {
    "heldout-v1": (HELDOUT_FLAT_RECIPES, HELDOUT_SLOPED_RECIPES),
    "heldout-v2": (HELDOUT_V2_FLAT_RECIPES, HELDOUT_V2_SLOPED_RECIPES),
    "heldout-v3": (HELDOUT_V3_FLAT_RECIPES, HELDOUT_V3_SLOPED_RECIPES),
    "heldout-v4": (HELDOUT_V4_FLAT_RECIPES, HELDOUT_V4_SLOPED_RECIPES),
    "heldout-v5": (HELDOUT_V5_FLAT_RECIPES, HELDOUT_V5_SLOPED_RECIPES),
}
FIRST_HELDOUT = "heldout-v1"


def heldout_set(heldout: bool | str) -> str | None:
    """The held-out set ``heldout`` names: None for False (the bank), the first set for True, else the
    name itself, which must be one of ``HELDOUT_SETS`` (ValueError)."""
    if heldout is False:
        return None
    if heldout is True:
        return FIRST_HELDOUT
    if heldout not in HELDOUT_SETS:
        raise ValueError(f"unknown held-out set {heldout!r}; choose one of {', '.join(HELDOUT_SETS)}")
    return heldout


def set_name(heldout: bool | str = False) -> str:
    """The name of the bank of the default recipes (``default-v1``) or of a held-out set
    (``heldout-v1``, ``heldout-v2``). Held-out sets are numbered in the order they were made; if
    RECIPE_VERSION ever changes their pixels, their banks gain ``-rN`` so they never pass for these."""
    name = heldout_set(heldout)
    if name is None:
        return f"default-v{RECIPE_VERSION}"
    return name if RECIPE_VERSION == 1 else f"{name}-r{RECIPE_VERSION}"


def recipes(kind: str | None = None, heldout: bool | str = False) -> tuple[Recipe, ...]:
    """The default recipes, or a held-out set's (``heldout``: True for the first, or a name of
    ``HELDOUT_SETS``), flat first, optionally one kind."""
    name = heldout_set(heldout)
    flat, sloped = (FLAT_RECIPES, SLOPED_RECIPES) if name is None else HELDOUT_SETS[name]
    if kind is None:
        return flat + sloped
    if kind not in KINDS:
        raise ValueError(f"kind must be one of {KINDS}, got {kind!r}")
    return flat if kind == "flat" else sloped


def recipe_by_id(recipe_id: str) -> Recipe:
    for recipe in recipes() + sum((recipes(heldout=name) for name in HELDOUT_SETS), ()):
        if recipe.id == recipe_id:
            return recipe
    raise KeyError(recipe_id)

"""Roof furniture: what stands on the roofs of a city. Pure numpy, no ``bpy``.

`LayoutParams.roof_furniture` (0..1, off by default) asks for it:

* flat roofs: the parapet the layout gives some of them (`Building.parapet_m`)
  as a rim around the edge, HVAC units (big roofs of offices, highrises and
  industrial halls carry many, often in rows of one model; small houses few),
  skylights (rows of them on halls), roof hatches, stair and lift housings on
  apartment, office and highrise roofs, and rows of tilted solar panels;
* sloped roofs: chimneys by the ridge, rising above the roof where they
  stand, roof windows and solar panels lying on one roof plane;
* water tanks: plastic cylinders (mostly black, also blue, white or beige)
  on flat roofs, alone or two or three together, some on a small steel
  stand. How often a roof has them depends on the city style of its
  building (`TANK_SHARE`): most flat roofs of a dense town, where water
  comes by the tank, some suburban ones, few downtown or industrial ones.

Nothing here is stored in the layout: a building's furniture follows from the
city seed, the building, its style and the density, drawn from a generator of
its own (``default_rng([seed, building id, FURNITURE_STREAM])``). So the
layout's streams and JSON stay as they were, a building carries the same
furniture in every tile, and the renderer makes it only for the buildings a
tile sees. Water tanks came last and draw after every other piece of a roof,
so the pieces from before them stand where they stood.

Every piece stands inside its building's footprint, and the label passes
paint it with its building's instance id and roof class: the labels of a
furnished city are those of the bare one. Sizes are metres, heights absolute
(the roof is at ``height_m``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from . import polygons
from .draws import pick, sign

Point = tuple[float, float]
Polygon = tuple[Point, ...]
Rect = tuple[float, float, float, float]  # x0, y0, x1, y1 in the building's own frame

FURNITURE_STREAM = 18  # the tag of each building's generator (roof jitter's is 7)
# Material of a piece; meshes.furniture_mesh gives each its slot in this order.
SURFACES = ("coping", "metal", "dark", "dome", "glass", "solar", "brick", "render",
            "tank-black", "tank-blue", "tank-white", "tank-beige")

PARAPET_WIDTH_M = (0.2, 0.4)
HVAC_SIZE_M = (1.0, 3.0)
HVAC_HEIGHT_M = (0.8, 1.8)
HOUSING_SIZE_M = (3.0, 6.0)  # stair or lift housing
HOUSING_HEIGHT_M = (2.4, 3.4)
HOUSING_MIN_ROOF_M2 = 200.0
SKYLIGHT_SIZE_M = (1.0, 2.5)
SKYLIGHT_HEIGHT_M = (0.2, 0.45)
HATCH_SIZE_M = (0.8, 1.1)
HATCH_HEIGHT_M = (0.3, 0.6)
CHIMNEY_SIZE_M = (0.5, 1.2)
CHIMNEY_RISE_M = (0.4, 1.0)  # above the highest roof point under it
CHIMNEY_FROM_RIDGE_M = (0.0, 1.5)  # its centre's distance (in plan) from the ridge line
PANEL_M = (1.0, 1.7)  # one solar module, across and up its slope
PANEL_TILT_DEG = (10.0, 20.0)  # rows on flat roofs
PANEL_FOOT_M = 0.2  # how high a flat-roof row's low edge stands
ON_PLANE_M = (0.03, 0.09)  # underside and top of panels and roof windows above a sloped roof plane
ROOF_WINDOW_M = ((0.7, 1.0), (1.0, 1.4))  # across, up the slope
EDGE_M = 0.4  # pieces keep this far inside the roof edge (or the parapet)
GAP_M = 0.5  # and this far apart
MAX_PIECES = 40  # of one kind on one roof
TANK_DIAMETER_M = (1.0, 1.6)
TANK_HEIGHT_M = (1.0, 1.8)
TANK_SIDES = 16  # of the polygon standing for a tank's circle
_TANK_CIRCLE = [(math.cos(a), math.sin(a)) for a in np.linspace(0.0, 2 * math.pi, TANK_SIDES, endpoint=False)]
TANK_STAND_M = (0.5, 1.5)  # height of a stand's deck above the roof
TANK_DECK_M = 0.06  # thickness of a stand's deck and side of its square legs
TANK_DECK_RIM_M = 0.05  # the deck reaches this far beyond its tank on every side

# Expected pieces per square metre of flat roof at roof_furniture 1 are 1 / these.
HVAC_M2 = {"residential": 400.0, "apartment": 150.0, "office": 90.0, "industrial": 110.0, "highrise": 70.0}
SKYLIGHT_M2 = {"residential": 900.0, "apartment": 500.0, "office": 400.0, "industrial": 140.0, "highrise": 900.0}
# Chances at roof_furniture 1.
HATCH_SHARE = {"residential": 0.3, "apartment": 0.7, "office": 0.6, "industrial": 0.4, "highrise": 0.5}
HOUSING_SHARE = {"apartment": 0.9, "office": 0.9, "highrise": 1.0}
FLAT_SOLAR_SHARE = {"residential": 0.4, "apartment": 0.35, "office": 0.3, "industrial": 0.45, "highrise": 0.15}
CHIMNEY_SHARE = {"residential": 0.8, "apartment": 0.6, "office": 0.2, "industrial": 0.15}
SLOPED_SOLAR_SHARE = {"residential": 0.45, "apartment": 0.35, "office": 0.3, "industrial": 0.4}
ROOF_WINDOW_SHARE = {"residential": 0.35, "apartment": 0.4, "office": 0.1, "industrial": 0.05}
# Chance at roof_furniture 1 that a flat roof carries water tanks, by the city style of its building
# (``CityLayout.style_of``); then how many, their colours and how often a stand lifts one.
TANK_SHARE = {"dense": 0.85, "suburban": 0.2, "downtown": 0.05, "industrial": 0.03}
TANK_COUNT = {1: 0.55, 2: 0.35, 3: 0.1}
TANK_COLOURS = {"tank-black": 0.55, "tank-blue": 0.2, "tank-white": 0.12, "tank-beige": 0.13}
TANK_SAME_COLOUR = 0.7  # a roof's further tanks are of its first one's colour this often
TANK_ON_STAND = 0.3


@dataclass(frozen=True)
class Fixture:
    """One piece of roof furniture in its building's own (unturned) frame, as `Building.footprint` is.

    A prism over `outline` (counter-clockwise) whose corners stand from `bottom` to `top` (heights of
    each corner; a tilted panel's differ), or, with `inner`, a rim between `outline` and `inner` (a
    parapet). `kind` says what it is, `surface` (one of `SURFACES`) what it is made of.
    """

    kind: str
    surface: str
    outline: Polygon
    bottom: tuple[float, ...]
    top: tuple[float, ...]
    inner: Polygon = ()


def roof_furniture(building, city_seed: int, density: float, style: str) -> tuple[Fixture, ...]:
    """The furniture of one building (a `layout.Building`) at `density` 0..1 (none at 0); `style` is the
    city style of the region it stands in (``CityLayout.style_of``), which sets how often it has tanks."""
    if density <= 0.0:
        return ()
    rng = np.random.default_rng([int(city_seed), int(building.id), FURNITURE_STREAM])
    if building.roof != "flat":
        return tuple(_sloped_roof(rng, building, float(density)))
    return tuple(_flat_roof(rng, building, float(density), TANK_SHARE[style]))


def world_south(building) -> Point:
    """The direction of world south in the building's own frame (panels face it)."""
    a = math.radians(building.rotation_deg)
    return (-math.sin(a), -math.cos(a))


# ---------------------------------------------------------------- placement


def _inset(polygon: Polygon, width: float) -> Polygon:
    """A counter-clockwise polygon with every edge moved `width` inwards (mitred corners)."""
    n = len(polygon)
    out = []
    for i in range(n):
        (ax, ay), (bx, by), (cx, cy) = polygon[i - 1], polygon[i], polygon[(i + 1) % n]
        normals = []
        for (px, py), (qx, qy) in (((ax, ay), (bx, by)), ((bx, by), (cx, cy))):
            length = math.hypot(qx - px, qy - py)
            normals.append((-(qy - py) / length, (qx - px) / length))  # left of the edge: inside
        (n1x, n1y), (n2x, n2y) = normals
        k = width / (1.0 + n1x * n2x + n1y * n2y)
        out.append((bx + k * (n1x + n2x), by + k * (n1y + n2y)))
    return tuple(out)


def _rect_outline(rect: Rect) -> Polygon:
    x0, y0, x1, y1 = rect
    return ((x0, y0), (x1, y0), (x1, y1), (x0, y1))


class _Roof:
    """Free room on a roof: axis-aligned pieces inside the footprint (kept `margin` from its edge) and
    `GAP_M` apart."""

    def __init__(self, footprint: Polygon, margin: float):
        self.footprint = footprint
        self.margin = margin
        self.bbox = x0, y0, x1, y1 = polygons.bbox(footprint)
        self.box = (x0 + margin, y0 + margin, x1 - margin, y1 - margin)
        self.rectangular = set(footprint) == set(_rect_outline(self.bbox)) and polygons.area(footprint) > 0.0
        self.taken: list[Rect] = []

    def fits(self, rect: Rect) -> bool:
        x0, y0, x1, y1 = rect
        if not all(x0 >= t[2] + GAP_M or t[0] >= x1 + GAP_M or y0 >= t[3] + GAP_M or t[1] >= y1 + GAP_M
                   for t in self.taken):
            return False
        m = self.margin
        gx0, gy0, gx1, gy1 = x0 - m, y0 - m, x1 + m, y1 + m
        fx0, fy0, fx1, fy1 = self.bbox
        if self.rectangular and fx0 <= gx0 and fy0 <= gy0 and gx1 <= fx1 and gy1 <= fy1:
            # Inside a rectangular footprint: the clipping below would give the rectangle back, its area
            # within rounding (far below the 1e-6 m2 allowed, even 5 km from the origin) of the rectangle's: yes.
            return True
        grown = _rect_outline((gx0, gy0, gx1, gy1))
        # Clipping the (perhaps L- or T-shaped) footprint by the rectangle keeps all of the rectangle
        # exactly when the rectangle lies inside.
        return polygons.overlap_area(self.footprint, grown) >= polygons.area(grown) - 1e-6

    def take(self, rect: Rect) -> bool:
        if self.fits(rect):
            self.taken.append(rect)
            return True
        return False

    def place(self, rng: np.random.Generator, w: float, h: float, tries: int = 12) -> Rect | None:
        """A free `w` x `h` rectangle at a random spot, taken; None when none was found."""
        bx0, by0, bx1, by1 = self.box
        if bx1 - bx0 < w or by1 - by0 < h:
            return None
        for _ in range(tries):
            x, y = rng.uniform(bx0, bx1 - w), rng.uniform(by0, by1 - h)
            if self.take((x, y, x + w, y + h)):
                return (x, y, x + w, y + h)
        return None


def _box(kind: str, surface: str, rect: Rect, z0: float, z1: float) -> Fixture:
    return Fixture(kind, surface, _rect_outline(rect), (z0,) * 4, (z1,) * 4)


def _count(rng: np.random.Generator, mean: float) -> int:
    return min(int(rng.poisson(mean)), MAX_PIECES)


# ---------------------------------------------------------------- flat roofs


def _flat_roof(rng: np.random.Generator, b, density: float, tank_share: float) -> list[Fixture]:
    z = b.height_m
    footprint = b.footprint
    out = []
    margin = EDGE_M
    if b.parapet_m > 0.0:
        width = rng.uniform(*PARAPET_WIDTH_M)
        n = len(footprint)
        out.append(Fixture("parapet", "coping", footprint, (z,) * n, (z + b.parapet_m,) * n,
                           _inset(footprint, width)))
        margin += width
    roof = _Roof(footprint, margin)
    area = polygons.area(footprint)
    sink = z - 0.05  # boxes start a little inside the roof: no face shares the roof's plane
    if area >= HOUSING_MIN_ROOF_M2 and rng.random() < density * HOUSING_SHARE.get(b.kind, 0.0):
        rect = roof.place(rng, rng.uniform(*HOUSING_SIZE_M), rng.uniform(*HOUSING_SIZE_M))
        if rect:
            out.append(_box("housing", "render", rect, sink, z + rng.uniform(*HOUSING_HEIGHT_M)))
    if rng.random() < density * FLAT_SOLAR_SHARE[b.kind]:
        out += _solar_rows(rng, roof, z, world_south(b))
    out += _rows_of(rng, roof, "hvac", "metal", _count(rng, density * area / HVAC_M2[b.kind]), HVAC_SIZE_M,
                    HVAC_HEIGHT_M, sink, z)
    out += _rows_of(rng, roof, "skylight", "dome", _count(rng, density * area / SKYLIGHT_M2[b.kind]),
                    SKYLIGHT_SIZE_M, SKYLIGHT_HEIGHT_M, sink, z)
    if rng.random() < density * HATCH_SHARE[b.kind]:
        side = rng.uniform(*HATCH_SIZE_M)
        rect = roof.place(rng, side, side)
        if rect:
            out.append(_box("hatch", "dark", rect, sink, z + rng.uniform(*HATCH_HEIGHT_M)))
    if rng.random() < density * tank_share:  # the last draws: the pieces above stay where they were
        out += _tanks(rng, roof, z, sink)
    return out


def _tanks(rng: np.random.Generator, roof: _Roof, z: float, sink: float) -> list[Fixture]:
    """One to three water tanks, each a cylinder standing on the roof or on a steel stand (a deck on four
    legs, its square just holding the tank); the square of each is placed like any other piece."""
    out: list[Fixture] = []
    colour = pick(rng, TANK_COLOURS)
    for k in range(int(pick(rng, TANK_COUNT))):
        if k and rng.random() >= TANK_SAME_COLOUR:
            colour = pick(rng, TANK_COLOURS)
        d = rng.uniform(*TANK_DIAMETER_M)
        height = polygons.clamp(d * rng.uniform(0.9, 1.3), *TANK_HEIGHT_M)
        stand = rng.uniform(*TANK_STAND_M) if rng.random() < TANK_ON_STAND else 0.0
        side = d + 2 * TANK_DECK_RIM_M if stand else d
        rect = roof.place(rng, side, side)
        if rect is None:
            continue
        x0, y0, x1, y1 = rect
        cx, cy = (x0 + x1) / 2, (y0 + y1) / 2
        foot = sink
        if stand:
            # Legs and tank reach into the deck, set in from its edges: no two faces share a plane.
            t, top = TANK_DECK_M, z + stand
            foot = top - t / 2
            out.append(_box("tank-stand", "dark", rect, top - t, top))
            out += [_box("tank-stand", "dark", (lx, ly, lx + t, ly + t), sink, foot)
                    for lx in (x0 + 0.02, x1 - 0.02 - t) for ly in (y0 + 0.02, y1 - 0.02 - t)]
        circle = tuple((cx + d / 2 * cos, cy + d / 2 * sin) for cos, sin in _TANK_CIRCLE)
        out.append(Fixture("tank", colour, circle, (foot,) * TANK_SIDES, (z + stand + height,) * TANK_SIDES))
    return out


def _rows_of(rng: np.random.Generator, roof: _Roof, kind: str, surface: str, n: int, size_m, height_m,
             z0: float, roof_z: float) -> list[Fixture]:
    """`n` boxes, most of them in rows of one model (same size, evenly spaced), the rest scattered."""
    out: list[Fixture] = []
    last = None
    for _ in range(n):
        rect = None
        if last is not None and rng.random() < 0.7:
            (x0, y0, x1, y1), height = last
            step = rng.uniform(GAP_M, GAP_M + 0.6)
            dx, dy = ((x1 - x0 + step, 0.0), (0.0, y1 - y0 + step))[int(rng.integers(2))]
            candidate = (x0 + dx, y0 + dy, x1 + dx, y1 + dy)
            rect = candidate if roof.take(candidate) else None
        if rect is None:
            height = rng.uniform(*height_m)
            rect = roof.place(rng, rng.uniform(*size_m), rng.uniform(*size_m))
            if rect is None:
                continue
        last = rect, height
        out.append(_box(kind, surface, rect, z0, roof_z + height))
    return out


def _solar_rows(rng: np.random.Generator, roof: _Roof, z: float, south: Point) -> list[Fixture]:
    """Rows of panels tilted towards the side of the roof nearest to south, in a block of the roof."""
    across_x = abs(south[0]) > abs(south[1])  # the panels face +-x, so their rows run along y
    facing = (south[0] if across_x else south[1]) > 0.0
    tilt = math.radians(rng.uniform(*PANEL_TILT_DEG))
    up = PANEL_M[1] * int(rng.integers(1, 3))  # one or two modules up each row
    depth = up * math.cos(tilt)
    gap = depth * rng.uniform(0.6, 1.2)
    bx0, by0, bx1, by1 = roof.box
    along_room, across_room = (by1 - by0, bx1 - bx0) if across_x else (bx1 - bx0, by1 - by0)
    along = math.floor(rng.uniform(0.4, 0.9) * along_room / PANEL_M[0]) * PANEL_M[0]
    rows = int((rng.uniform(0.3, 0.8) * across_room + gap) // (depth + gap))
    if along < 2 * PANEL_M[0] or rows < 1:
        return []
    across = rows * depth + (rows - 1) * gap
    block = roof.place(rng, *((across, along) if across_x else (along, across)))
    if block is None:
        return []
    out = []
    low, high = z + PANEL_FOOT_M, z + PANEL_FOOT_M + up * math.sin(tilt)
    for k in range(rows):
        a0 = k * (depth + gap)
        # Corners from the row's low edge (facing the sun) around, so the outline's first edge runs along it.
        if across_x:
            x0 = block[2] - a0 - depth if facing else block[0] + a0
            y0, y1, x1 = block[1], block[3], x0 + depth
            corners = ((x1, y0), (x1, y1), (x0, y1), (x0, y0)) if facing else ((x0, y1), (x0, y0), (x1, y0), (x1, y1))
        else:
            y0 = block[3] - a0 - depth if facing else block[1] + a0
            x0, x1, y1 = block[0], block[2], y0 + depth
            corners = ((x1, y1), (x0, y1), (x0, y0), (x1, y0)) if facing else ((x0, y0), (x1, y0), (x1, y1), (x0, y1))
        out.append(Fixture("solar", "solar", corners, (z,) * 4, (low, low, high, high)))
    return out


# ---------------------------------------------------------------- sloped roofs


@dataclass(frozen=True)
class _Slopes:
    """A gable or hip roof in plan: u along the ridge, v across, both from the eaves' corner."""

    building: object
    x0: float
    y0: float
    length: float
    width: float
    rise: float  # tan(pitch)

    @classmethod
    def of(cls, b) -> _Slopes:
        x0, y0, x1, y1 = polygons.bbox(b.footprint)
        o = b.overhang_m
        x0, y0, x1, y1 = x0 - o, y0 - o, x1 + o, y1 + o
        along_x = b.ridge_axis == "x"
        length, width = (x1 - x0, y1 - y0) if along_x else (y1 - y0, x1 - x0)
        return cls(b, x0, y0, length, width, math.tan(math.radians(b.roof_pitch_deg)))

    def xy(self, u: float, v: float) -> Point:
        return (self.x0 + u, self.y0 + v) if self.building.ridge_axis == "x" else (self.x0 + v, self.y0 + u)

    def height(self, u: float, v: float) -> float:
        """The roof's height over (u, v) (inside the roof outline)."""
        t = min(v, self.width - v)
        if self.building.roof == "hip":
            t = min(t, u, self.length - u)
        return self.building.height_m + t * self.rise

    def rect(self, u0: float, v0: float, u1: float, v1: float) -> Rect:
        (ax, ay), (bx, by) = self.xy(u0, v0), self.xy(u1, v1)
        return (min(ax, bx), min(ay, by), max(ax, bx), max(ay, by))


def _sloped_roof(rng: np.random.Generator, b, density: float) -> list[Fixture]:
    roof = _Slopes.of(b)
    room = _Roof(b.footprint, 0.0)  # the pieces keep off the eaves and ends themselves
    out = []
    south = world_south(b)
    # The long slope facing nearer to south: its eave is at v = 0 when it faces -v.
    down_v = south[1] if b.ridge_axis == "x" else south[0]
    sunny = 0 if down_v < 0.0 else 1
    if rng.random() < density * SLOPED_SOLAR_SHARE[b.kind]:
        out += _on_slope(rng, roof, room, sunny, "solar", "solar", PANEL_M, 4, 3)
    if rng.random() < density * ROOF_WINDOW_SHARE[b.kind]:
        for _ in range(int(rng.integers(1, 4))):
            size = tuple(rng.uniform(*r) for r in ROOF_WINDOW_M)
            out += _on_slope(rng, roof, room, int(rng.integers(2)), "roof-window", "glass", size, 1, 1)
    if rng.random() < density * CHIMNEY_SHARE[b.kind]:
        out += _chimney(rng, roof, room)
    return out


def _on_slope(rng: np.random.Generator, roof: _Slopes, room: _Roof, side: int, kind: str, surface: str,
              module: tuple[float, float], min_cols: int, max_rows: int) -> list[Fixture]:
    """A block of `module`-sized panels (across x up the slope) lying on one long slope of the roof, a
    few centimetres above it; side 0 is the slope whose eave is at v = 0. Returns one fixture or none."""
    half = roof.width / 2.0
    cos = 1.0 / math.sqrt(1.0 + roof.rise ** 2)
    depth_one = module[1] * cos  # one module up the slope, in plan
    low, high = roof.building.overhang_m + EDGE_M, half - EDGE_M  # distances from the eave in plan
    rows = min(max_rows, int((high - low) // depth_one))
    if rows < 1:
        return []
    rows = int(rng.integers(1, rows + 1))
    t0 = rng.uniform(low, high - rows * depth_one)
    t1 = t0 + rows * depth_one
    inset = t1 if roof.building.roof == "hip" else 0.0  # hip slopes narrow towards the ridge
    u_lo = max(low, inset + EDGE_M)
    u_hi = roof.length - u_lo
    cols = int((u_hi - u_lo) // module[0])
    if cols < min_cols:
        return []
    cols = int(rng.integers(max(min_cols, cols // 2), cols + 1))
    u0 = rng.uniform(u_lo, u_hi - cols * module[0])
    u1 = u0 + cols * module[0]
    v0, v1 = (t0, t1) if side == 0 else (roof.width - t0, roof.width - t1)
    if not room.take(roof.rect(u0, min(v0, v1), u1, max(v0, v1))):
        return []
    # From the eave-side corners up: the outline's first edge runs along the eave.
    corners = [(u0, v0), (u1, v0), (u1, v1), (u0, v1)]
    points = [roof.xy(u, v) for u, v in corners]
    if polygons.area(points) < 0.0:  # the (u, v) -> (x, y) map or the far slope mirrors it
        corners = [corners[1], corners[0], corners[3], corners[2]]
        points = [roof.xy(u, v) for u, v in corners]
    plane = [roof.height(u, v) for u, v in corners]
    return [Fixture(kind, surface, tuple(points), tuple(h + ON_PLANE_M[0] for h in plane),
                    tuple(h + ON_PLANE_M[1] for h in plane))]


def _chimney(rng: np.random.Generator, roof: _Slopes, room: _Roof) -> list[Fixture]:
    """A square chimney by the ridge, from the eaves (hidden under the roof) to above the roof under it."""
    side = rng.uniform(*CHIMNEY_SIZE_M)
    half = roof.width / 2.0
    lo = roof.building.overhang_m + EDGE_M + side / 2.0
    for _ in range(8):
        v = half + sign(rng) * rng.uniform(*CHIMNEY_FROM_RIDGE_M)
        v = min(max(v, lo), roof.width - lo)
        u = rng.uniform(lo, roof.length - lo)
        u0, v0, u1, v1 = u - side / 2, v - side / 2, u + side / 2, v + side / 2
        rect = roof.rect(u0, v0, u1, v1)
        if room.take(rect):
            top = max(max(roof.height(cu, cv) for cu in (u0, u1) for cv in (v0, v1)),
                      roof.height(u, min(max(half, v0), v1)))  # a chimney across the ridge clears it
            surface = "brick" if rng.random() < 0.6 else "render"
            return [_box("chimney", surface, rect, roof.building.height_m, top + rng.uniform(*CHIMNEY_RISE_M))]
    return []

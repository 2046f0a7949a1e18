"""Street details, clutter and real-sized trees of a city: pure numpy, no ``bpy``.

`layout.generate_layout` calls in here when a `LayoutParams` knob asks for
more than today's city (all of them are off by default):

* street details: a kerb and a concrete sidewalk inside the verge along every
  street side of a block, a driveway from each house's front to the street,
  paved yards (the whole lot) on commercial and industrial lots, with
  asphalt parking lots and painted stalls beside their buildings,
  and lane markings on the roads (a dashed centre line on streets; a double
  centre line and dashed lane lines on avenues), stopping short of junctions;
* cars parked along the kerbs, on driveways and in parking lots, and a few
  driving in the lanes;
* swimming pools in the back yards of houses whose lot has room;
* shrubs: hedges along lot edges and bushes around houses;
* trees of real sizes (``tree_size="real"``): rows along the verges and
  groups in yards and parks, their crowns clear of every roof.

That is the suburban street grid. In a styled city each region gets what its
style has: a street grid of another style is furnished in its own frame by
the same functions under its `GridRules` (downtown: full-width sidewalks,
rows of street trees, crossings, busy kerbs, parking lots on the empty lots;
industrial: trucks at the halls and in truck stalls, few trees; neither gets
pools or hedges); dense towns get real trees in the gaps between their houses,
bushes and a few cars parked by the lanes, and no kerbs, sidewalks or paint
(`gap_trees`, `gap_bushes`, `lane_cars`); the through roads between regions
get centre lines and traffic (`through_roads`) and, on the sides of regions
that have sidewalks, kerbs and sidewalks of those regions' widths
(`through_sidewalks`).

Everything here is ground clutter: the label passes see it as background.
This module knows nothing of `layout` (which imports it): it takes blocks,
lots and roads as plain rectangles and buildings through their ``bbox``,
``kind`` and ``lot_index`` (and, for dense towns and through roads, exact
outlines in a `polygons.Occupancy`). Its items are axis-aligned rectangles,
except vehicles, which carry a heading; `layout` turns a turned grid's items
with it and cuts pavings and markings at region borders.
"""

from __future__ import annotations

import bisect
import math
from dataclasses import dataclass, replace
from typing import Any, Sequence

import numpy as np

from ..core.errors import MetaSimError
from . import polygons
from .draws import pick

Point = tuple[float, float]
Polygon = tuple[Point, ...]
Rect = tuple[float, float, float, float]  # x0, y0, x1, y1

TREE_SIZES = ("small", "real")
CAR_COLOURS = {"white": 0.27, "silver": 0.17, "grey": 0.17, "black": 0.23, "red": 0.08, "blue": 0.08}
PAVING_KINDS = ("kerb", "sidewalk", "driveway", "parking", "yard")
PAVED_LOTS = ("office", "industrial", "highrise")  # their lots are paved all over (a "yard")
CAR_LENGTH_M = (4.2, 4.9)
CAR_WIDTH_M = (1.75, 1.9)
VEHICLES = ("car", "truck")
TRUCK_COLOURS = {"white": 0.55, "silver": 0.2, "grey": 0.1, "red": 0.08, "blue": 0.07}  # of CAR_COLOURS
TRUCK_LENGTH_M = (7.0, 16.5)  # a box truck to a tractor with its trailer
TRUCK_WIDTH_M = (2.45, 2.55)
TRUCK_STALL_M = (4.0, 17.5)  # width, depth of a truck's stall
TRUCK_AISLE_M = 15.0
CUT_CORNERS = (3, 8)  # a rectangle cut by a region border keeps three to eight corners
KERB_M = 0.3
SIDEWALK_M = (1.5, 2.0)
DRIVEWAY_M = (2.8, 3.4)
STALL_M = (2.5, 5.0)  # width, depth of a parking stall
TRAFFIC_PER_100M = 1.5  # cars driving per lane and 100 m of road at car_density 1
AISLE_M = 6.0
LINE_M = 0.3  # painted line width: wider than real paint, so a 0.3 m pixel never falls between its edges
DASH_M = (3.0, 6.0)  # dash, gap of a dashed line
ZEBRA_M = (0.5, 0.6)  # bar, gap of a zebra crossing
ZEBRA_DEPTH_M = 3.0  # length of its bars along the road
TREE_DIAMETER_M = (4.0, 15.0)
STREET_TREE_DIAMETER_M = 10.0  # a verge tree wider than this would shade half the street
TREE_HEIGHT_M = (5.0, 20.0)
CLEARANCE_M = 0.05  # between a crown and a roof outline, after rounding


_r = polygons.rounded
_clamp = polygons.clamp
_rect_polygon = polygons.rect_polygon
_polygon_bbox = polygons.bbox


def _read_rect(data: Any, where: str, corners: tuple[int, int] = (4, 4)) -> Polygon:
    """A polygon of a layout file: a rectangle of four corners (or, for pavings and markings cut by a
    region border, a convex polygon of three to eight)."""
    polygon = tuple((float(x), float(y)) for x, y in data)
    x0, y0, x1, y1 = _polygon_bbox(polygon) if polygon else (0.0, 0.0, 0.0, 0.0)
    if not (corners[0] <= len(polygon) <= corners[1] and x1 > x0 and y1 > y0
            and all(map(math.isfinite, (x0, y0, x1, y1)))):
        shape = "a rectangle of four corners" if corners == (4, 4) else "a convex polygon of three to eight corners"
        raise MetaSimError(f"{where}: polygon must be {shape}; the layout file is damaged")
    return polygon


def _overlaps(a: Rect, b: Rect, margin: float = 0.0) -> bool:
    return a[0] < b[2] + margin and b[0] < a[2] + margin and a[1] < b[3] + margin and b[1] < a[3] + margin


def _grow(rect: Rect, margin: float) -> Rect:
    return (rect[0] - margin, rect[1] - margin, rect[2] + margin, rect[3] + margin)


# ---------------------------------------------------------------- items


@dataclass(frozen=True)
class Paving:
    """A paved ground rectangle: kerb, sidewalk, driveway, yard (concrete; a yard is a whole paved
    commercial or industrial lot, under its building) or parking lot (asphalt, off every roof).
    In a turned grid it is turned with it, and cut where it crosses a region border."""

    polygon: Polygon
    kind: str

    @property
    def bbox(self) -> Rect:
        return _polygon_bbox(self.polygon)

    def to_dict(self) -> dict[str, Any]:
        return {"polygon": [list(p) for p in self.polygon], "kind": self.kind}

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> Paving:
        if data["kind"] not in PAVING_KINDS:
            raise MetaSimError(f"paving kind {data['kind']!r} is not one of {PAVING_KINDS}; the layout file is damaged")
        return cls(_read_rect(data["polygon"], "paving", CUT_CORNERS), str(data["kind"]))


@dataclass(frozen=True)
class Marking:
    """A painted line piece on a road or a parking lot (a thin white rectangle, turned and cut like a
    `Paving`)."""

    polygon: Polygon

    @property
    def bbox(self) -> Rect:
        return _polygon_bbox(self.polygon)

    def to_dict(self) -> dict[str, Any]:
        return {"polygon": [list(p) for p in self.polygon]}

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> Marking:
        return cls(_read_rect(data["polygon"], "marking", CUT_CORNERS))


@dataclass(frozen=True)
class Pool:
    """A swimming pool: `polygon` is the outer edge of its coping, `coping_m` wide around the water."""

    polygon: Polygon
    coping_m: float

    @property
    def bbox(self) -> Rect:
        return _polygon_bbox(self.polygon)

    def to_dict(self) -> dict[str, Any]:
        return {"polygon": [list(p) for p in self.polygon], "coping_m": self.coping_m}

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> Pool:
        pool = cls(_read_rect(data["polygon"], "pool"), float(data["coping_m"]))
        x0, y0, x1, y1 = pool.bbox
        if not 0.0 < pool.coping_m < min(x1 - x0, y1 - y0) / 2:
            raise MetaSimError("pool: coping_m must be positive and leave water; the layout file is damaged")
        return pool


@dataclass(frozen=True)
class Shrub:
    """A hedge piece or a bush: a rectangle of foliage `height_m` tall."""

    polygon: Polygon
    height_m: float

    @property
    def bbox(self) -> Rect:
        return _polygon_bbox(self.polygon)

    def to_dict(self) -> dict[str, Any]:
        return {"polygon": [list(p) for p in self.polygon], "height_m": self.height_m}

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> Shrub:
        shrub = cls(_read_rect(data["polygon"], "shrub"), float(data["height_m"]))
        if not 0.0 < shrub.height_m <= 5.0:
            raise MetaSimError("shrub: height_m must be in (0, 5]; the layout file is damaged")
        return shrub


@dataclass(frozen=True)
class Car:
    """A car or a truck (`kind`): a `length_m` x `width_m` box centred on (x, y), its front towards
    `heading_deg` (counter-clockwise from east), painted `colour`."""

    x: float
    y: float
    heading_deg: float
    length_m: float
    width_m: float
    colour: str
    kind: str = "car"

    @property
    def corners(self) -> Polygon:
        """The outline, counter-clockwise from the rear right corner."""
        a = math.radians(self.heading_deg)
        fx, fy = math.cos(a) * self.length_m / 2, math.sin(a) * self.length_m / 2
        sx, sy = -math.sin(a) * self.width_m / 2, math.cos(a) * self.width_m / 2
        return tuple((self.x + i * fx + j * sx, self.y + i * fy + j * sy)
                     for i, j in ((-1, -1), (1, -1), (1, 1), (-1, 1)))

    @property
    def bbox(self) -> Rect:
        return _polygon_bbox(self.corners)

    def to_dict(self) -> dict[str, Any]:
        out = {"x": self.x, "y": self.y, "heading_deg": self.heading_deg, "length_m": self.length_m,
               "width_m": self.width_m, "colour": self.colour}
        if self.kind != "car":  # layouts from before trucks keep their JSON
            out["kind"] = self.kind
        return out

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> Car:
        car = cls(float(data["x"]), float(data["y"]), float(data["heading_deg"]), float(data["length_m"]),
                  float(data["width_m"]), str(data["colour"]), str(data.get("kind", "car")))
        if car.kind not in VEHICLES:
            raise MetaSimError(f"vehicle kind {car.kind!r} is not one of {VEHICLES}; the layout file is damaged")
        if car.colour not in CAR_COLOURS:
            raise MetaSimError(f"car colour {car.colour!r} is not one of {tuple(CAR_COLOURS)}; "
                               "the layout file is damaged")
        if not (0.5 < car.length_m < 20.0 and 0.5 < car.width_m < 5.0):
            raise MetaSimError("car: length_m and width_m must be a car's; the layout file is damaged")
        return car


@dataclass(frozen=True)
class Clutter:
    """What `generate_clutter` adds to a city, and where trees must keep their trunks off."""

    pavings: tuple[Paving, ...] = ()
    markings: tuple[Marking, ...] = ()
    cars: tuple[Car, ...] = ()
    pools: tuple[Pool, ...] = ()
    shrubs: tuple[Shrub, ...] = ()
    no_trunks: tuple[Rect, ...] = ()  # driveways, parking lots, pools: trunks stay off them


# ---------------------------------------------------------------- the rules of each grid style


@dataclass(frozen=True)
class GridRules:
    """How the streets and lots of one street-grid style are furnished (`SUBURBAN`: today's city).

    kerb_cars, traffic: times `car_density`, the share of kerb spots taken and the cars driving per
    `TRAFFIC_PER_100M`; zebra: share of junctions with crossings; sidewalk_m: the sidewalk's width range;
    pools, hedges: whether houses get pools and lots hedges and bushes; paved_lots: the lots are paved
    already (no yard pavings; an empty lot is a parking lot); trucks: trucks at the halls' loading bays
    and in the empty lots' truck stalls; tree_rows: (a, b), the chance a verge gets a row of trees is
    a + b * tree_density; yard_trees: times the groups of trees in yards and parks.
    """

    kerb_cars: float = 0.6
    traffic: float = 1.0
    zebra: float = 0.5
    sidewalk_m: tuple[float, float] = SIDEWALK_M
    pools: bool = True
    hedges: bool = True
    paved_lots: bool = False
    trucks: bool = False
    tree_rows: tuple[float, float] = (0.25, 0.9)
    yard_trees: float = 1.0


SUBURBAN = GridRules()
GRID_RULES = {
    "suburban": SUBURBAN,
    # Busy streets: full-width sidewalks with street trees in pits, crossings at most junctions, surface
    # parking lots on the empty lots.
    "downtown": GridRules(kerb_cars=0.85, traffic=2.0, zebra=0.85, sidewalk_m=(4.4, 4.4), pools=False,
                          hedges=False, paved_lots=True, tree_rows=(0.45, 1.2), yard_trees=0.0),
    # Quiet streets, trucks at the halls, few trees.
    "industrial": GridRules(kerb_cars=0.25, traffic=0.6, zebra=0.15, pools=False, hedges=False, paved_lots=True,
                            trucks=True, tree_rows=(0.1, 0.4), yard_trees=0.3),
}


# ---------------------------------------------------------------- lot frames


@dataclass(frozen=True)
class _Frame:
    """A lot seen from its street: u along the frontage, v back from the front edge."""

    rect: Rect
    front: str  # "S", "N", "W" or "E"

    @property
    def frontage(self) -> float:
        x0, y0, x1, y1 = self.rect
        return x1 - x0 if self.front in "SN" else y1 - y0

    @property
    def depth(self) -> float:
        x0, y0, x1, y1 = self.rect
        return y1 - y0 if self.front in "SN" else x1 - x0

    @property
    def v_heading(self) -> float:
        """World heading (degrees) of the +v direction, into the lot."""
        return {"S": 90.0, "N": 270.0, "W": 0.0, "E": 180.0}[self.front]

    def world(self, u0: float, u1: float, v0: float, v1: float) -> Rect:
        return polygons.lot_to_world(self.rect, self.front, u0, u1, v0, v1)

    def local(self, rect: Rect) -> tuple[float, float, float, float]:
        """(u0, u1, v0, v1) of a world rectangle."""
        x0, y0, x1, y1 = self.rect
        a0, b0, a1, b1 = rect
        return {
            "S": (a0 - x0, a1 - x0, b0 - y0, b1 - y0),
            "N": (a0 - x0, a1 - x0, y1 - b1, y1 - b0),
            "W": (b0 - y0, b1 - y0, a0 - x0, a1 - x0),
            "E": (b0 - y0, b1 - y0, x1 - a1, x1 - a0),
        }[self.front]


def _front(lot: Rect, block: Rect, road_sides: frozenset, verge: float, roof: Rect | None) -> str | None:
    """The side of a lot that faces a street across the verge (the one nearest its roof if several)."""
    lx0, ly0, lx1, ly1 = lot
    bx0, by0, bx1, by1 = block
    on_street = {
        "S": abs(ly0 - (by0 + verge)) < 1e-3, "N": abs(ly1 - (by1 - verge)) < 1e-3,
        "W": abs(lx0 - (bx0 + verge)) < 1e-3, "E": abs(lx1 - (bx1 - verge)) < 1e-3,
    }
    sides = [s for s in "SNWE" if s in road_sides and on_street[s]]
    if not sides:
        return None
    if roof is None:
        return sides[0]
    gaps = {"S": roof[1] - ly0, "N": ly1 - roof[3], "W": roof[0] - lx0, "E": lx1 - roof[2]}
    return min(sides, key=lambda s: gaps[s])


# ---------------------------------------------------------------- streets


def _axis(road: Rect) -> int:
    """0 if a road runs along x, 1 along y."""
    return 0 if road[2] - road[0] >= road[3] - road[1] else 1


def _subtract(lo: float, hi: float, cuts: list[tuple[float, float]]) -> list[tuple[float, float]]:
    """The parts of [lo, hi] outside every cut interval."""
    pieces = [(lo, hi)]
    for c0, c1 in cuts:
        pieces = [p for a, b in pieces for p in ((a, min(b, c0)), (max(a, c1), b)) if p[1] > p[0]]
    return pieces


def _junctions(road: Rect, roads: Sequence[Rect]) -> list[tuple[float, float]]:
    """Along-axis extents of the crossing roads that overlap a road."""
    k = _axis(road)
    return [(other[k], other[k + 2]) for other in roads
            if other is not road and _axis(other) != k and _overlaps(road, other)]


def _strip(road: Rect, a0: float, a1: float, c0: float, c1: float) -> Rect:
    """A rectangle of a road from along-axis a0..a1 and across-axis c0..c1."""
    return (a0, c0, a1, c1) if _axis(road) == 0 else (c0, a0, c1, a1)


def _dashes(a0: float, a1: float, phase: float) -> list[tuple[float, float]]:
    dash, gap = DASH_M
    out, pos = [], a0 + phase
    while pos + dash <= a1:
        out.append((pos, pos + dash))
        pos += dash + gap
    return out


def _crosswalk(road: Rect, a0: float, a1: float) -> list[Marking]:
    """Zebra stripes across a road between along-axis a0 and a1: bars along the traffic, 1 m apart."""
    k = _axis(road)
    c_lo, c_hi = road[1 - k], road[3 - k]
    bars = np.arange(c_lo + 0.6, c_hi - 0.6 - ZEBRA_M[0] + 1e-9, ZEBRA_M[0] + ZEBRA_M[1])
    return [Marking(_rect_polygon(*_strip(road, a0, a1, c, c + ZEBRA_M[0]))) for c in bars]


def _road_markings(rng: np.random.Generator, roads: Sequence[Rect], road_width: float,
                   zebra: float) -> list[Marking]:
    """A dashed centre line on streets; a double centre line and two dashed lane lines on avenues;
    zebra crossings at some junctions, where the lines stop short."""
    out = []
    for road in roads:
        k = _axis(road)
        lo, hi = road[k], road[k + 2]
        c_lo, c_hi = road[1 - k], road[3 - k]
        centre, width = (c_lo + c_hi) / 2, c_hi - c_lo
        cuts = []
        for a, b in _junctions(road, roads):
            if rng.random() < zebra:
                for z0, z1 in ((a - 1.0 - ZEBRA_DEPTH_M, a - 1.0), (b + 1.0, b + 1.0 + ZEBRA_DEPTH_M)):
                    if lo <= z0 and z1 <= hi:
                        out += _crosswalk(road, z0, z1)
                cuts.append((a - 2.0 - ZEBRA_DEPTH_M, b + 2.0 + ZEBRA_DEPTH_M))
            else:
                cuts.append((a - 1.5, b + 1.5))
        for a0, a1 in _subtract(lo + 1.0, hi - 1.0, cuts):
            if a1 - a0 < DASH_M[0]:
                continue
            if width > 1.4 * road_width:
                for offset in (-0.3, 0.3):
                    c = centre + offset
                    out.append(Marking(_rect_polygon(*_strip(road, a0, a1, c - LINE_M / 2, c + LINE_M / 2))))
                for offset in (-width / 4, width / 4):
                    c = centre + offset
                    out += [Marking(_rect_polygon(*_strip(road, d0, d1, c - LINE_M / 2, c + LINE_M / 2)))
                            for d0, d1 in _dashes(a0, a1, 1.0)]
            else:
                out += [Marking(_rect_polygon(*_strip(road, d0, d1, centre - LINE_M / 2, centre + LINE_M / 2)))
                        for d0, d1 in _dashes(a0, a1, 1.0)]
    return out


def _sidewalks(rng: np.random.Generator, blocks, verge: float, widths: tuple[float, float]) -> list[Paving]:
    """A kerb at the road edge and a sidewalk at the lot side of the verge, along every street side."""
    out = []
    for rect, sides in blocks:
        x0, y0, x1, y1 = rect
        width = rng.uniform(*widths)
        for side in sorted(sides):
            for kind, near, far in (("kerb", 0.0, KERB_M), ("sidewalk", verge - 0.3 - width, verge - 0.3)):
                strip = {"S": (x0, y0 + near, x1, y0 + far), "N": (x0, y1 - far, x1, y1 - near),
                         "W": (x0 + near, y0, x0 + far, y1), "E": (x1 - far, y0, x1 - near, y1)}[side]
                out.append(Paving(_rect_polygon(*strip), kind))
    return out


def _truck(rng: np.random.Generator, x: float, y: float, heading: float, longest: float) -> Car:
    length = min(rng.uniform(*TRUCK_LENGTH_M), longest)
    colour = pick(rng, TRUCK_COLOURS)
    return Car(_r(x), _r(y), _r(heading), _r(length), _r(rng.uniform(*TRUCK_WIDTH_M)), colour, "truck")


def _car(rng: np.random.Generator, x: float, y: float, heading: float) -> Car:
    return Car(_r(x), _r(y), _r(heading), _r(rng.uniform(*CAR_LENGTH_M)), _r(rng.uniform(*CAR_WIDTH_M)),
               pick(rng, CAR_COLOURS))


def _kerb_cars(rng: np.random.Generator, roads: Sequence[Rect], mouths: Sequence[Rect], density: float) -> list[Car]:
    """Cars parked along both kerbs of every road, clear of junctions and driveway mouths."""
    out = []
    for road in roads:
        k = _axis(road)
        lo, hi = road[k], road[k + 2]
        for side, edge in ((-1, road[1 - k]), (1, road[3 - k])):
            touching = [m for m in mouths if abs((m[3 - k] if side < 0 else m[1 - k]) - edge) < 1e-3
                        and m[k] < hi and m[k + 2] > lo]
            cuts = [(a - 6.0, b + 6.0) for a, b in _junctions(road, roads)]
            cuts += [(m[k] - 0.8, m[k + 2] + 0.8) for m in touching]
            across = edge - side * (0.4 + CAR_WIDTH_M[1] / 2)  # room for a slight slant
            heading = (0.0 if side < 0 else 180.0) + (90.0 if k == 1 else 0.0)
            for a0, a1 in _subtract(lo, hi, cuts):
                pos = a0 + rng.uniform(0.0, 3.0)
                while pos + CAR_LENGTH_M[1] <= a1:
                    length = CAR_LENGTH_M[1]
                    if rng.random() < density:
                        c = across + rng.uniform(-0.1, 0.1)
                        along = pos + length / 2
                        x, y = (along, c) if k == 0 else (c, along)
                        out.append(_car(rng, x, y, heading + rng.uniform(-2.0, 2.0)))
                    pos += length + rng.uniform(0.8, 2.5)
    return out


def _traffic(rng: np.random.Generator, roads: Sequence[Rect], parked: Sequence[Car], road_width: float,
             density: float) -> list[Car]:
    """Cars driving in the lanes (right-hand traffic), clear of junctions and of the parked cars."""
    out: list[Car] = []
    parked_boxes = [_grow(c.bbox, 0.3) for c in parked]
    for road in roads:
        k = _axis(road)
        lo, hi = road[k], road[k + 2]
        c_lo, c_hi = road[1 - k], road[3 - k]
        centre, width = (c_lo + c_hi) / 2, c_hi - c_lo
        if width > 1.4 * road_width:
            lanes = (-width / 8, -(width / 4 + 1.1), width / 8, width / 4 + 1.1)
        else:
            lanes = (-1.6, 1.6) if width >= 7.0 else (0.0,)
        junctions = [(a - 1.0, b + 1.0) for a, b in _junctions(road, roads)]
        taken = [box for box in parked_boxes if _overlaps(box, road)]
        for offset in lanes:
            forward = offset < 0 if offset else rng.random() < 0.5
            heading = (0.0 if forward else 180.0) + (90.0 if k == 1 else 0.0)
            for _ in range(rng.poisson(density * TRAFFIC_PER_100M * (hi - lo) / 100.0)):
                along = rng.uniform(lo + 3.0, hi - 3.0) if hi - lo > 6.0 else (lo + hi) / 2
                across = centre + offset
                car = _car(rng, *((along, across) if k == 0 else (across, along)), heading + rng.uniform(-1.0, 1.0))
                box = car.bbox
                on_road = box[0] >= road[0] and box[1] >= road[1] and box[2] <= road[2] and box[3] <= road[3]
                free = not any(a < along < b for a, b in junctions) and not any(_overlaps(box, t) for t in taken)
                if on_road and free:
                    out.append(car)
                    taken.append(_grow(box, 0.3))
    return out


# ---------------------------------------------------------------- lots


def _driveway(rng: np.random.Generator, car_rng: np.random.Generator, frame: _Frame, roof: Rect, verge: float,
              density: float) -> tuple[Rect, list[Car]]:
    """A concrete strip from the street to the house (beside it if the side yard has room), with cars."""
    u0, u1, v0, v1 = frame.local(roof)
    width = rng.uniform(*DRIVEWAY_M)
    left, right = u0, frame.frontage - u1
    on_right = right > left if abs(right - left) > 0.5 else rng.random() < 0.5
    gap = right if on_right else left
    if gap >= width + 0.6:  # beside the house, to a garage at the side
        a = u1 + 0.3 if on_right else u0 - 0.3 - width
        end = min(v1, v0 + rng.uniform(4.0, 9.0))
    else:  # to the house front
        a = u1 - width - rng.uniform(0.3, 1.5) if on_right else u0 + rng.uniform(0.3, 1.5)
        end = v0
    a = _clamp(a, 0.2, frame.frontage - width - 0.2)
    cars = []
    length = CAR_LENGTH_M[1]
    for n in range(2):  # inside the lot (the sidewalk stays free), clear of the roof
        v_mid = end - 0.3 - length / 2 - n * (length + 0.6)
        if v_mid - length / 2 < 0.3 or car_rng.random() >= density:
            break
        cx, cy, _, _ = frame.world(a + width / 2, a + width / 2, v_mid, v_mid)
        heading = frame.v_heading + (180.0 if car_rng.random() < 0.3 else 0.0) + car_rng.uniform(-3.0, 3.0)
        cars.append(_car(car_rng, cx, cy, heading))
    return frame.world(a, a + width, -verge, end), cars


def _parking_lot(rng: np.random.Generator, car_rng: np.random.Generator, frame: _Frame, roof: Rect | None,
                 verge: float, density: float, trucks: bool = False) -> tuple[list[Paving], list[Marking], list[Car]]:
    """The largest free strip of a lot beside its building (the whole lot if it has none), paved, with
    stalls and parked cars (or, with `trucks`, wide deep stalls with trucks)."""
    f, d = frame.frontage, frame.depth
    if roof is None:
        candidates = [(0.5, f - 0.5, 0.5, d - 0.5)]
    else:
        u0, u1, v0, v1 = frame.local(roof)
        candidates = [(0.5, f - 0.5, 0.5, v0 - 0.5), (0.5, f - 0.5, v1 + 0.5, d - 0.5),
                      (0.5, u0 - 0.5, 0.5, d - 0.5), (u1 + 0.5, f - 0.5, 0.5, d - 0.5)]
    stall, aisle = (TRUCK_STALL_M, TRUCK_AISLE_M) if trucks else (STALL_M, AISLE_M)
    module = stall[1] + aisle
    fitting = [c for c in candidates if min(c[1] - c[0], c[3] - c[2]) >= module]
    if not fitting:
        return [], [], []
    cu0, cu1, cv0, cv1 = max(fitting, key=lambda c: (c[1] - c[0]) * (c[3] - c[2]))
    region = frame.world(cu0, cu1, cv0, cv1)
    pavings = [Paving(_rect_polygon(*region), "parking")]
    if cv0 < 1.0:  # an entrance from the street
        width = min(6.0, cu1 - cu0)
        a = cu0 if rng.random() < 0.5 else cu1 - width
        pavings.append(Paving(_rect_polygon(*frame.world(a, a + width, -verge, cv0)), "driveway"))
    x0, y0, x1, y1 = region
    k = 0 if x1 - x0 >= y1 - y0 else 1  # rows of stalls run along the long side
    lo, hi = region[k], region[k + 2]
    c_lo, c_hi = region[1 - k], region[3 - k]
    rows = []  # (near, far, +1 if its aisle lies on the far side else -1)
    pos = c_lo
    while pos + module <= c_hi + 1e-9:
        double = pos + module + stall[1] <= c_hi + 1e-9
        rows.append((pos, pos + stall[1], 1))
        if double:
            rows.append((pos + module, pos + module + stall[1], -1))
        pos += module + stall[1] * double
    n = int((hi - lo - 1.0) // stall[0])
    start = lo + (hi - lo - n * stall[0]) / 2
    markings, cars = [], []
    for near, far, facing in rows:
        for i in range(n + 1):
            a = start + i * stall[0]
            markings.append(Marking(_rect_polygon(*_strip(region, a - LINE_M / 2, a + LINE_M / 2, near, far))))
        for i in range(n):
            if car_rng.random() >= density:
                continue
            along = start + (i + 0.5) * stall[0] + car_rng.uniform(-0.15, 0.15)
            if trucks:  # backed in: the trailer's end at the back of the stall, the cab towards the aisle
                heading = (90.0 if k == 0 else 0.0) + (0.0 if facing > 0 else 180.0) + car_rng.uniform(-1.0, 1.0)
                truck = _truck(car_rng, 0.0, 0.0, heading, stall[1] - 0.5)
                half = truck.length_m / 2 + 0.25
                across = near + half if facing > 0 else far - half
                x, y = (along, across) if k == 0 else (across, along)
                cars.append(replace(truck, x=_r(x), y=_r(y)))
                continue
            across = (near + far) / 2  # a 4.9 m car all but fills a 5 m stall
            nose_in = car_rng.random() < 0.8
            heading = (90.0 if k == 0 else 0.0) + (0.0 if (facing > 0) == nose_in else 180.0)
            x, y = (along, across) if k == 0 else (across, along)
            cars.append(_car(car_rng, x, y, heading + car_rng.uniform(-1.5, 1.5)))
    return pavings, markings, cars


def _loading_bay(rng: np.random.Generator, frame: _Frame, roof: Rect, taken: Sequence[Rect],
                 density: float) -> list[Car]:
    """Trucks backed up to the hall side with the deepest free yard, side by side, clear of `taken`."""
    u0, u1, v0, v1 = frame.local(roof)
    f, d = frame.frontage, frame.depth
    # (wall along lo..hi, free depth in front of it, local (u, v) of a point at `along` and `out` from the wall)
    sides = [(u0, u1, v0 - 0.5, lambda a, o: (a, v0 - o)), (u0, u1, d - 0.5 - v1, lambda a, o: (a, v1 + o)),
             (v0, v1, u0 - 0.5, lambda a, o: (u0 - o, a)), (v0, v1, f - 0.5 - u1, lambda a, o: (u1 + o, a))]
    lo, hi, depth, at = max(sides, key=lambda side: side[2])
    out: list[Car] = []
    if depth < TRUCK_LENGTH_M[0] + 1.0:
        return out
    pitch = TRUCK_STALL_M[0] + rng.uniform(-0.3, 0.5)
    for a in np.arange(lo + 1.0 + pitch / 2, hi - 1.0 - pitch / 2, pitch):
        if rng.random() >= density:
            continue
        truck = _truck(rng, 0.0, 0.0, 0.0, depth - 0.5)
        (x0, y0), (x1, y1) = (frame.world(u, u, v, v)[:2] for u, v in (at(a, 0.3), at(a, 0.3 + truck.length_m)))
        heading = math.degrees(math.atan2(y1 - y0, x1 - x0)) + rng.uniform(-2.0, 2.0)
        placed = replace(truck, x=_r((x0 + x1) / 2), y=_r((y0 + y1) / 2), heading_deg=_r(heading))
        if not any(_overlaps(placed.bbox, t, 0.2) for t in taken):
            out.append(placed)
    return out


def _pool(rng: np.random.Generator, frame: _Frame, roof: Rect) -> Pool | None:
    """A pool in the back yard, 1.5 m behind the house and 1 m inside the lot, if it fits."""
    _, _, _, v1 = frame.local(roof)
    length, width, coping = rng.uniform(6.0, 10.0), rng.uniform(3.0, 5.0), rng.uniform(0.3, 0.6)
    free_u = frame.frontage - 2.0 - (length + 2 * coping)
    free_v = frame.depth - 1.0 - (v1 + 1.5) - (width + 2 * coping)
    if free_u < 0 or free_v < 0:
        return None
    a = 1.0 + rng.uniform(0.0, free_u)
    b = v1 + 1.5 + rng.uniform(0.0, free_v)
    return Pool(_rect_polygon(*frame.world(a, a + length + 2 * coping, b, b + width + 2 * coping)), _r(coping))


def _shrubs(rng: np.random.Generator, frame: _Frame, roof: Rect | None, density: float,
            taken: list[Rect]) -> list[Shrub]:
    """Hedges along a lot's edges (in pieces, broken where something else stands) and bushes by its house."""
    out: list[Shrub] = []
    lot = frame.rect
    blocked = list(taken) + ([_grow(roof, 0.2)] if roof else [])

    def add(rect: Rect, height: float) -> None:
        inside = rect[0] >= lot[0] and rect[1] >= lot[1] and rect[2] <= lot[2] and rect[3] <= lot[3]
        if inside and not any(_overlaps(rect, b, -0.01) for b in blocked):  # touching pieces make one hedge
            shrub = Shrub(_rect_polygon(*rect), _r(height))
            out.append(shrub)
            blocked.append(shrub.bbox)

    f, d = frame.frontage, frame.depth
    for edge in ("front", "back", "left", "right"):
        if rng.random() >= density * (0.35 if edge == "front" else 0.6):
            continue
        thick, base = rng.uniform(0.6, 1.1), rng.uniform(0.9, 1.8)
        length = f if edge in ("front", "back") else d
        pos = 0.1
        while pos < length - 0.6:
            piece = min(rng.uniform(3.0, 8.0), length - 0.1 - pos)
            u_or_v = (pos, pos + piece)
            if edge == "front":
                rect = frame.world(*u_or_v, 0.1, 0.1 + thick)
            elif edge == "back":
                rect = frame.world(*u_or_v, d - 0.1 - thick, d - 0.1)
            elif edge == "left":
                rect = frame.world(0.1, 0.1 + thick, *u_or_v)
            else:
                rect = frame.world(f - 0.1 - thick, f - 0.1, *u_or_v)
            add(rect, base * rng.uniform(0.85, 1.15))
            pos += piece
    if roof is not None:
        x0, y0, x1, y1 = roof
        for _ in range(rng.poisson(density * 2 * ((x1 - x0) + (y1 - y0)) / 5.0)):
            size = rng.uniform(0.8, 2.2)
            off = 0.3 + size / 2 + rng.uniform(0.0, 1.0)
            side = int(rng.integers(4))
            t = rng.uniform(0.0, 1.0)
            cx, cy = {0: (x0 + t * (x1 - x0), y0 - off), 1: (x0 + t * (x1 - x0), y1 + off),
                      2: (x0 - off, y0 + t * (y1 - y0)), 3: (x1 + off, y0 + t * (y1 - y0))}[side]
            w, h = size * rng.uniform(0.8, 1.25), size
            add((cx - w / 2, cy - h / 2, cx + w / 2, cy + h / 2), rng.uniform(0.5, 1.6))
    return out


def generate_clutter(rng: np.random.Generator, params, blocks, lots, buildings, roads: Sequence[Rect],
                     verge_m: float, road_width_m: float, rules: GridRules = SUBURBAN) -> Clutter:
    """Street details, cars, pools and shrubs for a street grid of one style (see the module docstring).

    `blocks` are (rect, road sides) pairs, `lots` (rect, block index) pairs. Each knob draws from its
    own stream, so changing `params.car_density` moves no pool, shrub or paving.
    """
    street_rng, car_rng, pool_rng, shrub_rng = (
        np.random.Generator(np.random.PCG64(child))
        for child in np.random.SeedSequence(int(rng.integers(2**63))).spawn(4))
    by_lot = {b.lot_index: b for b in buildings}
    pavings: list[Paving] = []
    markings: list[Marking] = []
    cars: list[Car] = []
    pools: list[Pool] = []
    shrubs: list[Shrub] = []
    no_trunks: list[Rect] = []
    taken: dict[int, list[Rect]] = {}
    if params.street_details:
        pavings += _sidewalks(street_rng, blocks, verge_m, rules.sidewalk_m)
        markings += _road_markings(street_rng, roads, road_width_m, rules.zebra)
    for index, (rect, block_index) in enumerate(lots):
        building = by_lot.get(index)
        if building is None:
            if rules.paved_lots:  # an empty paved lot is a parking lot
                block_rect, sides = blocks[block_index]
                front = _front(rect, block_rect, sides, verge_m, None)
                if front is not None:
                    lot_pavings, lot_markings, lot_cars = _parking_lot(
                        street_rng, car_rng, _Frame(rect, front), None, verge_m, params.car_density, rules.trucks)
                    no_trunks += [p.bbox for p in lot_pavings]
                    if params.street_details:
                        pavings += lot_pavings
                        markings += lot_markings
                        cars += lot_cars
            continue
        block_rect, sides = blocks[block_index]
        roof = building.bbox
        front = _front(rect, block_rect, sides, verge_m, roof)
        if front is None:
            continue
        frame = _Frame(rect, front)
        here = taken.setdefault(index, [])
        # Every lot draws its driveway or parking lot whatever the knobs, so the streams stay aligned.
        if building.kind in ("office", "industrial", "apartment"):
            lot_pavings, lot_markings, lot_cars = _parking_lot(street_rng, car_rng, frame, roof, verge_m,
                                                               params.car_density)
        else:
            lot_pavings, lot_markings, lot_cars = [], [], []
        if not lot_pavings and building.kind in ("residential", "apartment"):
            drive, lot_cars = _driveway(street_rng, car_rng, frame, roof, verge_m, params.car_density)
            lot_pavings = [Paving(_rect_polygon(*drive), "driveway")]
        if building.kind in PAVED_LOTS:
            if not any(p.kind == "driveway" for p in lot_pavings):  # an entrance from the street
                width = min(6.0, frame.frontage - 1.0)
                a = street_rng.uniform(0.5, frame.frontage - 0.5 - width)
                lot_pavings.append(Paving(_rect_polygon(*frame.world(a, a + width, -verge_m, 0.0)), "driveway"))
            lot_pavings.insert(0, Paving(_rect_polygon(*rect), "yard"))
        here += [p.bbox for p in lot_pavings]
        if params.street_details:
            pavings += [p for p in lot_pavings if not (rules.paved_lots and p.kind == "yard")]
            markings += lot_markings
            if params.car_density > 0:
                cars += lot_cars
        if rules.trucks and building.kind == "industrial" and params.car_density > 0:
            busy = [p.bbox for p in lot_pavings if p.kind != "yard"] + [c.bbox for c in lot_cars]
            trucks = _loading_bay(car_rng, frame, roof, busy, params.car_density)
            cars += trucks  # on the paved lot, where no trunk stands anyway
        if (rules.pools and building.kind == "residential" and params.pool_share > 0
                and pool_rng.random() < params.pool_share):
            pool = _pool(pool_rng, frame, roof)
            if pool is not None:
                pools.append(pool)
                here.append(_grow(pool.bbox, 0.3))
        no_trunks += here
    if params.car_density > 0:
        mouths = [p.bbox for p in pavings if p.kind == "driveway"]
        parked = _kerb_cars(car_rng, roads, mouths, rules.kerb_cars * params.car_density)
        cars += parked + _traffic(car_rng, roads, cars + parked, road_width_m, rules.traffic * params.car_density)
    if params.shrub_density > 0 and rules.hedges:
        for index, (rect, block_index) in enumerate(lots):
            building = by_lot.get(index)
            block_rect, sides = blocks[block_index]
            roof = building.bbox if building else None
            front = _front(rect, block_rect, sides, verge_m, roof) or "S"
            if building is None or building.kind in ("residential", "apartment"):
                shrubs += _shrubs(shrub_rng, _Frame(rect, front), roof, params.shrub_density, taken.get(index, []))
    return Clutter(tuple(pavings), tuple(markings), tuple(cars), tuple(pools), tuple(shrubs), tuple(no_trunks))


# ---------------------------------------------------------------- real trees


def _diameter(rng: np.random.Generator, hi: float = TREE_DIAMETER_M[1]) -> float:
    """Crown diameters skewed to 5-9 m with a tail of big trees."""
    return _clamp(rng.lognormal(math.log(6.8), 0.3), TREE_DIAMETER_M[0], hi)


def _height(rng: np.random.Generator, diameter: float) -> float:
    return _clamp(1.2 * diameter + 1.5 + rng.normal(0.0, 1.2), *TREE_HEIGHT_M)


class _Buckets:
    """Boxes filed by the grid cells they touch, so a query looks at the few boxes near a point."""

    CELL_M = 40.0

    def __init__(self, boxes: Sequence[Rect]):
        self.cells: dict[tuple[int, int], list[Rect]] = {}
        for box in boxes:
            x0, y0, x1, y1 = box
            for cx in range(int(x0 // self.CELL_M), int(x1 // self.CELL_M) + 1):
                for cy in range(int(y0 // self.CELL_M), int(y1 // self.CELL_M) + 1):
                    self.cells.setdefault((cx, cy), []).append(box)

    def near(self, x: float, y: float, reach: float) -> list[Rect]:
        """The boxes of the cells within `reach` of (x, y); a box in several of them comes as often (the
        callers ask whether any is near: it makes no difference)."""
        found: list[Rect] = []
        for cx in range(int((x - reach) // self.CELL_M), int((x + reach) // self.CELL_M) + 1):
            for cy in range(int((y - reach) // self.CELL_M), int((y + reach) // self.CELL_M) + 1):
                found += self.cells.get((cx, cy), ())
        return found


class _Stand:
    """The trees placed so far, and the test a new crown must pass."""

    def __init__(self, roofs: Sequence[Rect], no_trunks: Sequence[Rect], width: float, height: float):
        self.roofs, self.no_trunks = _Buckets(roofs), _Buckets(no_trunks)
        self.width, self.height = width, height
        self._xyr = np.zeros((64, 3))  # grown by doubling; the first len(self.trees) rows are placed
        self.trees: list[tuple[float, float, float, float]] = []

    @property
    def xyr(self) -> np.ndarray:
        return self._xyr[:len(self.trees)]

    def fits(self, x: float, y: float, r: float, overlap: float) -> bool:
        if x - r < 0 or y - r < 0 or x + r > self.width or y + r > self.height:
            return False
        reach = r + CLEARANCE_M
        for x0, y0, x1, y1 in self.roofs.near(x, y, reach):
            dx, dy = max(x0 - x, x - x1, 0.0), max(y0 - y, y - y1, 0.0)
            # The distance to a box is at least either leg: only a box within reach along both is measured.
            if dx < reach and dy < reach and np.hypot(dx, dy) < reach:
                return False
        trunks = self.no_trunks.near(x, y, 0.5)
        if any(x0 - 0.5 < x < x1 + 0.5 and y0 - 0.5 < y < y1 + 0.5 for x0, y0, x1, y1 in trunks):
            return False
        if len(self.xyr):
            gap = np.hypot(self.xyr[:, 0] - x, self.xyr[:, 1] - y)
            if np.any(gap < overlap * (self.xyr[:, 2] + r)):
                return False
        return True

    def add(self, rng: np.random.Generator, x: float, y: float, diameter: float) -> None:
        if len(self.trees) == len(self._xyr):
            self._xyr = np.vstack([self._xyr, np.zeros_like(self._xyr)])
        self._xyr[len(self.trees)] = (x, y, diameter / 2)
        self.trees.append((_r(x), _r(y), _r(diameter / 2), _r(_height(rng, diameter))))


def real_trees(rng: np.random.Generator, density: float, blocks, lots, roofs: Sequence[Rect], no_trunks,
               width: float, height: float, verge_m: float, row_offset_m: float,
               rules: GridRules = SUBURBAN) -> list[tuple[float, float, float, float]]:
    """Trees of real sizes as (x, y, crown radius, height): rows of one kind along verges (trunks
    `row_offset_m` from the kerb) and groups in yards and parks, as often as the grid's `rules` say.
    Crowns may reach over roads and neighbouring yards but never over a roof outline (the roof boxes
    given)."""
    stand = _Stand(roofs, no_trunks, width, height)
    for rect, sides in blocks:
        x0, y0, x1, y1 = rect
        for side in sorted(sides):
            if rng.random() >= min(1.0, rules.tree_rows[0] + rules.tree_rows[1] * density):
                continue
            lo, hi = (x0, x1) if side in "SN" else (y0, y1)
            across = {"S": y0 + row_offset_m, "N": y1 - row_offset_m,
                      "W": x0 + row_offset_m, "E": x1 - row_offset_m}[side]
            d0 = _diameter(rng, STREET_TREE_DIAMETER_M)
            pos = lo + verge_m + rng.uniform(0.0, d0 / 2)
            while pos < hi - verge_m:
                d = _clamp(d0 * rng.uniform(0.85, 1.15), TREE_DIAMETER_M[0], STREET_TREE_DIAMETER_M)
                x, y = (pos, across) if side in "SN" else (across, pos)
                if rng.random() < 0.75 + 0.25 * density and stand.fits(x, y, d / 2, 0.45):
                    stand.add(rng, x, y, d)
                pos += d0 * rng.uniform(0.9, 1.3)
    for (x0, y0, x1, y1), built in lots:
        area = (x1 - x0) * (y1 - y0)
        groups = rng.poisson(rules.yard_trees * density * area / (250.0 if built else 120.0))
        for _ in range(groups):
            cx, cy = rng.uniform(x0, x1), rng.uniform(y0, y1)
            d0 = _diameter(rng)
            spread = d0 * rng.uniform(0.3, 0.6)  # neighbours' crowns touch and merge into one canopy
            for _ in range(1 + rng.poisson(1.5 if built else 3.0)):
                for attempt in range(4):  # a crown too big for a yard is tried smaller
                    d = _clamp(d0 * rng.uniform(0.75, 1.25) * 0.8 ** attempt, *TREE_DIAMETER_M)
                    x, y = cx + rng.normal(0.0, spread), cy + rng.normal(0.0, spread)
                    if x0 < x < x1 and y0 < y < y1 and stand.fits(x, y, d / 2, 0.35):
                        stand.add(rng, x, y, d)
                        break
    return stand.trees


# ---------------------------------------------------------------- dense towns and through roads
#
# Places without a street grid: items are turned any way, and tested against the exact roof and road
# outlines (`polygons.Occupancy`) rather than boxes.

DENSE_M2_PER_TREE = 6.0  # of open ground (room for the smallest crown) per try at tree_density 1
DENSE_CARS_PER_100M = 3.0  # cars parked per 100 m of lane at car_density 1
DENSE_M2_PER_BUSH = 12.0  # of open ground per try at shrub_density 1


def _lane_spot(rng: np.random.Generator, lane) -> tuple[float, float, float, float, float]:
    """A random point on a lane's centre line, the unit normal towards a random side of it, and the
    lane's direction in degrees."""
    (ax, ay), (bx, by), _ = lane
    length = math.hypot(bx - ax, by - ay)
    dx, dy = (bx - ax) / length, (by - ay) / length
    t, side = rng.uniform(0.0, length), (1.0 if rng.random() < 0.5 else -1.0)
    return ax + dx * t, ay + dy * t, -side * dy, side * dx, math.degrees(math.atan2(dy, dx))


def lane_cars(rng: np.random.Generator, density: float, lanes, window: Polygon, roofs: polygons.Occupancy,
              taken: polygons.Occupancy) -> list[Car]:
    """A few cars parked at the edges of a dense town's lanes, as far off the lane as the houses leave
    room for (from beside the lane to on its edge), inside `window`, clear of roofs and of `taken`
    (which gets them)."""
    out = []
    for lane in lanes:
        (ax, ay), (bx, by), width = lane
        for _ in range(rng.poisson(density * DENSE_CARS_PER_100M * math.hypot(bx - ax, by - ay) / 100.0)):
            x, y, nx, ny, angle = _lane_spot(rng, lane)
            car = _car(rng, x, y, angle + (180.0 if rng.random() < 0.5 else 0.0) + rng.uniform(-4.0, 4.0))
            for shift in (1.2, 0.6, 0.0, -0.6, -1.1):  # the car's centre this far beyond the lane's edge
                off = width / 2 + shift
                moved = replace(car, x=_r(x + nx * off), y=_r(y + ny * off))
                outline = moved.corners
                if (polygons.inside(outline, window, 0.0) and roofs.clear(polygons.grown_box(outline, 0.3), 0.0)
                        and taken.clear(polygons.grown_box(outline, 0.3), 0.0)):
                    out.append(moved)
                    taken.add(outline)
                    break
    return out


def _crown_fits(x: float, y: float, r: float, xyr: np.ndarray, city: Rect, roofs: polygons.Occupancy) -> bool:
    """Whether a crown stays in the city, clear of every roof, and apart from the crowns `xyr` (x, y, r)."""
    inside = city[0] <= x - r and city[1] <= y - r and x + r <= city[2] and y + r <= city[3]
    apart = not len(xyr) or np.all(np.hypot(xyr[:, 0] - x, xyr[:, 1] - y) >= 0.4 * (xyr[:, 2] + r))
    return inside and apart and roofs.clear(polygons.disc(x, y, r + CLEARANCE_M), 0.0)


class OpenGround:
    """A raster of a dense town's ground in cells of `CELL_M`: which cell centres lie in its window, under
    a roof or on a road, so tries are drawn where there is room (each try is then checked exactly)."""

    CELL_M = 0.5

    def __init__(self, window: Polygon, roofs: polygons.Occupancy, roads: polygons.Occupancy):
        x0, y0, x1, y1 = _polygon_bbox(window)
        c = self.CELL_M
        self.xs = x0 + (np.arange(max(1, math.ceil((x1 - x0) / c))) + 0.5) * c
        self.ys = y0 + (np.arange(max(1, math.ceil((y1 - y0) / c))) + 0.5) * c
        self.inside = self._fill([window])
        self.roofs = self._fill([p for p, box in roofs.items if _overlaps(box, (x0, y0, x1, y1), 8.0)])
        self.roads = self._fill([p for p, box in roads.items if _overlaps(box, (x0, y0, x1, y1), 8.0)])

    def _fill(self, outlines) -> np.ndarray:
        """Cells whose centres lie inside any of the (counter-clockwise, convex) outlines."""
        mask = np.zeros((len(self.ys), len(self.xs)), bool)
        tolerance = -1e-9 * self.CELL_M
        xs, ys = self.xs.tolist(), self.ys.tolist()  # bisect on lists finds what searchsorted finds, sooner
        for outline in outlines:
            x0, y0, x1, y1 = _polygon_bbox(outline)
            i0, i1 = bisect.bisect_left(xs, x0), bisect.bisect_left(xs, x1)
            j0, j1 = bisect.bisect_left(ys, y0), bisect.bisect_left(ys, y1)
            if i0 >= i1 or j0 >= j1:
                continue
            gx, gy = self.xs[i0:i1], self.ys[j0:j1, None]  # broadcast to the (j, i) cells
            inside = mask[j0:j1, i0:i1]  # a view: the cells are set in place
            inside |= np.logical_and.reduce([(bx - ax) * (gy - ay) - (by - ay) * (gx - ax) >= tolerance
                                             for (ax, ay), (bx, by) in zip(outline, outline[1:] + outline[:1])])
        return mask

    def _grown(self, mask: np.ndarray, reach: float) -> np.ndarray:
        """Cells within `reach` of a set cell."""
        out = mask.copy()
        k = reach / self.CELL_M
        n, (ny, nx) = math.ceil(k), mask.shape
        for dy in range(-n, n + 1):
            for dx in range(-n, n + 1):
                if (dx or dy) and dx * dx + dy * dy <= k * k:
                    out[max(dy, 0):ny + min(dy, 0), max(dx, 0):nx + min(dx, 0)] |= \
                        mask[max(-dy, 0):ny - max(dy, 0), max(-dx, 0):nx - max(dx, 0)]
        return out

    def open(self, roof_gap: float, road_gap: float) -> np.ndarray:
        """Flat indices of the cells in the window at least about `roof_gap` from roofs and `road_gap` from roads."""
        return np.flatnonzero(self.inside & ~self._grown(self.roofs, roof_gap) & ~self._grown(self.roads, road_gap))

    def spot(self, rng: np.random.Generator, cells: np.ndarray) -> tuple[float, float]:
        """A random point in a random one of the cells."""
        j, i = divmod(int(cells[rng.integers(len(cells))]), len(self.xs))
        h = self.CELL_M / 2
        return self.xs[i] + rng.uniform(-h, h), self.ys[j] + rng.uniform(-h, h)


def gap_trees(rng: np.random.Generator, density: float, ground: OpenGround, window: Polygon, city: Rect,
              roofs: polygons.Occupancy, roads: polygons.Occupancy) -> list[tuple[float, float, float, float]]:
    """Real-sized trees of a dense town as (x, y, crown radius, height): in the gaps between its houses
    and by its lanes, a crown too big for its gap tried smaller. Trunks stand inside `window` and off the
    roads; crowns stay inside the city and clear of every roof, and may reach over lanes."""
    cells = ground.open(TREE_DIAMETER_M[0] / 2, 0.5)
    placed: list[tuple[float, float, float, float]] = []
    xyr = np.zeros((0, 3))
    for _ in range(rng.poisson(density * len(cells) * ground.CELL_M ** 2 / DENSE_M2_PER_TREE) if len(cells) else 0):
        x, y = ground.spot(rng, cells)
        trunk = _rect_polygon(x - 0.5, y - 0.5, x + 0.5, y + 0.5)
        d0 = _diameter(rng)
        if not (polygons.inside(((x, y),), window, 0.0) and roads.clear(trunk, 0.0)
                and _crown_fits(x, y, TREE_DIAMETER_M[0] / 2, xyr, city, roofs)):
            continue
        d = next((d for d in (d0, 0.8 * d0, 0.64 * d0)
                  if d > TREE_DIAMETER_M[0] and _crown_fits(x, y, d / 2, xyr, city, roofs)), TREE_DIAMETER_M[0])
        placed.append((_r(x), _r(y), _r(d / 2), _r(_height(rng, d))))
        xyr = np.vstack([xyr, (x, y, d / 2)])
    return placed


def gap_bushes(rng: np.random.Generator, density: float, ground: OpenGround, window: Polygon,
               roofs: polygons.Occupancy, roads: polygons.Occupancy, taken: polygons.Occupancy) -> list[Shrub]:
    """Bushes in the yards of a dense town: inside `window`, clear of roofs, roads and `taken` (which
    gets them)."""
    cells = ground.open(1.0, 1.0)
    out = []
    for _ in range(rng.poisson(density * len(cells) * ground.CELL_M ** 2 / DENSE_M2_PER_BUSH) if len(cells) else 0):
        cx, cy = ground.spot(rng, cells)
        size = rng.uniform(0.8, 2.2)
        w = size * rng.uniform(0.8, 1.25)
        rect = _rect_polygon(cx - w / 2, cy - size / 2, cx + w / 2, cy + size / 2)
        height = rng.uniform(0.5, 1.8)
        room = polygons.grown_box(rect, 0.3)
        if (polygons.inside(rect, window, 0.0) and roofs.clear(room, 0.0) and roads.clear(room, 0.0)
                and taken.clear(polygons.grown_box(rect, 0.1), 0.0)):
            out.append(Shrub(rect, _r(height)))
            taken.add(rect)
    return out


def _road_frame(polygon: Polygon) -> tuple[float, float, float, float, float, float, float]:
    """(cx, cy, direction in degrees, along lo, along hi, across lo, across hi) of a straight road:
    its long edges' direction, and its extents along and across it about the centroid."""
    edges = list(zip(polygon, polygon[1:] + polygon[:1]))
    (ax, ay), (bx, by) = max(edges, key=lambda e: math.dist(*e))
    angle = math.atan2(by - ay, bx - ax)
    dx, dy = math.cos(angle), math.sin(angle)
    cx, cy = sum(p[0] for p in polygon) / len(polygon), sum(p[1] for p in polygon) / len(polygon)
    along = [(x - cx) * dx + (y - cy) * dy for x, y in polygon]
    across = [-(x - cx) * dy + (y - cy) * dx for x, y in polygon]
    return cx, cy, math.degrees(angle), min(along), max(along), min(across), max(across)


def _on_road(frame, along: float, across: float) -> tuple[float, float]:
    """The world point `along` and `across` a road's `_road_frame`."""
    return _on_road_all(frame, ((along, across),))[0]


def _on_road_all(frame, points) -> Polygon:
    """`_on_road` of each (along, across) pair, the road's direction turned into a vector once."""
    cx, cy, angle = frame[:3]
    dx, dy = math.cos(math.radians(angle)), math.sin(math.radians(angle))
    return tuple((cx + along * dx - across * dy, cy + along * dy + across * dx) for along, across in points)


def through_roads(rng: np.random.Generator, roads, all_roads: polygons.Occupancy,
                  taken: polygons.Occupancy) -> tuple[list[Marking], list[Car]]:
    """Markings and traffic of the straight through roads between city regions, given as (polygon,
    marked, car density) triples: a dashed centre line on the marked ones and cars driving on both sides
    (right-hand traffic), stopping short of the other roads in `all_roads` that meet them, the cars
    clear of `taken` (which gets them)."""
    markings, cars = [], []
    for road, mark, density in roads:
        frame = _road_frame(road)
        _, _, angle, lo, hi, c_lo, c_hi = frame
        centre = (c_lo + c_hi) / 2
        if mark:
            s = lo + 1.0
            while s + DASH_M[0] <= hi - 1.0:
                dash = polygons.oriented_rect(*_on_road(frame, s + DASH_M[0] / 2, centre), DASH_M[0], LINE_M, angle)
                if polygons.inside(dash, road, 0.0) and all_roads.clear(polygons.grown_box(dash, 1.0), 0.0, skip=road):
                    markings.append(Marking(polygons.rounded_polygon(dash)))
                s += DASH_M[0] + DASH_M[1]
        half = (c_hi - c_lo) / 4
        for offset, heading in ((centre - half, angle), (centre + half, angle + 180.0)):
            for _ in range(rng.poisson(density * TRAFFIC_PER_100M * (hi - lo) / 100.0)):
                car = _car(rng, *_on_road(frame, rng.uniform(lo, hi), offset), heading + rng.uniform(-1.0, 1.0))
                outline = car.corners
                if (polygons.inside(outline, road, 0.0)
                        and all_roads.clear(polygons.grown_box(outline, 1.0), 0.0, skip=road)
                        and taken.clear(polygons.grown_box(outline, 0.5), 0.0)):
                    cars.append(car)
                    taken.add(outline)
    return markings, cars


THROUGH_STEP_M = 1.0  # a through road's kerbs and sidewalks are laid in pieces this long, each checked
THROUGH_ROAD_GAP_M = 0.5  # they stop this far short of the roads that meet the through road
SIDEWALK_NARROWING_M = 0.5  # a sidewalk narrows in steps of this where the ground beside it is taken
SIDEWALK_MIN_M = 1.0  # and stops where less than this is left
MIN_RUN_M = 2.0  # a kerb or sidewalk piece shorter than this is left out


def _beside(frame, edge: float, sign: float, s0: float, s1: float, a: float, b: float,
            grow: float = 0.0) -> Polygon:
    """The counter-clockwise piece of ground from s0 to s1 along a road's `_road_frame`, a to b metres out
    from its edge at `edge` across (on the side `sign` points to), grown by `grow` all round."""
    c0, c1 = (edge + a, edge + b) if sign > 0 else (edge - b, edge - a)
    return _on_road_all(frame, ((s0 - grow, c0 - grow), (s1 + grow, c0 - grow), (s1 + grow, c1 + grow),
                                (s0 - grow, c1 + grow)))


def through_sidewalks(rng: np.random.Generator, roads: Sequence[Polygon], regions, all_roads: polygons.Occupancy,
                      taken: polygons.Occupancy) -> list[Paving]:
    """Kerbs and sidewalks along the straight through roads between city regions: on each side a kerb at
    the road's edge and a sidewalk right behind it (no verge: the lots reach the road). `regions` are
    (window, sidewalk width range) pairs, the range None where a region has no sidewalks (a dense town);
    each side of a road takes the range of the region it borders and draws its width from it. A piece
    stays inside its region's window, off every road but its own (`THROUGH_ROAD_GAP_M` short of those that
    meet it) and off what `taken` holds (lots, pavings); where that ground comes nearer, the sidewalk
    narrows, down to `SIDEWALK_MIN_M`, and stops below it."""
    out: list[Paving] = []
    for road in roads:
        frame = _road_frame(road)
        lo, hi, c_lo, c_hi = frame[3:]
        steps = int((hi - lo) // THROUGH_STEP_M)
        for sign, edge in ((-1.0, c_lo), (1.0, c_hi)):
            u = rng.random()  # drawn for every side, so one side's region leaves the other's width alone
            probe = _on_road(frame, (lo + hi) / 2, edge + sign * 1.0)
            window, widths = next(((window, widths) for window, widths in regions
                                   if polygons.inside((probe,), window, 0.0)), (None, None))
            if widths is None:
                continue
            width = widths[0] + u * (widths[1] - widths[0])
            narrowed = [width - k * SIDEWALK_NARROWING_M
                        for k in range(int((width - SIDEWALK_MIN_M) // SIDEWALK_NARROWING_M) + 1)]
            for kind, start, choices in (("kerb", 0.0, [KERB_M]), ("sidewalk", KERB_M, narrowed)):
                runs: list[list] = []  # [first step, step after the last, width]
                for i in range(steps):
                    s0, s1 = lo + i * THROUGH_STEP_M, lo + (i + 1) * THROUGH_STEP_M
                    w = next((w for w in choices
                              if polygons.inside(_beside(frame, edge, sign, s0, s1, start, start + w), window, 0.0)
                              and all_roads.clear(_beside(frame, edge, sign, s0, s1, start, start + w,
                                                          THROUGH_ROAD_GAP_M), 0.0, skip=road)
                              and taken.clear(_beside(frame, edge, sign, s0, s1, start, start + w, 0.01), 0.0)),
                             None)
                    if w is not None and runs and runs[-1][1] == i and runs[-1][2] == w:
                        runs[-1][1] = i + 1
                    elif w is not None:
                        runs.append([i, i + 1, w])
                out += [Paving(polygons.rounded_polygon(_beside(frame, edge, sign, lo + i0 * THROUGH_STEP_M,
                                                                lo + i1 * THROUGH_STEP_M, start, start + w)), kind)
                        for i0, i1, w in runs if (i1 - i0) * THROUGH_STEP_M >= MIN_RUN_M]
    return out

"""Procedural city layout from a seed: roads, blocks, lots, buildings, trees.

Pure Python and numpy, no ``bpy``: the Blender builder turns a `CityLayout`
into a scene and the label passes take roof classes and instance ids from it.

Coordinates are metres, X east, Y north, ground at z = 0; the city covers
``[0, width_m] x [0, height_m]``. The rules follow Synthinel-1 (CityEngine):
a jittered street grid with some blocks merged and a few wider avenues;
blocks cut along their long side into 16-30 m frontages, two rows back to
back; building kinds residential / apartment / office / industrial /
highrise in about 63 / 5 / 13 / 10 / 9 percent of buildings over a 1-2 km
city (highrises only near the centre, industrial on whole-depth lots);
residential eave heights 3-3.5 or 5-6.5 m times a height factor; roof pitch
15-25 degrees, overhang 0.2-0.6 m.

That is the `suburban` style. `LayoutParams.style` mixes it with others:
the city is cut into Voronoi regions of about `REGION_M`, each region gets
one style (regions ranked at random, their areas cut at the mix's shares)
and streets run on the borders between regions of different
grids. `dense` regions are packed informal towns: long lanes bent at a few
kinks and short dirt tracks between them, all at the region's own angle;
houses turned with their lane stand in rows along each lane side and in
clusters grown from seeds in the blocks, often sharing a wall. `downtown`
and `industrial` regions take a street grid turned by an angle of its own,
with their own zones, on paved lots.

Every stage draws from its own generator spawned from the seed, so changing
`LayoutParams.tree_density` leaves roads and buildings unchanged, and
`sloped_share` changes roofs only. All stored floats are rounded to 0.1 mm so
the JSON of a layout is stable.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Mapping
from dataclasses import dataclass, replace
from functools import cached_property
from typing import Any

import numpy as np

from ..core.errors import MetaSimError
from . import polygons
from .clutter import (
    CUT_CORNERS,
    GRID_RULES,
    TREE_SIZES,
    Car,
    Marking,
    OpenGround,
    Paving,
    Pool,
    Shrub,
    gap_bushes,
    gap_trees,
    generate_clutter,
    lane_cars,
    real_trees,
    through_roads,
    through_sidewalks,
)
from .draws import pick, sign
from .water import Water, flood, water_bodies

LAYOUT_VERSION = 1
# What a city of the richer scene (a style other than the suburban grid, or roof furniture) shows, beyond
# its layout: tile headers and training-set keys of such cities carry it, so their caches are rendered and
# trained again when it changes (``scene_version``). 2: water tanks on flat roofs and kerbs and sidewalks
# along the roads between style regions. 3: the fast preset lights such a city with its own sun and sky
# (``quality.sun_studio_light``), so sloped roofs show a sunlit and a shaded side. 4: the fast preset's shadows
# cast from the sun's direction (``quality.workbench_direction``).
SCENE_VERSION = 4
TILE_M = 115.2  # 384 px at 0.3 m per pixel

KINDS = ("residential", "apartment", "office", "industrial", "highrise")
ROOFS = ("flat", "gable", "hip")
SHAPES = ("rect", "L", "T")
# Eave height ranges in metres; generate_layout keeps every building inside its kind's range.
HEIGHT_RANGES_M = {
    "residential": (2.8, 10.0),
    "apartment": (9.0, 24.0),
    "office": (10.0, 30.0),
    "industrial": (6.0, 12.0),
    "highrise": (40.0, 120.0),
}
PITCH_RANGE_DEG = (15.0, 25.0)
OVERHANG_RANGE_M = (0.2, 0.6)
PARAPET_RANGE_M = (0.3, 1.0)

VERGE_M = 5.0  # sidewalk and planting strip between kerb and lots; street trees stand here
# Roof outlines keep this far inside their lot, so outlines on neighbouring lots are >= 1 m apart.
BUILDING_MARGIN_M = 0.5
MIN_BUILDING_SIDE_M = 6.0
MIN_EDGE_BLOCK_M = 20.0  # a street closer than this to the city edge would leave an unusable sliver
AVENUE_PROBABILITY = 0.12
AVENUE_WIDTH_FACTOR = 1.8
MERGE_PROBABILITY = 0.1  # per cell and direction: merged cells make the grid irregular
CENTRAL_RADIUS_SHARE = 0.3  # of the shorter city side: highrises stand only this close to the centre

Point = tuple[float, float]
Polygon = tuple[Point, ...]
Rect = tuple[float, float, float, float]  # x0, y0, x1, y1


@dataclass(frozen=True)
class _Zone:
    """How a block of one land use is cut into lots and what stands on them."""

    frontage_m: tuple[float, float]
    min_row_depth_m: float  # two rows back to back only if each is at least this deep
    kinds: dict[str, float]  # building kind -> probability, given the lot is built on


ZONES = {
    "residential": _Zone((16.0, 30.0), 12.0, {"residential": 0.95, "apartment": 0.05}),
    "commercial": _Zone((24.0, 45.0), 20.0, {"office": 0.8, "apartment": 0.2}),
    "downtown": _Zone((24.0, 45.0), 20.0, {"highrise": 0.6, "office": 0.4}),
    "industrial": _Zone((30.0, 70.0), 40.0, {"industrial": 1.0}),
}


@dataclass(frozen=True)
class _Massing:
    """Footprint size rules of one building kind, in lot-local frontage (u) / depth (v)."""

    fill_scale: tuple[float, float]  # multiplies the density fill of the usable lot
    max_size_m: tuple[float, float]  # (u, v) caps: houses stay house-sized on deep lots
    setback_m: tuple[float, float]  # from the lot front
    notch_probability: float  # share of L / T footprints (always flat-roofed)


MASSING = {
    "residential": _Massing((0.8, 1.0), (20.0, 16.0), (2.0, 6.0), 0.0),
    "apartment": _Massing((0.9, 1.1), (40.0, 24.0), (1.0, 4.0), 0.4),
    "office": _Massing((1.0, 1.25), (80.0, 60.0), (0.0, 3.0), 0.4),
    "highrise": _Massing((0.8, 1.0), (40.0, 40.0), (0.0, 3.0), 0.0),
    "industrial": _Massing((1.0, 1.3), (120.0, 100.0), (0.0, 4.0), 0.4),
}
# Sloped roofs go to rectangular buildings in this order until sloped_share is met; never highrises.
SLOPED_PRIORITY = ("residential", "apartment", "industrial", "office")


_r = polygons.rounded
_clamp = polygons.clamp
rect_polygon = polygons.rect_polygon


def polygon_area(polygon: Polygon) -> float:
    """Signed shoelace area: positive for counter-clockwise vertices."""
    xs = np.array([p[0] for p in polygon])
    ys = np.array([p[1] for p in polygon])
    return float(0.5 * np.sum(xs * np.roll(ys, -1) - np.roll(xs, -1) * ys))


polygon_bbox = polygons.bbox


def _polygon_from_list(points: Any) -> Polygon:
    return tuple((float(x), float(y)) for x, y in points)


def _polygon_to_list(polygon: Polygon) -> list[list[float]]:
    return [[x, y] for x, y in polygon]


def _check_number(owner: str, name: str, value: Any, lo: float, hi: float) -> float:
    ok = isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, bool)
    if not ok or not math.isfinite(value) or not lo <= value <= hi:
        raise MetaSimError(f"{owner}.{name} must be a number in [{lo:g}, {hi:g}], got {value!r}")
    return float(value)


STYLES = ("suburban", "dense", "downtown", "industrial")
DEFAULT_STYLE = (("suburban", 1.0),)
StyleMix = tuple[tuple[str, float], ...]


def style_mix(value: Any) -> StyleMix:
    """A city style mix as ``((name, share), ...)`` in `STYLES` order, shares summing to 1.

    Takes a style name (``"dense"``), a mapping of names to non-negative shares (``{"dense": 0.7,
    "suburban": 0.3}``, as a design space's JSON gives it) or such pairs; MetaSimError otherwise.
    """
    usage = (f"LayoutParams.style must be a style name or a mapping of style names to shares, "
             f"with styles among {', '.join(STYLES)} and at least one share positive")
    if isinstance(value, str):
        value = {value: 1.0}
    elif isinstance(value, (list, tuple)):
        if not all(isinstance(pair, (list, tuple)) and len(pair) == 2 for pair in value):
            raise MetaSimError(f"{usage}; got {value!r}")
        value = dict(value)
    if not isinstance(value, Mapping) or not value:
        raise MetaSimError(f"{usage}; got {value!r}")
    shares = {}
    for name, share in value.items():
        if name not in STYLES:
            raise MetaSimError(f"{usage}; {name!r} is not a style")
        shares[name] = _check_number("LayoutParams", f"style[{name!r}]", share, 0.0, 1e6)
    total = sum(shares.values())
    if total <= 0.0:
        raise MetaSimError(f"{usage}; got {value!r}")
    return tuple((name, _r(shares[name] / total)) for name in STYLES if shares.get(name, 0.0) > 0.0)


def parse_style(text: str) -> StyleMix:
    """A style mix from its command-line form: ``dense`` or ``dense=0.7,suburban=0.3``."""
    parts = [part.strip() for part in str(text).split(",") if part.strip()]
    if len(parts) == 1 and "=" not in parts[0]:
        return style_mix(parts[0])
    shares = {}
    for part in parts:
        name, _, share = part.partition("=")
        try:
            shares[name.strip()] = float(share)
        except ValueError:
            raise MetaSimError(f"style {text!r}: write a style name or name=share pairs such as "
                               f"dense=0.7,suburban=0.3 (styles: {', '.join(STYLES)})") from None
    return style_mix(shares)


def style_text(mix: StyleMix) -> str:
    """The command-line form of a style mix: its one style's name, else name=share pairs."""
    return mix[0][0] if len(mix) == 1 else ",".join(f"{name}={share:g}" for name, share in mix)


@dataclass(frozen=True)
class LayoutParams:
    """User-facing knobs of the city generator.

    building_density: share of lots built on is ``1 - (1 - d)**2`` (0.91 at
        the default 0.7), and footprints fill ``0.4 + 0.5 d`` of a lot's
        usable width and depth (before per-kind scaling and caps). In dense
        regions: the share of places along the lanes built on, the seeds of
        house clusters in the blocks and how readily a cluster grows.
    sloped_share: share of buildings with gable or hip roofs. Sloped roofs
        go to rectangular residential buildings first, then apartments,
        industrial and office buildings; highrises and L/T footprints are
        always flat, which caps the share reachable (about 0.82 with the default mix).
    tree_density: street-tree probability per planting spot and yard trees
        per lot area; scaled down in downtown, industrial and dense regions
        (real trees: as each style's rules say, see `clutter.GridRules`).
    road_width_m: kerb-to-kerb width of ordinary streets; avenues are wider
        (grid styles; dense lanes have widths of their own).
    block_size_m: (min, max) side length of a block between streets (grid styles).
    style: the city styles and the share of the city each covers (see `style_mix`):
        suburban (the street grid above), dense (a packed informal town on bent
        lanes), downtown (offices and highrises on paved lots), industrial (halls
        on large paved lots). Stored as ``((name, share), ...)``.

    The knobs below add street details, clutter and real-sized trees (see
    ``sim/clutter.py``); at their defaults the city is today's, and `to_dict`
    leaves them out. In a styled city each region gets them as its style has
    them (`_styled_clutter`); a styled city without them stays as it was.

    tree_size: "small" (today's crowns of 1.2-4 m radius, scattered) or
        "real" (crown diameters 4-15 m, mostly 5-9 m, heights 5-20 m growing
        with the crown, in rows along the verges and groups in yards and
        parks; the renderer draws them as lumpy, textured, per-tree tinted
        crowns).
    street_details: kerbs and sidewalks in the verges (and along the roads
        between regions, beside the regions that have them), driveways to
        houses, paved commercial and industrial lots with parking lots and
        painted stalls, lane markings on the roads.
    car_density: 0..1, share of kerb parking spots (times 0.6), driveway and
        parking-lot stalls taken by a car, and traffic in the lanes (cars
        per 100 m of lane: 1.5 times it); cars stand on driveways and in
        parking lots only with `street_details`.
    pool_share: 0..1, share of houses with a pool in the back yard (where the
        lot has room behind the house).
    shrub_density: 0..1, how often lot edges carry a hedge and how many
        bushes stand around a house.
    open_share: 0..1, the share of a dense town's ground kept free of houses in open patches (round,
        radius 6-30 m, placed at random): fields, gardens and groves, where the town's trees and bushes
        grow as in its other gaps. Its roofs lose a little more than the share (houses cannot lean on a
        patch's edge). 0 packs the town as always; a larger share keeps the patches of a smaller one.
    large_buildings: 0..1, how many large buildings a dense town has among its houses: halls, markets,
        schools and blocks of flats of 14-45 m frontage and 12-30 m depth, half of them low halls, half
        blocks of three to eight storeys, each fronting a lane (about one per `LARGE_M2_PER_BUILDING` of town
        at 1; fewer fit where the lanes are close). 0 builds houses only, as always.
    tall_share: 0..1, the share of a dense town's houses whose storeys are drawn from `TALL_STOREYS` (two to
        six, as in Banepa's centre, casting long shadows into the lanes) instead of `DENSE_STOREYS` (mostly one
        or two, as in Kampala's settlements); 0 keeps the town as it was.
    water_share: 0..0.9, the share of the city under open water (rivers, lagoons, coasts: chains of discs
        from the city's edge, ``sim/water.py``). The water lies over the ground and the roads, and takes
        away the buildings, pools, cars and bushes it touches and the trees standing in it; the rest of the
        city stays as it was. In cities of every style.
    roof_furniture: 0..1, how much stands on the roofs (``sim/furniture.py``):
        parapet rims, HVAC units, skylights, hatches, stair housings and
        solar rows on flat roofs, chimneys, roof windows and solar panels on
        sloped ones. Unlike the knobs above it is built in cities of every
        style, and the layout does not store the pieces: they follow from the
        seed, each building and this value.
    """

    building_density: float = 0.7
    sloped_share: float = 0.6
    tree_density: float = 0.4
    road_width_m: float = 10.0
    block_size_m: tuple[float, float] = (60.0, 140.0)
    style: StyleMix = DEFAULT_STYLE
    tree_size: str = "small"
    street_details: bool = False
    car_density: float = 0.0
    pool_share: float = 0.0
    shrub_density: float = 0.0
    roof_furniture: float = 0.0
    open_share: float = 0.0
    water_share: float = 0.0
    large_buildings: float = 0.0
    tall_share: float = 0.0

    def __post_init__(self) -> None:
        owner = "LayoutParams"
        for name in ("car_density", "pool_share", "shrub_density", "roof_furniture", "open_share",
                     "large_buildings", "tall_share"):
            object.__setattr__(self, name, _check_number(owner, name, getattr(self, name), 0.0, 1.0))
        object.__setattr__(self, "water_share", _check_number(owner, "water_share", self.water_share, 0.0, 0.9))
        if not isinstance(self.tree_size, str) or self.tree_size not in TREE_SIZES:
            raise MetaSimError(f"{owner}.tree_size must be one of {', '.join(TREE_SIZES)}, got {self.tree_size!r}")
        if not isinstance(self.street_details, (bool, np.bool_)):
            raise MetaSimError(f"{owner}.street_details must be true or false, got {self.street_details!r}")
        object.__setattr__(self, "street_details", bool(self.street_details))
        for name in ("building_density", "sloped_share", "tree_density"):
            object.__setattr__(self, name, _check_number(owner, name, getattr(self, name), 0.0, 1.0))
        road = _check_number(owner, "road_width_m", self.road_width_m, 4.0, 40.0)
        object.__setattr__(self, "road_width_m", road)
        block = self.block_size_m
        if not isinstance(block, (tuple, list)) or len(block) != 2:
            raise MetaSimError(
                f"LayoutParams.block_size_m must be a (min, max) pair of metres in [30, 500], got {block!r}"
            )
        lo = _check_number(owner, "block_size_m[0]", block[0], 30.0, 500.0)
        hi = _check_number(owner, "block_size_m[1]", block[1], 30.0, 500.0)
        if lo > hi:
            raise MetaSimError(f"LayoutParams.block_size_m must be (min, max) with min <= max, got {block!r}")
        object.__setattr__(self, "block_size_m", (lo, hi))
        object.__setattr__(self, "style", style_mix(self.style))

    @property
    def richer_scene(self) -> bool:
        """Whether a city with these parameters is of the richer scene (a style other than the suburban grid,
        or roof furniture): what ``scene_version`` keys and the fast preset lights with the sun."""
        return self.roof_furniture > 0.0 or self.style != DEFAULT_STYLE

    def to_dict(self) -> dict[str, Any]:
        out = {
            "building_density": self.building_density,
            "sloped_share": self.sloped_share,
            "tree_density": self.tree_density,
            "road_width_m": self.road_width_m,
            "block_size_m": list(self.block_size_m),
        }
        if self.style != DEFAULT_STYLE:  # layouts from before styles keep their JSON
            out["style"] = dict(self.style)
        # Added knobs only when set, so today's layouts keep their JSON.
        out.update({name: getattr(self, name) for name, default in _CLUTTER_DEFAULTS.items()
                    if getattr(self, name) != default})
        return out

    @property
    def clutter(self) -> bool:
        """Whether any street detail or clutter knob is set."""
        return any(getattr(self, name) != _CLUTTER_DEFAULTS[name]
                   for name in ("street_details", "car_density", "pool_share", "shrub_density"))

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> LayoutParams:
        known = {"building_density", "sloped_share", "tree_density", "road_width_m", "block_size_m", "style",
                 *_CLUTTER_DEFAULTS}
        unknown = set(data) - known
        if unknown:
            raise MetaSimError(f"unknown layout parameter(s) {sorted(unknown)}; remove them")
        data = dict(data)
        if "block_size_m" in data and isinstance(data["block_size_m"], list):
            data["block_size_m"] = tuple(data["block_size_m"])
        return cls(**data)


ROAD_SURFACES = ("asphalt", "dirt")
LOT_SURFACES = ("ground", "paved")


def _surface(owner: str, value: Any, allowed: tuple[str, ...]) -> str:
    if value not in allowed:
        raise MetaSimError(f"{owner}: surface {value!r} is not one of {allowed}; the layout file is damaged")
    return str(value)


# The knobs added after the first layouts: `to_dict` writes them only when set.
_CLUTTER_DEFAULTS = {"tree_size": "small", "street_details": False, "car_density": 0.0, "pool_share": 0.0,
                     "shrub_density": 0.0, "roof_furniture": 0.0, "open_share": 0.0, "water_share": 0.0,
                     "large_buildings": 0.0, "tall_share": 0.0}


@dataclass(frozen=True)
class Road:
    """A street, lane or track: a convex polygon (roads may overlap at crossings and bends).

    Suburban streets are axis-aligned rectangles; the lanes of other styles run at any angle.
    `surface` is "asphalt" or "dirt" (a track).
    """

    polygon: Polygon
    surface: str = "asphalt"

    @property
    def bbox(self) -> Rect:
        return polygon_bbox(self.polygon)

    def to_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {"polygon": _polygon_to_list(self.polygon)}
        if self.surface != "asphalt":
            out["surface"] = self.surface
        return out

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> Road:
        return cls(_polygon_from_list(data["polygon"]), _surface("road", data.get("surface", "asphalt"), ROAD_SURFACES))


@dataclass(frozen=True)
class Lot:
    """A parcel (a convex polygon, axis-aligned in suburban blocks) that holds at most one building.

    `block_index` is the grid block of the lot, -1 for lots of a dense region (one per building).
    `surface` is "ground" or "paved" (downtown parking, industrial yards).
    """

    polygon: Polygon
    block_index: int
    surface: str = "ground"

    @property
    def bbox(self) -> Rect:
        return polygon_bbox(self.polygon)

    def to_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {"polygon": _polygon_to_list(self.polygon), "block_index": self.block_index}
        if self.surface != "ground":
            out["surface"] = self.surface
        return out

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> Lot:
        return cls(_polygon_from_list(data["polygon"]), int(data["block_index"]),
                   _surface("lot", data.get("surface", "ground"), LOT_SURFACES))


@dataclass(frozen=True)
class Building:
    """One building on one lot.

    `footprint` is the wall outline (CCW, axis-aligned edges). Walls rise to
    the eave height `height_m`. A sloped roof covers `roof_outline`, the
    footprint grown by `overhang_m`: its eaves lie on that outline at
    `height_m` and its planes rise at `roof_pitch_deg` to a ridge (gable) or
    top ridge (hip) along `ridge_axis`, the footprint's long side. Flat roofs
    have no overhang and an optional parapet of `parapet_m` around the edge.

    The building is turned by `rotation_deg` (counter-clockwise) about the
    centre of its footprint's bounding box: `footprint` stays axis-aligned in
    the building's own frame, and `wall_outline`, `roof_outline` and `bbox` are
    the turned outlines in the world.
    """

    id: int
    kind: str
    lot_index: int
    footprint: Polygon
    shape: str
    height_m: float
    roof: str
    roof_pitch_deg: float
    overhang_m: float
    ridge_axis: str
    parapet_m: float
    rotation_deg: float = 0.0

    @property
    def roof_class(self) -> int:
        """Label value of the roof-class pass: 1 flat roof, 2 sloped roof (0 is background)."""
        return 1 if self.roof == "flat" else 2

    @property
    def _own_roof_outline(self) -> Polygon:
        """The footprint grown by the overhang, in the building's own (unturned) frame."""
        if self.overhang_m == 0.0:
            return self.footprint
        x0, y0, x1, y1 = polygon_bbox(self.footprint)  # sloped roofs sit on rectangles only
        o = self.overhang_m
        return rect_polygon(x0 - o, y0 - o, x1 + o, y1 + o)

    def _turned(self, polygon: Polygon) -> Polygon:
        if self.rotation_deg == 0.0:
            return polygon
        x0, y0, x1, y1 = polygon_bbox(self.footprint)
        return polygons.rotate(polygon, (x0 + x1) / 2, (y0 + y1) / 2, self.rotation_deg)

    @property
    def wall_outline(self) -> Polygon:
        """The footprint turned into the world."""
        return self._turned(self.footprint)

    @property
    def roof_outline(self) -> Polygon:
        """The footprint grown by the overhang and turned into the world: what a nadir camera sees of the roof."""
        return self._turned(self._own_roof_outline)

    @property
    def bbox(self) -> Rect:
        """Bounding box of the roof outline."""
        return polygon_bbox(self.roof_outline)

    @property
    def ridge_height_m(self) -> float:
        """Height of the highest roof point: eave plus rise over half the outline's short side.

        Flat roofs: the eave height (parapet excluded).
        """
        if self.roof == "flat":
            return self.height_m
        x0, y0, x1, y1 = polygon_bbox(self._own_roof_outline)
        half_span = min(x1 - x0, y1 - y0) / 2.0
        return _r(self.height_m + half_span * math.tan(math.radians(self.roof_pitch_deg)))

    def to_dict(self) -> dict[str, Any]:
        return {
            "id": self.id,
            "kind": self.kind,
            "lot_index": self.lot_index,
            "footprint": _polygon_to_list(self.footprint),
            "shape": self.shape,
            "height_m": self.height_m,
            "roof": self.roof,
            "roof_pitch_deg": self.roof_pitch_deg,
            "overhang_m": self.overhang_m,
            "ridge_axis": self.ridge_axis,
            "parapet_m": self.parapet_m,
            **({"rotation_deg": self.rotation_deg} if self.rotation_deg != 0.0 else {}),
        }

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> Building:
        building = cls(
            id=int(data["id"]),
            kind=str(data["kind"]),
            lot_index=int(data["lot_index"]),
            footprint=_polygon_from_list(data["footprint"]),
            shape=str(data["shape"]),
            height_m=float(data["height_m"]),
            roof=str(data["roof"]),
            roof_pitch_deg=float(data["roof_pitch_deg"]),
            overhang_m=float(data["overhang_m"]),
            ridge_axis=str(data["ridge_axis"]),
            parapet_m=float(data["parapet_m"]),
            rotation_deg=float(data.get("rotation_deg", 0.0)),
        )
        where = f"building {building.id}"
        if not math.isfinite(building.rotation_deg):
            raise MetaSimError(f"{where}: rotation_deg must be finite; the layout file is damaged")
        for name, value, allowed in (
            ("kind", building.kind, KINDS),
            ("roof", building.roof, ROOFS),
            ("shape", building.shape, SHAPES),
            ("ridge_axis", building.ridge_axis, ("x", "y")),
        ):
            if value not in allowed:
                raise MetaSimError(f"{where}: {name} {value!r} is not one of {allowed}; the layout file is damaged")
        if len(building.footprint) < 4 or polygon_area(building.footprint) <= 0.0:
            raise MetaSimError(f"{where}: footprint must be a counter-clockwise polygon; the layout file is damaged")
        if building.roof != "flat" and building.shape != "rect":
            raise MetaSimError(f"{where}: sloped roofs need a rectangular footprint; the layout file is damaged")
        return building


@dataclass(frozen=True)
class Tree:
    """A tree seen from above as a disc of crown radius `radius_m`, `height_m` tall."""

    x: float
    y: float
    radius_m: float
    height_m: float

    @property
    def bbox(self) -> Rect:
        r = self.radius_m
        return (self.x - r, self.y - r, self.x + r, self.y + r)

    def to_dict(self) -> dict[str, Any]:
        return {"x": self.x, "y": self.y, "radius_m": self.radius_m, "height_m": self.height_m}

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> Tree:
        return cls(float(data["x"]), float(data["y"]), float(data["radius_m"]), float(data["height_m"]))


def _boxes(items: tuple[Any, ...]) -> np.ndarray:
    return np.array([item.bbox for item in items], dtype=float).reshape(-1, 4)


def _in_rect(items: tuple[Any, ...], boxes: np.ndarray, x0: float, y0: float, x1: float, y1: float) -> list[Any]:
    """Items whose box shares positive area with the rectangle (touching edges do not count)."""
    hit = (boxes[:, 0] < x1) & (boxes[:, 2] > x0) & (boxes[:, 1] < y1) & (boxes[:, 3] > y0)
    return [items[i] for i in np.flatnonzero(hit)]


_CLUTTER = {"pavings": Paving, "markings": Marking, "cars": Car, "pools": Pool, "shrubs": Shrub}
_DETAILS = {**_CLUTTER, "waters": Water}


@dataclass(frozen=True)
class CityLayout:
    """A whole city: the contract between the generator and the Blender builder."""

    seed: int
    width_m: float
    height_m: float
    params: LayoutParams
    roads: tuple[Road, ...]
    lots: tuple[Lot, ...]
    buildings: tuple[Building, ...]
    trees: tuple[Tree, ...]
    version: int = LAYOUT_VERSION
    pavings: tuple[Paving, ...] = ()
    markings: tuple[Marking, ...] = ()
    cars: tuple[Car, ...] = ()
    pools: tuple[Pool, ...] = ()
    shrubs: tuple[Shrub, ...] = ()
    waters: tuple[Water, ...] = ()

    def to_dict(self) -> dict[str, Any]:
        out = {
            "version": self.version,
            "seed": self.seed,
            "width_m": self.width_m,
            "height_m": self.height_m,
            "params": self.params.to_dict(),
            "roads": [road.to_dict() for road in self.roads],
            "lots": [lot.to_dict() for lot in self.lots],
            "buildings": [building.to_dict() for building in self.buildings],
            "trees": [tree.to_dict() for tree in self.trees],
        }
        out.update({name: [item.to_dict() for item in getattr(self, name)]
                    for name in _DETAILS if getattr(self, name)})
        return out

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> CityLayout:
        version = data.get("version") if isinstance(data, dict) else None
        if version != LAYOUT_VERSION:
            raise MetaSimError(
                f"city layout version {version!r} is not supported (expected {LAYOUT_VERSION}); "
                "regenerate the layout with this version of meta-sim"
            )
        try:
            return cls(
                seed=int(data["seed"]),
                width_m=float(data["width_m"]),
                height_m=float(data["height_m"]),
                params=LayoutParams.from_dict(data["params"]),
                roads=tuple(Road.from_dict(d) for d in data["roads"]),
                lots=tuple(Lot.from_dict(d) for d in data["lots"]),
                buildings=tuple(Building.from_dict(d) for d in data["buildings"]),
                trees=tuple(Tree.from_dict(d) for d in data["trees"]),
                version=version,
                **{name: tuple(kind.from_dict(d) for d in data.get(name, ())) for name, kind in _DETAILS.items()},
            )
        except (KeyError, TypeError, ValueError) as exc:
            raise MetaSimError(f"city layout is incomplete or damaged ({exc!r}); regenerate it") from exc

    @cached_property
    def _building_boxes(self) -> np.ndarray:
        return _boxes(self.buildings)

    @cached_property
    def _tree_boxes(self) -> np.ndarray:
        return _boxes(self.trees)

    @cached_property
    def _road_boxes(self) -> np.ndarray:
        return _boxes(self.roads)

    @cached_property
    def _lot_boxes(self) -> np.ndarray:
        return _boxes(self.lots)

    def buildings_in_rect(self, x0: float, y0: float, x1: float, y1: float) -> list[Building]:
        """Buildings whose roof-outline bbox shares positive area with the rectangle, in id order."""
        return _in_rect(self.buildings, self._building_boxes, x0, y0, x1, y1)

    def trees_in_rect(self, x0: float, y0: float, x1: float, y1: float) -> list[Tree]:
        """Trees whose crown bbox shares positive area with the rectangle."""
        return _in_rect(self.trees, self._tree_boxes, x0, y0, x1, y1)

    def roads_in_rect(self, x0: float, y0: float, x1: float, y1: float) -> list[Road]:
        """Roads whose bbox shares positive area with the rectangle."""
        return _in_rect(self.roads, self._road_boxes, x0, y0, x1, y1)

    def lots_in_rect(self, x0: float, y0: float, x1: float, y1: float) -> list[Lot]:
        """Lots whose bbox shares positive area with the rectangle."""
        return _in_rect(self.lots, self._lot_boxes, x0, y0, x1, y1)

    @cached_property
    def _detail_boxes(self) -> dict[str, np.ndarray]:
        return {name: _boxes(getattr(self, name)) for name in _DETAILS}

    def details_in_rect(self, name: str, x0: float, y0: float, x1: float, y1: float) -> list[Any]:
        """Street details, clutter or water of one kind ("pavings", "markings", "cars", "pools", "shrubs",
        "waters") whose bbox shares positive area with the rectangle."""
        return _in_rect(getattr(self, name), self._detail_boxes[name], x0, y0, x1, y1)

    def style_of(self, building: Building) -> str:
        """The city style (one of `STYLES`) of the region a building stands in, read from its lot: a
        dense town's lots hold one house each (block -1), downtown and industrial grids pave theirs, and
        only the industrial style builds industrial halls on paved lots."""
        lot = self.lots[building.lot_index]
        if lot.block_index < 0:
            return "dense"
        if lot.surface == "paved":
            return "industrial" if building.kind == "industrial" else "downtown"
        return "suburban"

    def tile_grid(self, tile_m: float = TILE_M) -> list[Rect]:
        """Square tiles from the origin covering the city, row-major, row 0 at y = 0 (south).

        The last column and row may reach past the city; that part is bare ground.
        """
        tile_m = _check_number("tile_grid", "tile_m", tile_m, 1.0, 1e5)
        cols = max(1, math.ceil(self.width_m / tile_m - 1e-9))
        rows = max(1, math.ceil(self.height_m / tile_m - 1e-9))
        return [
            (_r(c * tile_m), _r(r * tile_m), _r((c + 1) * tile_m), _r((r + 1) * tile_m))
            for r in range(rows)
            for c in range(cols)
        ]

    def stats(self) -> dict[str, Any]:
        """Counts by building kind and roof type, and the sloped share."""
        by_kind = {kind: 0 for kind in KINDS}
        by_roof = {roof: 0 for roof in ROOFS}
        for building in self.buildings:
            by_kind[building.kind] += 1
            by_roof[building.roof] += 1
        n = len(self.buildings)
        return {
            "buildings": n,
            "by_kind": by_kind,
            "by_roof": by_roof,
            "sloped_share": (by_roof["gable"] + by_roof["hip"]) / n if n else 0.0,
            "non_rect": sum(b.shape != "rect" for b in self.buildings),
            "roads": len(self.roads),
            "lots": len(self.lots),
            "empty_lots": len(self.lots) - n,
            "trees": len(self.trees),
        }


# ---------------------------------------------------------------- streets


def _street_strips(rng: np.random.Generator, length: float, params: LayoutParams) -> list[tuple[float, float]]:
    """(lo, hi) extents of the streets crossing one axis, with blocks of jittered size between."""
    lo_block, hi_block = params.block_size_m
    road = params.road_width_m
    # The first block is cut by the city edge; capping it gives every city wider than
    # a street plus two edge blocks at least one street.
    pos = rng.uniform(MIN_EDGE_BLOCK_M, max(MIN_EDGE_BLOCK_M, min(hi_block, length - road - MIN_EDGE_BLOCK_M)))
    strips = []
    while True:
        width = road * (AVENUE_WIDTH_FACTOR if rng.random() < AVENUE_PROBABILITY else 1.0)
        if pos + width + MIN_EDGE_BLOCK_M > length:
            return strips
        strips.append((pos, pos + width))
        pos += width + rng.uniform(lo_block, hi_block)


def _cells(strips: list[tuple[float, float]], length: float) -> list[tuple[float, float]]:
    """Spans between streets (and the city edges) along one axis."""
    edges = [0.0] + [v for strip in strips for v in strip] + [length]
    return list(zip(edges[0::2], edges[1::2]))


def _merge_cells(rng: np.random.Generator, ncols: int, nrows: int) -> np.ndarray:
    """Block index of every grid cell; a few neighbouring cells share a block (no street between)."""
    block_of = np.full((ncols, nrows), -1, dtype=int)
    count = 0
    for j in range(nrows):
        for i in range(ncols):
            if block_of[i, j] >= 0:
                continue
            block_of[i, j] = count
            u = rng.random()
            if u < MERGE_PROBABILITY and i + 1 < ncols and block_of[i + 1, j] < 0:
                block_of[i + 1, j] = count
            elif u < 2 * MERGE_PROBABILITY and j + 1 < nrows:
                block_of[i, j + 1] = count
            count += 1
    return block_of


def _street_runs(separate: np.ndarray, strip: tuple[float, float], cross: list[tuple[float, float]],
                 length: float) -> list[tuple[float, float, float, float]]:
    """Road rectangles along one street line, as (lo, hi, along_lo, along_hi).

    `separate[j]` says whether the cells on either side of the line in cross
    cell j belong to different blocks (then the street runs there). Each
    piece reaches over the crossing streets at both ends, so junctions are
    paved whichever street continues through them.
    """
    runs = []
    for is_street, group in itertools.groupby(range(len(separate)), key=lambda j: bool(separate[j])):
        if is_street:
            cells = list(group)
            along_lo = cross[cells[0] - 1][0] if cells[0] > 0 else 0.0
            along_hi = cross[cells[-1]][1] if cells[-1] < len(cross) else length
            runs.append((strip[0], strip[1], along_lo, along_hi))
    return runs


@dataclass(frozen=True)
class _Block:
    rect: Rect
    road_sides: frozenset[str]  # of "S", "N", "W", "E": sides facing a street, not the city edge


def _blocks_and_roads(rng: np.random.Generator, width: float, height: float,
                      params: LayoutParams) -> tuple[list[_Block], list[Road]]:
    xstrips = _street_strips(rng, width, params)
    ystrips = _street_strips(rng, height, params)
    cols, rows = _cells(xstrips, width), _cells(ystrips, height)
    block_of = _merge_cells(rng, len(cols), len(rows))
    roads = []
    for k, strip in enumerate(xstrips):
        for x0, x1, y0, y1 in _street_runs(block_of[k] != block_of[k + 1], strip, ystrips, height):
            roads.append(Road(rect_polygon(x0, y0, x1, y1)))
    for k, strip in enumerate(ystrips):
        for y0, y1, x0, x1 in _street_runs(block_of[:, k] != block_of[:, k + 1], strip, xstrips, width):
            roads.append(Road(rect_polygon(x0, y0, x1, y1)))
    blocks = []
    for b in range(int(block_of.max()) + 1):
        ii, jj = np.nonzero(block_of == b)
        x0, x1 = cols[ii.min()][0], cols[ii.max()][1]
        y0, y1 = rows[jj.min()][0], rows[jj.max()][1]
        sides = {"W": x0 > 0.0, "E": x1 < width, "S": y0 > 0.0, "N": y1 < height}
        blocks.append(_Block((x0, y0, x1, y1), frozenset(s for s, on_road in sides.items() if on_road)))
    return blocks, roads


# ---------------------------------------------------------------- lots


@dataclass(frozen=True)
class _LotPlan:
    rect: Rect
    front: str  # side facing the street ("S", "N", "W", "E"); buildings are set back from it
    zone: str
    block_index: int


def _zone_of(rng: np.random.Generator, rect: Rect, width: float, height: float) -> str:
    x0, y0, x1, y1 = rect
    central = math.hypot((x0 + x1 - width) / 2, (y0 + y1 - height) / 2) < CENTRAL_RADIUS_SHARE * min(width, height)
    if central:
        return pick(rng, {"downtown": 0.7, "commercial": 0.15, "residential": 0.15})
    return pick(rng, {"industrial": 0.28, "commercial": 0.07, "residential": 0.65})


def _frontage_cuts(rng: np.random.Generator, length: float, frontage: tuple[float, float]) -> list[float]:
    """Cut positions 0 .. length splitting one side into frontages within `frontage` where it fits."""
    lo, hi = frontage
    n_min = max(1, math.ceil(length / hi))
    n = int(rng.integers(n_min, max(n_min, math.floor(length / lo)) + 1))
    base = length / n
    # Jittering each cut by at most slack / 2 keeps every frontage inside [lo, hi].
    slack = max(0.0, min(base - lo, hi - base))
    return [0.0] + [k * base + rng.uniform(-slack / 2, slack / 2) for k in range(1, n)] + [length]


def _plan_block(rng: np.random.Generator, block: _Block, index: int, width: float, height: float,
                style: str = "suburban") -> list[_LotPlan]:
    """Cut a block's buildable area (inside the verges) into lots along its long side.

    Suburban blocks take their zone from where they lie; downtown and industrial ones from the style.
    """
    x0, y0, x1, y1 = block.rect
    sides = block.road_sides
    x0, x1 = x0 + VERGE_M * ("W" in sides), x1 - VERGE_M * ("E" in sides)
    y0, y1 = y0 + VERGE_M * ("S" in sides), y1 - VERGE_M * ("N" in sides)
    min_side = MIN_BUILDING_SIDE_M + 2 * (BUILDING_MARGIN_M + OVERHANG_RANGE_M[1])
    if min(x1 - x0, y1 - y0) < min_side:
        return []  # a sliver between a street and the city edge stays open ground
    zone = _zone_of(rng, block.rect, width, height) if style == "suburban" else pick(rng, STYLE_ZONES[style])
    along_x = x1 - x0 >= y1 - y0
    lo, hi, near, far = (x0, x1, y0, y1) if along_x else (y0, y1, x0, x1)
    fronts = ("S", "N") if along_x else ("W", "E")
    cuts = _frontage_cuts(rng, hi - lo, ZONES[zone].frontage_m)
    if far - near >= 2 * ZONES[zone].min_row_depth_m:
        mid = (near + far) / 2
        rows = [(near, mid, fronts[0]), (mid, far, fronts[1])]
    else:  # one row faces the first long side unless only the second one is a street
        rows = [(near, far, fronts[0] if fronts[0] in sides or fronts[1] not in sides else fronts[1])]
    plans = []
    for a, b in zip(cuts[:-1], cuts[1:]):
        for r0, r1, front in rows:
            rect = (lo + a, r0, lo + b, r1) if along_x else (r0, lo + a, r1, lo + b)
            plans.append(_LotPlan(rect, front, zone, index))
    return plans


# ---------------------------------------------------------------- buildings


@dataclass(frozen=True)
class _Sketch:
    """A building before its roof is chosen."""

    lot_index: int
    kind: str
    footprint: Polygon
    shape: str
    height_m: float
    rotation_deg: float = 0.0
    # Dense buildings touch their neighbours: their roof outline is what was placed, so a sloped
    # roof's walls step in by its overhang instead of the eaves growing out.
    outline_placed: bool = False


def _to_world(plan: _LotPlan, u0: float, u1: float, v0: float, v1: float) -> Rect:
    """Lot-local rectangle (u along the frontage, v back from the front) in world coordinates."""
    return polygons.lot_to_world(plan.rect, plan.front, u0, u1, v0, v1)


def _footprint_rect(rng: np.random.Generator, plan: _LotPlan, kind: str, fill: float) -> Rect | None:
    x0, y0, x1, y1 = plan.rect
    frontage, depth = (x1 - x0, y1 - y0) if plan.front in "SN" else (y1 - y0, x1 - x0)
    # Room for the widest overhang, whichever roof the building gets later.
    inset = BUILDING_MARGIN_M + OVERHANG_RANGE_M[1]
    free_u, free_v = frontage - 2 * inset, depth - 2 * inset
    if min(free_u, free_v) < MIN_BUILDING_SIDE_M:
        return None
    rules = MASSING[kind]
    setback = min(rng.uniform(*rules.setback_m), free_v - MIN_BUILDING_SIDE_M)
    w = _clamp(rng.uniform(*rules.fill_scale) * fill * free_u, MIN_BUILDING_SIDE_M, min(rules.max_size_m[0], free_u))
    h = _clamp(rng.uniform(*rules.fill_scale) * fill * free_v, MIN_BUILDING_SIDE_M,
               min(rules.max_size_m[1], free_v - setback))
    u0 = inset + rng.uniform(0.0, free_u - w)
    v0 = inset + setback
    return _to_world(plan, u0, u0 + w, v0, v0 + h)


def _notched(rng: np.random.Generator, rect: Rect) -> tuple[Polygon, str]:
    """An L (one corner cut away) or T (two corners of one side cut away) inside `rect`."""
    x0, y0, x1, y1 = rect
    w, h = x1 - x0, y1 - y0
    corners = [(x0, y0), (x1, y0), (x1, y1), (x0, y1)]
    k = int(rng.integers(4))
    if rng.random() < 0.6:
        shape, cuts = "L", {k: (rng.uniform(0.35, 0.6) * w, rng.uniform(0.35, 0.6) * h)}
    else:
        # Both cuts share the depth across side k -> k+1 and leave a stem in its middle.
        if k % 2 == 0:  # sides 0 -> 1 and 2 -> 3 run along x
            depth = rng.uniform(0.35, 0.6) * h
            cuts = {k: (rng.uniform(0.25, 0.38) * w, depth), (k + 1) % 4: (rng.uniform(0.25, 0.38) * w, depth)}
        else:
            depth = rng.uniform(0.35, 0.6) * w
            cuts = {k: (depth, rng.uniform(0.25, 0.38) * h), (k + 1) % 4: (depth, rng.uniform(0.25, 0.38) * h)}
        shape = "T"
    points = []
    for i, (px, py) in enumerate(corners):
        if i not in cuts:
            points.append((_r(px), _r(py)))
            continue
        prev, nxt = corners[i - 1], corners[(i + 1) % 4]
        cut_x, cut_y = cuts[i]
        into_prev, into_next = (cut_x, cut_y) if prev[1] == py else (cut_y, cut_x)
        # Walk from the corner toward each neighbour; the notch's inner vertex completes the square.
        ax, ay = px + np.sign(prev[0] - px) * into_prev, py + np.sign(prev[1] - py) * into_prev
        cx, cy = px + np.sign(nxt[0] - px) * into_next, py + np.sign(nxt[1] - py) * into_next
        points += [(_r(ax), _r(ay)), (_r(ax + cx - px), _r(ay + cy - py)), (_r(cx), _r(cy))]
    return tuple(points), shape


def _eave_height(rng: np.random.Generator, kind: str) -> float:
    lo, hi = HEIGHT_RANGES_M[kind]
    if kind != "residential":
        return rng.uniform(lo, hi)
    base = rng.uniform(3.0, 3.5) if rng.random() < 0.5 else rng.uniform(5.0, 6.5)  # one or two storeys
    # Synthinel's height factor lies in [0.5, 2]; most houses stay near their storey height.
    factor = _clamp(rng.lognormal(0.0, 0.25), 0.5, 2.0)
    return _clamp(base * factor, lo, hi)


def _sketch_buildings(rng: np.random.Generator, plans: list[_LotPlan], density: float) -> list[_Sketch]:
    occupancy = 1.0 - (1.0 - density) ** 2
    fill = 0.4 + 0.5 * density
    sketches = []
    for lot_index, plan in enumerate(plans):
        if rng.random() >= occupancy:
            continue
        kind = pick(rng, ZONES[plan.zone].kinds)
        rect = _footprint_rect(rng, plan, kind, fill)
        if rect is None:
            continue
        min_notch_side = 2 * MIN_BUILDING_SIDE_M + 4.0
        notch = min(rect[2] - rect[0], rect[3] - rect[1]) >= min_notch_side
        if notch and rng.random() < MASSING[kind].notch_probability:
            footprint, shape = _notched(rng, rect)
        else:
            footprint, shape = rect_polygon(*rect), "rect"
        sketches.append(_Sketch(lot_index, kind, footprint, shape, _r(_eave_height(rng, kind))))
    return sketches


def _roof_buildings(rng: np.random.Generator, sketches: list[_Sketch], sloped_share: float) -> list[Building]:
    """Give roofs: exactly round(sloped_share * n) sloped ones where enough rectangles allow it."""
    candidates: list[int] = []
    for kind in SLOPED_PRIORITY:
        group = [i for i, s in enumerate(sketches) if s.kind == kind and s.shape == "rect"]
        candidates += [group[j] for j in rng.permutation(len(group))]
    sloped = set(candidates[: round(sloped_share * len(sketches))])
    buildings = []
    for i, s in enumerate(sketches):
        x0, y0, x1, y1 = polygon_bbox(s.footprint)
        roof, pitch, overhang, parapet = "flat", 0.0, 0.0, 0.0
        footprint = s.footprint
        if i in sloped:
            roof = "gable" if rng.random() < 0.5 else "hip"
            pitch, overhang = rng.uniform(*PITCH_RANGE_DEG), rng.uniform(*OVERHANG_RANGE_M)
            if s.outline_placed:
                o = _r(overhang)
                footprint = rect_polygon(x0 + o, y0 + o, x1 - o, y1 - o)
        elif rng.random() < 0.6:
            parapet = rng.uniform(*PARAPET_RANGE_M)
        buildings.append(Building(
            id=i + 1,
            kind=s.kind,
            lot_index=s.lot_index,
            footprint=footprint,
            shape=s.shape,
            height_m=s.height_m,
            roof=roof,
            roof_pitch_deg=_r(pitch),
            overhang_m=_r(overhang),
            ridge_axis="x" if x1 - x0 >= y1 - y0 else "y",
            parapet_m=_r(parapet),
            rotation_deg=s.rotation_deg,
        ))
    return buildings


# ---------------------------------------------------------------- trees

STREET_TREE_SPACING_M = (8.0, 14.0)
YARD_M2_PER_TREE = 300.0  # at tree_density 1
PARK_TREE_FACTOR = 3.0  # empty lots are planted as small parks
TREE_CLEARANCE_M = 0.05  # keeps crowns off roofs after rounding to 0.1 mm


def _street_trees(rng: np.random.Generator, block: _Block, density: float) -> list[Tree]:
    """Trees in the verge along each street side of a block: off the road and off every lot."""
    x0, y0, x1, y1 = block.rect
    trees = []
    for side in sorted(block.road_sides):
        lo, hi = (x0, x1) if side in "SN" else (y0, y1)
        offset = {"S": y0 + VERGE_M / 2, "N": y1 - VERGE_M / 2, "W": x0 + VERGE_M / 2, "E": x1 - VERGE_M / 2}[side]
        spots = np.arange(lo + VERGE_M, hi - VERGE_M, rng.uniform(*STREET_TREE_SPACING_M))
        keep = rng.random(len(spots)) < density
        radii = rng.uniform(1.2, VERGE_M / 2 - 0.1, len(spots))
        heights = rng.uniform(4.0, 9.0, len(spots))
        for along, radius, height in zip(spots[keep], radii[keep], heights[keep]):
            x, y = (along, offset) if side in "SN" else (offset, along)
            trees.append(Tree(_r(x), _r(y), _r(radius), _r(height)))
    return trees


def _yard_trees(rng: np.random.Generator, lot: Lot, building: Building | None, density: float) -> list[Tree]:
    """Trees inside one lot, clear of its building's roof outline (other roofs are on other lots)."""
    x0, y0, x1, y1 = lot.bbox
    expected = density * (x1 - x0) * (y1 - y0) / YARD_M2_PER_TREE
    placed: list[Tree] = []
    for _ in range(rng.poisson(expected if building else expected * PARK_TREE_FACTOR)):
        for _attempt in range(4):
            radius = rng.uniform(1.5, 4.0)
            if min(x1 - x0, y1 - y0) < 2 * radius:
                continue
            x, y = rng.uniform(x0 + radius, x1 - radius), rng.uniform(y0 + radius, y1 - radius)
            if building is not None:
                bx0, by0, bx1, by1 = building.bbox
                dx, dy = max(bx0 - x, 0.0, x - bx1), max(by0 - y, 0.0, y - by1)
                if math.hypot(dx, dy) < radius + TREE_CLEARANCE_M:
                    continue
            if any(math.hypot(x - t.x, y - t.y) < max(radius, t.radius_m) for t in placed):
                continue
            placed.append(Tree(_r(x), _r(y), _r(radius), _r(radius * rng.uniform(1.8, 2.8))))
            break
    return placed


# ---------------------------------------------------------------- city styles

REGION_M = 200.0  # style regions are Voronoi cells of about this size
REGION_ROAD_M = (6.0, 8.0)  # streets on the borders between regions of different grids
DENSE_DIRT_STREETS = 0.5  # share of the streets between two dense regions that are dirt
STYLE_ZONES = {"downtown": {"downtown": 0.5, "commercial": 0.5}, "industrial": {"industrial": 1.0}}
STYLE_TREES = {"suburban": 1.0, "downtown": 0.25, "industrial": 0.15, "dense": 0.5}  # x tree_density
PAVED_STYLES = ("downtown", "industrial")  # whose lots are paved (parking, yards)
LOT_KEPT = 0.3  # share of a grid lot that must lie in its region for the rest to be kept

# Dense towns: bent lanes and tracks between irregular blocks of packed, often touching houses.
LANE_SPACING_M = (28.0, 50.0)  # between neighbouring long lanes: two rows of houses back to back
CROSS_SPACING_M = (30.0, 80.0)  # between the short lanes that join them
KINK_SPACING_M = (20.0, 55.0)
KINK_SHIFT_M = 3.0  # standard deviation of a lane's sideways step at each kink
LANE_WIDTH_M = {"dirt": (2.5, 4.5), "asphalt": (4.0, 6.0)}
DIRT_LANE_SHARE = 0.7
DENSE_FRONTAGE_M = (4.0, 12.0)
DENSE_DEPTH_M = (5.0, 14.0)
DENSE_ROWS = 3  # rows of houses tried behind each lane side
DENSE_TOUCHING = 0.7  # share of neighbours that share a wall
DENSE_M2_PER_SEED = 200.0  # interior seeds of house clusters, at building_density 1
SEED_TURN_DEG = 5.0  # a cluster's houses stand this much askew of their lane (standard deviation)
DENSE_GROWTH = (0.45, 0.5)  # a house's chance to get a neighbour on each side: a + b * building_density
DENSE_STOREYS = {1: 0.45, 2: 0.3, 3: 0.17, 4: 0.08}
TALL_STOREYS = {2: 0.1, 3: 0.25, 4: 0.3, 5: 0.2, 6: 0.15}  # a town of concrete frame houses (``tall_share``)
STOREY_M = 3.0
ROAD_CLEARANCE_M = 0.2  # between any roof outline and a road
TOUCH_M = 1e-3  # neighbours may share walls: outlines may meet within the 0.1 mm rounding
DENSE_M2_PER_TREE = 400.0  # at tree_density 1
OPEN_RADIUS_M = (6.0, 30.0)  # a dense town's open patches (``LayoutParams.open_share``): radius, log-uniform
OPEN_SAMPLES = 2000  # points a region's open share is measured on
OPEN_MAX_PATCHES = 400
LARGE_M2_PER_BUILDING = 600.0  # a dense town's large buildings tried per this much of it, at large_buildings 1
LARGE_FRONTAGE_M = (14.0, 45.0)  # log-uniform
LARGE_DEPTH_M = (12.0, 30.0)  # log-uniform, at most the frontage
LARGE_SHRINK = (1.0, 0.75, 0.55)  # a smaller one tried where a large one does not fit


@dataclass(frozen=True)
class _Region:
    style: str
    cell: Polygon  # convex, counter-clockwise
    angle_deg: float  # direction of a dense region's long lanes


def _piece(polygon, window) -> Polygon | None:
    """The part of a convex polygon inside a convex window, rounded; None if (almost) nothing is left."""
    piece = polygons.rounded_polygon(polygons.clip(polygon, window))
    return piece if len(piece) >= 3 and polygons.area(piece) > 1.0 else None


def _half_plane(a: Point, b: Point, size: float) -> Polygon:
    """A huge counter-clockwise quad standing for the half-plane of points nearer to `a` than to `b`."""
    mx, my = (a[0] + b[0]) / 2, (a[1] + b[1]) / 2
    length = math.hypot(a[0] - b[0], a[1] - b[1])
    dx, dy = (a[0] - b[0]) / length * size, (a[1] - b[1]) / length * size
    ex, ey = -dy, dx
    return ((mx + ex, my + ey), (mx - ex, my - ey), (mx - ex + dx, my - ey + dy), (mx + ex + dx, my + ey + dy))


def _style_regions(rng: np.random.Generator, width: float, height: float,
                   mix: StyleMix) -> tuple[list[_Region], list[Road]]:
    """The city cut into Voronoi cells, each of one style, and the streets between cells of different grids.

    Cells are ranked at random and their areas cut at the mix's cumulative shares, so each style
    covers about its share of the city (exactly so for a city of many cells).
    """
    nx, ny = max(1, round(width / REGION_M)), max(1, round(height / REGION_M))
    sites = [((i + rng.uniform(0.25, 0.75)) * width / nx, (j + rng.uniform(0.25, 0.75)) * height / ny)
             for j in range(ny) for i in range(nx)]
    city = rect_polygon(0.0, 0.0, width, height)
    cells = []
    for i, site in enumerate(sites):
        cell = city
        for j, other in enumerate(sites):
            if j != i:
                cell = polygons.clip(cell, _half_plane(site, other, 4 * (width + height)))
        cells.append(tuple(cell))
    areas = np.array([polygons.area(c) for c in cells])
    order = rng.permutation(len(cells))
    middles = (np.cumsum(areas[order]) - areas[order] / 2) / areas.sum()
    edges = np.cumsum([share for _, share in mix])
    styles = [""] * len(cells)
    for k, middle in zip(order, middles):
        styles[k] = mix[min(int(np.searchsorted(edges, middle, side="right")), len(mix) - 1)][0]
    regions = [_Region(style, polygons.rounded_polygon(cell), _r(rng.uniform(0.0, 180.0)) if style == "dense" else 0.0)
               for style, cell in zip(styles, cells)]
    roads = []
    for i, cell in enumerate(cells):
        for a, b in zip(cell, cell[1:] + cell[:1]):
            mid = ((a[0] + b[0]) / 2, (a[1] + b[1]) / 2)
            d = [math.hypot(mid[0] - x, mid[1] - y) for x, y in sites]
            j = min((k for k in range(len(sites)) if k != i), key=lambda k: abs(d[k] - d[i]), default=i)
            same_grid = styles[i] == styles[j] != "dense"
            if j <= i or abs(d[j] - d[i]) > 1e-6 or same_grid or math.dist(a, b) < 1.0:
                continue
            road_width = rng.uniform(*REGION_ROAD_M)
            # Between two dense regions the through road is often unpaved too.
            dirt = styles[i] == styles[j] == "dense" and rng.random() < DENSE_DIRT_STREETS
            piece = _piece(polygons.strip(*a, *b, road_width, road_width / 2), city)
            if piece:
                roads.append(Road(piece, "dirt" if dirt else "asphalt"))
    return regions, roads


def _dense_lanes(rng: np.random.Generator, region: _Region) -> tuple[list[Road], list[tuple[Point, Point, float]]]:
    """Bent long lanes across a dense region and short ones joining them, at the region's angle.

    Returns the lane pieces inside the region and the lanes' centre segments (start, end, width).
    """
    cx = sum(p[0] for p in region.cell) / len(region.cell)
    cy = sum(p[1] for p in region.cell) / len(region.cell)
    u0, v0, u1, v1 = polygon_bbox(polygons.rotate(region.cell, cx, cy, -region.angle_deg))
    roads: list[Road] = []
    segments: list[tuple[Point, Point, float]] = []

    def add(line, width: float, surface: str) -> None:
        points = polygons.rotate(line, cx, cy, region.angle_deg)
        for a, b in zip(points[:-1], points[1:]):
            # Lengthened by half a width, consecutive pieces cover the outside of each bend.
            piece = _piece(polygons.strip(*a, *b, width, width / 2), region.cell)
            if piece:
                roads.append(Road(piece, surface))
            segments.append((a, b, width))

    def lane_width() -> tuple[float, str]:
        surface = "dirt" if rng.random() < DIRT_LANE_SHARE else "asphalt"
        return rng.uniform(*LANE_WIDTH_M[surface]), surface

    lanes = []  # (u, v) of each long lane's kinks
    v = v0 + rng.uniform(8.0, LANE_SPACING_M[1] / 2)
    while v < v1 - 8.0:
        us = [u0 - 5.0]
        while us[-1] < u1 + 5.0:
            us.append(us[-1] + rng.uniform(*KINK_SPACING_M))
        shift = np.clip(np.cumsum(rng.normal(0.0, KINK_SHIFT_M, len(us))), -8.0, 8.0)
        lanes.append((np.array(us), v + shift))
        add(list(zip(us, v + shift)), *lane_width())
        v += rng.uniform(*LANE_SPACING_M)
    # Short lanes run between neighbouring long lanes (or a long lane and the region's edge),
    # at staggered places, so blocks are irregular and lanes meet in T junctions.
    bounds = [None, *lanes, None]
    for below, above in zip(bounds[:-1], bounds[1:]):
        u = u0 + rng.uniform(0.0, CROSS_SPACING_M[1] / 2)
        while u < u1:
            if rng.random() < 0.75:
                tilt = rng.uniform(-5.0, 5.0)
                ua, ub = u - tilt, u + tilt
                va = v0 - 5.0 if below is None else float(np.interp(ua, *below)) - 1.0
                vb = v1 + 5.0 if above is None else float(np.interp(ub, *above)) + 1.0
                width = rng.uniform(*LANE_WIDTH_M["dirt"])
                if vb - va > 4.0:
                    add([(ua, va), (ub, vb)], width, "dirt")
            u += rng.uniform(*CROSS_SPACING_M)
    return roads, segments


@dataclass(frozen=True)
class _Placed:
    outline: Polygon  # the roof outline in the world
    footprint: Polygon  # axis-aligned, in the building's own frame
    rotation_deg: float
    kind: str
    height_m: float


def _open_patches(rng: np.random.Generator, window: Polygon, share: float) -> polygons.Occupancy:
    """Round patches of a dense region kept free of houses, added until they cover about ``share`` of its
    ``window`` (measured on `OPEN_SAMPLES` points spread over it). The patches come in one order from
    ``rng``, so a larger share keeps the patches of a smaller one."""
    opens = polygons.Occupancy()
    x0, y0, x1, y1 = polygon_bbox(window)
    points = rng.uniform((x0, y0), (x1, y1), size=(OPEN_SAMPLES, 2))
    points = points[[polygons.inside(((x, y),), window, 0.0) for x, y in points]]
    covered = np.zeros(len(points), bool)
    for _ in range(OPEN_MAX_PATCHES if len(points) else 0):
        if covered.mean() >= share:
            break
        x, y = rng.uniform(x0, x1), rng.uniform(y0, y1)
        r = math.exp(rng.uniform(*np.log(OPEN_RADIUS_M)))
        opens.add(polygons.disc(x, y, r))
        covered |= np.hypot(points[:, 0] - x, points[:, 1] - y) <= r
    return opens


def _dense_buildings(rng: np.random.Generator, region: _Region, segments: list[tuple[Point, Point, float]],
                     roads: polygons.Occupancy, built: polygons.Occupancy, density: float, width: float,
                     height: float, opens: polygons.Occupancy | None = None, large: float = 0.0,
                     tall: float = 0.0) -> list[_Placed]:
    """Packed houses of one dense region: with ``large`` first its large buildings along the lanes, then rows
    of houses along both sides of every lane, then infill behind them; the share ``tall`` of the houses has
    the storeys of `TALL_STOREYS`.

    Each house keeps `ROAD_CLEARANCE_M` off every road and out of the ``opens`` patches and stays inside its
    region; houses of a row often share walls, and infill houses take the direction of the nearest lane.
    """
    window = polygons.clip(region.cell, rect_polygon(0.0, 0.0, width, height))
    placed: list[_Placed] = []
    storeys = DENSE_STOREYS if tall == 0.0 else {  # one draw either way: the mixture of the two
        n: (1.0 - tall) * DENSE_STOREYS.get(n, 0.0) + tall * TALL_STOREYS.get(n, 0.0)
        for n in sorted({*DENSE_STOREYS, *TALL_STOREYS})}

    def attempt(cx: float, cy: float, along: float, depth: float, angle: float, kind: str | None = None) -> bool:
        footprint = rect_polygon(cx - along / 2, cy - depth / 2, cx + along / 2, cy + depth / 2)
        rotation = _r(angle)
        x0, y0, x1, y1 = polygon_bbox(footprint)
        outline = polygons.rotate(footprint, (x0 + x1) / 2, (y0 + y1) / 2, rotation)  # as Building turns it
        if not polygons.inside(outline, window, 0.0) or not roads.clear(outline, ROAD_CLEARANCE_M):
            return False
        if opens is not None and not opens.clear(outline, 0.0):
            return False
        if not built.clear(outline, -TOUCH_M):
            return False
        built.add(outline)
        if kind is None:  # a house of the town
            floors = pick(rng, storeys)
            eave = floors * STOREY_M + rng.uniform(-0.2, 0.4)
            kind = "residential" if eave <= HEIGHT_RANGES_M["residential"][1] else "apartment"
        else:
            eave = _eave_height(rng, kind)
        placed.append(_Placed(outline, footprint, rotation, kind, _r(eave)))
        return True

    lengths = np.array([math.hypot(b[0] - a[0], b[1] - a[1]) for a, b, _ in segments]) if large > 0.0 else ()
    if len(lengths) and lengths.sum() > 0.0:
        for _ in range(rng.poisson(large * polygons.area(window) / LARGE_M2_PER_BUILDING)):
            (ax, ay), (bx, by), lane = segments[int(rng.choice(len(segments), p=lengths / lengths.sum()))]
            length = math.hypot(bx - ax, by - ay)
            dx, dy = (bx - ax) / length, (by - ay) / length
            side = 1.0 if rng.random() < 0.5 else -1.0
            kind = "industrial" if rng.random() < 0.5 else "apartment"
            along = math.exp(rng.uniform(*np.log(LARGE_FRONTAGE_M)))
            depth = min(along, math.exp(rng.uniform(*np.log(LARGE_DEPTH_M))))
            mid, front = rng.uniform(0.0, length), lane / 2 + ROAD_CLEARANCE_M + rng.uniform(0.0, 2.0)
            for shrink in LARGE_SHRINK:
                off = front + depth * shrink / 2
                cx, cy = ax + dx * mid - side * dy * off, ay + dy * mid + side * dx * off
                if attempt(cx, cy, along * shrink, depth * shrink, math.degrees(math.atan2(dy, dx)), kind):
                    break

    spot = 0.5 + 0.5 * density  # share of row places built on
    for (ax, ay), (bx, by), lane in segments:
        length = math.hypot(bx - ax, by - ay)
        dx, dy = (bx - ax) / length, (by - ay) / length
        angle = math.degrees(math.atan2(dy, dx))
        for side in (1.0, -1.0):
            # Rows of houses behind one another, the first facing the lane; a row's houses share its
            # depth band but not their depth, so the backs are ragged.
            front = lane / 2 + ROAD_CLEARANCE_M + rng.uniform(0.0, 1.0)
            for _row in range(DENSE_ROWS):
                band = rng.uniform(*DENSE_DEPTH_M)
                t = rng.uniform(0.0, 3.0)
                while t < length:
                    along, depth = rng.uniform(*DENSE_FRONTAGE_M), band * rng.uniform(0.6, 1.0)
                    if rng.random() < spot:
                        for d in (depth, 0.6 * depth):
                            off = front + rng.uniform(0.0, 0.4) + d / 2
                            mid = t + along / 2
                            cx, cy = ax + dx * mid - side * dy * off, ay + dy * mid + side * dx * off
                            if d >= DENSE_DEPTH_M[0] - 1.0 and attempt(cx, cy, along, d, angle):
                                break
                    t += along + (0.0 if rng.random() < DENSE_TOUCHING else rng.uniform(0.5, 3.0))
                front += band + rng.uniform(0.0, 1.5)
    # Seeds in the blocks' interiors, turned about like the nearest lane.
    starts = np.array([s[0] for s in segments]).reshape(-1, 2)
    step = np.array([s[1] for s in segments]).reshape(-1, 2) - starts
    x0, y0, x1, y1 = polygon_bbox(window)
    for _ in range(int(density * polygons.area(window) / DENSE_M2_PER_SEED) if len(segments) else 0):
        px, py = rng.uniform(x0, x1), rng.uniform(y0, y1)
        t = np.clip(((np.array([px, py]) - starts) * step).sum(1) / (step * step).sum(1), 0.0, 1.0)
        nearest = int(np.argmin(np.hypot(*(starts + t[:, None] * step - (px, py)).T)))
        angle = math.degrees(math.atan2(step[nearest, 1], step[nearest, 0])) + rng.normal(0.0, SEED_TURN_DEG)
        attempt(px, py, rng.uniform(*DENSE_FRONTAGE_M), rng.uniform(*DENSE_DEPTH_M), angle)
    # Growth: houses lean on the houses already there (often sharing a wall), until the block is full
    # but for yards.
    grow = DENSE_GROWTH[0] + DENSE_GROWTH[1] * density
    k = 0
    while k < len(placed):
        house = placed[k]
        k += 1
        fx0, fy0, fx1, fy1 = polygon_bbox(house.footprint)
        cx, cy, half_u, half_v = (fx0 + fx1) / 2, (fy0 + fy1) / 2, (fx1 - fx0) / 2, (fy1 - fy0) / 2
        c, s = math.cos(math.radians(house.rotation_deg)), math.sin(math.radians(house.rotation_deg))
        for side in rng.permutation(4):
            if rng.random() >= grow:
                continue
            along, depth = rng.uniform(*DENSE_FRONTAGE_M), rng.uniform(*DENSE_DEPTH_M)
            gap = 0.0 if rng.random() < DENSE_TOUCHING else rng.uniform(0.5, 2.0)
            for shrink in (1.0, 0.75, 0.5):  # a smaller house may fit where a big one does not
                a, d = max(DENSE_FRONTAGE_M[0], along * shrink), max(DENSE_FRONTAGE_M[0], depth * shrink)
                if side < 2:  # beside: along the house's frontage, one of the long lines even
                    u = (1 if side == 0 else -1) * (half_u + a / 2 + gap)
                    v = rng.uniform(-0.5, 0.5) + (d / 2 - half_v) * sign(rng)
                else:  # behind or in front
                    u = rng.uniform(-1.0, 1.0) * abs(half_u - a / 2)
                    v = (1 if side == 2 else -1) * (half_v + d / 2 + gap)
                if attempt(cx + c * u - s * v, cy + s * u + c * v, a, d, house.rotation_deg):
                    break
    return placed


def _dense_trees(rng: np.random.Generator, region: _Region, roads: polygons.Occupancy, built: polygons.Occupancy,
                 density: float, width: float, height: float) -> list[Tree]:
    """A few trees in the yards left between a dense region's houses, clear of roofs and roads."""
    window = polygons.clip(region.cell, rect_polygon(0.0, 0.0, width, height))
    x0, y0, x1, y1 = polygon_bbox(window)
    trees: list[Tree] = []
    for _ in range(rng.poisson(density * polygons.area(window) / DENSE_M2_PER_TREE)):
        for _attempt in range(20):
            radius = _r(rng.uniform(1.5, 4.0))
            x, y = _r(rng.uniform(x0, x1)), _r(rng.uniform(y0, y1))
            crown = rect_polygon(x - radius, y - radius, x + radius, y + radius)  # holds the disc
            if (polygons.inside(crown, window, 0.0) and roads.clear(crown, 0.0)
                    and built.clear(crown, TREE_CLEARANCE_M)
                    and all(math.hypot(x - t.x, y - t.y) >= max(radius, t.radius_m) for t in trees)):
                trees.append(Tree(x, y, radius, _r(radius * rng.uniform(1.8, 2.8))))
                break
    return trees


@dataclass(frozen=True)
class _Frame:
    """Where a style's street grid lies: made on a square of side `side` in its own frame, turned by
    `angle_deg` and centred on the city. Suburban grids keep the city's frame (no turn, no square)."""

    angle_deg: float
    side: float
    centre: Point

    @cached_property
    def _turning(self) -> tuple[float, float]:
        return polygons.turning(self.angle_deg)

    def _points(self, points) -> tuple[Point, ...]:
        half, (cx, cy) = self.side / 2, self.centre
        return polygons.turn([(x - half + cx, y - half + cy) for x, y in points], cx, cy, *self._turning)

    def point(self, x: float, y: float) -> Point:
        return self._points(((x, y),))[0]

    def polygon(self, polygon: Polygon) -> Polygon:
        return polygons.rounded_polygon(self._points(polygon))

    def sketch(self, sketch: _Sketch) -> _Sketch:
        """The sketch moved so its footprint's centre lands where the frame puts it, turned with the frame."""
        x0, y0, x1, y1 = polygon_bbox(sketch.footprint)
        cx, cy = (x0 + x1) / 2, (y0 + y1) / 2
        wx, wy = self.point(cx, cy)
        footprint = tuple((_r(x + wx - cx), _r(y + wy - cy)) for x, y in sketch.footprint)
        return _Sketch(sketch.lot_index, sketch.kind, footprint, sketch.shape, sketch.height_m, _r(self.angle_deg))


def _styled_layout(seed: int, width: float, height: float, params: LayoutParams) -> CityLayout:
    """A city of several styles (or one other than suburban): each region is made by its style's rules.

    The stages draw from the same generators as a suburban city's, in the same order (streets, lots,
    buildings, roofs, trees), plus one for the regions, so a stage's knob changes that stage only.
    Downtown and industrial grids are turned by an angle of their own; the suburban grid is not.
    """
    # The seventh stream (open patches) is drawn only when a town has them; the first six are those of six.
    road_rng, lot_rng, building_rng, roof_rng, tree_rng, region_rng, open_rng = stage_generators(seed, 7)
    regions, roads = _style_regions(region_rng, width, height, params.style)
    through = list(roads)
    grid_styles = [style for style, _ in params.style if style != "dense"]
    cells = {style: [r.cell for r in regions if r.style == style] for style in grid_styles}
    side = math.hypot(width, height)
    frames = {style: _Frame(_r(region_rng.uniform(0.0, 90.0)), side, (width / 2, height / 2))
              for style in grid_styles if style != "suburban"}
    extent = {style: (side, side) if style in frames else (width, height) for style in grid_styles}

    def world(style: str, polygon: Polygon) -> Polygon:
        return frames[style].polygon(polygon) if style in frames else polygon

    def inside_cells(style: str, polygon: Polygon) -> bool:
        return any(polygons.inside(polygon, c) for c in cells[style])

    blocks: dict[str, list[_Block]] = {}
    streets: dict[str, list[Rect]] = {}  # each grid's streets that made it into the city, in its frame
    for style in grid_styles:
        blocks[style], grid_roads = _blocks_and_roads(road_rng, *extent[style], params)
        streets[style] = []
        for road in grid_roads:
            pieces = [Road(piece) for cell in cells[style] if (piece := _piece(world(style, road.polygon), cell))]
            roads += pieces
            if pieces:
                streets[style].append(road.bbox)
    lanes = {}
    for k, region in enumerate(regions):
        if region.style == "dense":
            lane_roads, lanes[k] = _dense_lanes(road_rng, region)
            roads += lane_roads
    # Dirt first: where a track meets a paved street, the street is drawn over it.
    roads.sort(key=lambda road: road.surface != "dirt")
    road_space = polygons.Occupancy([road.polygon for road in roads])

    # A lot across a region's border keeps its part inside (most of it, or it is dropped).
    plans, lot_styles, lots, first_block, firsts = [], [], [], 0, {}
    for style in grid_styles:
        firsts[style] = first_block
        for index, block in enumerate(blocks[style]):
            for plan in _plan_block(lot_rng, block, first_block + index, *extent[style], style):
                outline = world(style, rect_polygon(*plan.rect))
                pieces = [piece for c in cells[style] if (piece := _piece(outline, c))]
                piece = max(pieces, key=polygons.area, default=None)
                if piece and polygons.area(piece) > LOT_KEPT * polygons.area(outline) and road_space.clear(piece, 0.0):
                    plans.append(plan)
                    lot_styles.append(style)
                    lots.append(Lot(piece, plan.block_index, "paved" if style in PAVED_STYLES else "ground"))
        first_block += len(blocks[style])

    def fits(sketch: _Sketch) -> bool:
        """Whether the widest roof the sketch may get stays on its (perhaps cut) lot."""
        x0, y0, x1, y1 = polygon_bbox(sketch.footprint)
        o = OVERHANG_RANGE_M[1]
        roof = rect_polygon(x0 - o, y0 - o, x1 + o, y1 + o)
        if sketch.rotation_deg:
            roof = polygons.rotate(roof, (x0 + x1) / 2, (y0 + y1) / 2, sketch.rotation_deg)
        return polygons.inside(roof, lots[sketch.lot_index].polygon, 1e-3)

    local = _sketch_buildings(building_rng, plans, params.building_density)  # in their grid's frame
    placed = [frames[lot_styles[s.lot_index]].sketch(s) if lot_styles[s.lot_index] in frames else s for s in local]
    kept = [i for i, sketch in enumerate(placed) if fits(sketch)]
    local, sketches = [local[i] for i in kept], [placed[i] for i in kept]
    built = polygons.Occupancy()
    dense = {}
    for k, region in enumerate(regions):
        if region.style == "dense":
            opens = (_open_patches(open_rng, polygons.clip(region.cell, rect_polygon(0.0, 0.0, width, height)),
                                   params.open_share) if params.open_share > 0 else None)
            dense[k] = _dense_buildings(building_rng, region, lanes[k], road_space, built,
                                        params.building_density, width, height, opens,
                                        params.large_buildings, params.tall_share)
            for house in dense[k]:
                lots.append(Lot(polygons.rounded_polygon(house.outline), -1))
                sketches.append(_Sketch(len(lots) - 1, house.kind, house.footprint, "rect", house.height_m,
                                        house.rotation_deg, outline_placed=True))
    buildings = _roof_buildings(roof_rng, sketches, params.sloped_share)

    # Grid trees are placed in their grid's frame (beside the unturned buildings) and then moved.
    local_buildings = {s.lot_index: replace(b, footprint=s.footprint, rotation_deg=0.0)
                       for s, b in zip(local, buildings)}
    trees: list[Tree] = []
    for style in grid_styles if params.tree_size == "small" else ():  # real trees come with the clutter
        density = params.tree_density * STYLE_TREES[style]
        planted = [tree for block in blocks[style] for tree in _street_trees(tree_rng, block, density)]
        for index, plan in enumerate(plans):
            if lot_styles[index] == style:
                lot = Lot(rect_polygon(*plan.rect), plan.block_index)
                planted += _yard_trees(tree_rng, lot, local_buildings.get(index), density)
        for tree in planted:
            if style in frames:
                x, y = frames[style].point(tree.x, tree.y)
                tree = Tree(_r(x), _r(y), tree.radius_m, tree.height_m)
            crown = rect_polygon(*tree.bbox)
            if inside_cells(style, crown) and road_space.clear(crown, 0.0):
                trees.append(tree)
    for k in dense if params.tree_size == "small" else ():
        trees += _dense_trees(tree_rng, regions[k], road_space, built, params.tree_density * STYLE_TREES["dense"],
                              width, height)
    details: dict[str, list] = {}
    if params.clutter or params.tree_size == "real":
        grids = {}
        for style in grid_styles:
            mine = [i for i, s in enumerate(lot_styles) if s == style]
            renumber = {i: j for j, i in enumerate(mine)}
            grids[style] = _Grid(
                frames.get(style), cells[style], extent[style],
                [(block.rect, block.road_sides) for block in blocks[style]], streets[style],
                [(plans[i].rect, plans[i].block_index - firsts[style]) for i in mine],
                [replace(b, lot_index=renumber[i]) for i, b in local_buildings.items() if i in renumber])
        details, real = _styled_clutter(seed, params, width, height, regions, lanes, through, grids, road_space,
                                        buildings, lots)
        trees += real
    return CityLayout(int(seed), _r(width), _r(height), params, tuple(roads), tuple(lots), tuple(buildings),
                      tuple(trees), **{name: tuple(items) for name, items in details.items()})


@dataclass(frozen=True)
class _Grid:
    """One street-grid style of a styled city, in its own frame (see `_Frame`), for its clutter."""

    frame: _Frame | None  # None: the city's own frame (suburban)
    cells: list[Polygon]  # the regions of the style, in the world
    extent: tuple[float, float]  # of the frame
    blocks: list[tuple[Rect, frozenset]]
    streets: list[Rect]  # the streets that lie in the cells
    lots: list[tuple[Rect, int]]  # (rect, index into blocks)
    buildings: list[Building]  # unturned, lot_index into lots

    def polygon(self, polygon: Polygon) -> Polygon:
        return self.frame.polygon(polygon) if self.frame else polygon

    def point(self, x: float, y: float) -> Point:
        return self.frame.point(x, y) if self.frame else (x, y)

    @property
    def angle_deg(self) -> float:
        return self.frame.angle_deg if self.frame else 0.0

    @cached_property
    def _cell_boxes(self) -> list[Rect]:
        return [polygon_bbox(cell) for cell in self.cells]

    def cut(self, polygon: Polygon) -> list[Polygon]:
        """The pieces of a (small, convex) world polygon inside the cells."""
        x0, y0, x1, y1 = polygon_bbox(polygon)
        out = []
        for cell, (cx0, cy0, cx1, cy1) in zip(self.cells, self._cell_boxes):
            if x1 <= cx0 or cx1 <= x0 or y1 <= cy0 or cy1 <= y0:
                continue
            if polygons.inside(polygon, cell, 0.0):
                return [polygon]
            piece = polygons.rounded_polygon(polygons.clip(polygon, cell))
            if CUT_CORNERS[0] <= len(piece) <= CUT_CORNERS[1] and polygons.area(piece) > 0.05:
                out.append(piece)
        return out

    def holds(self, polygon: Polygon) -> bool:
        return any(polygons.inside(polygon, cell, 0.0) for cell in self.cells)


CLUTTER_STREAM = 18  # after the seed in the clutter streams of styled cities: [seed, 18, part, index, what]


def _styled_clutter(seed: int, params: LayoutParams, width: float, height: float, regions: list[_Region],
                    lanes: dict, through: list[Road], grids: dict[str, _Grid], road_space: polygons.Occupancy,
                    buildings: list[Building], lots: list[Lot]) -> tuple[dict[str, list], list[Tree]]:
    """Street details, clutter and real trees of a styled city, region by region as its style has them.

    Each grid style's are made in its own frame by `clutter.generate_clutter` and `clutter.real_trees`
    with the style's `GRID_RULES`, then moved into the world and kept inside the style's regions (pavings
    and markings cut at their borders); dense towns get cars by their lanes, trees in the gaps between
    houses and bushes in the yards; the through roads between regions get centre lines and traffic, and
    kerbs and sidewalks on the sides of regions whose style has them. Every part draws from a generator of
    its own (`CLUTTER_STREAM`), so the city's stages keep their draws and a styled city without clutter
    stays as it was.
    """
    def rng(*part: int) -> np.random.Generator:
        return np.random.default_rng([seed, CLUTTER_STREAM, *part])

    city = (0.0, 0.0, width, height)
    roofs = polygons.Occupancy([b.roof_outline for b in buildings])
    borders = polygons.Occupancy([road.polygon for road in through])
    taken = polygons.Occupancy()  # vehicles and bushes placed so far, in the world
    out: dict[str, list] = {name: [] for name in _CLUTTER}
    trees: list[Tree] = []

    def plant(x: float, y: float, radius: float, height_m: float, window) -> None:
        """A real tree if its trunk stands in the window and off the roads and its crown in the city,
        clear of roofs; its trunk is taken (bushes and cars placed later keep off it)."""
        trunk = rect_polygon(x - 0.5, y - 0.5, x + 0.5, y + 0.5)
        if (window((x, y)) and radius <= x <= width - radius and radius <= y <= height - radius
                and road_space.clear(trunk, 0.0) and roofs.clear(polygons.disc(x, y, radius + TREE_CLEARANCE_M), 0.0)):
            trees.append(Tree(_r(x), _r(y), radius, height_m))
            taken.add(trunk)

    for style, grid in grids.items():
        part, rules = STYLES.index(style), GRID_RULES[style]
        clutter = generate_clutter(rng(0, part, 0), params, grid.blocks, grid.lots, grid.buildings, grid.streets,
                                   VERGE_M, params.road_width_m, rules) if params.clutter else None
        if clutter:
            for paving in clutter.pavings:
                out["pavings"] += [Paving(piece, paving.kind) for piece in grid.cut(grid.polygon(paving.polygon))]
            for marking in clutter.markings:  # not over the through roads the grid's streets run into
                out["markings"] += [Marking(piece) for piece in grid.cut(grid.polygon(marking.polygon))
                                    if borders.clear(piece, 0.0)]
            for car in clutter.cars:
                x, y = grid.point(car.x, car.y)
                moved = replace(car, x=_r(x), y=_r(y), heading_deg=_r((car.heading_deg + grid.angle_deg) % 360.0))
                if grid.holds(moved.corners) and borders.clear(polygons.grown_box(moved.corners, 0.3), 0.0):
                    out["cars"].append(moved)
                    taken.add(moved.corners)
            out["pools"] += [pool for pool in clutter.pools if grid.holds(pool.polygon)]
            out["shrubs"] += [shrub for shrub in clutter.shrubs
                              if grid.holds(shrub.polygon) and borders.clear(shrub.polygon, 0.0)]
        if params.tree_size == "real":
            # Street trees stand in the planting strip between kerb and sidewalk when there are sidewalks.
            row_offset = 1.6 if params.street_details else VERGE_M / 2
            built = {b.lot_index for b in grid.buildings}
            yards = [(rect, index in built) for index, (rect, _) in enumerate(grid.lots)]
            for x, y, radius, height_m in real_trees(
                    rng(0, part, 1), params.tree_density, grid.blocks, yards, [b.bbox for b in grid.buildings],
                    clutter.no_trunks if clutter else (), *grid.extent, VERGE_M, row_offset, rules):
                plant(*grid.point(x, y), radius, height_m, lambda p, grid=grid: grid.holds((p,)))
    for k, region in enumerate(regions):
        if region.style != "dense":
            continue
        window = polygons.clip(region.cell, rect_polygon(0.0, 0.0, width, height))
        # Trees, bushes, cars: each keeps off those before it, so more cars move no tree or bush.
        ground = OpenGround(window, roofs, road_space)
        if params.tree_size == "real":
            for x, y, radius, height_m in gap_trees(rng(1, k, 1), params.tree_density, ground, window, city,
                                                    roofs, road_space):
                plant(x, y, radius, height_m, lambda p, window=window: polygons.inside((p,), window, 0.0))
        if params.shrub_density > 0:
            out["shrubs"] += gap_bushes(rng(1, k, 2), params.shrub_density, ground, window, roofs, road_space,
                                        taken)
        if params.car_density > 0:
            out["cars"] += lane_cars(rng(1, k, 0), params.car_density, lanes[k], window, roofs, taken)
    if through and (params.street_details or params.car_density > 0):
        dense_cells = [region.cell for region in regions if region.style == "dense"]
        plan = [(road.polygon,
                 params.street_details and road.surface == "asphalt" and not _between(road.polygon, dense_cells),
                 params.car_density * (0.5 if road.surface == "dirt" else 1.0)) for road in through]
        markings, cars = through_roads(rng(2, 0, 0), plan, road_space, taken)
        out["markings"] += markings
        out["cars"] += cars
    if through and params.street_details:
        # Last, from a stream of their own, and kept off lots and pavings rather than the knobs' items:
        # everything above stays as it was, and they follow from the layout and street_details alone.
        sides = [(region.cell, None if region.style == "dense" else GRID_RULES[region.style].sidewalk_m)
                 for region in regions]
        ground = polygons.Occupancy([lot.polygon for lot in lots] + [paving.polygon for paving in out["pavings"]])
        paved = [road.polygon for road in through if road.surface == "asphalt"]
        out["pavings"] += through_sidewalks(rng(3, 0, 0), paved, sides, road_space, ground)
    return {name: items for name, items in out.items() if items}, trees


def _between(polygon: Polygon, cells: list[Polygon]) -> bool:
    """Whether a through road runs between two of the cells (it lies on their shared border)."""
    return sum(not polygons.apart(polygon, cell, 0.0) for cell in cells) >= 2


# ---------------------------------------------------------------- entry points

MIN_CITY_M = 30.0
MAX_CITY_M = 5000.0


def stage_generators(seed: int, n: int) -> list[np.random.Generator]:
    """``n`` independent generators for the stages of one seed: the streams ``default_rng(seed).spawn(n)``
    gives, built from ``SeedSequence.spawn`` because ``Generator.spawn`` needs numpy 1.25 and the add-on
    and the worker also run on Blender 4.2's older numpy."""
    return [np.random.Generator(np.random.PCG64(child)) for child in np.random.SeedSequence(seed).spawn(n)]


def generate_layout(seed: int, width_m: float, height_m: float, params: LayoutParams | None = None) -> CityLayout:
    """Generate the city covering [0, width_m] x [0, height_m]; the same seed gives the same layout."""
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise MetaSimError(f"seed must be a non-negative integer, got {seed!r}")
    width = _check_number("generate_layout", "width_m", width_m, MIN_CITY_M, MAX_CITY_M)
    height = _check_number("generate_layout", "height_m", height_m, MIN_CITY_M, MAX_CITY_M)
    params = LayoutParams() if params is None else params
    layout = (_styled_layout(int(seed), width, height, params) if params.style != DEFAULT_STYLE
              else _grid_layout(int(seed), width, height, params))
    if params.water_share <= 0.0:
        return layout
    # The water's stream is the eighth: spawning eight leaves the seven streams of a styled city as they were.
    waters = water_bodies(stage_generators(int(seed), 8)[7], width, height, params.water_share)
    details = {name: getattr(layout, name) for name in _CLUTTER}
    buildings, trees, details = flood(waters, layout.buildings, layout.trees, details)
    return replace(layout, buildings=tuple(buildings), trees=tuple(trees),
                   **{name: tuple(items) for name, items in details.items()}, waters=tuple(waters))


def _grid_layout(seed: int, width: float, height: float, params: LayoutParams) -> CityLayout:
    """A city of the suburban street grid alone (`generate_layout` without a style mix)."""
    # A sixth stream for clutter: spawning six leaves the first five streams as they were.
    road_rng, lot_rng, building_rng, roof_rng, tree_rng, clutter_rng = stage_generators(int(seed), 6)

    blocks, roads = _blocks_and_roads(road_rng, width, height, params)
    plans = [plan for index, block in enumerate(blocks) for plan in _plan_block(lot_rng, block, index, width, height)]
    sketches = _sketch_buildings(building_rng, plans, params.building_density)
    buildings = _roof_buildings(roof_rng, sketches, params.sloped_share)
    lots = [Lot(rect_polygon(*plan.rect), plan.block_index) for plan in plans]

    by_lot = {b.lot_index: b for b in buildings}
    street_blocks = [(block.rect, block.road_sides) for block in blocks]
    road_rects = [road.bbox for road in roads]
    clutter = generate_clutter(clutter_rng, params, street_blocks, [(lot.bbox, lot.block_index) for lot in lots],
                               buildings, road_rects, VERGE_M, params.road_width_m) if params.clutter else None
    if params.tree_size == "real":
        # Street trees stand in the planting strip between kerb and sidewalk when there are sidewalks.
        row_offset = 1.6 if params.street_details else VERGE_M / 2
        yards = [(lot.bbox, index in by_lot) for index, lot in enumerate(lots)]
        trees = [Tree(*t) for t in real_trees(tree_rng, params.tree_density, street_blocks, yards,
                                              [b.bbox for b in buildings], clutter.no_trunks if clutter else (),
                                              width, height, VERGE_M, row_offset)]
    else:
        trees = [tree for block in blocks for tree in _street_trees(tree_rng, block, params.tree_density)]
        for index, lot in enumerate(lots):
            trees += _yard_trees(tree_rng, lot, by_lot.get(index), params.tree_density)
    details = {} if clutter is None else {name: getattr(clutter, name) for name in _CLUTTER}
    return CityLayout(int(seed), _r(width), _r(height), params, tuple(roads), tuple(lots), tuple(buildings),
                      tuple(trees), **details)


def city_size_m(n_tiles: int, tile_m: float) -> tuple[float, float]:
    """(width, height) in metres of the city ``layout_for_tiles`` lays out for ``n_tiles`` tiles of ``tile_m``:
    what a render checks against ``MIN_CITY_M`` and ``MAX_CITY_M`` before it plans anything."""
    cols = math.ceil(math.sqrt(n_tiles))
    return cols * tile_m, math.ceil(n_tiles / cols) * tile_m


def layout_for_tiles(seed: int, n_tiles: int, tile_m: float = TILE_M,
                     params: LayoutParams | None = None) -> tuple[CityLayout, list[Rect]]:
    """A city over a near-square grid of tiles (cols = ceil(sqrt(n)), rows = ceil(n / cols)).

    Returns the layout and the first `n_tiles` tile rectangles in row-major order (row 0 south).
    """
    if isinstance(n_tiles, bool) or not isinstance(n_tiles, (int, np.integer)) or n_tiles < 1:
        raise MetaSimError(f"n_tiles must be a positive integer, got {n_tiles!r}")
    tile_m = _check_number("layout_for_tiles", "tile_m", tile_m, 1.0, MAX_CITY_M)
    layout = generate_layout(seed, *city_size_m(int(n_tiles), tile_m), params)
    return layout, layout.tile_grid(tile_m)[: int(n_tiles)]


def scene_version(overrides: Mapping) -> dict:
    """``{"scene": SCENE_VERSION}`` for a city with these layout overrides when it is of the richer
    scene (a style other than the suburban grid, or roof furniture), else {}: what tile headers and
    training-set keys add, so caches of plain cities stay valid when the richer scene changes."""
    style = overrides.get("style", "suburban")
    rich = float(overrides.get("roof_furniture", 0.0) or 0.0) > 0.0 or (style not in ("suburban", None))
    return {"scene": SCENE_VERSION} if rich else {}

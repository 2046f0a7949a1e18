"""Open water of a city (``LayoutParams.water_share``): rivers, lagoons and coasts. Pure numpy, no ``bpy``.

Real overhead imagery often holds water (Rio's SpaceNet chips: a muddy lagoon over a third of the test
scenes), and a segmenter that never saw water takes a flat grey-brown surface for a roof. A water body is a
chain of overlapping discs (`Water`, 15-50 m across in radius) that enters from the city's edge and wanders
inward, bending a little at each step, so a tile sees a bank with a curved edge; chains are added until the
discs cover about ``share`` of the city. The water lies over the ground, the lots, the pavings and the roads
(they end at its bank), and `flood` takes away what cannot stand in it: every building, pool, car and bush
that touches a disc, and every tree whose trunk stands in one (a crown may reach over the bank). Everything
else of the city is as it was: the water comes from a stream of its own, after every other stage.

All discs of a city share one colour of `WATER_COLOURS` (muddy, olive, dark blue-grey, brown): what its
renderer paints them with. The label passes see water as background.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..core.errors import MetaSimError
from . import polygons

# Linear RGB of open water seen from above: Rio's muddy lagoon, an algae-green pond, a deep lake, a silty river.
WATER_COLOURS = {"muddy": (0.19, 0.17, 0.11), "olive": (0.06, 0.085, 0.045), "deep": (0.02, 0.038, 0.05),
                 "silty": (0.16, 0.10, 0.05)}
RADIUS_M = (15.0, 50.0)  # a disc's radius, log-uniform
STEP = 0.8  # a chain's next disc this many of the last one's radii on
TURN_DEG = 25.0  # a chain's heading turns by this much at each step (standard deviation)
SAMPLES = 4000  # points the covered share is measured on
MAX_DISCS = 600


@dataclass(frozen=True)
class Water:
    """One disc of open water: centre, radius and the water's colour (a name of `WATER_COLOURS`)."""

    x: float
    y: float
    radius_m: float
    colour: str

    @property
    def bbox(self) -> tuple[float, float, float, float]:
        r = self.radius_m
        return (self.x - r, self.y - r, self.x + r, self.y + r)

    def to_dict(self) -> dict[str, Any]:
        return {"x": self.x, "y": self.y, "radius_m": self.radius_m, "colour": self.colour}

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> Water:
        water = cls(float(data["x"]), float(data["y"]), float(data["radius_m"]), data["colour"])
        if not (all(map(math.isfinite, (water.x, water.y, water.radius_m))) and 0.0 < water.radius_m <= 1000.0):
            raise MetaSimError("water: x, y must be finite and radius_m in (0, 1000] m; the layout file is damaged")
        if water.colour not in WATER_COLOURS:
            raise MetaSimError(f"water: colour {water.colour!r} is not one of {', '.join(WATER_COLOURS)}; "
                               "the layout file is damaged")
        return water


def water_bodies(rng: np.random.Generator, width: float, height: float, share: float) -> list[Water]:
    """Chains of discs covering about ``share`` of the city ``[0, width] x [0, height]`` (see the module)."""
    if share <= 0.0:
        return []
    colour = list(WATER_COLOURS)[int(rng.integers(len(WATER_COLOURS)))]
    points = rng.uniform((0.0, 0.0), (width, height), size=(SAMPLES, 2))
    covered = np.zeros(len(points), bool)
    out: list[Water] = []
    x = y = heading = 0.0
    inside = False
    while covered.mean() < share and len(out) < MAX_DISCS:
        if not inside:  # a new chain from a point on the city's edge, heading inward
            side = int(rng.integers(4))
            along = rng.uniform(0.0, 1.0)
            x, y, heading = ((along * width, 0.0, 90.0), (width, along * height, 180.0),
                             (along * width, height, 270.0), (0.0, along * height, 0.0))[side]
            heading += rng.uniform(-40.0, 40.0)
        r = math.exp(rng.uniform(*np.log(RADIUS_M)))
        out.append(Water(polygons.rounded(x), polygons.rounded(y), polygons.rounded(r), colour))
        covered |= np.hypot(points[:, 0] - x, points[:, 1] - y) <= r
        heading += rng.normal(0.0, TURN_DEG)
        x += STEP * r * math.cos(math.radians(heading))
        y += STEP * r * math.sin(math.radians(heading))
        inside = -r < x < width + r and -r < y < height + r
    return out


class _Discs:
    """The discs of a city's water, to test outlines and points against."""

    def __init__(self, waters) -> None:
        self.xyr = np.array([(w.x, w.y, w.radius_m) for w in waters], float).reshape(-1, 3)

    def holds(self, x: float, y: float) -> bool:
        """Whether the point lies in any disc."""
        return bool(np.any(np.hypot(self.xyr[:, 0] - x, self.xyr[:, 1] - y) < self.xyr[:, 2]))

    def touches(self, polygon) -> bool:
        """Whether the convex polygon shares area with any disc: its centre lies inside the polygon, or
        an edge passes nearer to the centre than the radius."""
        pts = np.asarray(polygon, float)
        x0, y0 = pts.min(0)
        x1, y1 = pts.max(0)
        c = self.xyr
        x, y, r = c[:, 0], c[:, 1], c[:, 2]
        near = c[(x + r > x0) & (x - r < x1) & (y + r > y0) & (y - r < y1)]
        if not len(near):
            return False
        a, b = pts, np.roll(pts, -1, axis=0)
        ab = b - a  # (edges, 2)
        centres = near[:, None, :2]  # (discs, 1, 2)
        t = np.clip(((centres - a) * ab).sum(-1) / np.maximum((ab * ab).sum(-1), 1e-12), 0.0, 1.0)
        closest = a + t[..., None] * ab
        dist = np.hypot(*(centres - closest).transpose(2, 0, 1)).min(1)
        cross = ab[:, 0] * (centres[..., 1] - a[:, 1]) - ab[:, 1] * (centres[..., 0] - a[:, 0])
        centre_inside = np.all(cross >= 0, axis=1) | np.all(cross <= 0, axis=1)
        return bool(np.any(centre_inside | (dist < near[:, 2])))


def flood(waters, buildings, trees, details: dict) -> tuple[list, list, dict]:
    """The buildings, trees and details (``name -> items``) left standing beside ``waters``: see the module.
    Pavings and markings stay (the water lies over them)."""
    if not waters:
        return list(buildings), list(trees), details
    discs = _Discs(waters)
    kept = {name: [item for item in items if not discs.touches(item.corners if name == "cars" else item.polygon)]
            if name in ("pools", "cars", "shrubs") else list(items) for name, items in details.items()}
    return ([b for b in buildings if not discs.touches(polygons.rect_polygon(*b.bbox))],
            [t for t in trees if not discs.holds(t.x, t.y)], kept)

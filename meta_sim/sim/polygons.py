"""Plane geometry of convex polygons for the city layout: rotation, clipping, overlap tests and
an occupancy grid.

Pure Python (polygons here have a handful of vertices, where numpy's call overhead dominates).
Polygons are sequences of (x, y) vertices, counter-clockwise.
"""

from __future__ import annotations

import functools
import itertools
import math

Point = tuple[float, float]


def rounded(value: float) -> float:
    """A coordinate rounded to 0.1 mm: the layout's stored floats, so its JSON is stable.

    It is ``round(value, 4)``, taken the short way where that is sure to agree: below 2e9 steps of
    0.1 mm the product ``value * 1e4`` is off by less than 1.2e-7, so away from the halfway points
    its nearest integer n is the exact value's, and ``n / 1e4`` is the float nearest to n steps, as
    Python's rounding returns it (a zero keeps the value's sign, as there)."""
    value = float(value)
    steps = value * 1e4
    if abs(steps) < 2e9:
        n = round(steps)
        if abs(steps - n) < 0.4999:
            return n / 1e4 if n else math.copysign(0.0, value)
    return round(value, 4)


def clamp(value: float, lo: float, hi: float) -> float:
    """``np.clip`` of one finite number, without numpy's per-call cost: the same value, even the sign of a zero."""
    value = value if value > lo else lo
    return value if value < hi else hi


def rect_polygon(x0: float, y0: float, x1: float, y1: float) -> tuple[Point, ...]:
    """Axis-aligned rectangle as a CCW polygon starting at its south-west corner (rounded coordinates)."""
    x0, y0, x1, y1 = rounded(x0), rounded(y0), rounded(x1), rounded(y1)
    return ((x0, y0), (x1, y0), (x1, y1), (x0, y1))


def bbox(points) -> tuple[float, float, float, float]:
    """(x0, y0, x1, y1) of the points (in one pass: the layout asks this of every polygon it tries)."""
    points = iter(points)
    first = next(points, None)
    if first is None:
        raise ValueError("bbox of no points")
    x0, y0 = x1, y1 = first
    for x, y in points:
        if x < x0:
            x0 = x
        elif x > x1:
            x1 = x
        if y < y0:
            y0 = y
        elif y > y1:
            y1 = y
    return (x0, y0, x1, y1)


def lot_to_world(rect, front: str, u0: float, u1: float, v0: float, v1: float) -> tuple[float, float, float, float]:
    """A lot-local rectangle (u along the frontage, v back from the front side ``front``: "S", "N", "W" or
    "E") of the axis-aligned lot ``rect`` in world coordinates."""
    x0, y0, x1, y1 = rect
    return {
        "S": (x0 + u0, y0 + v0, x0 + u1, y0 + v1),
        "N": (x0 + u0, y1 - v1, x0 + u1, y1 - v0),
        "W": (x0 + v0, y0 + u0, x0 + v1, y0 + u1),
        "E": (x1 - v1, y0 + u0, x1 - v0, y0 + u1),
    }[front]


def rotate(points, cx: float, cy: float, degrees: float) -> tuple[Point, ...]:
    """The points turned counter-clockwise by ``degrees`` about (cx, cy)."""
    return turn(points, cx, cy, *turning(degrees))


def turning(degrees: float) -> tuple[float, float]:
    """The cosine and sine `rotate` turns by."""
    return math.cos(math.radians(degrees)), math.sin(math.radians(degrees))


def turn(points, cx: float, cy: float, c: float, s: float) -> tuple[Point, ...]:
    """`rotate` by the angle of `turning` (c, s), for many turns by one angle."""
    return tuple((cx + c * (x - cx) - s * (y - cy), cy + s * (x - cx) + c * (y - cy)) for x, y in points)


def area(points) -> float:
    """Signed shoelace area: positive for counter-clockwise vertices."""
    n = len(points)
    return 0.5 * sum(points[i][0] * points[(i + 1) % n][1] - points[(i + 1) % n][0] * points[i][1]
                     for i in range(n))


def _axes(points) -> list[tuple[float, float]]:
    """The unit normals of a polygon's edges (but the vanishing ones)."""
    n = len(points)
    out = []
    for i in range(n):
        (x0, y0), (x1, y1) = points[i], points[(i + 1) % n]
        length = math.hypot(x1 - x0, y1 - y0)
        if length > 1e-12:
            out.append(((y1 - y0) / length, (x0 - x1) / length))
    return out


def separation(a, b) -> float:
    """Largest gap between the projections of two convex polygons on any of their edge normals.

    Positive: they are at least that far apart; zero: they touch; negative: they overlap (by at
    least that much along every axis). A lower bound of their distance.
    """
    best = -math.inf
    for axes_of in (a, b):
        for nx, ny in _axes(axes_of):
            pa = [x * nx + y * ny for x, y in a]
            pb = [x * nx + y * ny for x, y in b]
            best = max(best, min(pb) - max(pa), min(pa) - max(pb))
    return best


def _extents(points) -> list[tuple[float, float, float, float]]:
    """(nx, ny, lo, hi) for each edge normal of a convex polygon: the normal and the polygon's extent along it."""
    out = []
    (fx, fy), rest = points[0], points[1:]
    for nx, ny in _axes(points):
        lo = hi = fx * nx + fy * ny  # then as min() and max() find them: the first of equal values
        for x, y in rest:
            v = x * nx + y * ny
            if v < lo:
                lo = v
            elif v > hi:
                hi = v
        out.append((nx, ny, lo, hi))
    return out


def _separated(extents, points, gap: float) -> bool:
    """Whether the points lie at least ``gap`` off a polygon of these `_extents` along one of its normals.

    ``min(p) - hi >= gap`` holds exactly when it holds for every point (rounding keeps order), so each
    axis is left at the first points that show it cannot separate them.
    """
    for nx, ny, lo, hi in extents:
        beyond = before = True  # every point so far lies `gap` beyond hi / before lo
        for x, y in points:
            v = x * nx + y * ny
            beyond = beyond and v - hi >= gap
            before = before and lo - v >= gap
            if not (beyond or before):
                break
        else:
            return True
    return False


def apart(a, b, gap: float) -> bool:
    """Whether `separation` of the two polygons is at least ``gap`` (stops at the first axis that shows it)."""
    return _separated(_extents(a), b, gap) or _separated(_extents(b), a, gap)


def clip(subject, window) -> tuple[Point, ...]:
    """The part of a convex polygon inside a convex counter-clockwise window (Sutherland-Hodgman)."""
    out = list(subject)
    n = len(window)
    for i in range(n):
        if not out:
            break
        (ax, ay), (bx, by) = window[i], window[(i + 1) % n]

        def side(p, ax=ax, ay=ay, bx=bx, by=by):
            return (bx - ax) * (p[1] - ay) - (by - ay) * (p[0] - ax)

        points, out = out, []
        for j, p in enumerate(points):
            q = points[(j + 1) % len(points)]
            sp, sq = side(p), side(q)
            if sp >= 0:
                out.append(p)
            if (sp >= 0) != (sq >= 0):
                t = sp / (sp - sq)
                out.append((p[0] + t * (q[0] - p[0]), p[1] + t * (q[1] - p[1])))
    return tuple(out)


def overlap_area(a, b) -> float:
    """Area shared by two convex counter-clockwise polygons."""
    shared = clip(a, b)
    return area(shared) if len(shared) >= 3 else 0.0


def inside(points, window, tolerance: float = 1e-6) -> bool:
    """Whether every point lies in the convex counter-clockwise window (or within ``tolerance`` of it)."""
    n = len(window)
    limit = -tolerance
    for i in range(n):
        (ax, ay), (bx, by) = window[i], window[(i + 1) % n]
        ex, ey = bx - ax, by - ay
        length = math.hypot(ex, ey)
        if length <= 1e-12:
            continue
        for x, y in points:
            if (ex * (y - ay) - ey * (x - ax)) / length < limit:
                return False
    return True


def oriented_rect(cx: float, cy: float, along: float, across: float, degrees: float) -> tuple[Point, ...]:
    """A rectangle centred on (cx, cy), ``along`` long in the direction ``degrees`` and ``across`` wide."""
    u, v = along / 2.0, across / 2.0
    return rotate(((cx - u, cy - v), (cx + u, cy - v), (cx + u, cy + v), (cx - u, cy + v)), cx, cy, degrees)


def strip(x0: float, y0: float, x1: float, y1: float, width: float, extend: float = 0.0) -> tuple[Point, ...]:
    """The quad of a straight road ``width`` wide from (x0, y0) to (x1, y1), lengthened by ``extend`` at both ends."""
    length = math.hypot(x1 - x0, y1 - y0)
    dx, dy = (x1 - x0) / length, (y1 - y0) / length
    nx, ny = -dy * width / 2.0, dx * width / 2.0
    ax, ay, bx, by = x0 - dx * extend, y0 - dy * extend, x1 + dx * extend, y1 + dy * extend
    return ((ax - nx, ay - ny), (bx - nx, by - ny), (bx + nx, by + ny), (ax + nx, ay + ny))


def disc(x: float, y: float, r: float, sides: int = 12) -> tuple[Point, ...]:
    """A regular polygon holding the disc of radius r about (x, y) (its edges touch the circle)."""
    stretch, corners = _regular(sides)
    R = r / stretch
    return tuple((x + R * cos, y + R * sin) for cos, sin in corners)


@functools.lru_cache(maxsize=None)
def _regular(sides: int) -> tuple[float, tuple[Point, ...]]:
    """cos(pi / sides) and the corners of the regular polygon of that many sides on the unit circle."""
    return math.cos(math.pi / sides), tuple((math.cos(2 * math.pi * k / sides), math.sin(2 * math.pi * k / sides))
                                            for k in range(sides))


def grown_box(points, margin: float) -> tuple[Point, ...]:
    """The bounding box of the points grown by ``margin``, as a polygon (what `Occupancy` asks with
    to keep a clearance)."""
    x0, y0, x1, y1 = bbox(points)
    return ((x0 - margin, y0 - margin), (x1 + margin, y0 - margin), (x1 + margin, y1 + margin),
            (x0 - margin, y1 + margin))


class Occupancy:
    """Convex polygons hashed into square cells, to ask quickly whether a new one keeps clear of them."""

    def __init__(self, polygons_: list = (), cell_m: float = 16.0):
        self.cell_m = cell_m
        self.items: list[tuple[tuple[Point, ...], tuple[float, float, float, float]]] = []
        self.grid: dict[tuple[int, int], list[int]] = {}
        self._extents: list = []  # of each item, made when a query first gets past its box
        for polygon in polygons_:
            self.add(polygon)

    def _keys(self, box):
        x0, y0, x1, y1 = box
        c = self.cell_m
        return itertools.product(range(math.floor(x0 / c), math.floor(x1 / c) + 1),
                                 range(math.floor(y0 / c), math.floor(y1 / c) + 1))

    def add(self, polygon) -> None:
        box = bbox(polygon)
        self.items.append((polygon, box))
        self._extents.append(None)
        for key in self._keys(box):
            self.grid.setdefault(key, []).append(len(self.items) - 1)

    def clear(self, polygon, gap: float, skip=None) -> bool:
        """Whether the polygon keeps at least ``gap`` from every stored one (a negative gap allows touching)
        but ``skip`` (a stored polygon itself, say the road a marking lies on).

        Only polygons filed in the cells under the polygon's box are looked at: to keep a positive gap
        from all of them, ask with the polygon grown by it and a gap of zero."""
        box = qx0, qy0, qx1, qy1 = bbox(polygon)
        cells = [self.grid.get(key, ()) for key in self._keys(box)]
        near = cells[0] if len(cells) == 1 else dict.fromkeys(itertools.chain(*cells))  # each item once
        own = None
        for i in near:
            other, (x0, y0, x1, y1) = self.items[i]
            if other is skip:
                continue
            # The boxes' gap is a gap along an axis too: far enough apart, no need to look closer.
            if x0 - qx1 >= gap or qx0 - x1 >= gap or y0 - qy1 >= gap or qy0 - y1 >= gap:
                continue
            # `apart`, with both polygons' extents along their own normals made once: the stored one's
            # normals first (a long road's usually shows the gap at once), then the new one's.
            if self._extents[i] is None:
                self._extents[i] = _extents(other)
            if _separated(self._extents[i], polygon, gap):
                continue
            own = _extents(polygon) if own is None else own
            if not _separated(own, other, gap):
                return False
        return True


def rounded_polygon(points) -> tuple[Point, ...]:
    """The points rounded to 0.1 mm, without repeated neighbours (a clipped polygon's seams)."""
    out: list[Point] = []
    for x, y in points:
        p = (rounded(x), rounded(y))
        if not out or p != out[-1]:
            out.append(p)
    while len(out) > 1 and out[0] == out[-1]:
        out.pop()
    return tuple(out)

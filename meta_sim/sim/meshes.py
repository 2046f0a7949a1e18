"""City layout -> mesh arrays (vertices, polygons, UVs, labels), without bpy.

The Blender builder only copies these arrays into meshes, so the geometry is
testable without Blender. Everything of one role goes into one mesh (all
buildings, all roads, all trees): a city of hundreds of buildings is a handful
of objects, quick to build and to render.

Material slots of the building mesh: 0 walls, 1 flat roofs, 2 sloped roofs;
of the road mesh: 0 asphalt, 1 dirt. A turned building is built in its own
frame and its vertices turned about its centre. UVs are in metres; the
builder divides them by the repeat size of the texture a design puts on
each slot. Every polygon carries a label colour that encodes
its building instance id and roof class exactly (see ``label_color``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from . import polygons, surfaces
from .clutter import CAR_COLOURS
from .furniture import PANEL_M, SURFACES

WALL, FLAT_ROOF, SLOPED_ROOF = 0, 1, 2
ROAD_ASPHALT, ROAD_DIRT = 0, 1  # material slots of ``road_mesh``


def label_color(instance_id: int, roof_class: int) -> tuple[float, float, float, float]:
    """Instance id and roof class as colour channels that survive a half-float buffer.

    Each channel holds an integer 0..255 as k/256, exactly representable in
    half floats; the label renderer reads them back with ``decode_labels``.
    """
    if not 0 <= instance_id < 65536:
        raise ValueError(f"instance id {instance_id} does not fit the 16-bit label encoding")
    return ((instance_id & 255) / 256.0, (instance_id >> 8) / 256.0, roof_class / 256.0, 1.0)


def decode_labels(rgb: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(instance id, roof class) images from a rendered label colour image."""
    k = np.rint(np.asarray(rgb, dtype=np.float64)[..., :3] * 256.0).astype(np.int64)
    return (k[..., 0] + 256 * k[..., 1]).astype(np.uint32), k[..., 2].astype(np.uint32)


@dataclass
class MeshArrays:
    """Polygons as flat arrays, the layout bpy's ``foreach_set`` wants."""

    name: str
    vertices: list = field(default_factory=list)
    loop_vertex: list = field(default_factory=list)
    loop_start: list = field(default_factory=list)
    loop_total: list = field(default_factory=list)
    material: list = field(default_factory=list)
    uv: list = field(default_factory=list)
    label: list = field(default_factory=list)

    def add(self, points, material: int, uv, label) -> None:
        """One polygon: 3-D points (CCW seen from outside), per-corner UVs, one label colour."""
        base = len(self.vertices)
        self.loop_start.append(len(self.loop_vertex))
        self.loop_total.append(len(points))
        self.vertices.extend(tuple(map(float, p)) for p in points)
        self.loop_vertex.extend(range(base, base + len(points)))
        self.material.append(material)
        self.uv.extend(tuple(map(float, t)) for t in uv)
        self.label.extend([label] * len(points))

    @property
    def n_polygons(self) -> int:
        return len(self.loop_start)

    def arrays(self) -> dict[str, np.ndarray]:
        return {
            "vertices": np.asarray(self.vertices, dtype=np.float32).reshape(-1, 3),
            "loop_vertex": np.asarray(self.loop_vertex, dtype=np.int32),
            "loop_start": np.asarray(self.loop_start, dtype=np.int32),
            "loop_total": np.asarray(self.loop_total, dtype=np.int32),
            "material": np.asarray(self.material, dtype=np.int32),
            "uv": np.asarray(self.uv, dtype=np.float32).reshape(-1, 2),
            "label": np.asarray(self.label, dtype=np.float32).reshape(-1, 4),
        }


def _ccw(points):
    area = sum(x0 * y1 - x1 * y0 for (x0, y0), (x1, y1) in zip(points, points[1:] + points[:1]))
    return list(points) if area > 0 else list(reversed(points))


def _walls(mesh: MeshArrays, footprint, z0: float, z1: float, label) -> None:
    for (x0, y0), (x1, y1) in zip(footprint, footprint[1:] + footprint[:1]):
        length = math.hypot(x1 - x0, y1 - y0)
        mesh.add([(x0, y0, z0), (x1, y1, z0), (x1, y1, z1), (x0, y0, z1)], WALL,
                 [(0, z0), (length, z0), (length, z1), (0, z1)], label)


def _slope_uv(points):
    """UVs for a planar roof face: u along its eave (first edge), v up the slope, in metres."""
    p = np.asarray(points, dtype=np.float64)
    e = p[1] - p[0]
    e /= np.linalg.norm(e)
    normal = np.cross(p[1] - p[0], p[2] - p[0])
    s = np.cross(normal, e)
    s /= np.linalg.norm(s)
    return [(float(q @ e), float(q @ s)) for q in p]


def _sloped_roof(mesh: MeshArrays, b, label) -> None:
    """Gable or hip roof over a rectangular footprint, eaves grown by the overhang."""
    xs = [x for x, _ in b.footprint]
    ys = [y for _, y in b.footprint]
    o = b.overhang_m
    x0, x1, y0, y1 = min(xs) - o, max(xs) + o, min(ys) - o, max(ys) + o
    if b.ridge_axis == "y":  # work in a frame where the ridge runs along local x
        def world(u, v, z):
            return (x0 + v, y0 + u, z)
        length, width = y1 - y0, x1 - x0
    else:
        def world(u, v, z):
            return (x0 + u, y0 + v, z)
        length, width = x1 - x0, y1 - y0
    half = width / 2.0
    eave = b.height_m
    ridge_z = eave + half * math.tan(math.radians(b.roof_pitch_deg))
    inset = half if b.roof == "hip" else 0.0
    inset = min(inset, length / 2.0)
    a, bb = (0, 0, eave), (length, 0, eave)
    c, d = (length, width, eave), (0, width, eave)
    r0, r1 = (inset, half, ridge_z), (length - inset, half, ridge_z)
    faces = [[a, bb, r1, r0], [c, d, r0, r1]]  # the two long slopes (eave first)
    ends = [[d, a, r0], [bb, c, r1]]
    for face in faces:
        pts = [world(*p) for p in face]
        mesh.add(pts, SLOPED_ROOF, _slope_uv(pts), label)
    for face in ends:
        pts = [world(*p) for p in face]
        if b.roof == "hip":
            mesh.add(pts, SLOPED_ROOF, _slope_uv(pts), label)
        else:  # gable end: a vertical wall triangle
            mesh.add(pts, WALL, [(0, 0)] * 3, label)


def _turn(mesh: MeshArrays, start: int, b) -> None:
    """Turn the vertices from ``start`` on by the building's rotation about its footprint's bbox centre."""
    xs = [x for x, _ in b.footprint]
    ys = [y for _, y in b.footprint]
    cx, cy = (min(xs) + max(xs)) / 2, (min(ys) + max(ys)) / 2
    c, s = math.cos(math.radians(b.rotation_deg)), math.sin(math.radians(b.rotation_deg))
    mesh.vertices[start:] = [(cx + c * (x - cx) - s * (y - cy), cy + s * (x - cx) + c * (y - cy), z)
                             for x, y, z in mesh.vertices[start:]]


def building_mesh(buildings) -> MeshArrays:
    mesh = MeshArrays("buildings")
    for b in buildings:
        start = len(mesh.vertices)
        footprint = _ccw([tuple(p) for p in b.footprint])
        roof_class = FLAT_ROOF if b.roof == "flat" else SLOPED_ROOF
        label = label_color(b.id, roof_class)
        # Walls belong to their building but are no roof: seen only in a perspective view (a drone's photo)
        _walls(mesh, footprint, 0.0, b.height_m, label_color(b.id, 0))
        if b.roof == "flat":
            mesh.add([(x, y, b.height_m) for x, y in footprint], FLAT_ROOF, footprint, label)
        else:
            _sloped_roof(mesh, b, label)
        if b.rotation_deg:
            _turn(mesh, start, b)
    return mesh


def road_mesh(roads, z: float = 0.03, repeat_m: float = 1.0) -> MeshArrays:
    """Road polygons; crossing roads overlap, so each sits a millimetre above the last.

    UVs are metres divided by ``repeat_m``, the size one repeat of the road image covers.
    """
    mesh = MeshArrays("roads")
    background = label_color(0, 0)
    for k, road in enumerate(roads):
        pts = _ccw([tuple(p) for p in road.polygon])
        uv = pts if repeat_m == 1.0 else [(x / repeat_m, y / repeat_m) for x, y in pts]
        mesh.add([(x, y, z + 0.001 * k) for x, y in pts], ROAD_DIRT if road.surface == "dirt" else ROAD_ASPHALT, uv,
                 background)
    return mesh


def lot_mesh(lots, z: float = 0.015, repeat_m: float = 1.0) -> MeshArrays:
    """Paved lots (parking, yards) a little above the ground and below the roads; UVs in metres over
    ``repeat_m``."""
    mesh = MeshArrays("paved")
    background = label_color(0, 0)
    for lot in lots:
        pts = _ccw([tuple(p) for p in lot.polygon])
        uv = pts if repeat_m == 1.0 else [(x / repeat_m, y / repeat_m) for x, y in pts]
        mesh.add([(x, y, z) for x, y in pts], 0, uv, background)
    return mesh


def road_top(n_roads: int, z: float = 0.03) -> float:
    """The height of the highest of `n_roads` roads of ``road_mesh``."""
    return z + 0.001 * max(n_roads - 1, 0)


def ground_mesh(x0: float, y0: float, x1: float, y1: float, whole_image: bool = False) -> MeshArrays:
    """One quad; UVs in metres (a small texture repeated), or with ``whole_image`` one image spanning it."""
    mesh = MeshArrays("ground")
    pts = [(x0, y0), (x1, y0), (x1, y1), (x0, y1)]
    uv = [((x - x0) / (x1 - x0), (y - y0) / (y1 - y0)) for x, y in pts] if whole_image else pts
    mesh.add([(x, y, 0.0) for x, y in pts], 0, uv, label_color(0, 0))
    return mesh


def tree_mesh(trees, segments: int = 10) -> MeshArrays:
    """Each tree a low dome: a ring at mid height under a cap, enough for a nadir view."""
    mesh = MeshArrays("trees")
    background = label_color(0, 0)
    angles = [2 * math.pi * k / segments for k in range(segments)]
    for t in trees:
        ring_lo = [(t.x + 0.6 * t.radius_m * math.cos(a), t.y + 0.6 * t.radius_m * math.sin(a),
                    0.35 * t.height_m) for a in angles]
        ring_hi = [(t.x + t.radius_m * math.cos(a + math.pi / segments),
                    t.y + t.radius_m * math.sin(a + math.pi / segments),
                    0.7 * t.height_m) for a in angles]
        top = (t.x, t.y, t.height_m)
        for k in range(segments):
            j = (k + 1) % segments
            quad = [ring_lo[k], ring_lo[j], ring_hi[k], ring_hi[j]]
            mesh.add([quad[0], quad[1], quad[3], quad[2]], 0, [(p[0], p[1]) for p in quad], background)
            tri = [ring_hi[k], ring_hi[j], top]
            mesh.add(tri, 0, [(p[0], p[1]) for p in tri], background)
    return mesh


# ---------------------------------------------------------------- clutter (sim/clutter.py)

CONCRETE, ASPHALT, PAINT, WATER, COPING, YARD = range(6)  # material slots of ``detail_mesh``
GLASS = len(CAR_COLOURS)  # material slot of car windows; slots before it are the colours of CAR_COLOURS
TRUCK_HEIGHT_M = 3.9  # the top of a truck's trailer


def _item_rng(*values: float) -> np.random.Generator:
    """A generator fixed by an item's position, so its random shape is the same in every build."""
    return np.random.default_rng([int(round(abs(v) * 1000.0)) for v in values])


def _atlas_window(rng: np.random.Generator, cell: int, size_m: float):
    """UV mapping (metres from a window's corner -> atlas UV) of a random window of one atlas cell."""
    row, col = divmod(cell, surfaces.ATLAS_CELLS)
    span = min(size_m / surfaces.CELL_M, 1.0)
    ou, ov = rng.uniform(0.0, 1.0 - span, 2)

    def uv(dx: float, dy: float) -> tuple[float, float]:
        return ((col + ou + dx / surfaces.CELL_M) / surfaces.ATLAS_CELLS,
                (row + ov + dy / surfaces.CELL_M) / surfaces.ATLAS_CELLS)
    return uv


def _crown_outline(cx: float, cy: float, lobes, angles) -> list[float]:
    """Distance from a crown's centre to the edge of the union of its lobes (circles) along each angle."""
    out = []
    for a in angles:
        dx, dy = math.cos(a), math.sin(a)
        best = 0.0
        for lx, ly, r in lobes:
            ox, oy = lx - cx, ly - cy
            along = ox * dx + oy * dy
            disc = r * r - (ox * ox + oy * oy - along * along)
            if disc >= 0.0:
                best = max(best, along + math.sqrt(disc))
        out.append(best)
    return out


def _shell(mesh: MeshArrays, rings, apex, uv, label) -> None:
    """A closed crown-like shell: a bottom cap, bands between rings (bottom first), a fan to the apex.

    Closed shells keep the mesh manifold, which Workbench's shadows draw much faster.
    """
    n = len(rings[0])
    bottom = list(reversed(rings[0]))
    mesh.add(bottom, 0, [uv(p[0], p[1]) for p in bottom], label)
    for lo, hi in zip(rings, rings[1:]):
        for k in range(n):
            j = (k + 1) % n
            quad = [lo[k], lo[j], hi[j], hi[k]]
            mesh.add(quad, 0, [uv(p[0], p[1]) for p in quad], label)
    for k in range(n):
        tri = [rings[-1][k], rings[-1][(k + 1) % n], apex]
        mesh.add(tri, 0, [uv(p[0], p[1]) for p in tri], label)


def crown_mesh(trees, segments: int = 8) -> MeshArrays:
    """Real-sized crowns: one closed shell per tree whose outline is the union of a few overlapping
    lobes inside the crown radius (a lumpy, irregular edge), bulging up where the lobes are;
    textured with a window of one tree cell of ``surfaces.foliage_atlas`` (per-tree tint and clumps).
    Few polygons: Workbench's shadow cost grows with every silhouette edge."""
    mesh = MeshArrays("crowns")
    background = label_color(0, 0)
    angles = [2 * math.pi * (k + 0.5) / segments for k in range(segments)]
    for t in trees:
        rng = _item_rng(t.x, t.y)
        R, h = t.radius_m, t.height_m
        window = _atlas_window(rng, int(rng.integers(surfaces.TREE_CELLS)), 2 * R)

        def uv(x, y, x0=t.x - R, y0=t.y - R, window=window):
            return window(x - x0, y - y0)
        lobes = [(t.x, t.y, rng.uniform(0.5, 0.65) * R)]
        for _ in range(int(rng.integers(3, 7 if R > 3.0 else 5))):
            r = rng.uniform(0.3, 0.5) * R
            a, d = rng.uniform(0, 2 * math.pi), rng.uniform(0.5, 1.0) * (R - r)
            lobes.append((t.x + d * math.cos(a), t.y + d * math.sin(a), r))
        edge = _crown_outline(t.x, t.y, lobes, angles)
        lump = rng.uniform(0.9, 1.0, segments)
        rings = []
        for share, rise in ((1.0, 0.55), (0.6, 0.85)):
            rings.append([(t.x + share * e * math.cos(a), t.y + share * e * math.sin(a),
                           h * (rise + (1.0 - rise) * 0.5 * (e / R - 0.5)) * (lump[k] if rise > 0.6 else 1.0))
                          for k, (a, e) in enumerate(zip(angles, edge))])
        _shell(mesh, rings, (t.x, t.y, h), uv, background)
    return mesh


def water_mesh(waters, z: float, sides: int = 32) -> MeshArrays:
    """Open water (``sim/water.py``) as flat discs at `z` (above every road and painted line), the k-th a
    tenth of a millimetre above the one before: overlapping discs are never coplanar (a path tracer's
    shadow rays would hit the twin face). UVs are metres over ``surfaces.LAKE_REPEAT_M``."""
    mesh = MeshArrays("water")
    background = label_color(0, 0)
    for k, w in enumerate(waters):
        pts = polygons.disc(w.x, w.y, w.radius_m, sides)
        mesh.add([(x, y, z + 1e-4 * k) for x, y in pts], 0,
                 [(x / surfaces.LAKE_REPEAT_M, y / surfaces.LAKE_REPEAT_M) for x, y in pts], background)
    return mesh


def _box(mesh: MeshArrays, corners, z0, z1, slot: int, uv, label, top_corners=None,
         top_slot: int | None = None, side_slots=None, floor: bool = False, top_uv=None) -> None:
    """A prism from the outline `corners` (CCW) at z0 to `top_corners` (default the same) at z1,
    closed by a lid and, with `floor`, a floor (a closed shell keeps Workbench's shadows fast).
    z0 and z1 are one height or one per corner (a tilted lid); `top_uv` overrides the lid's UVs."""
    top = top_corners or corners
    n = len(corners)
    lo = list(z0) if isinstance(z0, (list, tuple)) else [z0] * n
    hi = list(z1) if isinstance(z1, (list, tuple)) else [z1] * n
    if floor:
        under = [(*p, z) for p, z in zip(corners, lo)][::-1]
        mesh.add(under, slot, [uv(p[0], p[1]) for p in under], label)
    for k in range(n):
        j = (k + 1) % n
        quad = [(*corners[k], lo[k]), (*corners[j], lo[j]), (*top[j], hi[j]), (*top[k], hi[k])]
        mesh.add(quad, slot if side_slots is None else side_slots[k], [uv(p[0], p[1]) for p in quad], label)
    mesh.add([(*p, z) for p, z in zip(top, hi)], slot if top_slot is None else top_slot,
             top_uv or [uv(*p) for p in top], label)


def shrub_mesh(shrubs) -> MeshArrays:
    """Hedge pieces as closed boxes narrowing to a rounded-off top, bushes (about as wide as long) as
    small lumpy shells; textured with the shrub cells of the foliage atlas."""
    mesh = MeshArrays("shrubs")
    background = label_color(0, 0)
    shrub_cells = surfaces.ATLAS_CELLS ** 2 - surfaces.TREE_CELLS
    for s in shrubs:
        x0, y0, x1, y1 = s.bbox
        rng = _item_rng(x0, y0, x1)
        window = _atlas_window(rng, surfaces.TREE_CELLS + int(rng.integers(shrub_cells)), max(x1 - x0, y1 - y0))

        def uv(x, y, x0=x0, y0=y0, window=window):
            return window(x - x0, y - y0)
        cx, cy, h = (x0 + x1) / 2, (y0 + y1) / 2, s.height_m
        if max(x1 - x0, y1 - y0) < 1.5 * min(x1 - x0, y1 - y0):
            r = min(x1 - x0, y1 - y0) / 2
            angles = [2 * math.pi * (k + rng.random() * 0.5) / 5 for k in range(5)]
            edge = r * (1.0 - 0.2 * rng.random(5))
            rings = [[(cx + e * math.cos(a), cy + e * math.sin(a), h * 0.45) for a, e in zip(angles, edge)]]
            _shell(mesh, rings, (cx, cy, h), uv, background)
            continue
        inset = 0.25 * min(x1 - x0, y1 - y0)
        ground = [(x0, y0), (x1, y0), (x1, y1), (x0, y1)]
        top = [(x0 + inset, y0 + inset), (x1 - inset, y0 + inset), (x1 - inset, y1 - inset), (x0 + inset, y1 - inset)]
        _box(mesh, ground, 0.02, h, 0, uv, background, top_corners=top, floor=True)
    return mesh


def car_mesh(cars) -> MeshArrays:
    """Each car a box in its body colour with a dark windscreen and rear window on top; a truck a tall
    box (its trailer or load) behind a lower cab with a windscreen. Material slot = the colour's index
    in CAR_COLOURS; windows use slot GLASS."""
    mesh = MeshArrays("cars")
    background = label_color(0, 0)
    colours = list(CAR_COLOURS)
    for c in cars:
        a = math.radians(c.heading_deg)
        fx, fy, sx, sy = math.cos(a), math.sin(a), -math.sin(a), math.cos(a)

        def outline(back: float, front: float, half: float, c=c, fx=fx, fy=fy, sx=sx, sy=sy):
            return [(c.x + u * fx + v * sx, c.y + u * fy + v * sy)
                    for u, v in ((back, -half), (front, -half), (front, half), (back, half))]
        slot = colours.index(c.colour)
        L, W = c.length_m, c.width_m

        def uv(x, y):
            return (x, y)
        if c.kind == "truck":
            cab = min(2.4, 0.3 * L)
            _box(mesh, outline(-L / 2, L / 2 - cab - 0.3, W / 2), 0.9, TRUCK_HEIGHT_M, slot, uv, background, floor=True)
            _box(mesh, outline(L / 2 - cab, L / 2, W / 2), 0.5, 2.9, slot, uv, background, floor=True)
            front = L / 2 - 0.25 * cab
            mesh.add([(*p, 2.91) for p in outline(front - 0.5, front, 0.44 * W)], GLASS, [(0, 0)] * 4, background)
            continue
        _box(mesh, outline(-L / 2, L / 2, W / 2), 0.25, 1.4, slot, uv, background, floor=True)
        # Windscreen and rear window as dark panes on the roof: one closed box per car keeps shadows cheap.
        for back, front in ((0.05 * L, 0.22 * L), (-0.32 * L, -0.24 * L)):
            mesh.add([(*p, 1.41) for p in outline(back, front, 0.44 * W)], GLASS, [(0, 0)] * 4, background)
    return mesh


def detail_mesh(pavings, pools, markings, paint_z: float) -> MeshArrays:
    """Pavings, pools and painted lines as flat quads just above the ground; lines at `paint_z`
    (above every road). UVs are metres over each surface's repeat (``surfaces``)."""
    mesh = MeshArrays("details")
    background = label_color(0, 0)

    def flat(polygon, z, slot, repeat):
        pts = [tuple(p) for p in polygon]
        mesh.add([(x, y, z) for x, y in pts], slot, [(x / repeat, y / repeat) for x, y in pts], background)

    def rect(box):
        x0, y0, x1, y1 = box
        return [(x0, y0), (x1, y0), (x1, y1), (x0, y1)]

    z_of = {"yard": 0.01, "sidewalk": 0.015, "kerb": 0.018, "parking": 0.015, "driveway": 0.021}
    for p in pavings:
        slot = {"parking": ASPHALT, "yard": YARD}.get(p.kind, CONCRETE)
        # Strips along y cross those along x at block corners: a millimetre apart, never coplanar (a path
        # tracer's shadow rays would hit the twin face and paint the overlap black). A strip's direction
        # is its longest edge's (a turned grid's strips are turned).
        (ax, ay), (bx, by) = max(zip(p.polygon, p.polygon[1:] + p.polygon[:1]), key=lambda e: math.dist(*e))
        along_y = 45.0 <= math.degrees(math.atan2(by - ay, bx - ax)) % 180.0 < 135.0
        lift = 0.001 if p.kind in ("sidewalk", "kerb") and along_y else 0.0
        flat(p.polygon, z_of[p.kind] + lift, slot,
             surfaces.ASPHALT_REPEAT_M if slot == ASPHALT else surfaces.CONCRETE_REPEAT_M)
    for pool in pools:
        x0, y0, x1, y1 = pool.bbox
        c = pool.coping_m
        flat(rect((x0, y0, x1, y1)), 0.03, COPING, surfaces.CONCRETE_REPEAT_M)
        flat(rect((x0 + c, y0 + c, x1 - c, y1 - c)), 0.035, WATER, surfaces.WATER_REPEAT_M)
    for m in markings:
        flat(m.polygon, paint_z, PAINT, 1.0)
    return mesh


# ---------------------------------------------------------------- roof furniture (sim/furniture.py)

FAN_LID = len(SURFACES)  # material slot of HVAC lids; the slots before it are furniture.SURFACES in order


def _metres(x: float, y: float) -> tuple[float, float]:
    return (x, y)


def _rim(mesh: MeshArrays, outer, inner, z0: float, z1: float, slot: int, label) -> None:
    """A closed ring from z0 to z1 between the CCW outline `outer` and `inner`, its inset: a parapet."""
    n = len(outer)
    for k in range(n):
        j = (k + 1) % n
        for face in ([(*outer[k], z0), (*outer[j], z0), (*outer[j], z1), (*outer[k], z1)],  # facing out
                     [(*inner[j], z0), (*inner[k], z0), (*inner[k], z1), (*inner[j], z1)],  # facing the roof
                     [(*outer[k], z1), (*outer[j], z1), (*inner[j], z1), (*inner[k], z1)],  # the coping
                     [(*inner[k], z0), (*inner[j], z0), (*outer[j], z0), (*outer[k], z0)]):  # underneath
            mesh.add(face, slot, [(p[0], p[1]) for p in face], label)


def furniture_mesh(furnished) -> MeshArrays:
    """Roof furniture (``sim/furniture.py``) of (building, fixtures) pairs, each piece a closed shell built
    in its building's own frame and turned with it. Every polygon carries its building's label colour
    (instance id and roof class), so the labels are those of the bare roofs.

    Material slot: the index of the piece's surface in ``furniture.SURFACES``; HVAC lids use FAN_LID,
    whose image spans each lid. Panel tops map one module of ``furniture.PANEL_M`` per image repeat,
    from the corner at the start of their low edge; other UVs are metres.
    """
    mesh = MeshArrays("roof-furniture")
    for b, fixtures in furnished:
        start = len(mesh.vertices)
        label = label_color(b.id, b.roof_class)
        for f in fixtures:
            slot = SURFACES.index(f.surface)
            if f.inner:
                _rim(mesh, f.outline, f.inner, f.bottom[0], f.top[0], slot, label)
                continue
            top_uv, top_slot = None, None
            if f.kind == "hvac":
                x0, y0, x1, y1 = polygons.bbox(f.outline)
                top_uv = [((x - x0) / (x1 - x0), (y - y0) / (y1 - y0)) for x, y in f.outline]
                top_slot = FAN_LID
            elif f.surface == "solar":
                uv = _slope_uv([(*p, z) for p, z in zip(f.outline, f.top)])
                top_uv = [((u - uv[0][0]) / PANEL_M[0], (v - uv[0][1]) / PANEL_M[1]) for u, v in uv]
            _box(mesh, list(f.outline), f.bottom, f.top, slot, _metres, label, top_slot=top_slot, floor=True,
                 top_uv=top_uv)
        if b.rotation_deg:
            _turn(mesh, start, b)
    return mesh

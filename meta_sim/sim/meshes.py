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

WALL, FLAT_ROOF, SLOPED_ROOF = 0, 1, 2
ASPHALT, DIRT = 0, 1


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
        _walls(mesh, footprint, 0.0, b.height_m, label)
        if b.roof == "flat":
            mesh.add([(x, y, b.height_m) for x, y in footprint], FLAT_ROOF, footprint, label)
        else:
            _sloped_roof(mesh, b, label)
        if b.rotation_deg:
            _turn(mesh, start, b)
    return mesh


def road_mesh(roads, z: float = 0.03) -> MeshArrays:
    """Road polygons; crossing roads overlap, so each sits a millimetre above the last."""
    mesh = MeshArrays("roads")
    background = label_color(0, 0)
    for k, road in enumerate(roads):
        pts = _ccw([tuple(p) for p in road.polygon])
        mesh.add([(x, y, z + 0.001 * k) for x, y in pts], DIRT if road.surface == "dirt" else ASPHALT, pts,
                 background)
    return mesh


def lot_mesh(lots, z: float = 0.015) -> MeshArrays:
    """Paved lots (parking, yards) a little above the ground and below the roads."""
    mesh = MeshArrays("paved")
    background = label_color(0, 0)
    for lot in lots:
        pts = _ccw([tuple(p) for p in lot.polygon])
        mesh.add([(x, y, z) for x, y in pts], 0, pts, background)
    return mesh


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

"""Roof furniture: the knob, its streams, where the pieces stand, their sizes and their labels."""

import json
import math

import numpy as np
import pytest

from meta_sim.core.errors import MetaSimError
from meta_sim.sim import furniture, meshes, polygons
from meta_sim.sim.design import DesignSpace
from meta_sim.sim.furniture import roof_furniture
from meta_sim.sim.layout import CityLayout, LayoutParams, generate_layout

TOL = 1e-6
MIX = {"suburban": 1.0, "dense": 1.0, "downtown": 1.0, "industrial": 1.0}  # every kind, turned buildings, L and T


@pytest.fixture(scope="module")
def city():
    return generate_layout(4, 600.0, 600.0, LayoutParams(style=MIX, roof_furniture=1.0))


@pytest.fixture(scope="module")
def furnished(city):
    return [(b, roof_furniture(b, city.seed, 1.0)) for b in city.buildings]


@pytest.mark.parametrize("value", [1.5, -0.1, "lots", True, float("nan"), None])
def test_bad_densities_name_the_field(value):
    with pytest.raises(MetaSimError, match=r"LayoutParams\.roof_furniture must be a number in \[0, 1\]"):
        LayoutParams(roof_furniture=value)
    with pytest.raises(MetaSimError, match="roof_furniture"):
        LayoutParams.from_dict({"roof_furniture": value})


def test_the_knob_stays_out_of_default_json_and_leaves_the_layout_alone(city):
    assert "roof_furniture" not in LayoutParams().to_dict()
    assert LayoutParams.from_dict({"roof_furniture": 0.6}).to_dict()["roof_furniture"] == 0.6
    assert CityLayout.from_dict(json.loads(json.dumps(city.to_dict()))) == city
    # Nothing of the furniture is drawn from the layout's streams or stored in it.
    bare = generate_layout(4, 600.0, 600.0, LayoutParams(style=MIX))
    assert (bare.roads, bare.lots, bare.buildings, bare.trees) == (city.roads, city.lots, city.buildings, city.trees)
    assert set(city.to_dict()) == set(bare.to_dict())


def test_design_spaces_ask_for_it_where_intended():
    assert DesignSpace.load("overhead-v1").layout["roof_furniture"] > 0
    assert "roof_furniture" not in DesignSpace.load("rooftops-v1").layout


def test_same_seed_same_furniture_and_none_at_zero(city, furnished):
    assert all(roof_furniture(b, city.seed, 1.0) == pieces for b, pieces in furnished)
    assert not any(roof_furniture(b, city.seed, 0.0) for b in city.buildings)
    other = [roof_furniture(b, city.seed + 1, 1.0) for b, _ in furnished]
    assert sum(o != pieces for o, (_, pieces) in zip(other, furnished)) > 0.5 * len(furnished)
    fewer = sum(len(roof_furniture(b, city.seed, 0.3)) for b in city.buildings)
    assert 0 < fewer < 0.7 * sum(len(pieces) for _, pieces in furnished)


def test_every_kind_of_piece_is_there(furnished):
    kinds = {(b.roof == "flat", f.kind) for b, pieces in furnished for f in pieces}
    assert kinds == {(True, k) for k in ("parapet", "housing", "solar", "hvac", "skylight", "hatch")} | {
        (False, k) for k in ("chimney", "roof-window", "solar")}
    assert all(f.surface in furniture.SURFACES for _, pieces in furnished for f in pieces)


def _inside(x, y, polygon, tol=1e-3):
    """Point in a (perhaps concave) polygon, or within `tol` of its edge."""
    inside = False
    for (ax, ay), (bx, by) in zip(polygon, polygon[1:] + polygon[:1]):
        dx, dy = bx - ax, by - ay
        t = min(1.0, max(0.0, ((x - ax) * dx + (y - ay) * dy) / (dx * dx + dy * dy)))
        if math.hypot(ax + t * dx - x, ay + t * dy - y) <= tol:
            return True
        if (ay > y) != (by > y) and x < ax + (y - ay) * dx / dy:
            inside = not inside
    return inside


def test_pieces_stand_inside_the_footprint_and_apart(furnished):
    turned = 0
    for b, pieces in furnished:
        vertices = meshes.furniture_mesh([(b, pieces)]).vertices
        wall = list(b.wall_outline)  # inside the walls, so inside the roof outline too
        assert all(_inside(x, y, wall) for x, y, _ in vertices), b.id
        turned += bool(pieces) and b.rotation_deg != 0.0
        boxes = [polygons.bbox(f.outline) for f in pieces if f.kind != "parapet"]
        for i, a in enumerate(boxes):  # in the building's frame every piece is an axis-aligned rectangle
            for c in boxes[i + 1:]:
                assert (a[0] >= c[2] or c[0] >= a[2] or a[1] >= c[3] or c[1] >= a[3]), b.id
    assert turned > 20


def test_sizes_and_heights_are_in_the_scene_proportions(furnished):
    for b, pieces in furnished:
        for f in pieces:
            x0, y0, x1, y1 = polygons.bbox(f.outline)
            w, d = sorted((x1 - x0, y1 - y0))
            if f.kind == "parapet":
                assert b.parapet_m > 0 and set(f.top) == {b.height_m + b.parapet_m}
                inner = polygons.area(f.inner)
                width = (polygons.area(f.outline) - inner) / (sum(
                    math.dist(p, q) for p, q in zip(f.outline, f.outline[1:] + f.outline[:1])))
                assert furniture.PARAPET_WIDTH_M[0] - 0.05 < width < furniture.PARAPET_WIDTH_M[1] + TOL
            elif f.kind == "hvac":
                lo, hi = furniture.HVAC_SIZE_M
                assert lo - TOL <= w and d <= hi + TOL
                rise = max(f.top) - b.height_m
                assert furniture.HVAC_HEIGHT_M[0] - TOL <= rise <= furniture.HVAC_HEIGHT_M[1] + TOL
            elif f.kind == "chimney":
                lo, hi = furniture.CHIMNEY_SIZE_M
                assert lo - TOL <= w <= d <= hi + TOL and abs(w - d) < TOL
                roof = furniture._Slopes.of(b)
                cx, cy = (x0 + x1) / 2 - roof.x0, (y0 + y1) / 2 - roof.y0
                under = roof.height(*((cx, cy) if b.ridge_axis == "x" else (cy, cx)))
                assert under + furniture.CHIMNEY_RISE_M[0] - TOL <= max(f.top)
                assert max(f.top) <= b.ridge_height_m + furniture.CHIMNEY_RISE_M[1] + TOL
            elif f.kind in ("solar", "roof-window") and b.roof != "flat":
                # A few centimetres above the roof plane at every corner.
                roof = furniture._Slopes.of(b)
                for (x, y), z0, z1 in zip(f.outline, f.bottom, f.top):
                    u, v = (x - roof.x0, y - roof.y0) if b.ridge_axis == "x" else (y - roof.y0, x - roof.x0)
                    assert z0 - roof.height(u, v) == pytest.approx(furniture.ON_PLANE_M[0])
                    assert z1 - roof.height(u, v) == pytest.approx(furniture.ON_PLANE_M[1])
            elif f.kind == "solar":  # a row tilted towards the sun's side, its low edge first
                assert f.top[0] == f.top[1] < f.top[2] == f.top[3]


def test_big_commercial_roofs_carry_more_hvac_than_houses(furnished):
    per_m2 = {}
    for kind in ("residential", "office", "industrial", "highrise"):
        flat = [(b, pieces) for b, pieces in furnished if b.kind == kind and b.roof == "flat"]
        units = sum(f.kind == "hvac" for _, pieces in flat for f in pieces)
        per_m2[kind] = units / sum(polygons.area(b.footprint) for b, _ in flat)
    assert min(per_m2["office"], per_m2["industrial"], per_m2["highrise"]) > 2 * per_m2["residential"]


def test_furniture_carries_its_buildings_labels(furnished):
    for b, pieces in furnished[:200]:
        mesh = meshes.furniture_mesh([(b, pieces)])
        labels = {tuple(label) for label in mesh.label}
        assert labels <= {meshes.label_color(b.id, b.roof_class)}
    arrays = meshes.furniture_mesh(furnished).arrays()
    assert arrays["material"].max() == meshes.FAN_LID and np.isfinite(arrays["vertices"]).all()
    ids, classes = meshes.decode_labels(arrays["label"][:, :3])
    roof_class = {b.id: b.roof_class for b, _ in furnished}
    assert all(roof_class[i] == c for i, c in zip(ids.tolist(), classes.tolist()))

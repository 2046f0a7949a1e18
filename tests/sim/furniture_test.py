"""Roof furniture: the knob, its streams, where the pieces stand, their sizes and their labels."""

import hashlib
import json
import math
from collections import Counter

import numpy as np
import pytest

from meta_sim.core.errors import MetaSimError
from meta_sim.sim import furniture, meshes, polygons
from meta_sim.sim import layout as layout_module
from meta_sim.sim.design import DesignSpace
from meta_sim.sim.furniture import roof_furniture
from meta_sim.sim.layout import STYLES, CityLayout, LayoutParams, generate_layout, stage_generators

TOL = 1e-6
_r = polygons.rounded
MIX = {"suburban": 1.0, "dense": 1.0, "downtown": 1.0, "industrial": 1.0}  # every kind, turned buildings, L and T


@pytest.fixture(scope="module")
def city():
    return generate_layout(4, 600.0, 600.0, LayoutParams(style=MIX, roof_furniture=1.0))


@pytest.fixture(scope="module")
def furnished(city):
    return [(b, roof_furniture(b, city.seed, 1.0, city.style_of(b))) for b in city.buildings]


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
    assert all(roof_furniture(b, city.seed, 1.0, city.style_of(b)) == pieces for b, pieces in furnished)
    assert not any(roof_furniture(b, city.seed, 0.0, city.style_of(b)) for b in city.buildings)
    other = [roof_furniture(b, city.seed + 1, 1.0, city.style_of(b)) for b, _ in furnished]
    assert sum(o != pieces for o, (_, pieces) in zip(other, furnished)) > 0.5 * len(furnished)
    fewer = sum(len(roof_furniture(b, city.seed, 0.3, city.style_of(b))) for b in city.buildings)
    assert 0 < fewer < 0.7 * sum(len(pieces) for _, pieces in furnished)


def test_every_kind_of_piece_is_there(furnished):
    kinds = {(b.roof == "flat", f.kind) for b, pieces in furnished for f in pieces}
    assert kinds == {(True, k) for k in ("parapet", "housing", "solar", "hvac", "skylight", "hatch", "tank",
                                         "tank-stand")} | {(False, k) for k in ("chimney", "roof-window", "solar")}
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
        # In the building's frame every piece but a tank's stand (under its tank) stands in an axis-aligned
        # rectangle of its own.
        boxes = [polygons.bbox(f.outline) for f in pieces if f.kind not in ("parapet", "tank-stand")]
        for i, a in enumerate(boxes):
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
    assert sum(f.kind == "tank" for _, pieces in furnished[:200] for f in pieces) > 20
    for b, pieces in furnished[:200]:
        mesh = meshes.furniture_mesh([(b, pieces)])
        labels = {tuple(label) for label in mesh.label}
        assert labels <= {meshes.label_color(b.id, b.roof_class)}
    arrays = meshes.furniture_mesh(furnished).arrays()
    assert arrays["material"].max() == meshes.FAN_LID and np.isfinite(arrays["vertices"]).all()
    tank_slots = {furniture.SURFACES.index(name) for name in furniture.TANK_COLOURS}
    assert tank_slots <= set(arrays["material"].tolist()) and max(tank_slots) < meshes.FAN_LID
    ids, classes = meshes.decode_labels(arrays["label"][:, :3])
    roof_class = {b.id: b.roof_class for b, _ in furnished}
    assert all(roof_class[i] == c for i, c in zip(ids.tolist(), classes.tolist()))


# --- water tanks --------------------------------------------------------------------------------------

def test_water_tanks_are_cylinders_standing_on_flat_roofs_or_on_stands(furnished):
    tanks = stands = 0
    for b, pieces in furnished:
        tank_boxes = [(polygons.bbox(f.outline), f) for f in pieces if f.kind == "tank"]
        if b.roof != "flat":
            assert not tank_boxes and not any(f.kind == "tank-stand" for f in pieces), b.id
            continue
        for (x0, y0, x1, y1), f in tank_boxes:
            tanks += 1
            d = x1 - x0
            assert furniture.TANK_DIAMETER_M[0] - TOL <= d <= furniture.TANK_DIAMETER_M[1] + TOL
            assert abs((y1 - y0) - d) < TOL and len(f.outline) == furniture.TANK_SIDES
            centre = ((x0 + x1) / 2, (y0 + y1) / 2)
            assert all(abs(math.dist(p, centre) - d / 2) < TOL for p in f.outline)
            assert polygons.area(f.outline) > 0.95 * math.pi * d * d / 4  # counter-clockwise, round
            assert f.surface in furniture.TANK_COLOURS and len(set(f.top)) == len(set(f.bottom)) == 1
            # As tall as a tank, from a few centimetres inside the roof or inside its stand's deck.
            tall = f.top[0] - f.bottom[0]
            assert furniture.TANK_HEIGHT_M[0] <= tall <= furniture.TANK_HEIGHT_M[1] + 0.05 + TOL
            lift = f.bottom[0] - b.height_m
            assert lift == pytest.approx(-0.05) or (
                furniture.TANK_STAND_M[0] - 0.05 < lift < furniture.TANK_STAND_M[1])
        for f in pieces:
            if f.kind != "tank-stand":
                continue
            stands += 1
            # A deck or a leg: under one tank, inside the square that holds it and its deck's rim.
            sx0, sy0, sx1, sy1 = polygons.bbox(f.outline)
            rim = furniture.TANK_DECK_RIM_M + TOL
            under = [t for (x0, y0, x1, y1), t in tank_boxes
                     if x0 - rim <= sx0 and sx1 <= x1 + rim and y0 - rim <= sy0 and sy1 <= y1 + rim]
            assert len(under) == 1 and max(f.top) <= under[0].bottom[0] + furniture.TANK_DECK_M, b.id
            assert f.surface == "dark" and min(f.bottom) >= b.height_m - 0.05 - TOL
    assert tanks > 300 and 0.1 * tanks * 5 < stands < 0.5 * tanks * 5  # a deck and four legs per stand


@pytest.fixture(scope="module")
def flat_city():
    """Every style, flat roofs only: how often each style's roofs carry tanks."""
    mix = {"suburban": 0.35, "dense": 0.05, "downtown": 0.3, "industrial": 0.3}
    city = generate_layout(6, 1000.0, 1000.0, LayoutParams(style=mix, sloped_share=0.0, roof_furniture=1.0))
    return city, [(b, roof_furniture(b, city.seed, 1.0, city.style_of(b))) for b in city.buildings]


def _tanks(pieces):
    return sum(f.kind == "tank" for f in pieces)


def test_how_often_a_roof_has_tanks_follows_its_style(flat_city):
    city, furnished = flat_city
    # The same roofs as if they stood in each style.
    share = {style: np.mean([_tanks(roof_furniture(b, city.seed, 1.0, style)) > 0 for b, _ in furnished])
             for style in STYLES}
    assert len(furnished) > 500
    assert share["dense"] > 0.6  # most flat roofs of a dense town
    assert 0.08 < share["suburban"] < 0.35  # some suburban ones
    assert max(share["downtown"], share["industrial"]) < 0.1  # few downtown or industrial ones
    # In the city, each roof as its own style has it.
    own = {style: np.mean([_tanks(pieces) > 0 for b, pieces in furnished if city.style_of(b) == style])
           for style in STYLES}
    assert own["dense"] > 0.6 and own["dense"] > own["suburban"] > max(own["downtown"], own["industrial"])
    per_roof, colours = Counter(), Counter()
    for b, _ in furnished:
        pieces = roof_furniture(b, city.seed, 1.0, "dense")
        per_roof[_tanks(pieces)] += 1
        colours.update(f.surface for f in pieces if f.kind == "tank")
    assert set(per_roof) == {0, 1, 2, 3} and per_roof[1] > per_roof[2] > per_roof[3]
    assert set(colours) == set(furniture.TANK_COLOURS) and colours.most_common(1)[0][0] == "tank-black"
    # Half the density, about half the roofs with tanks.
    half = np.mean([_tanks(roof_furniture(b, city.seed, 0.5, "dense")) > 0 for b, _ in furnished])
    assert 0.35 < half / share["dense"] < 0.65


def test_same_seed_same_tanks_and_another_seed_others(flat_city):
    city, furnished = flat_city
    dense = [(b, pieces) for b, pieces in furnished if city.style_of(b) == "dense"][:300]
    again = [roof_furniture(b, city.seed, 1.0, "dense") for b, _ in dense]
    assert again == [pieces for _, pieces in dense]
    tanks = [[f for f in pieces if f.kind == "tank"] for _, pieces in dense]
    assert sum(map(bool, tanks)) > 100
    other = [[f for f in roof_furniture(b, city.seed + 1, 1.0, "dense") if f.kind == "tank"] for b, _ in dense]
    assert sum(a != o for a, o in zip(tanks, other)) > 0.5 * len(dense)


def _digest(furnished):
    """sha256 of (building id, pieces) pairs, coordinates to the micrometre."""
    def r(v):
        return round(float(v), 6)
    data = [[bid, [[f.kind, f.surface, [[r(x), r(y)] for x, y in f.outline], [r(z) for z in f.bottom],
                    [r(z) for z in f.top], [[r(x), r(y)] for x, y in f.inner]] for f in pieces]]
            for bid, pieces in furnished]
    return hashlib.sha256(json.dumps(data).encode()).hexdigest()


# The furniture of every building of the `city` fixture at two densities, taken before water tanks came.
BEFORE_TANKS = {1.0: "3c8e8f5af4b8f42d7095eeb00bd71e0b774d8de1802aad0b9010fbf9014d62d1",
                0.4: "7a72904e677b94ae343cb739d5eea345a77ead13dee83812148878599da435ce"}


@pytest.mark.parametrize("density", sorted(BEFORE_TANKS))
def test_tanks_leave_every_other_piece_where_it_stood(city, density):
    furnished = [(b, roof_furniture(b, city.seed, density, city.style_of(b))) for b in city.buildings]
    assert sum(f.kind == "tank" for _, pieces in furnished for f in pieces) > 100
    for _, pieces in furnished:  # the tanks and their stands come after every other piece
        kinds = [f.kind.startswith("tank") for f in pieces]
        assert kinds == sorted(kinds)
    bare = [(b.id, [f for f in pieces if not f.kind.startswith("tank")]) for b, pieces in furnished]
    assert _digest(bare) == BEFORE_TANKS[density]


def test_a_buildings_style_is_that_of_the_region_it_stands_in(city):
    regions, _ = layout_module._style_regions(stage_generators(city.seed, 6)[5], city.width_m, city.height_m,
                                              city.params.style)
    seen = Counter()
    for b in city.buildings:
        x0, y0, x1, y1 = b.bbox
        centre = ((x0 + x1) / 2, (y0 + y1) / 2)
        (region,) = [r for r in regions if polygons.inside((centre,), r.cell, 0.0)]
        assert city.style_of(b) == region.style, b.id
        seen[region.style] += 1
    assert set(seen) == set(STYLES)
    plain = generate_layout(4, 300.0, 300.0)
    assert {plain.style_of(b) for b in plain.buildings} == {"suburban"}


def test_a_roof_takes_a_piece_where_clipping_the_footprint_keeps_all_of_it():
    # Inside a rectangular footprint _Roof answers without clipping: it must answer as the clipping does,
    # on rectangles and L shapes, far from the origin, for pieces inside, on the edge and across it.
    rng = np.random.default_rng(0)
    l_shape = ((0.0, 0.0), (20.0, 0.0), (20.0, 8.0), (9.0, 8.0), (9.0, 15.0), (0.0, 15.0))
    for k in range(4000):
        ox, oy = rng.uniform(0.0, 5000.0, 2)
        if k % 2:
            footprint = tuple((_r(x + ox), _r(y + oy)) for x, y in l_shape)
        else:
            footprint = polygons.rect_polygon(ox, oy, ox + rng.uniform(6.0, 120.0), oy + rng.uniform(6.0, 120.0))
        roof = furniture._Roof(footprint, rng.uniform(0.0, 0.8))
        x0, y0, x1, y1 = roof.bbox
        w, h = rng.uniform(0.5, 4.0, 2)
        x = rng.choice([x0, x0 + roof.margin, rng.uniform(x0 - 1.0, x1 - w + 1.0), x1 - w - roof.margin])
        y = rng.choice([y0, y0 + roof.margin, rng.uniform(y0 - 1.0, y1 - h + 1.0), y1 - h - roof.margin])
        m = roof.margin
        grown = ((x - m, y - m), (x + w + m, y - m), (x + w + m, y + h + m), (x - m, y + h + m))
        clipped = polygons.overlap_area(footprint, grown) >= polygons.area(grown) - 1e-6
        assert roof.fits((x, y, x + w, y + h)) == clipped, (footprint, x, y, w, h, m)

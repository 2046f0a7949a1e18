"""Street details, clutter and real-sized trees: placement rules, streams, JSON, validation."""

import hashlib
import json
import math
from dataclasses import replace

import numpy as np
import pytest
from toys import distance_to_polygon

from meta_sim.core.errors import MetaSimError
from meta_sim.sim import clutter, meshes, polygons, surfaces
from meta_sim.sim import layout as layout_module
from meta_sim.sim.clutter import CAR_COLOURS, GRID_RULES, KERB_M, SIDEWALK_MIN_M
from meta_sim.sim.layout import VERGE_M, CityLayout, LayoutParams, generate_layout, stage_generators

TOL = 1e-3
ALL_ON = LayoutParams(tree_size="real", street_details=True, car_density=0.7, pool_share=0.6, shrub_density=0.7)


@pytest.fixture(scope="module")
def city():
    return generate_layout(7, 700.0, 600.0, ALL_ON)


def _boxes(items):
    return np.array([item.bbox for item in items], dtype=float).reshape(-1, 4)


def _overlap(a, b, margin=0.0):
    """Pairs (i, j) of boxes of `a` and `b` closer than `margin` (positive area overlap for margin 0)."""
    return ((a[:, None, 0] < b[None, :, 2] + margin) & (b[None, :, 0] < a[:, None, 2] + margin)
            & (a[:, None, 1] < b[None, :, 3] + margin) & (b[None, :, 1] < a[:, None, 3] + margin))


def _inside_any(x, y, boxes):
    return bool(np.any((boxes[:, 0] - TOL <= x) & (x <= boxes[:, 2] + TOL)
                       & (boxes[:, 1] - TOL <= y) & (y <= boxes[:, 3] + TOL)))


def test_default_params_stay_out_of_the_json_and_new_ones_round_trip(city):
    assert set(LayoutParams().to_dict()) == {"building_density", "sloped_share", "tree_density", "road_width_m",
                                             "block_size_m"}
    assert set(generate_layout(1, 300, 300).to_dict()) == {"version", "seed", "width_m", "height_m", "params",
                                                           "roads", "lots", "buildings", "trees"}
    data = json.loads(json.dumps(city.to_dict()))
    assert data["params"]["tree_size"] == "real" and data["params"]["street_details"] is True
    assert {"pavings", "markings", "cars", "pools", "shrubs"} <= set(data)
    assert CityLayout.from_dict(data) == city
    assert LayoutParams.from_dict({"car_density": 0.5}).car_density == 0.5


def test_same_seed_same_clutter_and_the_first_stages_are_untouched(city):
    assert generate_layout(7, 700.0, 600.0, ALL_ON) == city
    base = generate_layout(7, 700.0, 600.0)
    assert city.roads == base.roads and city.lots == base.lots and city.buildings == base.buildings
    # Cars draw from their own stream: more cars move no paving, pool or shrub.
    busier = generate_layout(7, 700.0, 600.0, LayoutParams(**{**ALL_ON.to_dict(), "block_size_m": (60.0, 140.0),
                                                             "car_density": 1.0}))
    assert busier.pavings == city.pavings and busier.pools == city.pools and busier.shrubs == city.shrubs
    assert len(busier.cars) > len(city.cars)
    # Small trees with clutter: today's trees, untouched by the clutter stream.
    small = generate_layout(7, 700.0, 600.0, LayoutParams(street_details=True, car_density=0.5))
    assert small.trees == base.trees and small.cars


# sha256 of suburban layouts with clutter, taken before clutter came to styled cities: those must not move.
CLUTTER_HASHES = [
    ((7, 700.0, 600.0), ALL_ON, "6adca8e718319f36741fd110e7666de3aad45b44e3e61fcefe1f81cd883aae34"),
    ((1, 345.6, 345.6), ALL_ON, "b3b196a4e32cb50c971fe7d63ce267076a1a22a8e7733ee74ca02087e94c8365"),
    ((1, 345.6, 345.6), LayoutParams(street_details=True, car_density=0.4),
     "a51a11ad6888658c72fc5243d5179dacb56cf52e9f92b104cd4b5d924a3f1c71"),
]


@pytest.mark.parametrize("size,params,digest", CLUTTER_HASHES)
def test_suburban_clutter_is_byte_identical_to_before_styled_clutter(size, params, digest):
    text = json.dumps(generate_layout(*size, params).to_dict(), sort_keys=True)
    assert hashlib.sha256(text.encode()).hexdigest() == digest


def test_every_kind_of_item_is_there(city):
    kinds = {p.kind for p in city.pavings}
    assert kinds == {"kerb", "sidewalk", "driveway", "parking", "yard"}
    assert len(city.cars) > 50 and len(city.pools) > 3 and len(city.shrubs) > 50 and len(city.markings) > 50
    assert {c.colour for c in city.cars} == set(CAR_COLOURS)
    roads = _boxes(city.roads)

    def in_lane(c):  # on a road, away from both its kerbs: driving, not parked
        for x0, y0, x1, y1 in roads:
            if x0 < c.x < x1 and y0 < c.y < y1:
                return min(c.x - x0, x1 - c.x) > 2.5 if x1 - x0 < y1 - y0 else min(c.y - y0, y1 - c.y) > 2.5
        return False
    assert sum(map(in_lane, city.cars)) > 5


def test_real_trees_have_real_sizes_and_stay_off_roofs(city):
    trees = city.trees
    diameters = np.array([2 * t.radius_m for t in trees])
    heights = np.array([t.height_m for t in trees])
    assert len(trees) > 200
    assert diameters.min() >= 4.0 - TOL and diameters.max() <= 15.0 + TOL
    assert 5.0 <= np.median(diameters) <= 9.0 and np.mean((diameters >= 5) & (diameters <= 9)) > 0.5
    assert diameters.max() > 10.0  # a tail of big trees
    assert heights.min() >= 5.0 - TOL and heights.max() <= 20.0 + TOL
    assert np.corrcoef(diameters, heights)[0, 1] > 0.6
    roofs = _boxes(city.buildings)
    for t in trees:
        assert t.x - t.radius_m >= -TOL and t.y - t.radius_m >= -TOL
        assert t.x + t.radius_m <= city.width_m + TOL and t.y + t.radius_m <= city.height_m + TOL
        dx = np.maximum(np.maximum(roofs[:, 0] - t.x, t.x - roofs[:, 2]), 0.0)
        dy = np.maximum(np.maximum(roofs[:, 1] - t.y, t.y - roofs[:, 3]), 0.0)
        assert np.hypot(dx, dy).min() >= t.radius_m - TOL, t


def _clark_evans(trees, area):
    """Mean nearest-neighbour distance over its value for random points (below 1: clustered)."""
    xy = np.array([(t.x, t.y) for t in trees])
    d = np.hypot(xy[:, None, 0] - xy[None, :, 0], xy[:, None, 1] - xy[None, :, 1])
    np.fill_diagonal(d, np.inf)
    return d.min(axis=1).mean() / (0.5 / math.sqrt(len(xy) / area))


def test_real_trees_cluster_in_rows_and_groups(city):
    area = city.width_m * city.height_m
    assert _clark_evans(city.trees, area) < 0.85
    assert _clark_evans(city.trees, area) < _clark_evans(generate_layout(7, 700.0, 600.0).trees, area)
    # Rows: many street trees share a verge line with their neighbours.
    verge_lines = {}
    for t in city.trees:
        for key in (("x", round(t.x, 2)), ("y", round(t.y, 2))):
            verge_lines[key] = verge_lines.get(key, 0) + 1
    assert max(verge_lines.values()) >= 6


def test_cars_stand_on_roads_driveways_or_parking_and_never_on_buildings(city):
    cars = city.cars
    roofs, roads = _boxes(city.buildings), _boxes(city.roads)
    paved = _boxes([p for p in city.pavings if p.kind in ("driveway", "parking")])
    assert not _overlap(_boxes(cars), roofs).any(), "a car under or on a roof"
    for c in cars:
        assert _inside_any(c.x, c.y, roads) or _inside_any(c.x, c.y, paved), c
        assert all(_inside_any(x, y, np.vstack([roads, paved])) for x, y in c.corners), c
        assert 4.0 <= c.length_m <= 5.0 and 1.7 <= c.width_m <= 2.0
    xy = np.array([(c.x, c.y) for c in cars])
    d = np.hypot(xy[:, None, 0] - xy[None, :, 0], xy[:, None, 1] - xy[None, :, 1])
    np.fill_diagonal(d, np.inf)
    assert d.min() > 1.9, "two cars on one spot"


def test_pools_lie_in_lots_behind_houses_clear_of_buildings(city):
    roofs, lots = _boxes(city.buildings), _boxes(city.lots)
    assert not _overlap(_boxes(city.pools), roofs, 1.0).any()
    by_lot = {b.lot_index: b for b in city.buildings}
    for pool in city.pools:
        x0, y0, x1, y1 = pool.bbox
        inside = [i for i, lot in enumerate(lots) if lot[0] <= x0 + TOL and lot[1] <= y0 + TOL
                  and x1 <= lot[2] + TOL and y1 <= lot[3] + TOL]
        assert len(inside) == 1 and by_lot[inside[0]].kind == "residential"
        assert 6.0 <= max(x1 - x0, y1 - y0) and min(x1 - x0, y1 - y0) >= 3.0


def test_shrubs_are_low_and_off_roofs_and_streets(city):
    shrubs = _boxes(city.shrubs)
    assert not _overlap(shrubs, _boxes(city.buildings)).any()
    assert not _overlap(shrubs, _boxes(city.roads)).any()
    assert not _overlap(shrubs, _boxes(city.pools)).any()
    assert all(0.5 - TOL <= s.height_m <= 2.1 for s in city.shrubs)


def test_pavings_and_markings_lie_where_they_belong(city):
    roads, lots, roofs = _boxes(city.roads), _boxes(city.lots), _boxes(city.buildings)
    verge = [p for p in city.pavings if p.kind in ("kerb", "sidewalk")]
    assert not _overlap(_boxes(verge), roads).any() and not _overlap(_boxes(verge), lots).any()
    assert all(min(p.bbox[2] - p.bbox[0], p.bbox[3] - p.bbox[1]) <= VERGE_M for p in verge)
    drives = _boxes([p for p in city.pavings if p.kind == "driveway"])
    assert not _overlap(drives, roads).any()
    assert _overlap(drives, roads, 0.01).any(axis=1).all(), "a driveway that does not reach its street"
    parking = _boxes([p for p in city.pavings if p.kind == "parking"])
    assert not _overlap(parking, roofs).any()
    surfaces_ = np.vstack([roads, parking])
    for m in city.markings:
        x0, y0, x1, y1 = m.bbox
        assert _inside_any((x0 + x1) / 2, (y0 + y1) / 2, surfaces_), m


def test_meshes_of_the_clutter_are_background_and_modest(city):
    background = meshes.label_color(0, 0)
    for arrays in (meshes.crown_mesh(city.trees), meshes.shrub_mesh(city.shrubs), meshes.car_mesh(city.cars),
                   meshes.detail_mesh(city.pavings, city.pools, city.markings, 0.05)):
        data = arrays.arrays()
        assert np.all(data["label"] == np.asarray(background, np.float32)), arrays.name
        assert len(data["loop_start"]) and np.isfinite(data["vertices"]).all()
    crowns = meshes.crown_mesh(city.trees).arrays()
    assert len(crowns["loop_start"]) < 200 * len(city.trees)
    for t in city.trees[:50]:  # the lumpy outline stays inside the crown radius the layout checked
        mesh = meshes.crown_mesh([t]).arrays()["vertices"]
        assert np.hypot(mesh[:, 0] - t.x, mesh[:, 1] - t.y).max() <= t.radius_m + TOL
        assert mesh[:, 2].max() <= t.height_m + TOL
    assert meshes.crown_mesh(city.trees[:5]).arrays()["vertices"].tobytes() == \
        meshes.crown_mesh(city.trees[:5]).arrays()["vertices"].tobytes()


def test_baked_surfaces_are_deterministic_and_tile():
    for make in (surfaces.asphalt_image, surfaces.concrete_image, surfaces.water_image, surfaces.foliage_atlas):
        a = make(3)
        assert np.array_equal(a, make(3)) and a.dtype == np.float32 and 0 <= a.min() and a.max() <= 1
    water = surfaces.water_image(0).mean(axis=(0, 1))
    assert water[2] > 3 * water[0]
    asphalt = surfaces.asphalt_image(0)
    assert asphalt.std() > 0.01  # patches and cracks, not one flat grey
    # Tileable: the jump across the wrap is no bigger than between neighbouring pixels.
    assert np.abs(asphalt[0] - asphalt[-1]).mean() < 2 * np.abs(np.diff(asphalt, axis=0)).mean()


def test_dust_moves_a_roads_colour_towards_dust_and_keeps_its_texture():
    asphalt = surfaces.asphalt_image(0)
    assert np.array_equal(surfaces.dusty(asphalt, 0.0), asphalt)
    for dust in (0.5, 1.0):
        dusted = surfaces.dusty(asphalt, dust)
        mean = asphalt.reshape(-1, 3).mean(axis=0)
        want = (1 - dust) * mean + dust * np.array(surfaces.ROAD_DUST)
        assert np.allclose(dusted.reshape(-1, 3).mean(axis=0), want, rtol=1e-3)
        # the same cracks and patches: each pixel over the mean as before
        assert np.allclose(dusted / dusted.reshape(-1, 3).mean(axis=0), asphalt / mean, atol=1e-4)
    assert np.allclose(surfaces.dusty((0.09, 0.09, 0.095), 1.0), surfaces.ROAD_DUST)
    for bad in (-0.5, 2.0):
        with pytest.raises(MetaSimError, match="dust"):
            surfaces.dusty(asphalt, bad)


@pytest.mark.parametrize("kwargs,field", [
    ({"tree_size": "huge"}, "tree_size"),
    ({"tree_size": 3}, "tree_size"),
    ({"street_details": "yes"}, "street_details"),
    ({"street_details": 1}, "street_details"),
    ({"car_density": 1.5}, "car_density"),
    ({"pool_share": -0.1}, "pool_share"),
    ({"shrub_density": float("nan")}, "shrub_density"),
])
def test_bad_clutter_params_name_the_field(kwargs, field):
    with pytest.raises(MetaSimError, match=field):
        LayoutParams(**kwargs)


def test_damaged_clutter_in_a_layout_file_is_rejected(city):
    data = json.loads(json.dumps(city.to_dict()))
    data["cars"][0]["colour"] = "plaid"
    with pytest.raises(MetaSimError, match="colour"):
        CityLayout.from_dict(data)
    data = json.loads(json.dumps(city.to_dict()))
    data["pavings"][0]["kind"] = "lava"
    with pytest.raises(MetaSimError, match="kind"):
        CityLayout.from_dict(data)
    data = json.loads(json.dumps(city.to_dict()))
    data["pools"][0]["polygon"] = [[0, 0], [1, 1]]
    with pytest.raises(MetaSimError, match="rectangle"):
        CityLayout.from_dict(data)


def test_a_sixth_stage_stream_leaves_the_first_five_as_they_were():
    from meta_sim.sim.layout import stage_generators

    five = [g.random(4).tolist() for g in stage_generators(11, 5)]
    assert [g.random(4).tolist() for g in stage_generators(11, 6)][:5] == five


# --- clutter in styled cities ----------------------------------------------------------------------

KNOBS = {k: v for k, v in ALL_ON.to_dict().items() if k in ("tree_size", "street_details", "car_density",
                                                             "pool_share", "shrub_density")}
MIX = {"suburban": 0.3, "dense": 0.3, "downtown": 0.2, "industrial": 0.2}
STYLED = {"dense": (3, 345.6, 345.6, "dense"), "downtown": (2, 400.0, 300.0, "downtown"),
          "industrial": (4, 400.0, 300.0, "industrial"), "mixed": (5, 700.0, 600.0, MIX)}


@pytest.fixture(scope="module")
def styled():
    """name -> (city with everything on, the same city bare)"""
    return {name: (generate_layout(seed, w, h, LayoutParams(style=style, **KNOBS)),
                   generate_layout(seed, w, h, LayoutParams(style=style)))
            for name, (seed, w, h, style) in STYLED.items()}


def _near_pairs(items_a, items_b, margin=0.0):
    return zip(*np.nonzero(_overlap(_boxes(items_a), _boxes(items_b), margin)))


def _outline(item):
    return item.corners if hasattr(item, "corners") else item.polygon


@pytest.mark.parametrize("name", sorted(STYLED))
def test_styled_clutter_keeps_the_bare_city_and_is_deterministic(styled, name):
    city, bare = styled[name]
    assert city.roads == bare.roads and city.lots == bare.lots and city.buildings == bare.buildings
    seed, w, h, style = STYLED[name]
    assert generate_layout(seed, w, h, LayoutParams(style=style, **KNOBS)) == city
    assert CityLayout.from_dict(json.loads(json.dumps(city.to_dict()))) == city


@pytest.mark.parametrize("name", sorted(STYLED))
def test_styled_clutter_never_overlaps_a_building(styled, name):
    city, _ = styled[name]
    roofs = city.buildings
    flat = [p for p in city.pavings if p.kind != "yard"] + list(city.markings) + list(city.pools)
    for items in (flat, city.shrubs, city.cars):
        for i, j in _near_pairs(items, roofs):
            shared = polygons.overlap_area(_ccw(_outline(items[i])), roofs[j].roof_outline)
            assert shared < 1e-6, (items[i], roofs[j])
    for i, j in _near_pairs(city.trees, roofs):
        t = city.trees[i]
        assert distance_to_polygon(t.x, t.y, roofs[j].roof_outline) >= t.radius_m - TOL, (t, roofs[j])
    for t in city.trees:  # trunks off the roads, crowns in the city
        assert all(distance_to_polygon(t.x, t.y, city.roads[j].polygon) > 0.0
                   for j in np.flatnonzero(_overlap(_boxes([t]), _boxes(city.roads))[0])), t
        assert t.radius_m - TOL <= t.x <= city.width_m - t.radius_m + TOL
        assert t.radius_m - TOL <= t.y <= city.height_m - t.radius_m + TOL
    cars = city.cars
    for i, j in _near_pairs(cars, cars):
        if i < j:
            assert polygons.overlap_area(cars[i].corners, cars[j].corners) < 1e-3, (cars[i], cars[j])


def _ccw(polygon):
    return polygon if polygons.area(polygon) > 0 else tuple(reversed(polygon))


def _share_near_roads(city, items, reach):
    roads = city.roads
    near = _overlap(_boxes(items), _boxes(roads), reach)
    return np.mean([any(distance_to_polygon(it.x, it.y, roads[j].polygon) < reach for j in np.flatnonzero(row))
                    for it, row in zip(items, near)])


def test_a_dense_town_gets_real_trees_in_its_gaps_few_cars_and_bushes_but_no_streets(styled):
    city, bare = styled["dense"]
    diameters = np.array([2 * t.radius_m for t in city.trees])
    assert len(city.trees) > 100 and diameters.min() >= 4.0 - TOL and diameters.max() <= 15.0 + TOL
    assert np.median(diameters) < 9.0 and diameters.max() > 8.0
    assert 10 < len(city.cars) < 0.1 * len(city.buildings) and {c.kind for c in city.cars} == {"car"}
    assert _share_near_roads(city, city.cars, 2.5) == 1.0  # parked by the lanes
    assert len(city.shrubs) > 30 and not city.pools
    assert not city.pavings and not city.markings  # tracks and lanes without kerbs or paint


def test_downtown_gets_sidewalks_street_trees_busy_streets_and_parking_lots(styled):
    city, _ = styled["downtown"]
    kinds = {p.kind for p in city.pavings}
    assert {"kerb", "sidewalk", "parking", "driveway"} <= kinds and "yard" not in kinds  # the lots are paved
    area = city.width_m * city.height_m / 1e4
    suburb = generate_layout(2, 400.0, 300.0, ALL_ON)
    assert len(city.cars) > 1.5 * len(suburb.cars) and len(city.markings) > 2 * len(suburb.markings)
    assert len(city.cars) / area > 30
    assert not city.pools and not city.shrubs
    assert _share_near_roads(city, city.trees, VERGE_M) > 0.9  # in rows along the streets
    sidewalks = [p for p in city.pavings if p.kind == "sidewalk"]
    assert np.median([polygons.area(p.polygon) / max(math.dist(*e) for e in zip(p.polygon, p.polygon[1:]))
                      for p in sidewalks]) > 4.0  # kerb to lot, no planting strip
    assert any(len(p.polygon) != 4 for p in city.pavings)  # cut at the border between its regions


def test_industrial_gets_trucks_and_few_trees(styled):
    city, _ = styled["industrial"]
    trucks = [c for c in city.cars if c.kind == "truck"]
    assert len(trucks) > 20 and all(7.0 - TOL <= t.length_m <= 16.5 + TOL for t in trucks)
    assert not city.pools and not city.shrubs and city.markings
    downtown, _ = styled["downtown"]
    assert len(city.trees) < 0.5 * len(downtown.trees)


def test_a_mixed_city_furnishes_each_region_by_its_style(styled):
    city, bare = styled["mixed"]
    assert city.pools and any(c.kind == "truck" for c in city.cars)
    assert {"kerb", "sidewalk", "parking", "driveway", "yard"} <= {p.kind for p in city.pavings}
    # Pools in suburban back yards only: on a lot of the street grid, next to a house.
    houses = [b for b in city.buildings if b.kind == "residential" and city.lots[b.lot_index].block_index >= 0]
    for pool in city.pools:
        x0, y0, x1, y1 = pool.bbox
        assert any(polygons.inside(pool.polygon, city.lots[b.lot_index].polygon, TOL) for b in houses), pool
    # The through roads between regions have centre lines: markings that run along no axis.
    turned = [m for m in city.markings if len({round(x, 2) for x, _ in m.polygon}) > 2]
    assert len(turned) > 50


def test_each_knob_moves_only_its_own_items_in_a_styled_city(styled):
    city, bare = styled["mixed"]
    seed, w, h, style = STYLED["mixed"]

    def with_(**changes):
        return generate_layout(seed, w, h, LayoutParams(style=style, **{**KNOBS, **changes}))
    busier = with_(car_density=1.0)
    assert len(busier.cars) > len(city.cars)
    for name in ("pavings", "markings", "pools", "shrubs", "trees"):
        assert getattr(busier, name) == getattr(city, name), name
    assert not with_(car_density=0.0).cars and not with_(shrub_density=0.0).shrubs
    assert not with_(pool_share=0.0).pools
    plain = with_(street_details=False)
    assert not plain.pavings and not plain.markings and plain.cars
    assert with_(tree_size="small").trees == bare.trees  # small trees with clutter: the bare city's
    real_only = generate_layout(seed, w, h, LayoutParams(style=style, tree_size="real"))
    assert real_only.trees and not any(getattr(real_only, name) for name in ("pavings", "markings", "cars",
                                                                            "pools", "shrubs"))


def test_cut_pavings_and_trucks_round_trip_and_damage_is_rejected(styled):
    city, _ = styled["mixed"]
    data = json.loads(json.dumps(city.to_dict()))
    assert any(c.get("kind") == "truck" for c in data["cars"]) and any("kind" not in c for c in data["cars"])
    broken = json.loads(json.dumps(data))
    broken["cars"][0]["kind"] = "tank"
    with pytest.raises(MetaSimError, match="vehicle kind"):
        CityLayout.from_dict(broken)
    broken = json.loads(json.dumps(data))
    broken["pavings"][0]["polygon"] = [[i, i * i] for i in range(9)]
    with pytest.raises(MetaSimError, match="three to eight"):
        CityLayout.from_dict(broken)


def test_meshes_of_turned_pavings_and_trucks(styled):
    city, _ = styled["mixed"]
    turned = [p for p in city.pavings if len({round(x, 2) for x, _ in p.polygon}) > 2][:20]
    arrays = meshes.detail_mesh(turned, (), (), 0.05).arrays()
    assert np.allclose(arrays["vertices"][:, :2], [pt for p in turned for pt in p.polygon], atol=1e-3)
    trucks = [c for c in city.cars if c.kind == "truck"][:5]
    data = meshes.car_mesh(trucks).arrays()
    assert np.all(data["label"] == np.asarray(meshes.label_color(0, 0), np.float32))
    assert abs(data["vertices"][:, 2].max() - meshes.TRUCK_HEIGHT_M) < 1e-3
    for t in trucks:  # each truck's mesh lies in its outline
        mesh = meshes.car_mesh([t]).arrays()["vertices"][:, :2].astype(float)
        assert polygons.inside([tuple(p) for p in mesh], t.corners, 1e-3)


def test_greenness_tints_the_foliage_atlas_as_it_turns_the_small_trees():
    from meta_sim.sim.appearance import TREE_COLOUR, foliage_tint, vegetation_colour

    assert foliage_tint(None) is None  # the atlas stays as it is
    for g in (0.0, 0.4, 1.0):
        assert np.allclose(np.multiply(foliage_tint(g), TREE_COLOUR), vegetation_colour("tree", g, TREE_COLOUR))
    atlas = surfaces.foliage_atlas()
    dry, lush = (atlas * np.asarray(foliage_tint(g), np.float32) for g in (0.0, 1.0))
    assert dry[..., 0].mean() / dry[..., 1].mean() > 1.5 * lush[..., 0].mean() / lush[..., 1].mean()


# --- kerbs and sidewalks along the through roads between regions ------------------------------------

# Styled cities with everything on, taken before the through roads had kerbs and sidewalks: sha256 of the
# sorted JSON and the number of pavings then. Those came after every other paving, so the city with its
# first pavings only must be the one from before.
BEFORE_THROUGH_SIDEWALKS = [
    (*STYLED["mixed"], "f06cf421cd1d4836bd0d6b06070946601a430b977bcce1c094f108f2aab50e75", 505),
    (8, 460.8, 460.8, {"suburban": 0.5, "dense": 0.5},
     "e41d68eddd62070df69196730868068607c4f62f81d743cb9f853a112b521a7a", 110),
]


def _centroid(polygon):
    return (sum(x for x, _ in polygon) / len(polygon), sum(y for _, y in polygon) / len(polygon))


@pytest.mark.parametrize("seed,w,h,style,digest,before", BEFORE_THROUGH_SIDEWALKS)
def test_through_roads_get_kerbs_and_sidewalks_by_each_sides_style_and_nothing_else_moves(seed, w, h, style, digest,
                                                                                         before):
    city = generate_layout(seed, w, h, LayoutParams(style=style, **KNOBS))
    old = replace(city, pavings=city.pavings[:before])
    assert hashlib.sha256(json.dumps(old.to_dict(), sort_keys=True).encode()).hexdigest() == digest
    added = city.pavings[before:]
    assert {p.kind for p in added} == {"kerb", "sidewalk"}
    regions, through = layout_module._style_regions(stage_generators(seed, 6)[5], w, h, city.params.style)
    paved = [road.polygon for road in through if road.surface == "asphalt"]
    ground = [road.polygon for road in city.roads] + [lot.polygon for lot in city.lots] + [
        p.polygon for p in city.pavings[:before]]
    near = _overlap(_boxes(added), np.array([polygons.bbox(g) for g in ground]))
    widths = {}
    for p, row in zip(added, near):
        outline = _ccw(p.polygon)
        # Along a through road: a kerb at its edge, a sidewalk behind the kerb.
        gap, road = min((polygons.separation(outline, road), road) for road in paved)
        assert abs(gap - (0.0 if p.kind == "kerb" else KERB_M)) < 1e-3, p
        # On nobody's ground: off every road, lot and paving there was (but for the rounding to 0.1 mm).
        length = max(math.dist(a, b) for a, b in zip(outline, outline[1:] + outline[:1]))
        assert all(polygons.overlap_area(outline, _ccw(ground[j])) < 2e-4 * length for j in np.flatnonzero(row)), p
        (region,) = [r for r in regions if polygons.inside((_centroid(outline),), r.cell, 0.0)]
        assert region.style != "dense", p  # a dense town has no sidewalks
        if p.kind == "sidewalk":
            width = max(distance_to_polygon(x, y, road) for x, y in outline) - KERB_M
            assert SIDEWALK_MIN_M - TOL <= width <= GRID_RULES[region.style].sidewalk_m[1] + TOL
            widths.setdefault(region.style, []).append(width)
    # Every side of a long road that borders a region with sidewalks has a kerb.
    for road in paved:
        frame = clutter._road_frame(road)
        lo, hi, c_lo, c_hi = frame[3:]
        if hi - lo < 40.0:
            continue
        for sign, edge in ((-1, c_lo), (1, c_hi)):
            probe = clutter._on_road(frame, (lo + hi) / 2, edge + sign * 1.0)
            cells = [r for r in regions if polygons.inside((probe,), r.cell, 0.0)]
            if not cells or cells[0].style == "dense":
                continue
            assert any(p.kind == "kerb" and polygons.separation(_ccw(p.polygon), road) < 1e-3
                       and polygons.inside((_centroid(p.polygon),), cells[0].cell, 0.0) for p in added), road
    if "downtown" in widths:  # full width downtown, narrower in the suburbs
        assert np.median(widths["downtown"]) > 3.5 > 2.0 >= max(widths["suburban"]) - TOL


def test_through_road_sidewalks_come_with_street_details_only(styled):
    seed, w, h, style = STYLED["mixed"]
    _, bare = styled["mixed"]
    assert not bare.pavings
    assert not generate_layout(seed, w, h, LayoutParams(style=style, car_density=0.5, tree_size="real")).pavings
    details = generate_layout(seed, w, h, LayoutParams(style=style, street_details=True))
    assert details.pavings == styled["mixed"][0].pavings  # the other knobs move none of them

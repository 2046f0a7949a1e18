"""City styles: the default stays byte-identical; dense, downtown and industrial regions."""

import hashlib
import json
from dataclasses import replace

import numpy as np
import pytest
from toys import distance_to_polygon

from meta_sim.core.errors import MetaSimError
from meta_sim.sim import layout as layout_module
from meta_sim.sim import meshes, polygons
from meta_sim.sim.layout import Building, CityLayout, LayoutParams, Lot, Road, generate_layout, rect_polygon

# sha256 of the sorted JSON of default layouts, taken before city styles existed: published
# benchmarks and caches depend on the default city never changing.
DEFAULT_HASHES = {
    (0, 400.0, 300.0): "8cf954ea4158d2ef6908ab8f992ed1aec1a6d78b44bf88d1144d7a3a0f59587f",
    (0, 345.6, 345.6): "b8853d4e55deb5da8a4b8ae8f12a544f964a5a15a048d80f58eaa72ca3f8ce70",
    (1, 400.0, 300.0): "f781d59ac2955262b0374c60f0866c15a9ecad57c02def1d48c4648572d19f48",
    (1, 345.6, 345.6): "082a3591a80fbf9bc557f1d8561e01ec71d4328bceb95a20264545aba88f6968",
    (7, 400.0, 300.0): "76b218b4ee4016ff643c5863d295ad9062caaad6e96a3fbe2bac5a0c4266620b",
    (7, 345.6, 345.6): "7f6c2d470c495c33fe6cd749362ce1226df6501eb341d41171f6da7c54bcad7f",
}


def _digest(layout):
    return hashlib.sha256(json.dumps(layout.to_dict(), sort_keys=True).encode()).hexdigest()


@pytest.mark.parametrize("seed,width,height", sorted(DEFAULT_HASHES))
def test_default_layouts_are_byte_identical_to_before_styles(seed, width, height):
    assert _digest(generate_layout(seed, width, height)) == DEFAULT_HASHES[(seed, width, height)]


# sha256 of styled layouts without street details or clutter, taken before those came to styled cities:
# asking for clutter must not move what a styled city without it has.
MIX = {"suburban": 0.3, "dense": 0.3, "downtown": 0.2, "industrial": 0.2}
STYLED_HASHES = [
    (3, 345.6, 345.6, "dense", "6ca7b713f5f4526c1c19fab8e86f7cd3958b7f45b79718a77ca7b955cf9432d2"),
    (2, 400.0, 300.0, "downtown", "663ad337b63075981eafda6ff8a030e45eb64eb605e1bbf6d6683c1c1a6598f8"),
    (4, 400.0, 300.0, "industrial", "b10835904489234952c33faa5b68d1b33ca5993f98192914fa118c5ee842b609"),
    (5, 700.0, 600.0, MIX, "1053960323fb98912d64048faad0c578cf9f95e3c9784938bbda90d23b6c6f5f"),
]


@pytest.mark.parametrize("seed,width,height,style,digest", STYLED_HASHES)
def test_styled_layouts_without_clutter_are_byte_identical_to_before_styled_clutter(seed, width, height, style,
                                                                                      digest):
    assert _digest(generate_layout(seed, width, height, LayoutParams(style=style))) == digest


# --- the style mix as a parameter ------------------------------------------------------------------

def test_style_accepts_a_name_a_mapping_and_pairs_and_normalises_the_shares():
    assert LayoutParams().style == (("suburban", 1.0),)
    assert LayoutParams(style="dense") == LayoutParams(style={"dense": 1.0}) == LayoutParams(style={"dense": 3})
    mixed = LayoutParams(style={"suburban": 1, "dense": 3, "industrial": 0})
    assert mixed.style == (("suburban", 0.25), ("dense", 0.75))  # in STYLES order, zero shares dropped
    assert LayoutParams(style=[["dense", 3], ["suburban", 1]]) == mixed  # JSON has no tuples
    hash(mixed)  # the render loop groups jobs by their params


def test_style_reaches_the_layout_params_from_a_design_space_json(tmp_path):
    from meta_sim.render.loop import layout_params
    from meta_sim.sim.design import DesignSpace

    data = DesignSpace.load().to_dict()
    data["layout"] = {"style": {"dense": 0.7, "suburban": 0.3}}
    path = tmp_path / "space.json"
    path.write_text(json.dumps(data))
    space = DesignSpace.load(str(path))
    design = {p.name: p.choices[0] for p in space.parameters}
    assert layout_params(space, design).style == (("suburban", 0.3), ("dense", 0.7))


@pytest.mark.parametrize("style,message", [
    ("favela", "'favela' is not a style"),
    ({"dense": 1, "castle": 1}, "'castle' is not a style"),
    ({"dense": -0.5, "suburban": 1}, "style\\['dense'\\]"),
    ({"dense": float("nan")}, "style\\['dense'\\]"),
    ({"dense": float("inf")}, "style\\['dense'\\]"),
    ({"dense": "lots"}, "style\\['dense'\\]"),
    ({"dense": True}, "style\\['dense'\\]"),
    ({"dense": 0.0, "suburban": 0}, "at least one share positive"),
    ({}, "at least one share positive"),
    (3, "style name or a mapping"),
    ([["dense"]], "style name or a mapping"),
    (None, "style name or a mapping"),
])
def test_bad_styles_raise_a_clear_error(style, message):
    with pytest.raises(MetaSimError, match=message):
        LayoutParams(style=style)


def test_new_fields_are_left_out_of_json_at_their_defaults_and_read_back():
    default = generate_layout(2, 300.0, 300.0).to_dict()
    assert "style" not in default["params"]
    assert not any("rotation_deg" in b for b in default["buildings"])
    assert not any("surface" in r for r in default["roads"]) and not any("surface" in lot for lot in default["lots"])
    styled = generate_layout(2, 300.0, 300.0, LayoutParams(style={"dense": 0.5, "industrial": 0.5}))
    data = json.loads(json.dumps(styled.to_dict()))
    assert data["params"]["style"] == {"dense": 0.5, "industrial": 0.5}
    assert any("rotation_deg" in b for b in data["buildings"])
    assert {r.get("surface", "asphalt") for r in data["roads"]} == {"asphalt", "dirt"}
    assert {lot.get("surface", "ground") for lot in data["lots"]} == {"ground", "paved"}
    assert CityLayout.from_dict(data) == styled
    assert LayoutParams.from_dict(data["params"]) == styled.params
    broken = json.loads(json.dumps(data))
    broken["roads"][0]["surface"] = "lava"
    with pytest.raises(MetaSimError, match="surface"):
        CityLayout.from_dict(broken)


# --- turned buildings ------------------------------------------------------------------------------

def _building(**kw):
    base = dict(id=1, kind="residential", lot_index=0, footprint=rect_polygon(10, 20, 20, 26), shape="rect",
                height_m=3.0, roof="flat", roof_pitch_deg=0.0, overhang_m=0.0, ridge_axis="x", parapet_m=0.0)
    return Building(**{**base, **kw})


def test_a_turned_building_turns_its_outlines_and_bbox_about_its_centre():
    plain, turned = _building(), _building(rotation_deg=90.0)
    assert plain.roof_outline == plain.footprint and plain.bbox == (10, 20, 20, 26)
    assert np.allclose(turned.bbox, (12, 18, 18, 28))  # 10 x 6 about (15, 23) turned by a quarter
    assert polygons.area(turned.roof_outline) == pytest.approx(60.0)
    sloped = _building(roof="gable", roof_pitch_deg=20.0, overhang_m=0.5, rotation_deg=30.0)
    assert polygons.area(sloped.roof_outline) == pytest.approx(11 * 7)
    assert sloped.ridge_height_m == _building(roof="gable", roof_pitch_deg=20.0, overhang_m=0.5).ridge_height_m
    assert Building.from_dict(json.loads(json.dumps(sloped.to_dict()))) == sloped


@pytest.mark.parametrize("roof", ["flat", "gable", "hip"])
def test_building_mesh_of_a_turned_building_lies_on_its_outline(roof):
    b = _building(roof=roof, roof_pitch_deg=20.0 if roof != "flat" else 0.0,
                  overhang_m=0.4 if roof != "flat" else 0.0, rotation_deg=37.0)
    arrays = meshes.building_mesh([b]).arrays()
    xy = arrays["vertices"][:, :2].astype(float)
    assert polygons.inside([tuple(p) for p in xy], b.roof_outline, 1e-4)
    outline = np.array(b.roof_outline)
    for corner in outline:  # every corner of the roof outline is a vertex of the mesh
        assert np.min(np.hypot(*(xy - corner).T)) < 1e-4
    same_unturned = meshes.building_mesh([_building(roof=roof, roof_pitch_deg=b.roof_pitch_deg,
                                                     overhang_m=b.overhang_m)]).arrays()
    assert np.array_equal(arrays["uv"], same_unturned["uv"]) and np.array_equal(arrays["material"],
                                                                                same_unturned["material"])
    assert np.allclose(arrays["vertices"][:, 2], same_unturned["vertices"][:, 2])


def test_road_mesh_puts_dirt_roads_in_their_own_slot():
    roads = [Road(rect_polygon(0, 0, 10, 4)), Road(rect_polygon(0, 5, 10, 8), "dirt")]
    assert meshes.road_mesh(roads).arrays()["material"].tolist() == [meshes.ROAD_ASPHALT, meshes.ROAD_DIRT]


# --- styled cities: geometry ------------------------------------------------------------------------

OVERLAP_M2 = 0.01  # outlines are rounded to 0.1 mm: touching walls may overlap by that much


def _pairs(items_a, items_b, margin=0.0):
    """Index pairs whose bboxes come within ``margin`` of each other (i < j when both are the same list)."""
    a, b = (np.array([it.bbox for it in items], dtype=float).reshape(-1, 4) for items in (items_a, items_b))
    near = ((a[:, None, 0] < b[None, :, 2] + margin) & (b[None, :, 0] < a[:, None, 2] + margin)
            & (a[:, None, 1] < b[None, :, 3] + margin) & (b[None, :, 1] < a[:, None, 3] + margin))
    if items_a is items_b:
        near &= np.triu(np.ones(near.shape, dtype=bool), 1)
    return list(zip(*np.nonzero(near)))


def check_styled(layout):
    """What every city must keep, whatever its styles: nothing overlaps, all inside the city."""
    city = rect_polygon(0.0, 0.0, layout.width_m, layout.height_m)
    for item in (*layout.roads, *layout.lots):
        assert polygons.inside(item.polygon, city, 1e-3) and polygons.area(item.polygon) > 0, item
    for b in layout.buildings:
        assert polygons.inside(b.roof_outline, city, 1e-3), b
        assert polygons.inside(b.roof_outline, layout.lots[b.lot_index].polygon, 1e-3), b
        lo, hi = layout_module.HEIGHT_RANGES_M[b.kind]
        assert lo <= b.height_m <= hi and polygons.area(b.footprint) > 0, b
        if b.roof != "flat":
            assert b.shape == "rect" and b.overhang_m > 0
    assert [b.id for b in layout.buildings] == list(range(1, len(layout.buildings) + 1))
    assert len({b.lot_index for b in layout.buildings}) == len(layout.buildings)
    buildings = layout.buildings
    for i, j in _pairs(buildings, buildings):
        assert polygons.overlap_area(buildings[i].roof_outline, buildings[j].roof_outline) < OVERLAP_M2, \
            (buildings[i], buildings[j])
    for i, j in _pairs(buildings, layout.roads, 0.5):
        assert polygons.separation(buildings[i].roof_outline, layout.roads[j].polygon) >= 0.1, \
            (buildings[i], layout.roads[j])
    for i, j in _pairs(layout.trees, buildings):
        t = layout.trees[i]
        assert distance_to_polygon(t.x, t.y, buildings[j].roof_outline) >= t.radius_m - 1e-3, (t, buildings[j])
    for i, j in _pairs(layout.trees, layout.roads):
        t = layout.trees[i]
        assert distance_to_polygon(t.x, t.y, layout.roads[j].polygon) >= t.radius_m - 1e-3, (t, layout.roads[j])


@pytest.fixture(scope="module")
def dense_city():
    return generate_layout(3, 345.6, 345.6, LayoutParams(style="dense"))


@pytest.fixture(scope="module")
def mixed_city():
    return generate_layout(5, 700.0, 600.0, LayoutParams(style={"suburban": 0.3, "dense": 0.3, "downtown": 0.2,
                                                                 "industrial": 0.2}))


def test_dense_city_keeps_the_invariants(dense_city):
    check_styled(dense_city)


def test_mixed_city_keeps_the_invariants(mixed_city):
    check_styled(mixed_city)


@pytest.mark.parametrize("seed,width,height,style", [
    (0, 115.2, 115.2, "dense"),
    (1, 230.4, 115.2, {"dense": 0.5, "suburban": 0.5}),
    (2, 400.0, 300.0, "downtown"),
    (4, 400.0, 300.0, "industrial"),
    (6, 30.0, 30.0, "dense"),
    (7, 500.0, 120.0, {"industrial": 1, "dense": 1}),
])
def test_styled_cities_of_any_size_keep_the_invariants(seed, width, height, style):
    check_styled(generate_layout(seed, width, height, LayoutParams(style=style)))


def test_styled_layouts_are_deterministic(mixed_city):
    again = generate_layout(5, 700.0, 600.0, LayoutParams(style={"suburban": 0.3, "dense": 0.3, "downtown": 0.2,
                                                                  "industrial": 0.2}))
    assert again == mixed_city and _digest(again) == _digest(mixed_city)
    assert generate_layout(6, 700.0, 600.0, mixed_city.params).buildings != mixed_city.buildings


def test_a_dense_town_is_packed_turned_and_on_bent_lanes(dense_city):
    houses = dense_city.buildings
    sides = [np.ptp(np.array(b.footprint), axis=0) + 2 * b.overhang_m for b in houses]
    assert all(3.9 <= s.min() and s.max() <= 15.0 for s in sides)
    assert {b.kind for b in houses} <= {"residential", "apartment"} and max(b.height_m for b in houses) <= 12.5
    storeys = np.rint(np.array([b.height_m for b in houses]) / 3.0)
    assert set(storeys) == {1, 2, 3, 4} and np.mean(storeys == 1) > 0.3
    angles = {round(b.rotation_deg % 90.0) for b in houses}
    assert len(angles) > 10  # turned with their lanes, lanes turned per region and bent
    touching = {k for i, j in _pairs(houses, houses) for k in (i, j)
                if abs(polygons.separation(houses[i].roof_outline, houses[j].roof_outline)) < 1e-3}
    assert len(touching) > 0.4 * len(houses)  # many share a wall
    dirt = [r for r in dense_city.roads if r.surface == "dirt"]
    assert len(dirt) > 0.5 * len(dense_city.roads)
    # The short side of a whole (unclipped) piece is the lane's width.
    widths = [min(np.hypot(*np.subtract(a, b)) for a, b in zip(r.polygon, r.polygon[1:] + r.polygon[:1]))
              for r in dirt if len(r.polygon) == 4]
    assert 2.49 <= np.percentile(widths, 10) and np.median(widths) <= 5.0
    axis_aligned = [len(r.polygon) == 4 and len({round(x, 3) for x, _ in r.polygon}) == 2 for r in dense_city.roads]
    assert np.mean(axis_aligned) < 0.2
    assert len(dense_city.trees) < 0.05 * len(houses)  # few trees


def _coverage(layout, step=0.5):
    """Shares of the city covered by roofs, and by roofs among the ground that is not road."""
    xs = np.arange(step / 2, layout.width_m, step)
    ys = np.arange(step / 2, layout.height_m, step)
    gx, gy = np.meshgrid(xs, ys)

    def paint(items):
        mask = np.zeros(gx.shape, dtype=bool)
        for polygon in items:
            x0, y0, x1, y1 = layout_module.polygon_bbox(polygon)
            cols = slice(int(x0 / step), int(np.ceil(x1 / step)))
            rows = slice(int(y0 / step), int(np.ceil(y1 / step)))
            px, py = gx[rows, cols], gy[rows, cols]
            inside = np.ones(px.shape, dtype=bool)
            for (ax, ay), (bx, by) in zip(polygon, polygon[1:] + polygon[:1]):
                inside &= (bx - ax) * (py - ay) - (by - ay) * (px - ax) >= 0
            mask[rows, cols] |= inside
        return mask

    roofs, roads = paint(b.roof_outline for b in layout.buildings), paint(r.polygon for r in layout.roads)
    return roofs.mean(), roofs[~roads].mean()


def test_a_dense_town_covers_most_of_its_ground_with_roofs(dense_city):
    overall, off_road = _coverage(dense_city)
    assert 0.35 < overall and 0.5 < off_road < 0.75
    sparse = generate_layout(3, 345.6, 345.6, LayoutParams(style="dense", building_density=0.2))
    assert _coverage(sparse)[1] < off_road


@pytest.mark.parametrize("share", [0.3, 0.6])
def test_open_patches_keep_about_their_share_of_a_dense_town_free_of_houses(dense_city, share):
    """``open_share`` leaves round patches without houses (fields, gardens, groves) while the town keeps its
    invariants; at 0 the town is the packed one, and with real trees the patches fill with them."""
    open_city = generate_layout(3, 345.6, 345.6, LayoutParams(style="dense", open_share=share))
    check_styled(open_city)
    assert open_city.roads == dense_city.roads  # the lanes stay; only houses give way
    # the roofs lose the patches' share and a little more: houses cannot lean on a patch's edge
    ratio = _coverage(open_city)[0] / _coverage(dense_city)[0]
    assert 1 - 1.4 * share - 0.05 < ratio < 1 - share, ratio
    assert LayoutParams(style="dense", open_share=share).to_dict()["open_share"] == share
    assert "open_share" not in LayoutParams(style="dense").to_dict()
    real = {s: generate_layout(3, 345.6, 345.6, LayoutParams(style="dense", open_share=s, tree_size="real"))
            for s in (0.0, share)}
    assert len(real[share].trees) > 2 * len(real[0.0].trees)


HOUSE_M2 = 12.0 * 14.0 * 1.2  # more than any house of a dense town (its footprint and the roof's overhang)


def test_large_buildings_stand_among_a_dense_towns_houses_fronting_its_lanes(dense_city):
    """``large_buildings`` puts halls and blocks of flats into a dense town (Banepa's and Kampala's towns have
    them; the houses alone are at most 12 by 14 m): the lanes stay, the town keeps its invariants and its
    coverage, a larger value gives large buildings more of the roofs, and 0 is the town of houses alone."""
    def large_roofs(layout):
        areas = [layout_module.polygon_area(b.roof_outline) for b in layout.buildings]
        big = [a for a, b in zip(areas, layout.buildings) if b.kind == "industrial" or a > HOUSE_M2]
        return sum(big) / sum(areas), max(areas)

    share, biggest = large_roofs(dense_city)
    assert share == 0.0 and biggest < HOUSE_M2
    cities = {v: generate_layout(3, 345.6, 345.6, LayoutParams(style="dense", large_buildings=v)) for v in (0.3, 1.0)}
    for city in cities.values():
        check_styled(city)
        assert city.roads == dense_city.roads
        assert abs(_coverage(city)[0] - _coverage(dense_city)[0]) < 0.05
        kinds = {b.kind for b in city.buildings}
        assert {"industrial", "apartment", "residential"} <= kinds
    (share_few, _), (share_many, biggest) = large_roofs(cities[0.3]), large_roofs(cities[1.0])
    assert 0.0 < share_few < share_many and 0.1 < share_many < 0.4 and biggest > 300.0
    assert cities[1.0] == generate_layout(3, 345.6, 345.6, LayoutParams(style="dense", large_buildings=1.0))
    assert LayoutParams.from_dict(LayoutParams(large_buildings=0.3).to_dict()).large_buildings == 0.3
    assert "large_buildings" not in LayoutParams(style="dense").to_dict()
    for bad in (-0.1, 1.5, "some"):
        with pytest.raises(MetaSimError, match="large_buildings"):
            LayoutParams(large_buildings=bad)


def test_a_taller_town_has_the_same_houses_with_more_storeys(dense_city):
    """``tall_share`` draws a share of a dense town's storeys from `TALL_STOREYS` with the same one draw per
    house, so the town keeps its lanes and footprints and only grows: Banepa's three- to six-storey centre."""
    tall = generate_layout(3, 345.6, 345.6, LayoutParams(style="dense", tall_share=0.5))
    check_styled(tall)
    assert tall.roads == dense_city.roads
    assert len(tall.buildings) == len(dense_city.buildings)
    assert all(np.allclose(a.roof_outline, b.roof_outline, atol=1e-6)  # as placed; the roofs' kinds may change
               for a, b in zip(tall.buildings, dense_city.buildings))
    low, high = (np.array([b.height_m for b in city.buildings]) for city in (dense_city, tall))
    assert (high >= low - 1e-9).all() and high.mean() > 1.3 * low.mean() and high.max() > 17.0 > low.max()
    assert {b.kind for b in tall.buildings} == {"residential", "apartment"}
    assert LayoutParams.from_dict(LayoutParams(tall_share=0.5).to_dict()).tall_share == 0.5
    assert "tall_share" not in LayoutParams(style="dense").to_dict()
    for bad in (-0.1, 1.5, None):
        with pytest.raises(MetaSimError, match="tall_share"):
            LayoutParams(tall_share=bad)


def test_a_larger_open_share_keeps_the_patches_of_a_smaller_one():
    from meta_sim.sim.polygons import rounded_polygon

    window = rounded_polygon(((0.0, 0.0), (300.0, 0.0), (300.0, 200.0), (0.0, 200.0)))
    small, large = (layout_module._open_patches(np.random.default_rng(4), window, s) for s in (0.2, 0.5))
    assert 0 < len(small.items) < len(large.items) and large.items[:len(small.items)] == small.items
    assert not layout_module._open_patches(np.random.default_rng(4), window, 0.0).items
    for bad in (-0.1, 1.5, "some"):
        with pytest.raises(MetaSimError, match="open_share"):
            LayoutParams(open_share=bad)


def test_stages_keep_their_own_generators_in_styled_cities(mixed_city):
    params = mixed_city.params
    fewer_trees = generate_layout(5, 700.0, 600.0, replace(params, tree_density=0.1))
    assert fewer_trees.roads == mixed_city.roads and fewer_trees.buildings == mixed_city.buildings
    assert len(fewer_trees.trees) < len(mixed_city.trees)
    flatter = generate_layout(5, 700.0, 600.0, replace(params, sloped_share=0.2))
    assert flatter.lots == mixed_city.lots
    for a, b in zip(flatter.buildings, mixed_city.buildings, strict=True):
        if mixed_city.lots[b.lot_index].block_index >= 0:  # grid buildings keep their walls, roofs overhang
            assert a.footprint == b.footprint
        else:  # dense houses keep their roof outline (touching neighbours), walls step in under a sloped roof
            assert np.allclose(a.roof_outline, b.roof_outline, atol=1e-3)


@pytest.mark.parametrize("share", [0.0, 0.6, 0.9])
def test_sloped_share_holds_in_a_dense_town(share):
    stats = generate_layout(8, 230.4, 230.4, LayoutParams(style="dense", sloped_share=share)).stats()
    assert abs(stats["sloped_share"] - share) < 0.01
    assert stats["by_roof"]["gable"] > 0 or share == 0.0


def test_each_style_builds_its_own_kinds(mixed_city):
    downtown = generate_layout(2, 400.0, 400.0, LayoutParams(style="downtown"))
    assert {b.kind for b in downtown.buildings} == {"office", "highrise", "apartment"}
    assert all(lot.surface == "paved" for lot in downtown.lots)
    industrial = generate_layout(2, 400.0, 400.0, LayoutParams(style="industrial"))
    assert {b.kind for b in industrial.buildings} == {"industrial"}
    frontages = [min(np.hypot(*np.subtract(a, b)) for a, b in zip(lot.polygon, lot.polygon[1:] + lot.polygon[:1]))
                 for lot in industrial.lots]
    assert np.median(frontages) > 25.0  # (lots cut by a region border are smaller)
    assert len({b.rotation_deg for b in downtown.buildings}) == 1  # one turned grid
    assert all(lot.surface == "paved" for lot in industrial.lots)
    kinds = {b.kind for b in mixed_city.buildings}
    assert kinds == {"residential", "apartment", "office", "highrise", "industrial"}
    assert any(b.rotation_deg for b in mixed_city.buildings) and not all(b.rotation_deg for b in mixed_city.buildings)


def test_style_shares_set_how_much_of_the_city_each_style_covers():
    def turned_share(style):
        layout = generate_layout(9, 600.0, 600.0, LayoutParams(style=style))
        lots = [lot for lot in layout.lots if lot.block_index == -1]  # dense houses
        return sum(polygons.area(lot.polygon) for lot in lots) / 600.0**2

    little, much = turned_share({"dense": 0.2, "suburban": 0.8}), turned_share({"dense": 0.8, "suburban": 0.2})
    assert 0.0 < little < much / 2.5


@pytest.mark.parametrize("text,mix", [
    ("dense", (("dense", 1.0),)),
    ("dense=0.7,suburban=0.3", (("suburban", 0.3), ("dense", 0.7))),
    (" industrial = 2 , downtown=2 ", (("downtown", 0.5), ("industrial", 0.5))),
])
def test_style_from_the_command_line_and_back(text, mix):
    assert layout_module.parse_style(text) == mix
    assert layout_module.parse_style(layout_module.style_text(mix)) == mix


@pytest.mark.parametrize("text,message", [
    ("dense=lots", "name=share pairs"), ("dense=0.5,slum=0.5", "'slum' is not a style"),
    ("dense=0", "at least one share positive"), ("", "style name or a mapping"),
])
def test_bad_style_text_raises_a_clear_error(text, message):
    with pytest.raises(MetaSimError, match=message):
        layout_module.parse_style(text)


def test_polygons_apart_agrees_with_their_separation():
    rng = np.random.default_rng(0)
    for _ in range(300):
        a, b = (polygons.oriented_rect(*rng.uniform(0, 20, 2), *rng.uniform(1, 8, 2), rng.uniform(0, 180))
                for _ in range(2))
        gap = rng.uniform(-2, 2)
        assert polygons.apart(a, b, gap) == (polygons.separation(a, b) >= gap)


def test_lot_mesh_lays_paved_lots_between_ground_and_roads():
    lots = [Lot(rect_polygon(0, 0, 30, 20), 0, "paved"), Lot(polygons.oriented_rect(50, 50, 20, 10, 30.0), 1)]
    arrays = meshes.lot_mesh(lots).arrays()
    assert arrays["loop_total"].tolist() == [4, 4]
    assert np.all((arrays["vertices"][:, 2] > 0.0) & (arrays["vertices"][:, 2] < 0.03))
    assert np.all(arrays["label"] == meshes.label_color(0, 0))  # background in the labels

"""City layout: geometric invariants, determinism, proportions, queries, validation."""

import json

import numpy as np
import pytest
from toys import distance_to_polygon

from meta_sim.core.errors import MetaSimError
from meta_sim.sim.layout import (
    HEIGHT_RANGES_M,
    KINDS,
    OVERHANG_RANGE_M,
    PITCH_RANGE_DEG,
    TILE_M,
    CityLayout,
    LayoutParams,
    generate_layout,
    layout_for_tiles,
    polygon_area,
)

TOL = 1e-3  # coordinates are rounded to 0.1 mm


def _boxes(items):
    return np.array([item.bbox for item in items], dtype=float).reshape(-1, 4)


def _separation(a, b):
    """Chebyshev gap between every box of `a` and every box of `b` (negative: positive-area overlap)."""
    gap_x = np.maximum(b[None, :, 0] - a[:, None, 2], a[:, None, 0] - b[None, :, 2])
    gap_y = np.maximum(b[None, :, 1] - a[:, None, 3], a[:, None, 1] - b[None, :, 3])
    return np.maximum(gap_x, gap_y)


def _inside(box, outer):
    return (box[0] >= outer[0] - TOL and box[1] >= outer[1] - TOL
            and box[2] <= outer[2] + TOL and box[3] <= outer[3] + TOL)


def _is_axis_rect(polygon):
    xs = sorted({p[0] for p in polygon})
    ys = sorted({p[1] for p in polygon})
    return len(polygon) == 4 and len(xs) == 2 and len(ys) == 2 and polygon_area(polygon) > 0


def check_invariants(layout: CityLayout) -> None:
    city = (0.0, 0.0, layout.width_m, layout.height_m)
    buildings, lots, roads, trees = layout.buildings, layout.lots, layout.roads, layout.trees
    roof_boxes, lot_boxes, road_boxes = _boxes(buildings), _boxes(lots), _boxes(roads)

    for item in (*roads, *lots, *buildings, *trees):
        assert _inside(item.bbox, city), item
    assert all(_is_axis_rect(r.polygon) for r in roads)
    assert all(_is_axis_rect(lot.polygon) for lot in lots)

    if len(lots) > 1:
        lot_sep = _separation(lot_boxes, lot_boxes)
        np.fill_diagonal(lot_sep, np.inf)
        assert lot_sep.min() >= -TOL, "lots overlap"
    if len(roads) and len(lots):
        assert _separation(lot_boxes, road_boxes).min() >= -TOL, "a lot overlaps a road"

    if len(buildings) > 1:
        roof_sep = _separation(roof_boxes, roof_boxes)
        np.fill_diagonal(roof_sep, np.inf)
        assert roof_sep.min() >= 1.0 - TOL, "roof outlines closer than 1 m"
    if len(buildings) and len(roads):
        assert _separation(roof_boxes, road_boxes).min() >= 1.0 - TOL, "a roof outline reaches a road"

    assert [b.id for b in buildings] == list(range(1, len(buildings) + 1))
    assert len({b.lot_index for b in buildings}) == len(buildings), "two buildings on one lot"
    for b in buildings:
        lot_box = lots[b.lot_index].bbox
        assert all(_inside((x, y, x, y), lot_box) for x, y in b.footprint), b
        assert _inside(b.bbox, lot_box), b
        assert b.kind in KINDS
        lo, hi = HEIGHT_RANGES_M[b.kind]
        assert lo <= b.height_m <= hi, b
        assert polygon_area(b.footprint) > 0, "footprint not counter-clockwise"
        corners = zip(b.footprint, b.footprint[1:] + b.footprint[:1])
        assert all(x0 == x1 or y0 == y1 for (x0, y0), (x1, y1) in corners)
        x0, y0, x1, y1 = (min(p[0] for p in b.footprint), min(p[1] for p in b.footprint),
                          max(p[0] for p in b.footprint), max(p[1] for p in b.footprint))
        assert b.ridge_axis == ("x" if x1 - x0 >= y1 - y0 else "y")
        if b.roof == "flat":
            assert b.roof_class == 1 and b.overhang_m == 0.0 and b.roof_outline == b.footprint
            assert b.ridge_height_m == b.height_m
        else:
            assert b.roof_class == 2 and b.shape == "rect" and b.kind != "highrise"
            assert PITCH_RANGE_DEG[0] <= b.roof_pitch_deg <= PITCH_RANGE_DEG[1]
            assert OVERHANG_RANGE_M[0] <= b.overhang_m <= OVERHANG_RANGE_M[1]
            assert b.ridge_height_m > b.height_m
            grown = (x0 - b.overhang_m, y0 - b.overhang_m, x1 + b.overhang_m, y1 + b.overhang_m)
            assert np.allclose(b.bbox, grown, atol=TOL)
        expected_vertices = {"rect": 4, "L": 6, "T": 8}[b.shape]
        assert len(b.footprint) == expected_vertices, b

    tree_boxes = _boxes(trees)
    assert all(t.radius_m > 0 and t.height_m > 0 for t in trees)
    if len(trees) and len(roads):
        assert _separation(tree_boxes, road_boxes).min() >= -TOL, "a tree crown reaches a road"
    if len(trees) and len(buildings):
        # Exact disc-polygon check only where the boxes overlap.
        for i, j in zip(*np.nonzero(_separation(tree_boxes, roof_boxes) < 0)):
            t, outline = trees[i], buildings[j].roof_outline
            assert distance_to_polygon(t.x, t.y, outline) >= t.radius_m - TOL, (t, buildings[j])


@pytest.fixture(scope="module")
def big_city():
    return generate_layout(7, 1000.0, 1000.0)


@pytest.mark.parametrize("seed,width,height", [
    (0, TILE_M, TILE_M),
    (1, 345.6, 345.6),
    (2, 350.0, 210.0),
    (3, 2000.0, TILE_M),
    (4, 30.0, 30.0),
])
def test_invariants_hold_for_sizes(seed, width, height):
    check_invariants(generate_layout(seed, width, height))


def test_invariants_hold_for_big_city(big_city):
    check_invariants(big_city)


def test_invariants_hold_over_many_seeds_and_params():
    rng = np.random.default_rng(2024)
    for seed in range(30):
        lo = rng.uniform(30, 120)
        params = LayoutParams(
            building_density=rng.uniform(0, 1),
            sloped_share=rng.uniform(0, 1),
            tree_density=rng.uniform(0, 1),
            road_width_m=rng.uniform(4, 20),
            block_size_m=(lo, lo + rng.uniform(0, 100)),
        )
        layout = generate_layout(seed, rng.uniform(60, 450), rng.uniform(60, 450), params)
        check_invariants(layout)


def test_same_seed_same_layout_and_json():
    a, b = generate_layout(11, 400, 300), generate_layout(11, 400, 300)
    assert a == b
    assert json.dumps(a.to_dict(), sort_keys=True) == json.dumps(b.to_dict(), sort_keys=True)


def test_different_seeds_differ():
    dicts = [generate_layout(seed, 400, 400).to_dict() for seed in range(4)]
    for i in range(len(dicts)):
        for j in range(i + 1, len(dicts)):
            assert dicts[i]["buildings"] != dicts[j]["buildings"]
            assert dicts[i]["roads"] != dicts[j]["roads"]


def test_json_round_trip(big_city):
    text = json.dumps(big_city.to_dict())
    again = CityLayout.from_dict(json.loads(text))
    assert again == big_city
    assert json.dumps(again.to_dict()) == text


def test_stages_draw_from_their_own_generators():
    base = generate_layout(5, 500, 500)
    fewer_trees = generate_layout(5, 500, 500, LayoutParams(tree_density=0.1))
    assert fewer_trees.roads == base.roads and fewer_trees.buildings == base.buildings
    assert len(fewer_trees.trees) < len(base.trees)
    flatter = generate_layout(5, 500, 500, LayoutParams(sloped_share=0.2))
    assert [b.footprint for b in flatter.buildings] == [b.footprint for b in base.buildings]


def test_proportions_over_one_km(big_city):
    stats = big_city.stats()
    n = stats["buildings"]
    by_kind = stats["by_kind"]
    assert n > 300
    assert by_kind["residential"] / n > 0.5
    assert all(count > 0 for count in by_kind.values()), by_kind
    for kind in ("office", "industrial", "highrise"):
        assert 0.03 < by_kind[kind] / n < 0.2, by_kind
    assert abs(stats["sloped_share"] - 0.6) < 0.01
    assert stats["non_rect"] > 0
    assert {b.shape for b in big_city.buildings} >= {"rect", "L", "T"}
    assert stats["by_roof"]["gable"] > 0 and stats["by_roof"]["hip"] > 0
    assert stats["empty_lots"] > 0 and stats["trees"] > 0


@pytest.mark.parametrize("share", [0.0, 0.3, 0.8])
def test_sloped_share_follows_parameter(share):
    stats = generate_layout(3, 800, 800, LayoutParams(sloped_share=share)).stats()
    assert abs(stats["sloped_share"] - share) < 0.01


def test_density_extremes():
    assert generate_layout(1, 300, 300, LayoutParams(building_density=0.0)).buildings == ()
    full = generate_layout(1, 300, 300, LayoutParams(building_density=1.0))
    assert full.stats()["empty_lots"] < 0.1 * len(full.lots)
    assert generate_layout(1, 300, 300, LayoutParams(tree_density=0.0)).trees == ()


def test_rect_queries_match_brute_force(big_city):
    rng = np.random.default_rng(0)
    for _ in range(40):
        x0, y0 = rng.uniform(-50, 1000, 2)
        x1, y1 = x0 + rng.uniform(1, 300), y0 + rng.uniform(1, 300)
        for query, items in ((big_city.buildings_in_rect, big_city.buildings),
                             (big_city.trees_in_rect, big_city.trees),
                             (big_city.roads_in_rect, big_city.roads)):
            expected = [it for it in items
                        if it.bbox[0] < x1 and it.bbox[2] > x0 and it.bbox[1] < y1 and it.bbox[3] > y0]
            assert query(x0, y0, x1, y1) == expected
    assert big_city.buildings_in_rect(-10, -10, 1010, 1010) == list(big_city.buildings)
    assert big_city.buildings_in_rect(2000, 2000, 2100, 2100) == []


def test_tile_grid_and_layout_for_tiles():
    layout, tiles = layout_for_tiles(9, 9)
    assert (layout.width_m, layout.height_m) == (pytest.approx(3 * TILE_M), pytest.approx(3 * TILE_M))
    assert len(tiles) == 9 and tiles == layout.tile_grid(TILE_M)
    assert tiles[0] == (0.0, 0.0, TILE_M, TILE_M) and tiles[1][0] == TILE_M  # row-major from the south-west
    layout, tiles = layout_for_tiles(9, 5)
    assert len(layout.tile_grid()) == 6 and len(tiles) == 5
    assert (layout.width_m, layout.height_m) == (pytest.approx(3 * TILE_M), pytest.approx(2 * TILE_M))
    assert generate_layout(0, 300, 200).tile_grid(100.0)[-1] == (200.0, 100.0, 300.0, 200.0)


@pytest.mark.parametrize("kwargs,field", [
    ({"building_density": 1.5}, "building_density"),
    ({"sloped_share": -0.1}, "sloped_share"),
    ({"tree_density": "many"}, "tree_density"),
    ({"tree_density": float("nan")}, "tree_density"),
    ({"road_width_m": 2.0}, "road_width_m"),
    ({"block_size_m": (150.0, 100.0)}, "block_size_m"),
    ({"block_size_m": (10.0, 100.0)}, "block_size_m[0]"),
    ({"block_size_m": 80.0}, "block_size_m"),
])
def test_bad_params_name_the_field(kwargs, field):
    with pytest.raises(MetaSimError, match=field.replace("[", r"\[").replace("]", r"\]")):
        LayoutParams(**kwargs)


@pytest.mark.parametrize("call", [
    lambda: generate_layout(-1, 100, 100),
    lambda: generate_layout(1.5, 100, 100),
    lambda: generate_layout(1, 0, 100),
    lambda: generate_layout(1, 100, 1e6),
    lambda: layout_for_tiles(1, 0),
    lambda: layout_for_tiles(1, 4, tile_m=-1),
    lambda: generate_layout(1, 100, 100).tile_grid(0),
])
def test_bad_arguments_raise_metasim_error(call):
    with pytest.raises(MetaSimError):
        call()


def test_damaged_layout_files_are_rejected():
    data = generate_layout(1, 200, 200).to_dict()
    with pytest.raises(MetaSimError, match="version"):
        CityLayout.from_dict({**data, "version": 99})
    with pytest.raises(MetaSimError, match="regenerate"):
        CityLayout.from_dict({k: v for k, v in data.items() if k != "trees"})
    broken = json.loads(json.dumps(data))
    broken["buildings"][0]["kind"] = "castle"
    with pytest.raises(MetaSimError, match="kind"):
        CityLayout.from_dict(broken)
    with pytest.raises(MetaSimError, match="unknown layout parameter"):
        CityLayout.from_dict({**data, "params": {**data["params"], "density": 1}})


def test_stage_generators_are_default_rngs_spawned_streams_without_generator_spawn(monkeypatch):
    """Blender 4.2 bundles a numpy without ``Generator.spawn``: the layout must not need it."""
    from meta_sim.sim import layout as layout_module

    expected = [g.random(4).tolist() for g in np.random.default_rng(11).spawn(5)]  # this numpy has spawn
    before = json.dumps(generate_layout(11, 300.0, 300.0).to_dict())

    class OldGenerator(np.random.Generator):
        def spawn(self, n_children):
            raise AttributeError("'numpy.random.Generator' object has no attribute 'spawn' (numpy < 1.25)")

    monkeypatch.setattr(layout_module.np.random, "Generator", OldGenerator)
    assert [g.random(4).tolist() for g in layout_module.stage_generators(11, 5)] == expected
    assert json.dumps(generate_layout(11, 300.0, 300.0).to_dict()) == before


# Published benchmarks and tile caches were rendered from these layouts: the default must never move.
DEFAULT_LAYOUT_SHA256 = {
    0: "8cf954ea4158d2ef6908ab8f992ed1aec1a6d78b44bf88d1144d7a3a0f59587f",
    1: "f781d59ac2955262b0374c60f0866c15a9ecad57c02def1d48c4648572d19f48",
    7: "76b218b4ee4016ff643c5863d295ad9062caaad6e96a3fbe2bac5a0c4266620b",
}


@pytest.mark.parametrize("seed", sorted(DEFAULT_LAYOUT_SHA256))
def test_default_layout_is_unchanged(seed):
    import hashlib

    text = json.dumps(generate_layout(seed, 400, 300).to_dict(), sort_keys=True)
    assert hashlib.sha256(text.encode()).hexdigest() == DEFAULT_LAYOUT_SHA256[seed]

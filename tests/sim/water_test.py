"""Open water (``LayoutParams.water_share``, ``sim/water.py``): its share, what it takes away, what it keeps."""

import json

import numpy as np
import pytest

from meta_sim.core.errors import MetaSimError
from meta_sim.sim import polygons
from meta_sim.sim.layout import CityLayout, LayoutParams, generate_layout
from meta_sim.sim.water import WATER_COLOURS, Water, _Discs, water_bodies

TOWN = dict(style="dense", tree_size="real", car_density=0.4, shrub_density=0.4)
SUBURB = dict(tree_size="real", street_details=True, car_density=0.4, pool_share=0.3, shrub_density=0.4)


def _covered(layout, n=20000):
    points = np.random.default_rng(0).uniform((0, 0), (layout.width_m, layout.height_m), (n, 2))
    xyr = np.array([(w.x, w.y, w.radius_m) for w in layout.waters]).reshape(-1, 3)
    inside = np.hypot(points[:, None, 0] - xyr[None, :, 0], points[:, None, 1] - xyr[None, :, 1]) < xyr[None, :, 2]
    return inside.any(1).mean()


@pytest.fixture(scope="module")
def towns():
    return {share: generate_layout(3, 345.6, 345.6, LayoutParams(**TOWN, water_share=share)) for share in (0.0, 0.3)}


def test_water_covers_about_its_share_and_takes_away_what_stands_in_it(towns):
    dry, wet = towns[0.0], towns[0.3]
    assert not dry.waters and 0.3 <= _covered(wet) < 0.45
    assert len({w.colour for w in wet.waters}) == 1 and wet.waters[0].colour in WATER_COLOURS
    discs = _Discs(wet.waters)
    assert not any(discs.touches(polygons.rect_polygon(*b.bbox)) for b in wet.buildings)
    assert not any(discs.holds(t.x, t.y) for t in wet.trees)
    assert not any(discs.touches(c.corners) for c in wet.cars)
    assert not any(discs.touches(s.polygon) for s in wet.shrubs)
    # the rest of the city stays as it was: the same roads, and what is left of the rest is the dry city's
    assert wet.roads == dry.roads and wet.lots == dry.lots
    assert set(wet.buildings) < set(dry.buildings) and set(wet.trees) < set(dry.trees)
    assert 0.4 < len(wet.buildings) / len(dry.buildings) < 0.85


def test_water_in_a_suburb_keeps_pavings_and_takes_pools_away():
    dry = generate_layout(2, 400.0, 300.0, LayoutParams(**SUBURB))
    wet = generate_layout(2, 400.0, 300.0, LayoutParams(**SUBURB, water_share=0.4))
    assert wet.pavings == dry.pavings and wet.markings == dry.markings  # the water lies over them
    assert set(wet.pools) < set(dry.pools) and set(wet.buildings) < set(dry.buildings)
    assert not any(_Discs(wet.waters).touches(p.polygon) for p in wet.pools)


def test_water_is_deterministic_round_trips_and_is_left_out_of_dry_json(towns):
    wet = towns[0.3]
    assert generate_layout(3, 345.6, 345.6, LayoutParams(**TOWN, water_share=0.3)) == wet
    assert CityLayout.from_dict(json.loads(json.dumps(wet.to_dict()))) == wet
    assert "waters" not in towns[0.0].to_dict() and "water_share" not in towns[0.0].params.to_dict()
    assert wet.params.to_dict()["water_share"] == 0.3
    assert {*wet.details_in_rect("waters", 0.0, 0.0, 345.6, 345.6)} == set(wet.waters)


def test_a_chain_starts_at_the_edge_and_a_larger_share_keeps_a_smaller_ones_discs():
    small, large = (water_bodies(np.random.default_rng(5), 300.0, 200.0, s) for s in (0.2, 0.5))
    assert 0 < len(small) < len(large) and large[:len(small)] == small
    first = small[0]
    assert min(first.x, 300.0 - first.x, first.y, 200.0 - first.y) < 1e-6  # on the city's edge
    assert water_bodies(np.random.default_rng(5), 300.0, 200.0, 0.0) == []


def test_disc_tests_are_exact():
    discs = _Discs([Water(0.0, 0.0, 10.0, "muddy")])
    assert discs.holds(7.0, 7.0) and not discs.holds(7.1, 7.1)
    assert discs.touches(polygons.rect_polygon(9.0, -1.0, 12.0, 1.0))  # an edge within the radius
    assert not discs.touches(polygons.rect_polygon(7.2, 7.2, 9.0, 9.0))  # the bbox overlaps, the disc does not
    assert discs.touches(polygons.rect_polygon(-50.0, -50.0, 50.0, 50.0))  # the disc inside the polygon


@pytest.mark.parametrize("bad", [-0.1, 0.95, "some", float("nan")])
def test_bad_water_share_names_the_field(bad):
    with pytest.raises(MetaSimError, match="water_share"):
        LayoutParams(water_share=bad)


@pytest.mark.parametrize("field,value", [("colour", "pink"), ("radius_m", 0.0), ("radius_m", 5000.0),
                                         ("x", float("inf"))])
def test_damaged_water_in_a_layout_file_is_rejected(towns, field, value):
    data = json.loads(json.dumps(towns[0.3].to_dict()))
    data["waters"][0][field] = value
    with pytest.raises(MetaSimError, match="water"):
        CityLayout.from_dict(data)

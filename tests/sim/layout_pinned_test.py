"""Whole cities pinned bit for bit: the layout's JSON and every building's roof furniture.

The digests were taken before the layout code was made faster; speed-ups must not move a single
float of any style, with or without clutter, at any building density. The stand-ins for numpy calls the
layout makes by the thousand (`draws`, `polygons.clamp`) are held to the calls they stand in for.
"""

import hashlib
import itertools
import json
import math

import numpy as np
import pytest

from meta_sim.sim.furniture import roof_furniture
from meta_sim.sim.layout import TILE_M, LayoutParams, generate_layout

# overhead-v1's layout block: clutter, real trees and roof furniture.
CLUTTER = dict(tree_size="real", street_details=True, car_density=0.4, pool_share=0.15, shrub_density=0.4)
FURNITURE = 0.6
MIX = {"suburban": 0.3, "dense": 0.3, "downtown": 0.2, "industrial": 0.2}
SIDE = 3 * TILE_M  # the city of a render's nine tiles

# (seed, width, height, style, clutter, building density) -> sha256 of the city and its furniture.
PINNED = {
    (11, SIDE, SIDE, "suburban", True, 0.5): "b48802a450e953364b7b6ef01e1aa02cf07b03e5aee3926c1a02d7698d8de6c2",
    (12, SIDE, SIDE, "suburban", True, 0.9): "52f73abff20f92492fdd5ea48ee77dedb33df3fd12002c9475e0326c8148c1ed",
    (13, SIDE, SIDE, "suburban", False, 0.5): "aefacbde95c8b8663f74533773b5b371c6c15dfbcbd621501056551dd878ace9",
    (14, SIDE, SIDE, "suburban", False, 0.9): "3e3db6fa1e6f09de8d3fde89bb983387fbe592ffe4672650c93460af52559566",
    (21, SIDE, SIDE, "dense", True, 0.5): "cbc4f6a7d381bcf5e432cf479767b287dba4bc6e03e412a33350a8924049c980",
    (22, SIDE, SIDE, "dense", True, 0.9): "cec20b5d5e3ee316e4f0c362df506675f1e330da06418df284a07a6b9c31fd6b",
    (23, SIDE, SIDE, "dense", False, 0.5): "5b2cf5de0ee1d953a3d3c1fb5c018d5991135309db33c8a9011a23feabcbe39d",
    (24, SIDE, SIDE, "dense", False, 0.9): "744b1b16f868a30ed4348a9718e847a183ed32764b8ed150f58a97f0530111a9",
    (31, SIDE, SIDE, "downtown", True, 0.5): "ad9a61ff199349bef2596621966a947de9bdc042f3f61efce4c5a8c28c34c324",
    (32, SIDE, SIDE, "downtown", True, 0.9): "4243ea104d598657122fbd3fef762f7cf07d81db8a1fc50f2b453954ca08982b",
    (33, SIDE, SIDE, "downtown", False, 0.5): "5c1be33caa4b4144a6badbbc5b32d90256ce0cad4de2807f5dc1d2c655f934ea",
    (34, SIDE, SIDE, "downtown", False, 0.9): "3f74a88000ef815fbb9218a7e618b35d4b9b1a9eb038f2ad1967fc35c11e237b",
    (41, SIDE, SIDE, "industrial", True, 0.5): "8a116ce9f00f20bb34a2b51a9847a2f17f3288ca8fb26dcbfc292caf7207b592",
    (42, SIDE, SIDE, "industrial", True, 0.9): "74720d7ac5c43ed3a03b9364a9e02442e69cdc0beebd60a3a3d350749ab4911a",
    (43, SIDE, SIDE, "industrial", False, 0.5): "a977d0b4660e3521d30c9fa35c440831453494f344fa29dcc995df25bf8249f7",
    (44, SIDE, SIDE, "industrial", False, 0.9): "013d738c4d20360886df15b6f36608701ac2a271c67ee0710a2b15cd2e057f29",
    (51, 460.8, 460.8, "mix", True, 0.5): "90570b57a63354f40e72a3d80fa824376d51f6e00945c1f152fc4bd4498d6ca3",
    (52, 460.8, 460.8, "mix", True, 0.9): "f564bf0be46b336efff4250bd3b9806a94b10c3b183bbac84f88e7f36ed7d737",
    (53, 460.8, 460.8, "mix", False, 0.5): "bcd61f2307219b8510aa8fbf1f8d1cb706e71479be566a8ba2aa5fea005bb2bb",
    (54, 460.8, 460.8, "mix", False, 0.9): "7c12f7f724acd764c6365ef68050feacb46764643055bfd9e8f3b81e01a44d6f",
    (5, 700.0, 600.0, "mix", True, 0.7): "fcb8e5295f11ee9b39853282290e67b29824295a878fdd91ac563c1d5afc3efc",
    (3, 345.6, 230.4, "dense", True, 0.7): "96d972960918971a3c48b28421be0582002187cdfab6a9904dfbd9f4028d31ce",
}


def city_digest(seed, width, height, style, clutter, density):
    """sha256 of the sorted JSON of the layout and the exact floats of each building's furniture."""
    params = LayoutParams(style=MIX if style == "mix" else style, building_density=density,
                          tree_density=0.3 if density < 0.7 else 0.7, roof_furniture=FURNITURE,
                          **(CLUTTER if clutter else {}))
    layout = generate_layout(seed, width, height, params)
    furniture = [[b.id, [[f.kind, f.surface, f.outline, f.bottom, f.top, f.inner]
                         for f in roof_furniture(b, layout.seed, FURNITURE, layout.style_of(b))]]
                 for b in layout.buildings]
    text = json.dumps([layout.to_dict(), furniture], sort_keys=True)  # floats as repr: every bit counts
    return hashlib.sha256(text.encode()).hexdigest()


@pytest.mark.parametrize("case", sorted(PINNED, key=str), ids=str)
def test_city_and_its_furniture_are_bit_identical_to_before_the_speed_up(case):
    assert city_digest(*case) == PINNED[case]


def test_the_cheap_draws_take_what_generator_choice_takes():
    from meta_sim.sim.draws import pick, sign

    weights = {"a": 0.45, "b": 0.3, "c": 0.17, "d": 0.08}
    for seed in range(200):
        mine, theirs = np.random.default_rng(seed), np.random.default_rng(seed)
        for _ in range(20):
            assert pick(mine, weights) == list(weights)[theirs.choice(4, p=list(weights.values()))]
            assert sign(mine) == theirs.choice((-1, 1))
        assert mine.random() == theirs.random()  # and leave the stream where choice leaves it


def test_clamp_is_np_clip_of_one_number_to_the_sign_of_zero():
    from meta_sim.sim.polygons import clamp

    values = [-2.0, -0.0, 0.0, 0.3, 1.0, 1.7, 2.0, 5.0]
    for value, lo, hi in itertools.product(values, repeat=3):
        mine, theirs = clamp(value, lo, hi), float(np.clip(value, lo, hi))
        assert (mine, math.copysign(1.0, mine)) == (theirs, math.copysign(1.0, theirs)), (value, lo, hi)


def test_rounded_is_round_to_four_places_to_the_last_bit():
    from meta_sim.sim.polygons import rounded

    rng = np.random.default_rng(0)
    values = np.concatenate([rng.uniform(-6000.0, 6000.0, 200000), rng.uniform(-1.0, 1.0, 50000),
                             rng.uniform(-1e-4, 1e-4, 10000), np.round(rng.uniform(-6000.0, 6000.0, 50000), 4),
                             (np.round(rng.uniform(-6000.0, 6000.0, 50000), 4) + 0.00005),  # the halfway points
                             [0.0, -0.0, 0.00005, -0.00005, 0.00015, 2.5e-5, 1e12, -3e15, 0.1, 0.3]])
    for value in values.tolist():
        mine, theirs = rounded(value), round(value, 4)
        assert (mine, math.copysign(1.0, mine)) == (theirs, math.copysign(1.0, theirs)), value

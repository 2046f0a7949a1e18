import dataclasses
import json

import numpy as np
import pytest

from meta_sim.core.errors import MetaSimError
from meta_sim.sim.design import DesignSpace


@pytest.fixture(scope="module")
def space():
    return DesignSpace.load()


def test_default_space_is_the_papers_84_d_one_hot(space):
    assert space.names == ("flat_roof", "sloped_roof")
    assert [p.width for p in space.parameters] == [40, 44]
    assert space.dim == 84


def test_default_space_choices_are_the_bank_textures(space, bank):
    assert list(space.parameter("flat_roof").choices) == bank.ids("flat")
    assert list(space.parameter("sloped_roof").choices) == bank.ids("sloped")


def test_flat_only_space_declares_one_parameter_and_no_sloped_roofs():
    space = DesignSpace.load("rooftops-flat-v1")
    assert space.names == ("flat_roof",) and space.dim == 40
    assert space.layout_overrides({"flat_roof": space.parameter("flat_roof").choices[0]}) == {"sloped_share": 0.0}


def test_choice_by_index_or_id(space):
    by_index = space.parse("flat_roof=3,sloped_roof=7")
    flat, sloped = space.parameter("flat_roof"), space.parameter("sloped_roof")
    assert by_index == {"flat_roof": flat.choices[3], "sloped_roof": sloped.choices[7]}
    assert space.parse(f"flat_roof={flat.choices[3]},sloped_roof={sloped.choices[7]}") == by_index
    assert space.parse(space.format(by_index)) == by_index


def test_encode_decode_round_trip_every_choice(space):
    for design in space.sample(np.random.default_rng(0), 200):
        vec = space.encode(design)
        assert vec.shape == (84,) and vec.sum() == 2
        assert space.decode(vec) == design


def test_uniform_sampling_is_seeded_and_covers_choices(space):
    a = space.sample(np.random.default_rng(5), 2000)
    assert a == space.sample(np.random.default_rng(5), 2000)
    assert a != space.sample(np.random.default_rng(6), 2000)
    counts = np.bincount([space.parameter("flat_roof").choices.index(d["flat_roof"]) for d in a], minlength=40)
    assert counts.min() > 20 and counts.max() < 90  # 50 expected per choice


@pytest.mark.parametrize("text, message", [
    ("flat_roof=3,chimney=1", "unknown design parameter"),
    ("flat_roof=no-such-texture,sloped_roof=1", "unknown choice 'no-such-texture'"),
    ("flat_roof=40,sloped_roof=1", "index 40 is out of range"),
    ("flat_roof=3", "missing sloped_roof"),
    ("flat_roof", "write name=value"),
    ("flat_roof=1,flat_roof=2,sloped_roof=1", "given twice"),
])
def test_bad_designs_raise_clear_errors(space, text, message):
    with pytest.raises(MetaSimError, match=message):
        space.parse(text)


def test_continuous_parameter_encodes_in_unit_range_and_validates(tmp_path):
    spec = {"format": "meta-sim-design-space", "version": 1, "name": "t", "parameters": [
        {"name": "flat_roof", "type": "categorical", "texture_kind": "flat", "choices": ["a", "b"]},
        {"name": "building_density", "type": "continuous", "low": 0.2, "high": 0.8,
         "layout_field": "building_density"}]}
    path = tmp_path / "space.json"
    path.write_text(json.dumps(spec))
    space = DesignSpace.load(path)
    design = space.parse("flat_roof=b,building_density=0.5")
    assert np.allclose(space.encode(design), [0, 1, 0.5])
    assert space.decode([0.2, 0.9, 1.7]) == {"flat_roof": "b", "building_density": 0.8}
    assert space.layout_overrides(design) == {"building_density": 0.5}
    with pytest.raises(MetaSimError, match="out of range"):
        space.parse("flat_roof=a,building_density=0.9")
    with pytest.raises(MetaSimError, match="not a number"):
        space.parse("flat_roof=a,building_density=dense")
    assert DesignSpace.from_dict(space.to_dict()) == space


def _appearance_space(*extra):
    return DesignSpace.from_dict({"format": "meta-sim-design-space", "version": 1, "name": "look", "parameters": [
        {"name": "flat_roof", "type": "categorical", "texture_kind": "flat", "choices": ["a", "b"]},
        {"name": "ground", "type": "categorical", "appearance": "ground", "choices": ["plain", "arid"]},
        {"name": "sensor", "type": "categorical", "appearance": "sensor", "choices": ["drone", "satellite"]},
        {"name": "greenness", "type": "continuous", "appearance": "greenness", "low": 0.0, "high": 1.0},
        {"name": "sun", "type": "continuous", "appearance": "sun_elevation_deg", "low": 30, "high": 70},
        {"name": "style", "type": "categorical", "layout_field": "style", "choices": ["suburban", "dense"]},
        *extra]})


def test_appearance_parameters_set_the_look_of_a_design_and_round_trip():
    from meta_sim.sim.appearance import Appearance
    from meta_sim.sim.sensor import get_sensor

    space = _appearance_space()
    design = space.parse("flat_roof=a,ground=arid,sensor=satellite,greenness=0.25,sun=40,style=dense")
    assert space.dim == 2 + 2 + 2 + 1 + 1 + 2
    look = Appearance(roof_jitter=0.3).with_design(space, design)
    assert look == Appearance(get_sensor("satellite"), 0.3, "arid", 0.25, 40.0)
    assert look.header() == {"sensor": get_sensor("satellite").to_dict(), "roof_jitter": 0.3, "ground": "arid",
                             "greenness": 0.25, "sun_elevation_deg": 40.0}
    assert Appearance().header() == {}
    assert space.layout_overrides(design) == {"style": "dense"}
    assert DesignSpace.from_dict(space.to_dict()) == space
    assert space.decode(space.encode(design)) == design


@pytest.mark.parametrize("extra, message", [
    ({"name": "x", "type": "categorical", "appearance": "ground", "choices": ["plain", "jungle"]},
     "no choice 'jungle'"),
    ({"name": "x", "type": "categorical", "appearance": "weather", "choices": ["a"]}, "categorical appearance field"),
    ({"name": "x", "type": "continuous", "appearance": "ground", "low": 0, "high": 1}, "continuous appearance field"),
    ({"name": "x", "type": "continuous", "appearance": "roof_jitter", "low": 0, "high": 2}, r"within \[0, 1\]"),
    ({"name": "x", "type": "continuous", "appearance": "greenness", "layout_field": "tree_density", "low": 0,
      "high": 1}, "not both"),
    ({"name": "x", "type": "categorical", "appearance": "sensor", "texture_kind": "flat", "choices": ["drone"]},
     "at most one of"),
    ({"name": "x", "type": "categorical", "appearance": "sensor", "choices": ["drone"]}, "each appearance"),
    ({"name": "x", "type": "continuous", "appearance": "sun elevation", "low": 0, "high": 1}, "must be a field name"),
    ({"name": "x", "type": "continuous", "appearance": "ground_albedo", "low": 0.1, "high": 1}, r"within \[0.2, 2\]"),
    ({"name": "x", "type": "continuous", "appearance": "ground_albedo", "low": 0.5, "high": 2.5}, r"within \[0.2, 2\]"),
    ({"name": "x", "type": "continuous", "appearance": "ground_albedo", "low": "dark", "high": 1}, "finite number"),
    ({"name": "x", "type": "categorical", "appearance": "ground_albedo", "choices": ["dark"]},
     "categorical appearance field"),
])
def test_bad_appearance_parameters_raise(extra, message):
    with pytest.raises(MetaSimError, match=message):
        _appearance_space(extra)


ALBEDO = {"name": "albedo", "type": "continuous", "appearance": "ground_albedo", "low": 0.4, "high": 1.1}


def test_ground_albedo_is_a_continuous_look_of_the_scene_recorded_in_the_header():
    from meta_sim.sim.appearance import Appearance

    space = _appearance_space(ALBEDO)
    design = space.parse("flat_roof=a,ground=arid,sensor=drone,greenness=0.5,sun=40,style=dense,albedo=0.5")
    look = Appearance().with_design(space, design)
    assert look.ground_albedo == 0.5 and look.header()["ground_albedo"] == 0.5
    without = Appearance().with_design(_appearance_space(), {k: v for k, v in design.items() if k != "albedo"})
    assert "ground_albedo" not in without.header() and without.ground_albedo is None
    # a scene of its own: the ground's colours are built into it, unlike brightness or the sensor
    assert look.scene_key() != without.scene_key()
    assert look.scene_key() != Appearance().with_design(space, {**design, "albedo": 0.6}).scene_key()
    assert Appearance().scene_key() == ("plain", *[None] * 8) and Appearance().header() == {}
    assert space.decode(space.encode(design)) == pytest.approx(design)
    for bad, message in (("2", "out of range"), ("0.3", "out of range"), ("dark", "not a number")):
        with pytest.raises(MetaSimError, match=message):
            space.parse(f"flat_roof=a,ground=arid,sensor=drone,greenness=0.5,sun=40,style=dense,albedo={bad}")


def test_shadow_depth_is_a_continuous_look_of_the_scene_below_one():
    from meta_sim.sim.appearance import Appearance

    shadow = {"name": "shadow", "type": "continuous", "appearance": "shadow_depth", "low": 0.3, "high": 0.95}
    space = _appearance_space(shadow)
    design = space.parse("flat_roof=a,ground=arid,sensor=drone,greenness=0.5,sun=40,style=dense,shadow=0.8")
    look = Appearance().with_design(space, design)
    assert look.shadow_depth == 0.8 and look.header()["shadow_depth"] == 0.8
    without = Appearance().with_design(_appearance_space(), {k: v for k, v in design.items() if k != "shadow"})
    assert without.shadow_depth is None and "shadow_depth" not in without.header()
    assert look.scene_key() != without.scene_key()  # set in the scene's light, like the sun
    with pytest.raises(MetaSimError, match=r"shadow_depth must stay within \[0, 0.95\]"):
        _appearance_space({**shadow, "high": 1.0})


def test_ground_albedo_scales_the_bare_ground_colours_and_none_leaves_them_as_they_were():
    from meta_sim.sim.appearance import ground_colours, vegetation_colour
    from meta_sim.sim.ground import COVERS, DIRT

    # None: exactly the colours renders had before the field existed (their tiles stay valid)
    assert ground_colours(None, None) == {**COVERS, "dirt": DIRT}
    assert ground_colours(0.3, None)["lawn"] == vegetation_colour("lawn", 0.3, COVERS["lawn"])
    assert DIRT == (0.30, 0.22, 0.15)
    half = ground_colours(0.3, 0.5)
    for name, colour in ground_colours(0.3, None).items():
        assert half[name] == pytest.approx(tuple(0.5 * c for c in colour))
    assert ground_colours(None, 1.0) == ground_colours(None, None)
    assert max(max(c) for c in ground_colours(None, 2.0).values()) == 1.0  # a reflectance stays at most 1
    assert ground_colours(None, 2.0)["lawn"] == pytest.approx((0.40, 0.52, 0.24))


def test_soil_redness_takes_the_bare_soil_sand_and_dirt_to_laterite_in_the_scene():
    """A design's soil redness moves the soil, sand and dirt tracks towards `LATERITE` (0: as before, the lawn,
    dry grass, gravel and pavement untouched, the albedo applied after); it is built into the scene (its key)
    and recorded in the header."""
    from meta_sim.sim.appearance import LATERITE, Appearance, ground_colours

    plain = ground_colours(0.4, None)
    assert ground_colours(0.4, None, 0.0) == plain
    red = ground_colours(0.4, None, 1.0)
    for name, colour in LATERITE.items():
        assert red[name] == pytest.approx(colour)
    assert all(red[name] == plain[name] for name in plain if name not in LATERITE)
    half = ground_colours(0.4, None, 0.5)
    for name in LATERITE:
        assert half[name] == pytest.approx(tuple((a + b) / 2 for a, b in zip(plain[name], LATERITE[name])))
        assert half[name][0] / half[name][1] > plain[name][0] / plain[name][1]  # redder
    assert ground_colours(0.4, 0.5, 1.0)["soil"] == pytest.approx(tuple(0.5 * c for c in LATERITE["soil"]))
    space = _appearance_space({"name": "red", "type": "continuous", "appearance": "soil_redness", "low": 0.0,
                               "high": 1.0})
    design = space.parse("flat_roof=a,ground=arid,sensor=drone,greenness=0.5,sun=40,style=dense,red=0.7")
    look = Appearance().with_design(space, design)
    assert look.soil_redness == 0.7 and look.header()["soil_redness"] == 0.7
    assert look.scene_key() != Appearance().with_design(space, {**design, "red": 0.2}).scene_key()


def test_saturation_scales_the_colours_of_the_finished_render_around_their_luminance():
    """``saturate``: 1 leaves an image, 0 makes it grey at its luminance, 1.5 moves every colour half as far
    again from its luminance (kept where nothing clips); a design's saturation applies to the finished render
    (not the scene: its key stays), the header records it, and the space refuses a range beyond 0.5 to 2."""
    from meta_sim.sim.appearance import Appearance, saturate
    from meta_sim.sim.jitter import LUMA

    rng = np.random.default_rng(3)
    image = (0.2 + 0.5 * rng.random((8, 8, 3))).astype(np.float32)
    assert np.allclose(saturate(image, 1.0), image)
    grey = saturate(image, 0.0)
    assert np.allclose(grey, (image @ LUMA)[..., None].repeat(3, axis=-1), atol=1e-6)
    vivid = saturate(image, 1.5)
    assert np.allclose(vivid - grey, 1.5 * (image - grey), atol=1e-5)
    unclipped = (vivid > 0).all(axis=-1)
    assert np.allclose((vivid @ LUMA)[unclipped], (image @ LUMA)[unclipped], atol=1e-5)
    assert saturate(np.array([[0.0, 0.5, 0.0]], np.float32), 2.0).min() == 0.0  # clipped at 0, never negative
    space = _appearance_space({"name": "sat", "type": "continuous", "appearance": "saturation", "low": 0.7,
                               "high": 1.5})
    design = space.parse("flat_roof=a,ground=arid,sensor=drone,greenness=0.5,sun=40,style=dense,sat=1.3")
    look = Appearance().with_design(space, design)
    assert look.saturation == 1.3 and look.header()["saturation"] == 1.3
    assert look.scene_key() == Appearance().with_design(space, {**design, "sat": 0.8}).scene_key()
    flat = np.zeros((8, 8), np.int32)
    plain = dataclasses.replace(look, saturation=None)  # the same sensor, roofs and brightness
    assert np.allclose(look.apply(image, flat, flat, 1, 0), plain.apply(saturate(image, 1.3), flat, flat, 1, 0))
    assert not np.allclose(look.apply(image, flat, flat, 1, 0), plain.apply(image, flat, flat, 1, 0))
    with pytest.raises(MetaSimError, match=r"saturation must stay within \[0.5, 2\]"):
        _appearance_space({"name": "sat", "type": "continuous", "appearance": "saturation", "low": 0.2,
                           "high": 1.5})


def test_overhead_v2_is_overhead_v1_plus_the_ground_albedo():
    from meta_sim.sim.appearance import Appearance
    from meta_sim.sim.design import builtin_spaces

    v1, v2 = DesignSpace.load("overhead-v1"), DesignSpace.load("overhead-v2")
    assert {"overhead-v1", "overhead-v2"} <= set(builtin_spaces())
    albedo = v2.parameter("ground_albedo")
    assert (albedo.appearance, albedo.low, albedo.high) == ("ground_albedo", 0.4, 1.1)
    assert tuple(p for p in v2.parameters if p.name != "ground_albedo") == v1.parameters
    assert v2.layout == v1.layout and v2.dim == v1.dim + 1
    # overhead-v1 as its models and caches know it: no albedo, the same parameters in the same order
    assert v1.dim == 100 and "ground_albedo" not in v1.names
    assert v1.names == ("flat_roof", "sloped_roof", "style", "ground", "greenness", "tree_density",
                        "building_density", "sun_elevation", "brightness", "roof_jitter", "sensor")
    designs = v2.sample(np.random.default_rng(4), 200)
    assert designs == v2.sample(np.random.default_rng(4), 200)
    values = np.array([d["ground_albedo"] for d in designs])
    assert values.min() >= 0.4 and values.max() <= 1.1 and values.min() < 0.5 and values.max() > 1.0
    for design in designs[:20]:
        assert v2.decode(v2.encode(design)) == pytest.approx(design)
        assert Appearance().with_design(v2, design).header()["ground_albedo"] == design["ground_albedo"]
    for design in v1.sample(np.random.default_rng(4), 20):
        assert "ground_albedo" not in Appearance().with_design(v1, design).header()


def test_overhead_v3_is_overhead_v2_with_sparse_towns():
    v2, v3 = DesignSpace.load("overhead-v2"), DesignSpace.load("overhead-v3")
    density = v3.parameter("building_density")
    assert (density.low, density.high) == (0.05, 1.0) and v2.parameter("building_density").low == 0.4
    assert tuple(p for p in v3.parameters if p.name != "building_density") == tuple(
        p for p in v2.parameters if p.name != "building_density")
    assert v3.layout == v2.layout and v3.dim == v2.dim and v3.names == v2.names
    values = np.array([d["building_density"] for d in v3.sample(np.random.default_rng(4), 200)])
    assert values.min() >= 0.05 and values.min() < 0.2


def test_overhead_towns_v1_is_overhead_v2_with_every_city_a_dense_town():
    """The towns space: no style to infer, every city the dense style (its cache key says so)."""
    from meta_sim.render.loop import layout_params
    from meta_sim.sim.layout import generate_layout

    v2, towns = DesignSpace.load("overhead-v2"), DesignSpace.load("overhead-towns-v1")
    assert towns.names == tuple(n for n in v2.names if n != "style")
    assert tuple(towns.parameters) == tuple(p for p in v2.parameters if p.name != "style")
    assert towns.layout == {**v2.layout, "style": "dense"} and towns.scene_version() == v2.scene_version()
    for design in towns.sample(np.random.default_rng(3), 5):
        overrides = towns.layout_overrides(design)
        assert overrides["style"] == "dense" and overrides["building_density"] == design["building_density"]
    layout = generate_layout(7, 120.0, 120.0, layout_params(towns, towns.sample(np.random.default_rng(3), 1)[0]))
    assert {layout.style_of(b) for b in layout.buildings} == {"dense"}


def test_overhead_towns_v2_is_towns_v1_with_painted_roofs_and_darker_ground_recorded_in_the_header():
    from meta_sim.sim.appearance import Appearance

    v1, v2 = DesignSpace.load("overhead-towns-v1"), DesignSpace.load("overhead-towns-v2")
    paint, albedo = v2.parameter("roof_paint"), v2.parameter("ground_albedo")
    assert (paint.appearance, paint.low, paint.high) == ("roof_paint", 0.0, 0.8)
    assert (albedo.low, albedo.high) == (0.3, 0.9) and v1.parameter("ground_albedo").low == 0.4
    changed = ("roof_paint", "ground_albedo")
    assert tuple(p for p in v2.parameters if p.name not in changed) == tuple(p for p in v1.parameters
                                                                          if p.name not in changed)
    after = v1.names.index("roof_jitter") + 1
    assert v2.names == (*v1.names[:after], "roof_paint", *v1.names[after:])
    assert v2.layout == v1.layout and v2.scene_version() == v1.scene_version()
    for design in v2.sample(np.random.default_rng(5), 5):
        look = Appearance().with_design(v2, design)
        assert look.roof_paint == design["roof_paint"] and look.header()["roof_paint"] == design["roof_paint"]
    assert "roof_paint" not in Appearance().with_design(v1, v1.sample(np.random.default_rng(5), 1)[0]).header()
    with pytest.raises(MetaSimError, match=r"roof_paint must stay within \[0, 1\]"):
        DesignSpace.from_dict({**v2.to_dict(), "parameters": [
            {**p.to_dict(), "high": 1.5} if p.name == "roof_paint" else p.to_dict() for p in v2.parameters]})


def test_overhead_towns_v3_is_towns_v2_with_open_ground_and_deeper_shadows():
    from meta_sim.sim.appearance import Appearance
    from meta_sim.sim.layout import LayoutParams

    v2, v3 = DesignSpace.load("overhead-towns-v2"), DesignSpace.load("overhead-towns-v3")
    open_share, shadow = v3.parameter("open_share"), v3.parameter("shadow_depth")
    assert (open_share.layout_field, open_share.low, open_share.high) == ("open_share", 0.0, 0.3)
    assert (shadow.appearance, shadow.low, shadow.high) == ("shadow_depth", 0.55, 0.9)
    assert tuple(p for p in v3.parameters if p.name not in ("open_share", "shadow_depth")) == v2.parameters
    assert v3.names.index("open_share") == v3.names.index("building_density") + 1
    assert v3.names.index("shadow_depth") == v3.names.index("sun_elevation") + 1
    assert v3.layout == v2.layout and v3.scene_version() == v2.scene_version()
    for design in v3.sample(np.random.default_rng(5), 5):
        overrides = v3.layout_overrides(design)
        assert LayoutParams(**overrides).open_share == design["open_share"] == overrides["open_share"]
        look = Appearance().with_design(v3, design)
        assert look.shadow_depth == design["shadow_depth"] == look.header()["shadow_depth"]


def test_overhead_towns_v4_is_towns_v3_with_open_water():
    from meta_sim.sim.layout import LayoutParams

    v3, v4 = DesignSpace.load("overhead-towns-v3"), DesignSpace.load("overhead-towns-v4")
    water = v4.parameter("water_share")
    assert (water.layout_field, water.low, water.high) == ("water_share", 0.0, 0.4)
    assert v4.parameters[:-1] == v3.parameters and v4.parameters[-1] == water
    assert v4.layout == v3.layout
    for design in v4.sample(np.random.default_rng(5), 5):
        overrides = v4.layout_overrides(design)
        assert LayoutParams(**overrides).water_share == design["water_share"] == overrides["water_share"]


def test_overhead_towns_v5_is_towns_v4_with_deeper_shadows():
    from meta_sim.sim.appearance import Appearance

    v4, v5 = DesignSpace.load("overhead-towns-v4"), DesignSpace.load("overhead-towns-v5")
    depth = v5.parameter("shadow_depth")
    assert (depth.appearance, depth.low, depth.high) == ("shadow_depth", 0.75, 0.95)
    assert v4.parameter("shadow_depth").low == 0.55
    assert [p for p in v5.parameters if p.name != "shadow_depth"] == [p for p in v4.parameters
                                                                       if p.name != "shadow_depth"]
    assert [p.name for p in v5.parameters] == [p.name for p in v4.parameters] and v5.layout == v4.layout
    for design in v5.sample(np.random.default_rng(3), 20):
        look = Appearance().with_design(v5, design)
        assert 0.75 <= look.shadow_depth == design["shadow_depth"] <= 0.95


@pytest.mark.parametrize("patch, message", [
    ({"format": "other"}, "not a design-space file"),
    ({"version": 99}, "version 99 is not supported"),
    ({"parameters": []}, "at least one parameter"),
    ({"parameters": [{"name": "x", "type": "categorical", "choices": ["a", "a"]}]}, "unique ids"),
    ({"parameters": [{"name": "x", "type": "ordinal"}]}, "must be 'categorical' or 'continuous'"),
])
def test_bad_space_files_raise(patch, message):
    spec = {"format": "meta-sim-design-space", "version": 1, "name": "t",
            "parameters": [{"name": "x", "type": "categorical", "choices": ["a"]}]}
    spec.update(patch)
    with pytest.raises(MetaSimError, match=message):
        DesignSpace.from_dict(spec)


def test_unknown_space_name_lists_the_built_in_ones():
    with pytest.raises(MetaSimError, match="overhead-v1, overhead-v2, overhead-v3, rooftops-flat-v1, rooftops-v1"):
        DesignSpace.load("no-such-space")


def test_decode_rejects_wrong_length_and_nan(space):
    with pytest.raises(MetaSimError, match="84"):
        space.decode(np.zeros(10))
    vec = np.zeros(84)
    vec[0] = np.nan
    with pytest.raises(MetaSimError, match="NaN"):
        space.decode(vec)


def test_one_parameter_one_choice_space():
    space = DesignSpace.from_dict({"format": "meta-sim-design-space", "version": 1, "name": "t",
                                   "parameters": [{"name": "x", "type": "categorical", "choices": ["only"]}]})
    assert space.dim == 1
    assert space.sample(np.random.default_rng(0), 3) == [{"x": "only"}] * 3
    assert space.decode(space.encode({"x": 0})) == {"x": "only"}


def test_a_view_height_outside_its_range_is_refused():
    spec = {"format": "meta-sim-design-space", "version": 1, "name": "t",
            "parameters": [{"name": "v", "type": "continuous", "appearance": "view_height_m", "low": 5.0,
                            "high": 100.0}]}
    with pytest.raises(MetaSimError, match="view_height_m must stay within"):
        DesignSpace.from_dict(spec)


# --- declared once: {"all": KIND} choices and "extends" ----------------------------------------------------------

# sha256 of each shipped space's to_dict() as json.dumps gives it with sort_keys (the canonical form preset and
# search caches key on) and without (the feature cache's, where the layout's key order counts too), computed
# from the files before they were shortened with "all" and "extends": a rewrite must never change a space.
SHIPPED_SPACE_SHA256 = {
    "overhead-towns-v1": ("1070097e35e5a7b0f4b82f7243fa1bec7c01d13aad8df99f963ee04fbdb12428",
                         "0513093ef80ee91b55c517487280ae6177954bba656d786beacc0eb72d41eccf"),
    "overhead-towns-v10": ("42a8eecc6b523f537935cfb772a5bfd6464c1022434b5c3b12ec7a0e0c35ec17",
                          "f51c009ba89ce3e8d394f1096c3dba77c74b3cc97780ead320858883648bc5f1"),
    "overhead-towns-v11": ("bf4c9a95cd6c9fc254159887d2cc8d782236aaf91d6daba2254f99a8b87bc8c9",
                          "a50b69e103b85c0e36cf6161db5043bac14d5daf5b6f872b790fe94089126612"),
    "overhead-towns-v12": ("dd9cf6d03ff20e75853cd339eec8d56c100f3ff2344a0eafb18d95965ce83ae6",
                          "9f483a2f9305527d1f4504a1a8fb081367a89d90c2748f408bd2440923325236"),
    "overhead-towns-v13": ("eae0b0d1404c1583631889d4a4ac87dbbed3e67755435a52491df3e31ee64b36",
                          "e0533961dde635e1fb7fcaa6c98e44a4c5083abfe4f21e86ec23a10d4073f779"),
    "overhead-towns-v2": ("2d2ad55e68929e5e72f63070bc2427a2772f8ac2060847e5beee9c112e0cb342",
                         "6e691721e5e2914b022e3827106ea3d01243fc90db439360ddee15995c048a35"),
    "overhead-towns-v3": ("d420d20d44d5c7d8239c7c088d90e2dd23bff81b2cd63fd863b60d718ed65323",
                         "f60162389a280b0711bc5ef363a0a030e0dc9231915e9ac22c35cbf6baf88637"),
    "overhead-towns-v4": ("2378a57d19e8106dd73242e3f3831ae1a7c1807218f5015fa6ab163611dc55fd",
                         "ec6a7382d56a1435d762c07f78d8487a61664473b3fd87c87fc34f96c3bd0722"),
    "overhead-towns-v5": ("a06d57221f3940e04322eceef7801d6d85fdcb7af0f3d1b07f0de5dd67d4e12b",
                         "32e4f95031514c286533a5ed19a49c0d78f5c578ac68de40ce650529ca7df5fb"),
    "overhead-towns-v6": ("0c8273444651455833838a651f42164145bce244e75b8e1d9f55d2b3e80dc626",
                         "d96f806f45b1245e954f43f4cd3df051194b4d20479ffb38c160f535f3f7e064"),
    "overhead-towns-v7": ("79de781b14e136afffc960eab0762538ee2b8e4bd32b66301723c2c4097d6bef",
                         "97806e6fd697d313ca7c3760a34fe89299827d3119d96da2d2ca94e3eb24faa9"),
    "overhead-towns-v8": ("dca72f3c4c2ae797567fb0d8b4eefc31d737562de4ecad21ed39b809fa37f8fb",
                         "4a05823b71f845fd3856c42df8eef9fc9df5d34bd64f112858fc8c97ca84c6af"),
    "overhead-towns-v9": ("59f88c766ad5a048eb4034d7c8b83a6d6d400fc55b693d8a73406227041e151a",
                         "44cedf21bf98dcf089de72005d2ecf7b1f062f36cddd5cdffa17b4e4fa9ff73e"),
    "overhead-v1": ("112d7d12a2292a360a6c90f069fcffa10f329ff3a667a75abdd9eb4deebd8c9d",
                   "87e9785453b3ed098469411492a08ded75719cd787172072714e7f6d6b1897f1"),
    "overhead-v2": ("e578ee82ae1eda2b3a8e31dcd8eec98b027db581e25a7e0cdad3138a20251cfb",
                   "119b235bf5e1894745d9b765edf79f363ac290599c407bc4c40bf873d1c8a423"),
    "overhead-v3": ("777c80348c3bab4bfc2e74b80f63496eb4a2f37978c050f8d0a007b2bdf0961b",
                   "0d20d24376dc7cbe39fb79f05a980ed3768cace2e8ea4d2c1a1828ac4eb5d024"),
    "rooftops-flat-v1": ("22cc4ba8f3d8b6f077d5dde20e20e17681ca8799b56d3c22f1b3625c37465a54",
                        "32f5d2bd88fd6750120ca2635fd58afdfb6a971e0c41be66ee6f413528b990f8"),
    "rooftops-v1": ("422b43d26b1c68e8a3c5de7430f3ff84c25a94ff6060095d111955e4b475e3fd",
                   "76b5a7ea08d35b62e1e17c06d899e4c213985de66466eecfe3277c90b1c6ba36"),
}


def _declared(**fields) -> dict:
    return {"format": "meta-sim-design-space", "version": 1, "name": "mine", **fields}


def _write(folder, name, data) -> str:
    path = folder / f"{name}.json"
    path.write_text(json.dumps(data))
    return str(path)


@pytest.mark.parametrize("name", sorted(SHIPPED_SPACE_SHA256))
def test_shipped_spaces_load_exactly_as_pinned(name):
    import hashlib

    data = DesignSpace.load(name).to_dict()
    canonical, as_written = SHIPPED_SPACE_SHA256[name]
    assert hashlib.sha256(json.dumps(data, sort_keys=True).encode()).hexdigest() == canonical
    assert hashlib.sha256(json.dumps(data).encode()).hexdigest() == as_written


def test_every_shipped_space_is_pinned():
    from meta_sim.sim.design import builtin_spaces

    assert sorted(SHIPPED_SPACE_SHA256) == builtin_spaces()


def test_all_choices_are_the_default_banks_textures_in_manifest_order(tmp_path, bank):
    path = _write(tmp_path, "mine", _declared(parameters=[
        {"name": "flat_roof", "type": "categorical", "texture_kind": "flat", "choices": {"all": "flat"}},
        {"name": "sloped_roof", "type": "categorical", "texture_kind": "sloped", "choices": {"all": "sloped"}}]))
    space = DesignSpace.load(path)
    assert list(space.parameter("flat_roof").choices) == bank.ids("flat")
    assert list(space.parameter("sloped_roof").choices) == bank.ids("sloped")
    assert space.to_dict()["parameters"] == DesignSpace.load("rooftops-v1").to_dict()["parameters"]


@pytest.mark.parametrize("choices, texture_kind, message", [
    ({"all": "sloped"}, "flat", r'need "texture_kind": "sloped"'),
    ({"all": "flat"}, None, r'need "texture_kind": "flat"'),
    ({"all": "round"}, "flat", r'a list of ids or \{"all": "flat"\} or \{"all": "sloped"\}'),
    ({"all": "flat", "but": ["flat-wood-deck"]}, "flat", "a list of ids or"),
    ({}, "flat", "non-empty list of unique ids"),
])
def test_all_choices_are_checked(choices, texture_kind, message):
    raw = {"name": "roof", "type": "categorical", "choices": choices}
    if texture_kind:
        raw["texture_kind"] = texture_kind
    with pytest.raises(MetaSimError, match=message):
        DesignSpace.from_dict(_declared(parameters=[raw]))


def test_extends_replaces_in_place_adds_removes_and_merges_the_layout(tmp_path):
    base = DesignSpace.load("overhead-v2")
    density = {"name": "building_density", "type": "continuous", "layout_field": "building_density",
               "low": 0.05, "high": 1.0}
    open_share = {"name": "open_share", "type": "continuous", "layout_field": "open_share", "low": 0.0, "high": 0.3}
    paint = {"name": "roof_paint", "type": "continuous", "appearance": "roof_paint", "low": 0.0, "high": 0.8}
    ground = {"name": "ground", "type": "categorical", "appearance": "ground", "choices": ["plain", "arid"]}
    space = DesignSpace.load(_write(tmp_path, "mine", _declared(
        extends="overhead-v2", remove=["style", "greenness"],
        parameters=[density, {**open_share, "after": "building_density"}, paint, {**ground, "after": "sensor"}],
        layout={"roof_furniture": None, "style": "dense", "car_density": 0.1})))
    # ground, a replacement placed after sensor, moves there: before roof_paint, appended before it was placed
    assert space.names == ("flat_roof", "sloped_roof", "ground_albedo", "tree_density", "building_density",
                           "open_share", "sun_elevation", "brightness", "roof_jitter", "sensor", "ground",
                           "roof_paint")
    assert space.name == "mine"
    assert (space.parameter("building_density").low, space.parameter("ground").choices) == (0.05, ("plain", "arid"))
    assert space.parameter("flat_roof") == base.parameter("flat_roof")
    # the base's keys keep their places, a changed value too; a new key goes at the end, null drops one
    layout = {k: v for k, v in base.layout.items() if k != "roof_furniture"}
    assert list(space.layout.items()) == list({**layout, "car_density": 0.1, "style": "dense"}.items())


def test_extends_with_its_differences_gives_the_shipped_space(tmp_path):
    path = _write(tmp_path, "v13", _declared(name="overhead-towns-v13", extends="overhead-towns-v10",
                                             layout={"roof_furniture": 1.0}))
    assert DesignSpace.load(path).to_dict() == DesignSpace.load("overhead-towns-v13").to_dict()


@pytest.mark.parametrize("extends", ["overhead-v99", "../../etc/passwd", "/etc/passwd", "rooftops-v1.json",
                                     "spaces/rooftops-v1", "", ["rooftops-v1"], 1])
def test_extends_names_only_a_shipped_space(extends):
    with pytest.raises(MetaSimError, match="is not a space meta-sim ships; extend one of: overhead-towns-v1, "):
        DesignSpace.from_dict(_declared(extends=extends))


@pytest.fixture
def shipped_folder(tmp_path, monkeypatch):
    """A folder standing in for the shipped spaces, so tests can ship spaces that extend each other."""
    from meta_sim.sim import design, space_names

    monkeypatch.setattr(space_names, "SPACES_DIR", tmp_path)
    monkeypatch.setattr(design, "SPACES_DIR", tmp_path)
    return tmp_path


def test_extends_refuses_cycles(shipped_folder):
    _write(shipped_folder, "a", _declared(name="a", extends="b"))
    _write(shipped_folder, "b", _declared(name="b", extends="a"))
    _write(shipped_folder, "c", _declared(name="c", extends="c"))
    with pytest.raises(MetaSimError, match="extend each other in a cycle: b -> a -> b"):
        DesignSpace.load("a")
    with pytest.raises(MetaSimError, match="cycle: c -> c"):
        DesignSpace.load("c")


def test_extends_is_at_most_a_few_steps_deep(shipped_folder):
    from meta_sim.sim.design import MAX_EXTENDS

    roof = {"name": "flat_roof", "type": "categorical", "texture_kind": "flat", "choices": {"all": "flat"}}
    _write(shipped_folder, "s0", _declared(name="s0", parameters=[roof]))
    for k in range(1, MAX_EXTENDS + 2):
        _write(shipped_folder, f"s{k}", _declared(name=f"s{k}", extends=f"s{k - 1}"))
    assert DesignSpace.load(f"s{MAX_EXTENDS}").names == ("flat_roof",)
    with pytest.raises(MetaSimError, match=f"more than {MAX_EXTENDS} \"extends\" deep"):
        DesignSpace.load(f"s{MAX_EXTENDS + 1}")


_ROOF = {"name": "flat_roof", "type": "categorical", "texture_kind": "flat", "choices": {"all": "flat"}}


@pytest.mark.parametrize("fields, message", [
    ({"extend": "rooftops-v1"}, r'unknown design-space key\(s\) "extend"; a space has "format", "version", '),
    ({"parameters": [{**_ROOF, "kind": "flat"}]},
     r'flat_roof: unknown key\(s\) "kind"; a categorical parameter has "name", "type", "choices"'),
    ({"parameters": [{"name": "x", "type": "continuous", "low": 0, "high": 1, "choices": [1]}]},
     r'x: unknown key\(s\) "choices"; a continuous parameter has'),
    ({"parameters": [{**_ROOF, "after": "x"}]}, r'"remove" and "after" change a base space: add "extends"'),
    ({"parameters": [_ROOF], "remove": ["x"]}, r'"remove" and "after" change a base space'),
    ({"extends": "rooftops-v1", "remove": ["style"]}, "cannot remove 'style': the base has flat_roof, sloped_roof"),
    ({"extends": "rooftops-v1", "remove": "flat_roof"}, r'"remove" must be a list of parameter names'),
    ({"extends": "rooftops-v1", "remove": ["flat_roof"], "parameters": [_ROOF]}, "both removed and declared"),
    ({"extends": "rooftops-v1", "parameters": [_ROOF, _ROOF]}, "each parameter may be declared once"),
    ({"extends": "rooftops-v1", "parameters": [{**_ROOF, "name": "roof2", "after": "style"}]},
     r'roof2: "after" must name a parameter of the space, one of flat_roof, sloped_roof; not \'style\''),
    ({"extends": "rooftops-v1", "layout": {"style": None}}, "null drops a key of the base's layout, which has none"),
    ({"extends": "rooftops-v1", "layout": ["style"]}, r'"layout" must be an object'),
    ({"extends": "rooftops-v1", "version": 2}, "version 2 is not supported"),
])
def test_declarations_are_checked_key_by_key(fields, message):
    with pytest.raises(MetaSimError, match=message):
        DesignSpace.from_dict(_declared(**fields))


@pytest.mark.parametrize("value", [float("inf"), float("nan"), [1], {"a": float("inf")}, {"a": {"b": 1}}, None,
                                   "x" * 201])
def test_a_layout_override_is_a_finite_number_a_flag_or_a_short_name(value):
    """The reader fuzz test found an infinite layout value accepted, then refused by every JSON writer."""
    data = DesignSpace.load("rooftops-v1").to_dict()
    with pytest.raises(MetaSimError, match="design-space layout x"):
        DesignSpace.from_dict({**data, "layout": {"x": value}})
    fine = DesignSpace.from_dict({**data, "layout": {"x": 1, "y": True, "style": {"dense": 0.7, "suburban": 0.3}}})
    assert fine.layout["y"] is True and fine.layout["style"] == {"dense": 0.7, "suburban": 0.3}

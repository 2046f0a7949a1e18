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

import json

import pytest

from meta_sim.core.errors import MetaSimError
from meta_sim.sim.design import DesignSpace
from meta_sim.sim.presets import DesignPreset, load_preset, population, save_preset


@pytest.fixture(scope="module")
def space():
    return DesignSpace.load()


def _preset(space, flat=0, sloped=0, name="g0"):
    design = space.parse(f"flat_roof={flat},sloped_roof={sloped}")
    shares = {p: {design[p]: 0.7, "other": 0.3} for p in space.names}
    return DesignPreset(kind="group", name=name, design_space=space.name, design=design, vote_shares=shares,
                        search={"method": "adjoint", "loss": 0.5}, source_images=["a.png"], model_id="abc")


def test_round_trip_and_confidence(space, tmp_path):
    preset = _preset(space, 3, 4)
    path = save_preset(tmp_path / "p.json", preset)
    loaded = load_preset(path, space)
    assert loaded.to_dict() == preset.to_dict()
    assert loaded.confidence("flat_roof") == 0.7
    assert [p.name for p in tmp_path.iterdir()] == ["p.json"]  # no temporary left behind


def test_roof_evidence_is_read_from_the_search_and_held_against_the_training_range(space, tmp_path):
    """A group's roof pixels per kind, the training range beside them, and whether they fall below or above
    it; a preset without them has none, and values that are not shares are left out, never trusted."""
    preset = _preset(space)
    assert preset.roof_evidence() == {}
    preset.search.update(roof_pixels_flat=0.01, roof_pixels_low_flat=0.02, roof_pixels_high_flat=0.3,
                         roof_pixels_sloped=0.9, roof_pixels_low_sloped=0.0, roof_pixels_high_sloped=0.2)
    loaded = load_preset(save_preset(tmp_path / "p.json", preset), space)
    assert loaded.roof_evidence() == {"flat": {"share": 0.01, "range": (0.02, 0.3), "outside": "low"},
                                      "sloped": {"share": 0.9, "range": (0.0, 0.2), "outside": "high"}}
    loaded.search.update(roof_pixels_sloped=0.1, roof_pixels_high_flat=True)
    assert loaded.roof_evidence() == {"flat": {"share": 0.01, "range": None, "outside": None},
                                      "sloped": {"share": 0.1, "range": (0.0, 0.2), "outside": None}}
    loaded.search.update(roof_pixels_flat=1.5, roof_pixels_sloped="0.1", roof_pixels_low_sloped=0.3)
    assert loaded.roof_evidence() == {}


@pytest.mark.parametrize("patch, message", [
    ({"format": "something-else"}, "not a meta-sim design preset"),
    ({"version": 2}, "newer than this meta-sim reads"),
    ({"kind": "spell"}, "kind 'spell'"),
    ({"design": {}}, "has no design"),
    ({"design": {"flat_roof": "flat-unobtainium", "sloped_roof": 0}}, "unknown choice 'flat-unobtainium'"),
    ({"vote_shares": [1, 2]}, "must be an object"),
])
def test_bad_presets_are_rejected_with_a_message(space, tmp_path, patch, message):
    data = _preset(space).to_dict()
    data.update(patch)
    path = tmp_path / "bad.json"
    path.write_text(json.dumps(data))
    with pytest.raises(MetaSimError, match=message):
        load_preset(path, space)


def test_non_json_and_missing_files(tmp_path, space):
    path = tmp_path / "evil.json"
    path.write_text("__import__('os').system('echo pwned')")
    with pytest.raises(MetaSimError, match="not valid JSON"):
        load_preset(path, space)
    with pytest.raises(MetaSimError, match="does not exist"):
        load_preset(tmp_path / "nope.json")


def test_population_counts_designs(space):
    groups = [_preset(space, 1, 2, "a"), _preset(space, 1, 2, "b"), _preset(space, 5, 2, "c")]
    pop = population(groups, space, "all", model_id="abc")
    flat = space.parameter("flat_roof").choices
    assert pop.design["flat_roof"] == flat[1]
    assert pop.distribution["flat_roof"] == {flat[1]: 2 / 3, flat[5]: 1 / 3}
    assert pop.designs[0]["count"] == 2
    assert DesignPreset.from_dict(pop.to_dict(), space).distribution == pop.distribution
    with pytest.raises(MetaSimError):
        population([], space, "none")
    # With near designs: the distribution stays the groups', the designs to sample are the near ones.
    near = [groups[0].design, groups[2].design, groups[2].design]
    spread = population(groups, space, "all", near=near, near_per_group=1)
    assert spread.distribution == pop.distribution and spread.search == {"groups": 3, "near": 1}
    assert spread.designs == [{"design": groups[2].design, "count": 2}, {"design": groups[0].design, "count": 1}]
    assert DesignPreset.from_dict(spread.to_dict(), space).designs == spread.designs
    with pytest.raises(MetaSimError, match="at least one"):
        population(groups, space, "all", near=[])


def test_a_preset_of_overhead_v2_carries_its_ground_albedo_and_an_unfit_one_is_refused(tmp_path):
    import numpy as np

    space = DesignSpace.load("overhead-v2")
    design = {**space.sample(np.random.default_rng(1), 1)[0], "ground_albedo": 0.55}
    preset = DesignPreset(kind="group", name="dark-ground", design_space=space.name, design=design)
    loaded = load_preset(save_preset(tmp_path / "p.json", preset), space)
    assert loaded.design["ground_albedo"] == 0.55 and loaded.to_dict() == preset.to_dict()
    for value, message in ((1.5, "out of range"), (0.2, "out of range"), ("dark", "not a number"),
                           (None, "finite number"), (float("nan"), "finite number")):
        path = tmp_path / "bad.json"
        path.write_text(json.dumps({**preset.to_dict(), "design": {**design, "ground_albedo": value}}))
        with pytest.raises(MetaSimError, match=message):
            load_preset(path, space)
    path.write_text(json.dumps({**preset.to_dict(), "design": {k: v for k, v in design.items()
                                                               if k != "ground_albedo"}}))
    with pytest.raises(MetaSimError, match="missing ground_albedo"):
        load_preset(path, space)
    with pytest.raises(MetaSimError, match="unknown design parameter.*ground_albedo"):
        load_preset(tmp_path / "p.json", DesignSpace.load("overhead-v1"))

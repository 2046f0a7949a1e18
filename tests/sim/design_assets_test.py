"""What the asset library of a presets folder holds, decided without Blender (design_assets)."""

import json
import uuid
from pathlib import Path

import numpy as np
import pytest

from meta_sim.core.errors import MetaSimError
from meta_sim.sim import design_assets as lib
from meta_sim.sim.design import DesignSpace
from meta_sim.sim.presets import DesignPreset, population, save_preset


@pytest.fixture(scope="module")
def space():
    return DesignSpace.load()


def _group(space, flat, name, images=("/data/kampala/a.png", "/data/kampala/b.png"), loss=0.4123):
    design = space.parse(f"flat_roof={flat},sloped_roof=2")
    return DesignPreset(kind="group", name=name, design_space=space.name, design=design,
                        vote_shares={"flat_roof": {design["flat_roof"]: 0.62, "x": 0.38}},
                        search={"method": "adjoint", "loss": loss}, source_images=list(images), model_id="m1")


@pytest.fixture
def folder(tmp_path, space):
    """An infer output: population.json and report.json on top, groups in presets/, two bad files."""
    groups = [_group(space, k, f"kampala-{k:03d}") for k in (1, 2)]
    for preset in groups:
        save_preset(tmp_path / "presets" / f"{preset.name}.json", preset)
    save_preset(tmp_path / "population.json", population(groups, space, "kampala-population", "m1"))
    (tmp_path / "report.json").write_text(json.dumps({"groups": []}))
    (tmp_path / "presets" / "bad.json").write_text("[")
    (tmp_path / "notes.json").write_text(json.dumps({"format": "something-else"}))
    return tmp_path


def test_scan_reads_the_top_and_presets_folder_and_keeps_the_bad_files_apart(folder, space):
    found, bad = lib.scan(folder, space)
    assert [f.rel for f in found] == ["population.json", "presets/kampala-001.json", "presets/kampala-002.json"]
    assert sorted(p.name for p, _ in bad) == ["bad.json", "notes.json"]  # report.json is infer's, not a preset
    with pytest.raises(MetaSimError, match="does not exist"):
        lib.scan(folder / "missing", space)
    (folder / "empty").mkdir()
    with pytest.raises(MetaSimError, match="no presets"):
        lib.scan(folder / "empty", space)


def test_asset_names_are_unique(folder, space):
    found, _ = lib.scan(folder, space)
    assert lib.asset_names(found) == ["kampala-population", "kampala-001", "kampala-002"]
    twin = lib.Found(found[1].path, "other/kampala-001.json", found[1].preset, space)
    assert lib.asset_names([found[1], twin]) == ["presets/kampala-001", "other/kampala-001"]


def test_catalogs_by_target_folder_with_stable_ids(space):
    assert lib.catalog_path(_group(space, 1, "a")) == "Meta-Sim/kampala"
    assert lib.catalog_path(_group(space, 1, "a", images=["/d/rio:2/x.png"])) == "Meta-Sim/rio_2"
    assert lib.catalog_path(_group(space, 1, "a", images=[])) == "Meta-Sim/Unknown target"
    text = lib.catalogs_text(["Meta-Sim/kampala", "Meta-Sim/rio", "Meta-Sim/kampala"])
    lines = [line for line in text.splitlines() if line and not line.startswith("#")]
    assert lines[0] == "VERSION 1"
    entries = [line.split(":") for line in lines[1:]]
    assert [e[1] for e in entries] == ["Meta-Sim", "Meta-Sim/kampala", "Meta-Sim/rio"]
    assert [e[2] for e in entries] == ["Meta-Sim", "Meta-Sim-kampala", "Meta-Sim-rio"]
    assert all(str(uuid.UUID(e[0])) == e[0] == lib.catalog_id(e[1]) for e in entries)
    assert lib.catalogs_text(["Meta-Sim/kampala"]) == lib.catalogs_text(["Meta-Sim/kampala"])  # rebuilt: same ids


def test_description_properties_and_tags_carry_what_the_preset_says(folder, space):
    found, _ = lib.scan(folder, space)
    group, pop = found[1], found[0]
    text = lib.description(group.preset, space)
    flat = group.preset.design["flat_roof"]
    assert f"flat_roof {flat} (62% of votes)" in text and "Search loss 0.4123." in text
    assert "Target: 2 images in /data/kampala." in text and "Model m1." in text
    props = lib.properties(group)
    assert props["preset"] == "presets/kampala-001.json" and props["search_loss"] == 0.4123
    assert json.loads(props["vote_shares"]) == group.preset.vote_shares and props["source_images"] == 2
    assert all(isinstance(v, (str, int, float)) for v in props.values())  # what Blender's custom properties take
    assert lib.tags(group.preset, space)[:2] == ["Meta-Sim", "group"] and flat in lib.tags(group.preset, space)
    assert "2 distinct designs over 2 groups" in lib.description(pop.preset, space)
    assert props["far_from_every_design"] == 0 and lib.FAR_TAG not in lib.tags(group.preset, space)
    assert "Unlike every design" not in text


def test_a_group_unlike_every_design_says_so(space):
    far = _group(space, 1, "rio-000")
    far.search["far"] = True  # infer searched it again by the roof colours alone (nams ColourComparison.far)
    assert "Unlike every design the model knows" in lib.description(far, space)
    assert lib.properties(lib.Found(Path("x.json"), "presets/x.json", far, space))["far_from_every_design"] == 1
    assert lib.tags(far, space)[-1] == lib.FAR_TAG
    far.search["far"] = "yes"  # only a true boolean counts
    assert lib.FAR_TAG not in lib.tags(far, space) and "Unlike" not in lib.description(far, space)


def test_an_asset_finds_its_preset_only_inside_the_presets_folder(folder, space):
    found, _ = lib.scan(folder, space)
    blend = folder / lib.LIBRARY_DIR / lib.BLEND_FILE
    props = lib.properties(found[1])
    assert lib.preset_of_asset(blend, props) == (folder / "presets" / "kampala-001.json").resolve()
    for change, message in (({"meta_sim_format": "x"}, "not a Meta-Sim design"),
                            ({"meta_sim_version": 2}, "newer than this add-on reads"),
                            ({"preset": "/etc/passwd.json"}, "does not name its preset file"),
                            ({"preset": "presets/kampala-001.py"}, "does not name its preset file"),
                            ({"preset": "../elsewhere.json"}, "points outside its folder"),
                            ({"preset": "presets/gone.json"}, "is gone")):
        with pytest.raises(MetaSimError, match=message):
            lib.preset_of_asset(blend, {**props, **change})
    assert not lib.is_design_asset(None) and not lib.is_design_asset({"meta_sim_format": 1})


def test_preview_keys_and_the_population_mosaic(space):
    design, knobs = {"flat_roof": "a", "sloped_roof": "b"}, {"seed": 1}
    key = lib.preview_key(design, space, knobs, "fast", "default-v1")
    assert key == lib.preview_key(dict(reversed(design.items())), space, knobs, "fast", "default-v1")
    flat = DesignSpace.load("rooftops-flat-v1")
    assert len({key, lib.preview_key(design, space, {"seed": 2}, "fast", "default-v1"),
                lib.preview_key(design, space, knobs, "balanced", "default-v1"),
                lib.preview_key(design, flat, knobs, "fast", "default-v1"),
                lib.preview_key({**design, "flat_roof": "c"}, space, knobs, "fast", "default-v1")}) == 5
    tiles = [np.full((4, 4, 3), v, dtype=np.float32) for v in (0.1, 0.5, 0.9)]
    assert lib.mosaic(tiles[:1]) is tiles[0]
    grid = lib.mosaic(tiles)
    assert grid.shape == (4, 4, 3)
    assert [grid[0, 0, 0], grid[0, 2, 0], grid[2, 0, 0], grid[2, 2, 0]] == pytest.approx([0.1, 0.5, 0.9, 0.1])
    pop = population([_group(space, k, f"g{k}") for k in (1, 1, 2, 3, 4, 5)], space, "p")
    assert lib.population_designs(pop)[0] == pop.designs[0]["design"] and len(lib.population_designs(pop)) == 4


def test_each_preset_is_read_in_the_space_it_names(tmp_path, space):
    towns = DesignSpace.load("overhead-towns-v5")
    design = towns.sample(np.random.default_rng(4), 1)[0]
    preset = DesignPreset(kind="group", name="banepa-000", design_space=towns.name, design=design)
    save_preset(tmp_path / "towns.json", preset)
    save_preset(tmp_path / "roofs.json", _group(space, 3, "roofs"))
    unnamed = _group(space, 4, "unnamed")
    unnamed.design_space = ""  # an old preset names no space: the scene's
    save_preset(tmp_path / "unnamed.json", unnamed)
    save_preset(tmp_path / "unknown.json", DesignPreset(kind="group", name="x", design_space="my-space-v9",
                                                        design=design))
    bright = towns.parameter("brightness")
    save_preset(tmp_path / "outside.json", DesignPreset(kind="group", name="too-bright", design_space=towns.name,
                                                        design={**design, "brightness": bright.high * 2}))
    found, bad = lib.scan(tmp_path, space)
    assert {f.rel: f.space.name for f in found} == {"roofs.json": space.name, "towns.json": towns.name,
                                                   "unnamed.json": space.name}
    assert next(f for f in found if f.rel == "towns.json").preset.design == design
    reasons = {path.name: why for path, why in bad}
    assert set(reasons) == {"unknown.json", "outside.json"}
    assert "'my-space-v9' is not one meta-sim ships" in reasons["unknown.json"]
    assert "brightness" in reasons["outside.json"] and "out of range" in reasons["outside.json"]
    assert all("\n" not in why for why in reasons.values())
    mine = DesignSpace.from_dict({**towns.to_dict(), "name": "my-space-v9"})  # the scene's own space from a file
    assert lib.load_in_own_space(tmp_path / "unknown.json", mine)[1] is mine

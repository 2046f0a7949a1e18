"""Real Blender renders (bpy module), at reduced pixel counts so the suite stays fast."""

import dataclasses
import json
import math
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from meta_sim.cli import main as cli
from meta_sim.core.errors import MetaSimError
from meta_sim.render.jobs import RenderSettings, single_job
from meta_sim.render.loop import render_jobs
from meta_sim.sim import tiles
from meta_sim.sim.design import DesignSpace
from meta_sim.sim.imageio import linear_to_srgb, read_rgb8
from meta_sim.sim.layout import LayoutParams, layout_for_tiles, polygon_area
from meta_sim.sim.quality import PRESETS, get_preset

ROOT = Path(__file__).resolve().parents[2]
SMALL = {"tile_px": 96, "pixel_size_m": 1.2}  # a full 115.2 m tile at a quarter of the pixels
SEED = 3


@pytest.fixture(scope="module")
def space():
    return DesignSpace.load()


def _render(space, banks, out, design, preset="fast", n_tiles=4, seed=SEED, preview=False, **kw):
    settings = RenderSettings(space=space, banks=banks, preset=get_preset(preset), out_dir=Path(out),
                              n_tiles=n_tiles, preview=preview, **{**SMALL, **kw})
    job = single_job(space, space.validate(design), seed)
    summary = render_jobs([job], settings)
    return summary, [tiles.read_tile(out / f"{job.name}_t{j:02d}.exr") for j in range(n_tiles)]


def _design(space, flat=0, sloped=0):
    return {"flat_roof": flat, "sloped_roof": sloped}


@pytest.fixture(scope="module")
def rendered(space, bank, tmp_path_factory):
    out = tmp_path_factory.mktemp("render")
    summary, tile_list = _render(space, [bank], out, _design(space, 5, 9), preview=True)
    return out, summary, tile_list


def _rasterise(layout, rect, px, gsd):
    """Instance ids of roof outlines sampled at pixel centres (row 0 north): the reference labels."""
    x0, y0, x1, y1 = rect
    xs = x0 + (np.arange(px) + 0.5) * gsd
    ys = y1 - (np.arange(px) + 0.5) * gsd
    gx, gy = np.meshgrid(xs, ys)
    out = np.zeros((px, px), dtype=np.uint32)
    for b in layout.buildings_in_rect(*rect):
        poly = np.asarray(b.roof_outline)
        inside = np.zeros(gx.shape, dtype=bool)
        for (ax, ay), (bx, by) in zip(poly, np.roll(poly, -1, axis=0)):
            crosses = (ay > gy) != (by > gy)
            with np.errstate(divide="ignore", invalid="ignore"):
                x_at = ax + (gy - ay) * (bx - ax) / (by - ay)
            inside ^= crosses & (gx < x_at)
        out[inside] = b.id
    return out


def test_tiles_have_labels_and_metadata(rendered, space):
    out, summary, tile_list = rendered
    assert summary.written == 4 and summary.skipped == 0
    for j, tile in enumerate(tile_list):
        assert tile.rgb.shape == (96, 96, 3) and tile.rgb.dtype == np.float32
        assert np.isfinite(tile.rgb).all() and tile.rgb.max() > 0.05
        assert tile.meta["tile_index"] == j and tile.meta["city_seed"] == SEED
        assert tile.meta["design"] == space.validate(_design(space, 5, 9))
        assert tile.meta["preset"] == "fast" and tile.meta["pixel_size_m"] == 1.2
        assert tile.meta["software"]["blender"].startswith("5.0")


def test_labels_are_consistent_and_match_the_layout_geometry(rendered):
    _, _, tile_list = rendered
    layout, rects = layout_for_tiles(SEED, 4, 96 * 1.2)
    roof_class_of = {b.id: b.roof_class for b in layout.buildings}
    classes_seen = set()
    for tile, rect in zip(tile_list, rects):
        building = tile.building.astype(bool)
        assert np.array_equal(building, tile.instance > 0)  # every building pixel has an instance id
        assert np.array_equal(building, tile.roof_class > 0)
        ids = np.unique(tile.instance[building])
        assert set(ids) <= set(roof_class_of)
        expected = np.vectorize(lambda i: roof_class_of.get(int(i), 0), otypes=[np.uint32])(tile.instance)
        assert np.array_equal(tile.roof_class, expected)  # roof class follows the instance's roof type
        classes_seen |= set(np.unique(tile.roof_class)) - {0}
        # Exact labels: the rendered ids agree with the roof outlines sampled at pixel centres.
        reference = _rasterise(layout, rect, 96, 1.2)
        assert (reference == tile.instance).mean() > 0.995
    assert classes_seen == {1, 2}


def test_previews_are_written(rendered):
    out, _, _ = rendered
    pngs = sorted(p.name for p in out.glob("*.png"))
    assert len([p for p in pngs if p.endswith("_labels.png")]) == 4
    assert any(p.endswith("_mosaic.png") for p in pngs)
    rgb = read_rgb8(next(out.glob("*_t00.png")))
    assert rgb.shape == (96, 96, 3) and rgb.std() > 5


def test_same_seed_same_pixels_and_resume_skips_valid_tiles(rendered, space, bank, tmp_path):
    out, _, first = rendered
    summary, again = _render(space, [bank], tmp_path, _design(space, 5, 9))
    for a, b in zip(first, again):
        assert np.array_equal(a.rgb, b.rgb) and np.array_equal(a.instance, b.instance)
    # Resume: nothing to do; then a deleted and a truncated tile are re-rendered, the rest kept.
    summary, _ = _render(space, [bank], tmp_path, _design(space, 5, 9))
    assert (summary.written, summary.skipped) == (0, 4)
    names = sorted(tmp_path.glob("*.exr"))
    names[0].unlink()
    names[1].write_bytes(names[1].read_bytes()[:2000])
    kept = names[2].stat().st_mtime_ns
    summary, resumed = _render(space, [bank], tmp_path, _design(space, 5, 9))
    assert (summary.written, summary.skipped) == (2, 2)
    assert names[2].stat().st_mtime_ns == kept
    for a, b in zip(first, resumed):
        assert np.array_equal(a.rgb, b.rgb)


def _erode(mask, steps):
    for _ in range(steps):
        inner = mask.copy()
        inner[1:] &= mask[:-1]
        inner[:-1] &= mask[1:]
        inner[:, 1:] &= mask[:, :-1]
        inner[:, :-1] &= mask[:, 1:]
        mask = inner
    return mask


def test_sloped_design_change_leaves_flat_roof_pixels_unchanged(rendered, space, bank, tmp_path):
    _, _, base = rendered
    _, other = _render(space, [bank], tmp_path, _design(space, 5, 30))
    flat_changed = sloped_changed = flat_pixels = 0
    for a, b in zip(base, other):
        assert np.array_equal(a.instance, b.instance)
        flat = _erode(a.roof_class == 1, 2)
        sloped = _erode(a.roof_class == 2, 2)
        flat_pixels += flat.sum()
        flat_changed += (np.abs(a.rgb - b.rgb).max(axis=-1) > 0)[flat].sum()
        sloped_changed += (np.abs(a.rgb - b.rgb).max(axis=-1) > 0.01)[sloped].mean()
    assert flat_pixels > 500 and flat_changed == 0
    assert sloped_changed > 0.5 * len(base)


def test_flat_roof_colour_follows_the_flat_texture(space, bank, tmp_path):
    flat_ids = bank.ids("flat")
    luminance = {i: read_rgb8(bank.image_path(i)).mean() for i in flat_ids}
    dark, light = min(luminance, key=luminance.get), max(luminance, key=luminance.get)
    means = {}
    for name in (dark, light):
        _, tile_list = _render(space, [bank], tmp_path / name, {"flat_roof": name, "sloped_roof": 0},
                               n_tiles=1)
        flat = tile_list[0].roof_class == 1
        means[name] = tile_list[0].rgb[flat].mean()
    assert means[light] > 2 * means[dark]


@pytest.fixture(scope="module")
def traced(space, bank, tmp_path_factory):
    """The tiles of ``rendered`` with the path-traced preset."""
    return _render(space, [bank], tmp_path_factory.mktemp("traced"), _design(space, 5, 9), preset="balanced")[1]


def test_path_traced_preset_renders_same_labels(rendered, traced):
    _, _, base = rendered
    for a, b in zip(traced, base):
        assert np.array_equal(a.instance, b.instance)
        assert np.isfinite(a.rgb).all() and a.rgb.mean() > 0.02
        assert a.meta["preset"] == "balanced"


def test_presets_render_roofs_equally_bright(rendered, traced):
    """The rasterised preset's exposure brings its roofs to the path-traced brightness (without
    it, the studio light renders them at about a third; see quality.FAST_EXPOSURE)."""
    _, _, base = rendered

    def roof_luminance(tile_list):
        return np.median(np.concatenate([t.rgb[t.instance > 0] @ np.array([0.2126, 0.7152, 0.0722])
                                         for t in tile_list]))

    assert base[0].meta["exposure"] == get_preset("fast").exposure != 1.0
    assert base[0].meta["render"] == get_preset("fast").to_dict()
    assert 0.75 < roof_luminance(base) / roof_luminance(traced) < 1.33


def test_held_out_texture_can_be_rendered(space, bank, heldout_bank, tmp_path):
    held = heldout_bank.ids("flat")[0]
    extra = {"flat_roof": heldout_bank.ids("flat")}
    design = space.validate({"flat_roof": held, "sloped_roof": 0}, extra)
    settings = RenderSettings(space=space, banks=[bank, heldout_bank], preset=get_preset("fast"),
                              out_dir=tmp_path, n_tiles=1, **SMALL)
    summary = render_jobs([single_job(space, design, SEED)], settings)
    assert summary.written == 1
    assert tiles.read_tile(summary.paths[0]).meta["design"]["flat_roof"] == held


# --- the CLI and its error handling ---------------------------------------------------------------
def _cli(*args):
    return CliRunner().invoke(cli, [str(a) for a in args])


@pytest.mark.parametrize("args, message", [
    (["--design", "flat_roof=no-such,sloped_roof=1"], "unknown choice 'no-such'"),
    (["--design", "flat_roof=1,sloped_roof=1", "--preset", "ultra"], "unknown render preset 'ultra'"),
    (["--design", "flat_roof=1,sloped_roof=1", "--tiles", "0"], "--tiles must be a whole number from 1 to"),
    (["--design", "flat_roof=1"], "missing sloped_roof"),
    ([], "exactly one of --design, --random-designs or --population"),
])
def test_render_cli_rejects_bad_input_and_writes_nothing(tmp_path, args, message):
    out = tmp_path / "out"
    result = _cli("render", *args, "--out", out, "--tile-px", 32, "--gsd", 3.6)
    assert result.exit_code == 2, result.output
    assert message in result.output and "Traceback" not in result.output
    assert not out.exists() or not any(out.iterdir())


def test_render_cli_reports_unwritable_output(tmp_path):
    blocker = tmp_path / "a-file"
    blocker.write_text("not a folder")
    result = _cli("render", "--design", "flat_roof=1,sloped_roof=1", "--out", blocker / "tiles")
    assert result.exit_code == 2 and "cannot write to folder" in result.output


def test_render_cli_reports_missing_texture_file(tmp_path, bank):
    import shutil

    copy = tmp_path / "bank"
    shutil.copytree(bank.root, copy)
    victim = bank.by_id(bank.ids("flat")[1])
    (copy / victim.path).unlink()
    out = tmp_path / "out"
    result = _cli("render", "--bank", copy, "--design", "flat_roof=1,sloped_roof=1", "--out", out)
    assert result.exit_code == 2
    assert victim.path.split("/")[-1] in result.output
    assert not out.exists() or not list(out.glob("*.exr"))


def test_worker_runs_as_module_and_as_blender_script_with_identical_tiles(tmp_path):
    args = ["--design", "flat_roof=2,sloped_roof=4", "--seed", "9", "--tiles", "1",
            "--tile-px", "48", "--gsd", "2.4"]
    env = dict(os.environ)
    module = subprocess.run([sys.executable, "-m", "meta_sim.render.worker", *args, "--out", str(tmp_path / "a")],
                            capture_output=True, text=True, env=env, cwd=ROOT)
    assert module.returncode == 0, module.stderr
    script = subprocess.run([sys.executable, "jobs/render_tiles.py", "--", *args, "--out", str(tmp_path / "b")],
                            capture_output=True, text=True, env=env, cwd=ROOT)
    assert script.returncode == 0, script.stderr
    a, b = (tiles.read_tile(next((tmp_path / d).glob("*.exr"))) for d in "ab")
    assert np.array_equal(a.rgb, b.rgb) and np.array_equal(a.instance, b.instance)
    bad = subprocess.run([sys.executable, "-m", "meta_sim.render.worker", "--design", "flat_roof=99,sloped_roof=1",
                          "--out", str(tmp_path / "c")], capture_output=True, text=True, env=env, cwd=ROOT)
    assert bad.returncode == 2 and "out of range" in bad.stderr


def test_scene_builds_only_what_the_tiles_see(space):
    from meta_sim.blender.scene import CityScene

    layout, rects = layout_for_tiles(SEED, 9, 115.2)
    scene = CityScene(layout, [rects[4]], pixel_size_m=1.2, shadow_margin_m=20.0)
    try:
        x0, y0, x1, y1 = rects[4]
        assert 0 < len(scene.buildings) < len(layout.buildings) / 2
        for b in scene.buildings:
            bx0, by0, bx1, by1 = b.bbox
            assert bx1 > x0 - 20 and bx0 < x1 + 20 and by1 > y0 - 20 and by0 < y1 + 20
        assert 0 < scene.n_trees < len(layout.trees)
    finally:
        scene.close()


@pytest.mark.parametrize("preset, strips", [("balanced", 3), ("fast", 1)])
def test_a_render_in_strips_has_the_pixels_of_one_render(space, bank, preset, strips):
    """The add-on renders path-traced previews in strips (progress, Esc between them): the same pixels."""
    from meta_sim.blender.scene import CityScene
    from meta_sim.render.loop import resolve_textures

    layout, rects = layout_for_tiles(SEED, 1, 115.2)
    scene = CityScene(layout, rects, pixel_size_m=115.2 / 150)  # 150 rows: strips of 50
    try:
        scene.set_roofs(resolve_textures(space, space.validate(_design(space, 3, 5)), [bank]))
        whole = scene.render_rgb(scene.rects[0], get_preset(preset))
        steps = scene.render_rgb_in_strips(scene.rects[0], get_preset(preset), rows=64)
        shares = []
        while True:
            try:
                shares.append(next(steps))
            except StopIteration as done:
                striped = done.value
                break
        assert shares == [(k + 1) / strips for k in range(strips)]
        assert striped.shape == whole.shape == (150, 150, 3) and (striped == whole).all()
        assert not scene.scene.render.use_border  # the next whole render is whole again
    finally:
        scene.close()


def test_training_set_manifest_lists_every_design(tmp_path):
    result = _cli("render", "--random-designs", 3, "--tiles", 1, "--seed", 4, "--cities", 2,
                  "--tile-px", 32, "--gsd", 3.6, "--out", tmp_path)
    assert result.exit_code == 0, result.output
    import json

    manifest = json.loads((tmp_path / "designs.json").read_text())
    assert [j["name"] for j in manifest["jobs"]] == ["d00000", "d00001", "d00002"]
    assert [j["city_seed"] for j in manifest["jobs"]] == [4, 5, 4]
    for job in manifest["jobs"]:
        tile = tiles.read_tile(tmp_path / job["tiles"][0])
        assert tile.meta["design"] == job["design"] and tile.meta["city_seed"] == job["city_seed"]
    again = _cli("render", "--random-designs", 3, "--tiles", 1, "--seed", 4, "--cities", 2,
                 "--tile-px", 32, "--gsd", 3.6, "--out", tmp_path)
    assert "0 tiles written, 3 already done" in again.output


def test_end_to_end_full_size_render_through_the_console_script(tmp_path):
    """The demo's command at full size: 9 tiles of 384 x 384 px at 0.3 m/px with previews."""
    meta_sim = Path(sys.executable).with_name("meta-sim")
    result = subprocess.run([str(meta_sim), "render", "--design", "flat_roof=flat-membrane-white-tpo,"
                             "sloped_roof=sloped-clay-terracotta", "--seed", "1", "--tiles", "9",
                             "--preset", "fast", "--out", str(tmp_path), "--preview"],
                            capture_output=True, text=True, cwd=ROOT)
    assert result.returncode == 0, result.stderr
    exrs = sorted(tmp_path.glob("*.exr"))
    assert len(exrs) == 9
    total_building = 0
    for path in exrs:
        tile = tiles.read_tile(path)
        assert tile.rgb.shape == (384, 384, 3) and tile.meta["pixel_size_m"] == 0.3
        total_building += tile.building.sum()
    assert total_building > 0.05 * 9 * 384 * 384  # a city, not an empty field
    mosaic = read_rgb8(next(tmp_path.glob("*_mosaic.png")))
    assert mosaic.shape == (1152, 1152, 3)


def test_user_photo_folder_becomes_a_bank_and_renders(tmp_path, bank):
    import shutil

    photos = tmp_path / "photos"
    for kind, count in (("flat", 2), ("sloped", 2)):
        (photos / kind).mkdir(parents=True)
        for texture_id in bank.ids(kind)[:count]:
            shutil.copy(bank.image_path(texture_id), photos / kind / f"My {texture_id}.png")
    user_bank = tmp_path / "bank"
    built = _cli("textures", "build", "--from", photos, "--out", user_bank)
    assert built.exit_code == 0, built.output
    out = tmp_path / "tiles"
    result = _cli("render", "--bank", user_bank, "--design", "flat_roof=1,sloped_roof=0", "--tiles", 1,
                  "--tile-px", 48, "--gsd", 2.4, "--out", out)
    assert result.exit_code == 0, result.output
    tile = tiles.read_tile(next(out.glob("*.exr")))
    assert tile.meta["design"]["flat_roof"].startswith("flat-my-")
    assert tile.meta["design_space"].startswith("bank:")


def test_flat_only_bank_builds_no_sloped_roofs(tmp_path, bank):
    import shutil

    photos = tmp_path / "photos"
    (photos / "flat").mkdir(parents=True)
    for texture_id in bank.ids("flat")[:3]:
        shutil.copy(bank.image_path(texture_id), photos / "flat" / f"{texture_id}.png")
    assert _cli("textures", "build", "--from", photos, "--out", tmp_path / "bank").exit_code == 0
    out = tmp_path / "tiles"
    result = _cli("render", "--bank", tmp_path / "bank", "--design", "flat_roof=2", "--tiles", 4,
                  "--tile-px", 48, "--gsd", 2.4, "--out", out)
    assert result.exit_code == 0, result.output
    classes = set()
    for path in out.glob("*.exr"):
        classes |= set(np.unique(tiles.read_tile(path).roof_class))
    assert classes == {0, 1}


def test_worker_and_farm_worker_help_format():
    from meta_sim.render.worker import build_argparser

    assert "--cities" in build_argparser().format_help()  # argparse %-formats every option's help
    done = subprocess.run([sys.executable, "-m", "meta_sim.farm.worker", "--help"], capture_output=True, text=True)
    assert done.returncode == 0 and "--shard" in done.stdout


def _population(path, designs_counts):
    from meta_sim.sim.presets import DesignPreset, save_preset

    designs = [{"design": d, "count": c} for d, c in designs_counts]
    return save_preset(path, DesignPreset(kind="population", name="p", design_space="rooftops-v1",
                                          design=designs[0]["design"], designs=designs))


def test_sample_population_follows_the_counts_and_rejects_to_uniform():
    from meta_sim.render.jobs import sample_population

    space = DesignSpace.load()
    a = {"flat_roof": space.parameters[0].choices[0], "sloped_roof": space.parameters[1].choices[0]}
    b = {"flat_roof": space.parameters[0].choices[1], "sloped_roof": space.parameters[1].choices[1]}
    drawn = sample_population(space, [a, b], [3, 1], 2000, 0.0, seed=4)
    assert {tuple(d.values()) for d in drawn} == {tuple(a.values()), tuple(b.values())}
    assert abs(sum(d == a for d in drawn) / 2000 - 0.75) < 0.04
    assert drawn == sample_population(space, [a, b], [3, 1], 2000, 0.0, seed=4)
    assert drawn[:10] == sample_population(space, [a, b], [3, 1], 10, 0.0, seed=4)
    mixed = sample_population(space, [a, b], [3, 1], 2000, 0.25, seed=4)
    others = [d for d in mixed if d not in (a, b)]
    assert 0.2 < len(others) / 2000 < 0.3  # a uniform draw is rarely a or b


def test_render_from_a_population_records_the_sampled_designs(tmp_path, bank):
    space = DesignSpace.load()
    a = {"flat_roof": space.parameters[0].choices[2], "sloped_roof": space.parameters[1].choices[3]}
    b = {"flat_roof": space.parameters[0].choices[5], "sloped_roof": space.parameters[1].choices[1]}
    population = _population(tmp_path / "population.json", [(a, 2), (b, 1)])
    result = _cli("render", "--population", population, "--images", 3, "-r", 0, "--seed", 2, "--cities", 2,
                  "--tiles", 1, "--tile-px", 32, "--gsd", 3.6, "--out", tmp_path / "out")
    assert result.exit_code == 0, result.output
    jobs = json.loads((tmp_path / "out" / "designs.json").read_text())["jobs"]
    assert len(jobs) == 3 and all(job["design"] in (a, b) for job in jobs)
    assert all((tmp_path / "out" / job["tiles"][0]).is_file() for job in jobs)
    group = tmp_path / "group.json"
    group.write_text(population.read_text().replace('"population"', '"group"', 1))
    bad = _cli("render", "--population", group, "--tiles", 1, "--tile-px", 32, "--gsd", 3.6, "--out", tmp_path / "bad")
    assert bad.exit_code == 2 and "not a population preset" in bad.output
    assert not (tmp_path / "bad").exists()


@pytest.mark.parametrize("preset", ["fast", "balanced"])
def test_a_sensor_keeps_a_white_roof_from_clipping_and_leaves_the_labels(space, bank, tmp_path, preset):
    from meta_sim.sim.sensor import get_sensor

    design = {"flat_roof": "flat-membrane-white-tpo", "sloped_roof": 0}
    _, plain = _render(space, [bank], tmp_path / "plain", design, preset, n_tiles=1)
    summary, sensed = _render(space, [bank], tmp_path / "sensed", design, preset, n_tiles=1,
                              sensor=get_sensor("satellite"))

    def clipped(tile):
        roof = tile.roof_class == 1
        assert roof.sum() > 100
        return float((linear_to_srgb(tile.rgb)[roof].max(axis=1) >= 254.5 / 255).mean())

    assert clipped(plain[0]) <= 0.01 and clipped(sensed[0]) <= 0.01  # the preset's tone curve, the sensor's
    for name in ("building", "roof_class", "instance"):
        assert np.array_equal(getattr(plain[0], name), getattr(sensed[0], name))
    assert sensed[0].meta["sensor"]["name"] == "satellite" and "sensor" not in plain[0].meta
    sun = plain[0].meta["sun"]  # drawn per city: elevation 30-60 degrees, any azimuth
    assert 30 <= sun["elevation_deg"] <= 60 and 0 <= sun["azimuth_deg"] < 360 and sensed[0].meta["sun"] == sun
    jittered_summary, jittered = _render(space, [bank], tmp_path / "jittered", design, preset, n_tiles=1,
                                         roof_jitter=0.8)
    assert jittered[0].meta["roof_jitter"] == 0.8 and np.array_equal(jittered[0].instance, plain[0].instance)
    ground = plain[0].building == 0
    assert np.array_equal(jittered[0].rgb[ground], plain[0].rgb[ground])
    assert not np.array_equal(jittered[0].rgb[~ground], plain[0].rgb[~ground])
    _, covered = _render(space, [bank], tmp_path / "covered", design, preset, n_tiles=1, ground="mixed")
    assert covered[0].meta["ground"] == "mixed" and np.array_equal(covered[0].instance, plain[0].instance)
    assert np.array_equal(covered[0].roof_class, plain[0].roof_class)
    assert np.abs(covered[0].rgb[ground] - plain[0].rgb[ground]).mean() > 0.01
    assert covered[0].rgb[ground].std(axis=0).mean() > plain[0].rgb[ground].std(axis=0).mean()
    # a tile rendered without the sensor is not taken for one with it
    again, _ = _render(space, [bank], tmp_path / "plain", design, preset, n_tiles=1, sensor=get_sensor("drone"))
    assert again.written == 1 and again.skipped == 0


def test_a_space_declaring_appearance_renders_each_design_with_its_look(space, bank, tmp_path):
    from meta_sim.sim.appearance import Appearance

    look_space = DesignSpace.from_dict({**space.to_dict(), "name": "look", "parameters": [
        *space.to_dict()["parameters"],
        {"name": "ground", "type": "categorical", "appearance": "ground", "choices": ["plain", "arid"]},
        {"name": "greenness", "type": "continuous", "appearance": "greenness", "low": 0.0, "high": 1.0},
        {"name": "sun", "type": "continuous", "appearance": "sun_elevation_deg", "low": 30, "high": 80},
        {"name": "sensor", "type": "categorical", "appearance": "sensor", "choices": ["none", "drone"]},
        {"name": "light", "type": "continuous", "appearance": "brightness", "low": 0.5, "high": 1.0}]})
    base = {"flat_roof": 5, "sloped_roof": 9}
    lush = {**base, "ground": "plain", "greenness": 1.0, "sun": 80.0, "sensor": "none", "light": 1.0}
    dry = {**base, "ground": "arid", "greenness": 0.0, "sun": 30.0, "sensor": "drone", "light": 1.0}
    settings = RenderSettings(space=look_space, banks=[bank], preset=get_preset("fast"), out_dir=tmp_path,
                              n_tiles=1, **SMALL)
    jobs = [single_job(look_space, look_space.validate(d), SEED) for d in (lush, dry)]
    summary = render_jobs(jobs, settings)
    assert summary.written == 2 and summary.cities == 2  # the ground and the sun belong to the scene
    wet, arid = (tiles.read_tile(tmp_path / f"{job.name}_t00.exr") for job in jobs)
    assert wet.meta["sun"]["elevation_deg"] == 80.0 and arid.meta["sun"]["elevation_deg"] == 30.0
    assert wet.meta["sun"]["azimuth_deg"] == arid.meta["sun"]["azimuth_deg"]  # the city's own
    assert "sensor" not in wet.meta and arid.meta["sensor"]["name"] == "drone"
    assert arid.meta["ground"] == "arid" and wet.meta["greenness"] == 1.0 and arid.meta["greenness"] == 0.0
    assert np.array_equal(wet.instance, arid.instance) and np.array_equal(wet.roof_class, arid.roof_class)
    ground = (wet.building == 0)
    green = wet.rgb[ground].mean(axis=0)
    brown = arid.rgb[ground].mean(axis=0)
    assert green[1] > green[0] and brown[0] > brown[1]  # green lawn against dry soil
    # a longer shadow at a low sun: darker ground pixels next to buildings
    assert (linear_luma(arid.rgb)[ground] < 0.5 * np.median(linear_luma(arid.rgb)[ground])).mean() > \
        (linear_luma(wet.rgb)[ground] < 0.5 * np.median(linear_luma(wet.rgb)[ground])).mean()
    # rendering again skips both; a header is what the design's appearance asks for
    assert render_jobs(jobs, settings).skipped == 2
    assert Appearance().with_design(look_space, jobs[1].design).header()["ground"] == "arid"
    # brightness scales the light of the render only (same scene, so the one city is reused)
    dim = single_job(look_space, look_space.validate({**lush, "light": 0.5}), SEED)
    assert render_jobs([dim], settings).written == 1
    darker = tiles.read_tile(tmp_path / f"{dim.name}_t00.exr")
    assert darker.meta["brightness"] == 0.5 and "brightness" not in wet.meta
    below_knee = wet.rgb.max(axis=-1) < get_preset("fast").tone[0]  # where the tone curve is the identity
    assert below_knee.mean() > 0.5
    assert np.allclose(darker.rgb[below_knee], wet.rgb[below_knee] * 0.5, atol=2e-3)
    assert (darker.rgb <= wet.rgb + 2e-3).all()


def linear_luma(rgb):
    return rgb @ np.array([0.2126, 0.7152, 0.0722], np.float32)


ALBEDO = {"name": "ground_albedo", "type": "continuous", "appearance": "ground_albedo", "low": 0.4, "high": 1.1}


@pytest.mark.parametrize("ground", ["plain", "mixed"])
def test_ground_albedo_darkens_the_bare_ground_in_the_scene_and_leaves_roofs_and_roads(space, bank, tmp_path,
                                                                                       ground):
    """The same city with its ground's reflectance halved: the bare ground renders at half its linear
    light, roofs and roads as they were; at 1.0 the render is that of a space without the field."""
    albedo_space = DesignSpace.from_dict({**space.to_dict(), "name": "albedo",
                                          "parameters": [*space.to_dict()["parameters"], ALBEDO]})
    design = space.validate(_design(space, 5, 9))
    _, (plain,) = _render(space, [bank], tmp_path / "plain", design, n_tiles=1, ground=ground)
    settings = RenderSettings(space=albedo_space, banks=[bank], preset=get_preset("fast"), out_dir=tmp_path / "a",
                              n_tiles=1, ground=ground, **SMALL)
    jobs = [single_job(albedo_space, {**design, "ground_albedo": a}, SEED) for a in (0.5, 1.0)]
    summary = render_jobs(jobs, settings)
    assert summary.written == 2 and summary.cities == 2  # the albedo is built into the scene
    assert render_jobs(jobs, settings).skipped == 2  # the headers hold what the designs ask for
    dark, same = (tiles.read_tile(tmp_path / "a" / f"{job.name}_t00.exr") for job in jobs)
    assert dark.meta["ground_albedo"] == 0.5 and same.meta["ground_albedo"] == 1.0
    assert "ground_albedo" not in plain.meta
    assert np.array_equal(same.rgb, plain.rgb)
    for name in ("instance", "roof_class", "building"):
        assert np.array_equal(getattr(dark, name), getattr(plain, name))
    px, gsd = SMALL["tile_px"], SMALL["pixel_size_m"]
    layout, (rect,) = layout_for_tiles(SEED, 1, px * gsd, LayoutParams())
    roads = _rasterise_polygons([r.polygon for r in layout.roads], rect, px, gsd)
    crowns = _rasterise_polygons([polygons_disc(t) for t in layout.trees], rect, px, gsd)
    knee = get_preset("fast").tone[0]  # below it the tone curve is the identity
    linear = (plain.rgb.max(axis=-1) < knee) & (dark.rgb.max(axis=-1) < knee)
    bare = _erode((plain.building == 0) & ~roads & ~crowns, 2) & linear
    luma, dark_luma = linear_luma(plain.rgb), linear_luma(dark.rgb)
    lit = bare & (luma > np.median(luma[bare]))  # away from the shadows
    assert lit.sum() > 500
    ratio = dark_luma[lit] / luma[lit]
    assert np.median(ratio) == pytest.approx(0.5, abs=0.02) and (np.abs(ratio - 0.5) < 0.05).mean() > 0.9
    # FXAA blends along edges as far as their contrast reaches (a few pixels along the bright roof outlines),
    # so pixels near a darker ground change too: compare away from the edges
    roofs = _erode(plain.building > 0, 4) & linear
    road = _erode(roads & ~crowns & (plain.building == 0), 2) & linear
    assert roofs.sum() > 300 and road.sum() > 300
    for part in (roofs, road):
        assert np.abs(dark.rgb[part] - plain.rgb[part]).max() < 2e-3
        assert np.mean(dark_luma[part]) / np.mean(luma[part]) == pytest.approx(1.0, abs=0.005)


PAINT = {"name": "roof_paint", "type": "continuous", "appearance": "roof_paint", "low": 0.0, "high": 1.0}


def test_a_declared_roof_paint_share_repaints_roofs_of_the_finished_render_and_records_it(space, bank, tmp_path):
    """A design's roof_paint paints a share of the roofs after the render (one scene for every share), the
    ground and the labels untouched; 0 is the render of a space without the field."""
    paint_space = DesignSpace.from_dict({**space.to_dict(), "name": "paint",
                                         "parameters": [*space.to_dict()["parameters"], PAINT]})
    design = space.validate(_design(space, 5, 9))
    _, (plain,) = _render(space, [bank], tmp_path / "plain", design, n_tiles=1)
    settings = RenderSettings(space=paint_space, banks=[bank], preset=get_preset("fast"), out_dir=tmp_path / "p",
                              n_tiles=1, **SMALL)
    jobs = [single_job(paint_space, {**design, "roof_paint": a}, SEED) for a in (0.0, 1.0)]
    summary = render_jobs(jobs, settings)
    assert summary.written == 2 and summary.cities == 1  # applied to the finished render
    assert render_jobs(jobs, settings).skipped == 2
    same, painted = (tiles.read_tile(tmp_path / "p" / f"{job.name}_t00.exr") for job in jobs)
    assert painted.meta["roof_paint"] == 1.0 and "roof_paint" not in same.meta
    assert np.array_equal(same.rgb, plain.rgb)
    for name in ("instance", "roof_class", "building"):
        assert np.array_equal(getattr(painted, name), getattr(plain, name))
    roofs = (plain.roof_class > 0) & (plain.instance > 0)
    assert np.array_equal(painted.rgb[~roofs], plain.rgb[~roofs])
    hue = np.arctan2(np.sqrt(3) * (painted.rgb[..., 1] - painted.rgb[..., 2]),
                     2 * painted.rgb[..., 0] - painted.rgb[..., 1] - painted.rgb[..., 2])
    means = np.array([np.median(hue[roofs & (plain.instance == k)]) for k in np.unique(plain.instance[roofs])])
    assert len(means) >= 3 and np.ptp(means) > 1.0  # roofs of one texture now differ in colour


SHADOW = {"name": "shadow_depth", "type": "continuous", "appearance": "shadow_depth", "low": 0.3, "high": 0.95}


def test_a_declared_shadow_depth_darkens_cast_shadows_and_leaves_sunlit_ground_as_it_was(space, bank):
    """The same dense town with its shadows deeper: ground the sun lights keeps its brightness and ground in a
    cast shadow keeps 1 - depth of it: in Workbench its shadow intensity, in Cycles the sky's share of the
    light (``quality.cycles_light``). The default depth renders as a space without the field."""
    from meta_sim.blender.scene import CityScene
    from meta_sim.render.loop import resolve_textures
    from meta_sim.sim.quality import SHADOW_DEPTH, cycles_light

    layout, rects = layout_for_tiles(5, 1, 115.2, LayoutParams(style="dense", sloped_share=0.5))
    scene = CityScene(layout, rects, pixel_size_m=0.6, sun_elevation_deg=35.0)
    try:
        scene.set_roofs(resolve_textures(space, space.validate({"flat_roof": "flat-concrete-slab",
                                                                 "sloped_roof": "sloped-seam-grey"}), [bank]))
        _, roof_class = scene.render_labels(scene.rects[0])
        renders = {}
        for preset, depth in (("fast", None), ("fast", SHADOW_DEPTH), ("fast", 0.9), ("balanced", None),
                              ("balanced", 0.9)):
            scene.shadow_depth = depth
            renders[preset, depth] = linear_luma(scene.render_rgb(scene.rects[0], get_preset(preset)))
    finally:
        scene.close()
    assert np.array_equal(renders["fast", SHADOW_DEPTH], renders["fast", None])
    below_knee = np.logical_and.reduce([r < get_preset(p).tone[0] for (p, _), r in renders.items()])
    ground = _erode(roof_class == 0, 2) & below_knee
    # Workbench's shadow takes its intensity's share of all the light: the lit ground stays, the shadowed
    # ground keeps (1 - 0.9) / (1 - default) of its light
    fast = renders["fast", 0.9] / np.maximum(renders["fast", None], 1e-6)
    lit, shade = ground & (np.abs(fast - 1) < 0.02), ground & (fast < 0.5)
    assert lit.sum() > 2000 and shade.sum() > 500, (lit.sum(), shade.sum())
    assert np.median(fast[shade]) == pytest.approx((1 - 0.9) / (1 - SHADOW_DEPTH), abs=0.02)
    # Cycles, on the same lit and shadowed ground: the sun and sky keep their sum (walls hide a little of the
    # sky from the ground near them); a shadow keeps the sky's new share of the old sky (0.28 here) plus the
    # light sunlit walls and ground bounce into it, which grows with the sun (0.45 measured)
    plain, deep = renders["balanced", None], renders["balanced", 0.9]
    sky = cycles_light(np.radians(35.0), 0.9)[1] / cycles_light(np.radians(35.0))[1]
    assert deep[lit].mean() / plain[lit].mean() == pytest.approx(1.0, abs=0.1)
    assert sky - 0.03 < deep[shade].mean() / plain[shade].mean() < 0.6


def test_the_far_plane_just_under_the_ground_cuts_no_shadow_and_no_surface(space, bank):
    """The nadir camera's far plane lies just below the ground, which cuts Workbench's shadow volumes where
    their shadows end: a dense town with roof furniture, trees and cars renders as with the far plane a
    kilometre down (depth rounding may flip a pixel), shadows and all, in the fast and a path-traced preset."""
    from meta_sim.blender.scene import CAMERA_HEIGHT_M, FAR_BELOW_GROUND_M, CityScene
    from meta_sim.render.loop import resolve_textures

    layout, rects = layout_for_tiles(5, 1, 115.2, LayoutParams(**{**CLUTTER_KNOBS, "style": "dense",
                                                                            "roof_furniture": 1.0}))
    scene = CityScene(layout, rects, pixel_size_m=0.6, sun_elevation_deg=35.0)
    try:
        assert scene.camera.data.clip_end == CAMERA_HEIGHT_M + FAR_BELOW_GROUND_M
        scene.set_roofs(resolve_textures(space, space.validate({"flat_roof": "flat-concrete-slab",
                                                                 "sloped_roof": "sloped-seam-grey"}), [bank]))
        renders = {}
        for far in (scene.camera.data.clip_end, CAMERA_HEIGHT_M + 1000.0):
            scene.camera.data.clip_end = far
            for preset in ("fast", "balanced"):
                renders[preset, far] = linear_luma(scene.render_rgb(scene.rects[0], get_preset(preset)))
        _, roof_class = scene.render_labels(scene.rects[0])
    finally:
        scene.close()
    near, deep = CAMERA_HEIGHT_M + FAR_BELOW_GROUND_M, CAMERA_HEIGHT_M + 1000.0
    assert np.array_equal(renders["balanced", near], renders["balanced", deep])
    changed = np.abs(renders["fast", near] - renders["fast", deep]) > 0.02
    assert changed.mean() < 1e-3, changed.mean()
    ground = renders["fast", near][roof_class == 0]
    shaded = ground < 0.5 * np.percentile(ground, 90)
    assert shaded.mean() > 0.1  # the shadows are there


def test_the_ground_albedo_reaches_the_lawn_the_ground_covers_and_the_dirt_tracks_only():
    """What counts as ground: the ground quad's lawn or cover mix and the unpaved tracks' dirt. Walls, roads,
    pavings, yards, pools, cars and foliage keep their images; without the albedo every image is today's."""
    import bpy

    from meta_sim.blender.scene import CITY_TAG, CityScene
    from meta_sim.sim.ground import MIXES

    layout, rects = layout_for_tiles(SEED, 9, 115.2, LayoutParams(**CLUTTER_KNOBS))

    def images(**kw):
        scene = CityScene(layout, [rects[4]], pixel_size_m=1.2, shadow_margin_m=20.0, **kw)
        try:
            out = {}
            for image in bpy.data.images:
                if image.get(CITY_TAG) == scene.key:
                    pixels = np.empty(len(image.pixels), np.float32)
                    image.pixels.foreach_get(pixels)
                    out[image.name] = pixels.reshape(-1, 4)[:, :3]
            return out
        finally:
            scene.close()

    for mix, ground in ((None, "ground"), (MIXES["mixed"], "ground-cover")):
        today, half = images(ground=mix), images(ground=mix, ground_albedo=0.5)
        assert set(today) == set(half) and {ground, "dirt", "wall", "asphalt", "concrete", "yard", "water",
                                             "foliage", "glass"} <= set(today)
        for name, pixels in today.items():
            if name in (ground, "dirt"):
                assert pixels.mean() > 0.1 and np.allclose(half[name], 0.5 * pixels, rtol=1e-5, atol=1e-7), name
            else:
                assert np.array_equal(half[name], pixels), name


def _rasterise_polygons(polygons_, rect, px, gsd):
    """Pixels (row 0 north) whose centres lie inside any of the convex counter-clockwise polygons."""
    x0, y0, x1, y1 = rect
    gx, gy = np.meshgrid(x0 + (np.arange(px) + 0.5) * gsd, y1 - (np.arange(px) + 0.5) * gsd)
    out = np.zeros((px, px), dtype=bool)
    for polygon in polygons_:
        inside = np.ones((px, px), dtype=bool)
        for (ax, ay), (bx, by) in zip(polygon, polygon[1:] + polygon[:1]):
            inside &= (bx - ax) * (gy - ay) - (by - ay) * (gx - ax) >= 0
        out |= inside
    return out


def test_large_buildings_render_labelled_and_a_taller_town_casts_more_shadow(space, bank, tmp_path):
    """A dense town with `large_buildings` renders its halls and blocks of flats labelled as laid out, and the
    same town with `tall_share` 1 (the same footprints, more storeys) darkens more of the ground around them."""
    import dataclasses

    px, gsd, seed = 192, 0.6, 6  # a tile holding five large buildings whole
    tiles_of = {}
    for tall in (0.0, 1.0):
        layout_fields = {"style": "dense", "large_buildings": 1.0, "tall_share": tall}
        town = dataclasses.replace(space, name=f"rooftops-dense-large-{tall:g}", layout=layout_fields)
        _, (tiles_of[tall],) = _render(town, [bank], tmp_path / f"t{tall:g}", _design(space, 5, 9), n_tiles=1,
                                       seed=seed, tile_px=px, pixel_size_m=gsd)
    layout, (rect,) = layout_for_tiles(seed, 1, px * gsd, LayoutParams(style="dense", large_buildings=1.0))
    large = [b for b in layout.buildings  # halls, and blocks larger than any house (12 x 14 m and its roof)
             if b.kind == "industrial" or polygon_area(b.roof_outline) > 12.0 * 14.0 * 1.2]
    ious = []
    for b in large:
        reference = _rasterise_polygons([b.roof_outline], rect, px, gsd)
        if reference.sum() >= 100:
            rendered = tiles_of[0.0].instance == b.id
            ious.append((reference & rendered).sum() / (reference | rendered).sum())
    assert len(ious) >= 3 and min(ious) > 0.9, ious
    largest = np.bincount(tiles_of[0.0].instance.ravel())[1:].max() * gsd ** 2
    assert largest > 12.0 * 14.0 * 1.2, largest  # a roof larger than any house's, in the label pass
    low, high = tiles_of[0.0], tiles_of[1.0]
    # the same footprints seen from straight above (a roof that turns sloped may differ at its edge pixels)
    assert ((low.instance > 0) == (high.instance > 0)).mean() > 0.99
    ground = _erode(low.instance == 0, 1)
    brightness = [t.rgb[ground].mean() for t in (low, high)]
    assert brightness[1] < 0.9 * brightness[0], brightness


def test_a_dense_town_renders_with_turned_buildings_labelled_exactly_and_brown_dirt_tracks(space, bank, tmp_path):
    import dataclasses

    dense = dataclasses.replace(space, name="rooftops-dense", layout={"style": "dense"})
    px, gsd, seed = 192, 0.6, 4
    _, (tile,) = _render(dense, [bank], tmp_path, _design(space, 5, 9), n_tiles=1, seed=seed, tile_px=px,
                         pixel_size_m=gsd)
    layout, (rect,) = layout_for_tiles(seed, 1, px * gsd, LayoutParams(style="dense"))
    turned = [b for b in layout.buildings if b.rotation_deg % 90.0]
    assert len(turned) > 50
    ious = []
    for b in layout.buildings:
        reference = _rasterise_polygons([b.roof_outline], rect, px, gsd)
        if reference.sum() < 30:
            continue
        rendered = tile.instance == b.id
        ious.append((reference & rendered).sum() / (reference | rendered).sum())
    assert len(ious) > 50 and min(ious) > 0.9, sorted(ious)[:5]
    # Dirt tracks render light brown, asphalt grey: pixels of each surface away from roofs, trees and edges.
    asphalt = _rasterise_polygons([r.polygon for r in layout.roads if r.surface == "asphalt"], rect, px, gsd)
    dirt = _rasterise_polygons([r.polygon for r in layout.roads if r.surface == "dirt"], rect, px, gsd)
    covered = (tile.instance > 0) | _rasterise_polygons(
        [((t.x - t.radius_m, t.y - t.radius_m), (t.x + t.radius_m, t.y - t.radius_m),
          (t.x + t.radius_m, t.y + t.radius_m), (t.x - t.radius_m, t.y + t.radius_m)) for t in layout.trees],
        rect, px, gsd)
    dirt_only = _erode(dirt & ~asphalt & ~covered, 1)
    assert dirt_only.sum() > 200
    r, g, b = tile.rgb[dirt_only].mean(axis=0)
    assert r > g > b and r > 1.5 * b, (r, g, b)
    if (_erode(asphalt & ~covered, 1)).sum() > 50:
        ar, ag, ab = tile.rgb[_erode(asphalt & ~covered, 1)].mean(axis=0)
        assert ar < 1.3 * ab and ar < r


def test_render_cli_takes_a_city_style_and_records_it(tmp_path):
    args = ["render", "--design", "flat_roof=1,sloped_roof=1", "--tiles", 1, "--tile-px", 48, "--gsd", 2.4,
            "--seed", 4]
    result = _cli(*args, "--style", "dense=3,suburban=1", "--out", tmp_path / "a")
    assert result.exit_code == 0, result.output
    tile = tiles.read_tile(next((tmp_path / "a").glob("*.exr")))
    assert tile.meta["style"] == "suburban=0.25,dense=0.75" and tile.instance.max() > 0
    again = _cli(*args, "--style", "suburban=1,dense=3", "--out", tmp_path / "a")
    assert "0 tiles written, 1 already done" in again.output  # one spelling of one mix
    plain = _cli(*args, "--out", tmp_path / "b")
    assert plain.exit_code == 0 and "style" not in tiles.read_tile(next((tmp_path / "b").glob("*.exr"))).meta
    bad = _cli(*args, "--style", "slum", "--out", tmp_path / "c")
    assert bad.exit_code == 2 and "'slum' is not a style" in bad.output
    space = DesignSpace.load().to_dict()
    space["layout"] = {"style": "dense"}
    (tmp_path / "space.json").write_text(json.dumps(space))
    twice = _cli(*args, "--space", tmp_path / "space.json", "--style", "industrial", "--out", tmp_path / "d")
    assert twice.exit_code == 2 and "declares a city style already" in twice.output


def _paint(layout, items, rect, px, gsd):
    """Pixels whose centres fall inside any of the items' boxes (row 0 north)."""
    x0, y0, x1, y1 = rect
    gx, gy = np.meshgrid(x0 + (np.arange(px) + 0.5) * gsd, y1 - (np.arange(px) + 0.5) * gsd)
    mask = np.zeros((px, px), dtype=bool)
    for item in items:
        bx0, by0, bx1, by1 = item.bbox
        mask |= (gx > bx0) & (gx < bx1) & (gy > by0) & (gy < by1)
    return mask


def test_clutter_renders_with_the_labels_of_the_bare_city(space, bank, tmp_path):
    """Everything on (real trees, street details, cars, pools, shrubs), one full-size tile: the labels
    are those of the same city without clutter, pools are blue and lane markings show on the road."""
    from dataclasses import replace

    from meta_sim.sim.layout import LayoutParams

    knobs = {"tree_size": "real", "street_details": True, "car_density": 0.8, "pool_share": 1.0,
             "shrub_density": 0.8}
    cluttered = replace(space, name="cluttered", layout={**space.layout, **knobs})
    seed, full = 1, {"tile_px": 384, "pixel_size_m": 0.3}
    settings = RenderSettings(space=cluttered, banks=[bank], preset=get_preset("fast"), out_dir=tmp_path / "on",
                              n_tiles=1, **full)
    render_jobs([single_job(cluttered, cluttered.validate(_design(space, 5, 9)), seed)], settings)
    on = tiles.read_tile(next((tmp_path / "on").glob("*.exr")))
    _, (off,) = _render(space, [bank], tmp_path / "off", _design(space, 5, 9), n_tiles=1, seed=seed, **full)
    assert on.rgb.shape == (384, 384, 3) and np.isfinite(on.rgb).all()
    assert np.array_equal(on.instance, off.instance) and np.array_equal(on.roof_class, off.roof_class)
    assert (on.instance > 0).mean() > 0.05
    layout, rects = layout_for_tiles(seed, 1, 115.2, LayoutParams(**knobs))
    rect = rects[0]
    # Where nothing of the clutter stands, roofs look as without it (trees may shade a few of them).
    roofs = _erode(on.instance > 0, 2)
    same = np.abs(on.rgb - off.rgb).max(axis=-1) < 1e-4
    assert same[roofs].mean() > 0.7
    water = _erode(_paint(layout, layout.pools, rect, 384, 0.3), 3)  # inside the coping
    assert water.sum() > 50
    blue = on.rgb[water & ~_paint(layout, layout.trees, rect, 384, 0.3)]
    assert len(blue) > 20 and np.median(blue[:, 2]) > 2 * np.median(blue[:, 0])
    lines = _paint(layout, layout.markings, rect, 384, 0.3)
    road = _paint(layout, layout.roads, rect, 384, 0.3) & ~_paint(
        layout, [*layout.markings, *layout.cars, *layout.trees], rect, 384, 0.3)
    lines &= ~_paint(layout, [*layout.cars, *layout.trees], rect, 384, 0.3)
    assert lines.sum() > 30 and road.sum() > 1000
    luminance = on.rgb @ np.array([0.2126, 0.7152, 0.0722], np.float32)
    assert np.median(luminance[lines]) > 2.5 * np.median(luminance[road])


@pytest.mark.parametrize("preset", sorted(PRESETS))
def test_white_roofs_do_not_clip_in_any_preset(space, bank, tmp_path, preset):
    """Issue 18 item 5: at most 1% of roof pixels of a white-roof design reach 8-bit white, in every
    preset; without the tone curve most of them do (white roofs render at a linear 1.0-1.8)."""
    design = space.validate({"flat_roof": "flat-membrane-white-tpo", "sloped_roof": "sloped-seam-white"})

    def clipped(render_preset, out):
        settings = RenderSettings(space=space, banks=[bank], preset=render_preset, out_dir=out, n_tiles=1,
                                  tile_px=128)
        tile = tiles.read_tile(render_jobs([single_job(space, design, 3)], settings).paths[0])
        roofs = tile.roof_class > 0
        display = np.floor(np.clip(linear_to_srgb(tile.rgb), 0.0, 1.0) * 255.0 + 0.5)[roofs]
        assert roofs.sum() > 500
        return tile, (display >= 255).any(axis=-1).mean(), np.median(display.max(axis=-1))

    toned = get_preset(preset)
    tile, share, median = clipped(toned, tmp_path / "toned")
    assert tile.meta["tone"] == list(toned.tone) and share <= 0.01
    assert median > 200  # still white, not greyed down
    assert clipped(dataclasses.replace(toned, tone=None), tmp_path / "raw")[1] > 0.3


@pytest.mark.parametrize("style, seed", [("suburban", 1), ("dense", 1)])
def test_roof_furniture_keeps_the_labels_and_shows_on_the_roofs(space, bank, tmp_path, style, seed):
    """One city with and without roof furniture (axis-aligned suburban buildings; turned dense houses,
    most flat ones with water tanks): the instance and roof-class labels are the same, the RGB differs
    where the pieces stand."""
    from dataclasses import replace

    from meta_sim.sim import polygons
    from meta_sim.sim.furniture import roof_furniture

    px, gsd = 192, 0.6
    out = {}
    for name, density in (("off", 0.0), ("on", 1.0)):
        scene = replace(space, name=f"roofs-{name}", layout={"style": style, "roof_furniture": density})
        _, (out[name],) = _render(scene, [bank], tmp_path / name, _design(space, 5, 9), n_tiles=1, seed=seed,
                                  tile_px=px, pixel_size_m=gsd)
    on, off = out["on"], out["off"]
    assert np.array_equal(on.instance, off.instance) and np.array_equal(on.roof_class, off.roof_class)
    assert on.meta["roof_furniture"] == 1.0 and "roof_furniture" not in off.meta
    layout, (rect,) = layout_for_tiles(seed, 1, px * gsd, LayoutParams(style=style))
    outlines, tanks = [], []
    for b in layout.buildings_in_rect(*rect):
        x0, y0, x1, y1 = polygons.bbox(b.footprint)
        for f in roof_furniture(b, seed, 1.0, layout.style_of(b)):
            if f.kind != "parapet":
                outlines.append(polygons.rotate(f.outline, (x0 + x1) / 2, (y0 + y1) / 2, b.rotation_deg))
                if f.kind == "tank":
                    tanks.append(outlines[-1])
    pieces = _rasterise_polygons(outlines, rect, px, gsd)
    changed = np.abs(on.rgb - off.rgb).max(axis=-1) > 0.02
    assert pieces.sum() > 100 and changed[pieces].mean() > 0.8
    if style == "dense":
        on_tanks = _rasterise_polygons(tanks, rect, px, gsd)
        assert len(tanks) > 20 and on_tanks.sum() > 50 and changed[on_tanks].mean() > 0.8
    assert (pieces <= (on.instance > 0)).all()  # every piece stands on a roof
    roofs = on.instance > 0
    assert 0.03 < changed[roofs].mean() < 0.6  # furniture covers parts of the roofs, not whole roofs


def _styled_render(space, bank, out, name, layout, extra=(), design=None, seed=2):
    """One full-size tile of a styled city; `extra` parameters are added to the space."""
    from dataclasses import replace

    styled = DesignSpace.from_dict({**space.to_dict(), "name": name, "parameters": [
        *space.to_dict()["parameters"], *extra]}) if extra else space
    styled = replace(styled, layout=layout)
    settings = RenderSettings(space=styled, banks=[bank], preset=get_preset("fast"), out_dir=out, n_tiles=1,
                              tile_px=384, pixel_size_m=0.3)
    job = single_job(styled, styled.validate({**_design(space, 5, 9), **(design or {})}), seed)
    render_jobs([job], settings)
    return tiles.read_tile(out / f"{job.name}_t00.exr")


CLUTTER_KNOBS = {"tree_size": "real", "street_details": True, "car_density": 0.8, "pool_share": 1.0,
                 "shrub_density": 0.8}


def test_a_dense_town_with_clutter_keeps_its_labels_and_greenness_tints_the_tree_crowns(space, bank, tmp_path):
    green = {"name": "greenness", "type": "continuous", "appearance": "greenness", "low": 0.0, "high": 1.0}
    layout = {"style": "dense", **CLUTTER_KNOBS}
    lush, dry = (_styled_render(space, bank, tmp_path / str(g), "dense-clutter", layout, [green], {"greenness": g})
                 for g in (1.0, 0.0))
    bare = _styled_render(space, bank, tmp_path / "bare", "dense-bare", {"style": "dense"})
    for tile in (lush, dry):
        assert np.array_equal(tile.instance, bare.instance) and np.array_equal(tile.roof_class, bare.roof_class)
    layout_, (rect,) = layout_for_tiles(2, 1, 115.2, LayoutParams(style="dense", **CLUTTER_KNOBS))
    crowns = _erode(_rasterise_polygons([polygons_disc(t) for t in layout_.trees], rect, 384, 0.3), 2)
    crowns &= ~_paint(layout_, layout_.cars, rect, 384, 0.3) & (bare.instance == 0)
    assert crowns.sum() > 300

    def redness(tile):
        r, g, _ = np.median(tile.rgb[crowns], axis=0)
        return r / g
    assert redness(dry) > 1.5 * redness(lush)  # dry-season crowns turn olive and brown, as the lawn does
    assert not np.array_equal(lush.rgb, bare.rgb)


def polygons_disc(tree):
    from meta_sim.sim import polygons

    return polygons.disc(tree.x, tree.y, tree.radius_m)


def test_downtown_with_clutter_keeps_its_labels_and_shows_markings_cars_and_street_trees(space, bank, tmp_path):
    layout = {"style": "downtown", **CLUTTER_KNOBS}
    on = _styled_render(space, bank, tmp_path / "on", "downtown-clutter", layout)
    bare = _styled_render(space, bank, tmp_path / "bare", "downtown-bare", {"style": "downtown"})
    assert np.array_equal(on.instance, bare.instance) and np.array_equal(on.roof_class, bare.roof_class)
    layout_, (rect,) = layout_for_tiles(2, 1, 115.2, LayoutParams(style="downtown", **CLUTTER_KNOBS))
    assert len(layout_.cars) > 25 and len(layout_.trees) > 20
    above = [*layout_.cars, *layout_.trees]
    lines = _erode(_rasterise_polygons([m.polygon for m in layout_.markings], rect, 384, 0.3), 0)
    lines &= ~_paint(layout_, above, rect, 384, 0.3)
    road = _rasterise_polygons([r.polygon for r in layout_.roads], rect, 384, 0.3)
    road &= ~_paint(layout_, [*above, *layout_.markings], rect, 384, 0.3)
    assert lines.sum() > 100 and road.sum() > 1000
    luminance = linear_luma(on.rgb)
    assert np.median(luminance[lines]) > 2.5 * np.median(luminance[road])


def test_the_scene_of_a_styled_clutter_city_builds_only_what_the_tiles_see():
    from meta_sim.blender.scene import CityScene

    layout, rects = layout_for_tiles(SEED, 9, 115.2, LayoutParams(style={"dense": 0.5, "downtown": 0.5},
                                                                  **CLUTTER_KNOBS))
    scene = CityScene(layout, [rects[4]], pixel_size_m=1.2, shadow_margin_m=20.0)
    try:
        assert 0 < scene.n_trees < len(layout.trees) / 2
        for name in ("cars", "pavings", "markings", "shrubs"):
            assert 0 < scene.n_details[name] < len(getattr(layout, name)) / 2, name
    finally:
        scene.close()


def test_open_water_lies_over_the_roads_in_its_colour_and_takes_away_the_houses_it_covers(space, bank, tmp_path):
    from meta_sim.sim.water import WATER_COLOURS

    town = {"style": "dense", "tree_size": "real", "car_density": 0.5}
    wet = _styled_render(space, bank, tmp_path / "wet", "dense-water", {**town, "water_share": 0.5})
    dry = _styled_render(space, bank, tmp_path / "dry", "dense-dry", town)
    layout, (rect,) = layout_for_tiles(2, 1, 115.2, LayoutParams(**town, water_share=0.5))
    water = _rasterise_polygons([polygons_disc(w) for w in layout.waters], rect, 384, 0.3)
    water = _erode(water, 2) & ~_paint(layout, layout.trees, rect, 384, 0.3)  # crowns may reach over the bank
    assert 0.2 < water.mean() < 0.9, water.mean()
    assert not (wet.instance[water] > 0).any() and (dry.instance[water] > 0).sum() > 1000  # houses gone, labelled
    assert ((wet.instance > 0) <= (dry.instance > 0)).all()  # nothing new is built
    roads = water & _rasterise_polygons([r.polygon for r in layout.roads], rect, 384, 0.3)
    assert roads.sum() > 500
    colour = np.asarray(WATER_COLOURS[layout.waters[0].colour])
    med_road, med_open = np.median(wet.rgb[roads], axis=0), np.median(wet.rgb[water & ~roads], axis=0)
    assert np.allclose(med_road, med_open, rtol=0.1)  # the roads end at the bank: water lies over them
    assert np.allclose(med_open / med_open.sum(), colour / colour.sum(), atol=0.05)  # in the water's colour
    assert np.std(linear_luma(wet.rgb[water])) < 0.5 * np.std(linear_luma(dry.rgb[water]))


def test_the_scene_builds_only_the_water_the_tiles_see():
    from meta_sim.blender.scene import CityScene

    layout, rects = layout_for_tiles(SEED, 25, 115.2, LayoutParams(style="dense", water_share=0.4))
    scene = CityScene(layout, [rects[12]], pixel_size_m=1.2, shadow_margin_m=20.0)
    try:
        assert len(layout.waters) > 10 and scene.n_details["waters"] < len(layout.waters) / 2
    finally:
        scene.close()


def test_overhead_v3_renders_a_few_houses_among_trees_at_its_low_building_density(bank, tmp_path):
    # The sparse end overhead-v2 cannot reach (its building density starts at 0.4): a suburban town at
    # density 0.08 has a fraction of the buildings of one at 0.9, and more of it is green.
    v3 = DesignSpace.load("overhead-v3")
    base = {"flat_roof": "flat-concrete-slab", "sloped_roof": "sloped-clay-red", "style": "suburban",
            "ground": "suburban", "ground_albedo": 0.7, "greenness": 1.0, "tree_density": 1.0, "sun_elevation": 60.0,
            "brightness": 0.7, "roof_jitter": 0.5, "sensor": "satellite"}
    settings = RenderSettings(space=v3, banks=[bank], preset=get_preset("fast"), out_dir=tmp_path, n_tiles=4,
                              **SMALL)
    jobs = [single_job(v3, v3.validate({**base, "building_density": d}), SEED) for d in (0.08, 0.9)]
    assert render_jobs(jobs, settings).written == 8
    sparse, built = ([tiles.read_tile(tmp_path / f"{job.name}_t{j:02d}.exr") for j in range(4)] for job in jobs)

    def share(tile_list, of):
        return float(np.mean([of(t).mean() for t in tile_list]))

    buildings = [share(t, lambda t: t.building > 0) for t in (sparse, built)]
    green = [share(t, lambda t: (t.building == 0) & (t.rgb[..., 1] > 1.1 * t.rgb[..., 0])) for t in (sparse, built)]
    assert buildings[0] < 0.08 and buildings[0] < buildings[1] / 3, buildings
    assert green[0] > green[1], green


def _plane_and_cone_scene(albedo: float):
    """A fresh Blender session with a flat square and a cone of 72 faces (slope 0.6) seen from above, lit by
    Workbench's studio light; returns a render function (pixel brightness at world x, y) and the shading."""
    import bmesh
    import bpy

    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    mesh, bm = bpy.data.meshes.new("shapes"), bmesh.new()
    tip = bm.verts.new((0.0, 0.0, 0.6))
    ring = [bm.verts.new((np.cos(2 * np.pi * k / 72), np.sin(2 * np.pi * k / 72), 0.0)) for k in range(72)]
    for k in range(72):
        bm.faces.new([ring[k], ring[(k + 1) % 72], tip])
    bm.faces.new([bm.verts.new(c) for c in ((1.2, -1.4, 0), (1.4, -1.4, 0), (1.4, -1.2, 0), (1.2, -1.2, 0))])
    bm.to_mesh(mesh)
    scene.collection.objects.link(bpy.data.objects.new("shapes", mesh))
    camera = bpy.data.cameras.new("nadir")
    camera.type, camera.ortho_scale = "ORTHO", 3.0
    camera_obj = bpy.data.objects.new("nadir", camera)
    camera_obj.location = (0.0, 0.0, 10.0)
    scene.collection.objects.link(camera_obj)
    scene.camera = camera_obj
    scene.render.engine = "BLENDER_WORKBENCH"
    scene.render.resolution_x = scene.render.resolution_y = 300
    scene.view_settings.view_transform = "Standard"
    scene.render.image_settings.file_format, scene.render.image_settings.color_depth = "OPEN_EXR", "32"
    shading = scene.display.shading
    shading.light, shading.color_type, shading.single_color = "STUDIO", "SINGLE", (albedo,) * 3
    shading.show_specular_highlight = False  # as the fast preset renders

    def render(path):
        scene.render.filepath = str(path)
        bpy.ops.render.render(write_still=True)
        image = bpy.data.images.load(str(path), check_existing=False)
        pixels = np.array(image.pixels[:]).reshape(300, 300, 4)[..., 0] / albedo  # row 0 at the bottom
        bpy.data.images.remove(image)
        return lambda x, y: float(pixels[int((y / 3 + 0.5) * 300), int((x / 3 + 0.5) * 300)])

    return render, shading


def test_the_sun_studio_light_lights_flat_ground_as_the_studio_light_and_slopes_from_the_sun(tmp_path):
    """The Blender facts `quality.sun_studio_light` rests on, measured: a flat surface under Workbench's studio
    light (STUDIO_FLAT per unit albedo), and under the sun's studio light as bright at any elevation; each face
    of a cone lit as the sun and sky light it (ambient + WORKBENCH_DIFFUSE x sun x cos), its brightest side
    towards the sun whatever the azimuth, so the studio light's axes are mapped to the world's right."""
    import bpy

    from meta_sim.sim.quality import SKY_SHARE, STUDIO_FLAT, WORKBENCH_DIFFUSE, sun_studio_light

    render, shading = _plane_and_cone_scene(0.4)
    shading.studio_light, shading.use_world_space_lighting = "Default", False
    assert render(tmp_path / "studio.exr")(1.3, -1.3) == pytest.approx(STUDIO_FLAT, rel=0.005)
    prefs = bpy.context.preferences
    for elevation_deg, azimuth_deg in ((45, 0), (30, 120), (70, 250)):
        elevation, azimuth = np.radians(elevation_deg), np.radians(azimuth_deg)
        path = tmp_path / f"sun-{azimuth_deg}.sl"
        path.write_text(sun_studio_light(elevation, azimuth))
        light = prefs.studio_lights.load(str(path), "STUDIO")
        try:
            shading.studio_light, shading.use_world_space_lighting = light.name, True
            at = render(tmp_path / f"sun-{azimuth_deg}.exr")
        finally:
            prefs.studio_lights.remove(light)
        assert at(1.3, -1.3) == pytest.approx(STUDIO_FLAT, rel=0.005)
        to_sun = np.array([np.cos(elevation) * np.sin(azimuth), -np.cos(elevation) * np.cos(azimuth),
                           np.sin(elevation)])
        angles = 2 * np.pi * (np.arange(72) + 0.5) / 72
        faces = np.array([at(0.45 * np.cos(a), 0.45 * np.sin(a)) for a in angles])
        normals = np.stack([0.6 * np.cos(angles), 0.6 * np.sin(angles), np.ones(72)], axis=1)
        normals /= np.linalg.norm(normals, axis=1, keepdims=True)
        sun = (1 - SKY_SHARE) * STUDIO_FLAT / (WORKBENCH_DIFFUSE * np.sin(elevation))
        expected = SKY_SHARE * STUDIO_FLAT + WORKBENCH_DIFFUSE * sun * np.clip(normals @ to_sun, 0.0, None)
        assert np.abs(faces - expected).max() < 0.01, (elevation_deg, azimuth_deg)
        brightest = angles[np.argmax(faces)]
        towards_sun = np.arctan2(to_sun[1], to_sun[0])
        assert abs(np.angle(np.exp(1j * (brightest - towards_sun)))) < np.radians(6)


def test_sun_studio_light_files_name_the_sun_in_studio_light_axes_and_refuse_a_sun_below_the_horizon():
    from meta_sim.sim.quality import SKY_SHARE, STUDIO_FLAT, sun_studio_light

    text = sun_studio_light(np.radians(90), 0.0)  # overhead: studio light y is up
    values = dict(line.split(" ") for line in text.splitlines()[1:])
    assert text.startswith("version 1\n") and float(values["light_ambient.x"]) == pytest.approx(SKY_SHARE * STUDIO_FLAT,
                                                                                               abs=1e-6)
    assert [float(values[f"light[0].vec.{c}"]) for c in "xyz"] == pytest.approx([0.0, 1.0, 0.0], abs=1e-6)
    assert all(values[f"light[{i}].flag"] == "0" for i in (1, 2, 3))
    south = dict(line.split(" ") for line in sun_studio_light(np.radians(30), 0.0).splitlines()[1:])
    assert [float(south[f"light[0].vec.{c}"]) for c in "xyz"] == pytest.approx([0.0, 0.5, np.cos(np.radians(30))],
                                                                               abs=1e-6)  # z: south
    for bad in (0.0, -0.1):
        with pytest.raises(MetaSimError, match="above the horizon"):
            sun_studio_light(bad, 0.0)


def test_the_fast_preset_shows_sloped_roofs_sunlit_on_the_suns_side_in_a_richer_city(space, bank):
    """Issue 18: a city of the richer scene (here a dense town) is lit by its sun and sky in the fast preset:
    across its sloped roofs the brightness rises towards the sun (each roof's brightness gradient, summed, points
    within 30 degrees of the sun's azimuth), while flat roofs stay as bright as under the studio light, which
    the same city is rendered with too."""
    from meta_sim.blender.scene import CityScene
    from meta_sim.render.loop import resolve_textures

    layout, rects = layout_for_tiles(5, 1, 115.2, LayoutParams(style="dense", sloped_share=0.8))
    assert layout.params.richer_scene
    scene = CityScene(layout, rects, pixel_size_m=0.6)
    try:
        assert scene.sun_lit
        scene.set_roofs(resolve_textures(space, space.validate({"flat_roof": "flat-concrete-slab",
                                                                 "sloped_roof": "sloped-seam-grey"}), [bank]))
        instance, roof_class = scene.render_labels(scene.rects[0])
        sunlit = scene.render_rgb(scene.rects[0], get_preset("fast")).mean(axis=-1)
        scene.sun_lit = False
        studio = scene.render_rgb(scene.rects[0], get_preset("fast")).mean(axis=-1)
        azimuth = np.radians(scene.sun["azimuth_deg"])
    finally:
        scene.close()
    flat = roof_class == 1
    assert flat.sum() > 500 and np.median(sunlit[flat]) == pytest.approx(np.median(studio[flat]), rel=0.05)
    rows, cols = np.indices(instance.shape)
    gradients = {"sunlit": np.zeros(2), "studio": np.zeros(2)}
    buildings = 0
    for b in np.unique(instance[roof_class == 2]):
        on = (instance == b) & (roof_class == 2)
        if on.sum() < 60:
            continue
        buildings += 1
        east, north = cols[on] - cols[on].mean(), rows[on].mean() - rows[on]  # row 0 is north
        design = np.stack([np.ones(on.sum()), east, north], axis=1)
        for name, image in (("sunlit", sunlit), ("studio", studio)):
            slope = np.linalg.lstsq(design, image[on], rcond=None)[0][1:]
            gradients[name] += slope / (np.linalg.norm(slope) + 1e-12)
    assert buildings >= 8, buildings
    towards_sun = np.arctan2(-np.cos(azimuth), np.sin(azimuth))
    direction = np.arctan2(gradients["sunlit"][1], gradients["sunlit"][0])
    assert abs(np.angle(np.exp(1j * (direction - towards_sun)))) < np.radians(30)
    assert np.linalg.norm(gradients["sunlit"]) > 0.5 * buildings  # most roofs agree


def test_fast_shadows_fall_away_from_each_citys_sun_and_lit_ground_keeps_its_brightness(space, bank, tmp_path):
    """The fast preset's shadows come from the city's sun, whatever its azimuth: the ground just beyond the
    buildings on the side away from the sun is dark far more often than on the side facing it
    (Workbench's shadow direction mapped to its light frame, ``quality.workbench_direction``). Given the
    world vector, the sun stood below the horizon for most azimuths: no cast shadows, and every flat surface
    at half its light. And ground the sun lights is as bright under a low sun as under a high one
    (Workbench's shading ramp off, ``quality.SHADOW_SHIFT``; with it a 30-degree sun darkened it by a third)."""
    from scipy import ndimage

    def dark_share(tile, step):
        """The share of dark ground 3 pixels (3.6 m) from the buildings in the (row, column) direction ``step``."""
        luma = linear_luma(tile.rgb)
        buildings = tile.building > 0
        ground = ~ndimage.binary_dilation(buildings, iterations=1)
        dark = luma < 0.7 * np.percentile(luma[ground], 90)  # below the lit lawn
        moved = ndimage.shift(buildings.astype(float), step * 3.0, order=0) > 0.5
        return dark[moved & ground].mean()

    azimuths, contrast = [], []
    for seed in (3, 4, 5, 6, 7):
        _, (tile,) = _render(space, [bank], tmp_path / str(seed), _design(space, 5, 9), n_tiles=1, seed=seed)
        azimuth = np.radians(tile.meta["sun"]["azimuth_deg"])
        azimuths.append(azimuth)
        # row 0 is north; the sun's direction on the ground is (sin a, -cos a) (east, north), azimuth 0 south
        away = np.array([-np.cos(azimuth), -np.sin(azimuth)])
        contrast.append(dark_share(tile, away) - dark_share(tile, -away))
    assert np.ptp(np.array(azimuths) % (2 * np.pi)) > np.pi / 2  # suns from several sides
    assert min(contrast) > 0.0 and np.mean(contrast) > 0.3, contrast

    sun_space = DesignSpace.from_dict({**space.to_dict(), "name": "sun", "parameters": [
        *space.to_dict()["parameters"],
        {"name": "sun", "type": "continuous", "appearance": "sun_elevation_deg", "low": 30, "high": 80}]})
    settings = RenderSettings(space=sun_space, banks=[bank], preset=get_preset("fast"), out_dir=tmp_path / "sun",
                              n_tiles=1, **SMALL)
    jobs = [single_job(sun_space, sun_space.validate({**_design(space, 5, 9), "sun": e}), SEED) for e in (30.0, 80.0)]
    render_jobs(jobs, settings)
    low, high = (tiles.read_tile(tmp_path / "sun" / f"{job.name}_t00.exr") for job in jobs)
    knee = get_preset("fast").tone[0]  # below it the tone curve is the identity
    lit = (low.rgb.max(axis=-1) < knee) & (high.rgb.max(axis=-1) < knee) & (low.building == 0)
    for tile in (low, high):
        luma = linear_luma(tile.rgb)
        lit &= luma > 0.7 * np.percentile(luma[tile.building == 0], 90)
    assert lit.sum() > 1000
    ratio = linear_luma(low.rgb)[lit] / linear_luma(high.rgb)[lit]
    assert np.median(ratio) == pytest.approx(1.0, abs=0.01)


VIEW = {"name": "view_height", "type": "continuous", "appearance": "view_height_m", "low": 60.0, "high": 800.0}


def test_a_perspective_view_shows_walls_and_leans_roofs_out_from_each_tiles_centre(space, bank, tmp_path,
                                                                                    monkeypatch):
    """A design's view height puts a camera that high over each tile's centre: the ground keeps its pixel
    size, roofs lean out from the centre (the farther and the taller, the more), walls show and are labelled
    as their building, RGB and labels line up; each tile is one render of its own, and the header records it."""
    from meta_sim.blender.scene import CityScene

    view_space = DesignSpace.from_dict({**space.to_dict(), "name": "view",
                                        "parameters": [*space.to_dict()["parameters"], VIEW]})
    design = space.validate(_design(space, 5, 9))
    params = dict(style="dense", building_density=1.0)
    cluttered = DesignSpace.from_dict({**view_space.to_dict(), "layout": params})
    framed = []
    real_render = CityScene.render_rgb
    monkeypatch.setattr(CityScene, "render_rgb", lambda self, rect, preset: framed.append(rect) or
                        real_render(self, rect, preset))
    settings = RenderSettings(space=cluttered, banks=[bank], preset=get_preset("fast"), out_dir=tmp_path / "v",
                              n_tiles=2, tile_px=192, pixel_size_m=0.6)
    jobs = [single_job(cluttered, {**design, "view_height": h}, SEED) for h in (60.0, 800.0)]
    summary = render_jobs(jobs, settings)
    assert summary.written == 4 and summary.cities == 2  # the view is built into the scene
    assert len(framed) == 4 and all(r.x1 - r.x0 == pytest.approx(115.2) for r in framed)  # tile by tile
    flat = DesignSpace.from_dict({**space.to_dict(), "name": "flat", "layout": params})
    ortho_settings = dataclasses.replace(settings, space=flat, out_dir=tmp_path / "o")
    render_jobs([single_job(flat, design, SEED)], ortho_settings)
    ortho = tiles.read_tile(tmp_path / "o" / f"{single_job(flat, design, SEED).name}_t00.exr")
    low, high = (tiles.read_tile(tmp_path / "v" / f"{job.name}_t00.exr") for job in jobs)
    assert low.meta["view_height_m"] == 60.0 and "view_height_m" not in ortho.meta
    walls = [((t.instance > 0) & (t.roof_class == 0)).mean() for t in (ortho, high, low)]
    assert walls[0] == 0.0 and walls[1] < 0.02 < 0.1 < walls[2], walls  # walls show from a low view

    def lean(tile):
        """Per building whose roof lies whole inside both views (40+ pixels), how much farther from the
        tile's centre its roof is in ``tile`` than in the orthographic view: H / (H - roof height)."""
        out = []
        for i in np.unique(ortho.instance[ortho.roof_class > 0]):
            here, there = (np.nonzero((t.instance == i) & (t.roof_class > 0)) for t in (tile, ortho))
            if min(len(here[0]), len(there[0])) < 40 or any(min(a.min(), 191 - a.max()) < 2 for a in (*here, *there)):
                continue
            radius = [np.hypot(rows.mean() - 95.5, cols.mean() - 95.5) for rows, cols in (here, there)]
            if radius[1] > 30:
                out.append(radius[0] / radius[1])
        return np.array(out)
    steep, far = lean(low), lean(high)
    assert len(steep) > 5 and len(far) > 5
    assert 1.04 < np.median(steep) < 1.4 and np.median(far) == pytest.approx(1.0, abs=0.015)
    # Near the centre a photo looks straight down: there the two views agree.
    centre = (slice(80, 112), slice(80, 112))
    agree = (low.building[centre] > 0) == (ortho.building[centre] > 0)
    assert agree.mean() > 0.8
    # RGB and labels line up: the image changes most where the labels do (roof to wall, wall to ground)
    luma = linear_luma(low.rgb)
    step = np.hypot(*np.gradient(luma))
    label = low.instance.astype(np.int64) * 3 + low.roof_class
    edge = np.zeros(label.shape, bool)
    edge[:-1] |= label[:-1] != label[1:]
    edge[:, :-1] |= label[:, :-1] != label[:, 1:]
    inner = (slice(4, -4), slice(4, -4))
    shifted = [step[inner][np.roll(edge, shift, axis=(0, 1))[inner]].mean()
               for shift in ((3, 0), (-3, 0), (0, 3), (0, -3))]
    assert step[inner][edge[inner]].mean() > 1.05 * max(shifted)  # the labels three pixels off fit worse


GRAIN = {"name": "grain", "type": "continuous", "appearance": "ground_grain", "low": 0.0, "high": 1.0}


@pytest.mark.parametrize("ground", ["plain", "arid"])
def test_a_declared_ground_grain_roughens_the_bare_ground_and_leaves_roofs_and_labels(space, bank, tmp_path,
                                                                                       ground):
    """A design's ground grain gives the bare ground (the plain lawn too) its fine texture in the scene; roofs
    and labels stay as they were, and the header records it."""
    grain_space = DesignSpace.from_dict({**space.to_dict(), "name": "grain",
                                         "parameters": [*space.to_dict()["parameters"], GRAIN]})
    design = space.validate(_design(space, 5, 9))
    settings = RenderSettings(space=grain_space, banks=[bank], preset=get_preset("fast"), out_dir=tmp_path / "g",
                              n_tiles=1, ground=ground, tile_px=192, pixel_size_m=0.6)
    jobs = [single_job(grain_space, {**design, "grain": g}, SEED) for g in (0.0, 1.0)]
    assert render_jobs(jobs, settings).cities == 2  # the grain is built into the scene
    smooth, grainy = (tiles.read_tile(tmp_path / "g" / f"{job.name}_t00.exr") for job in jobs)
    assert grainy.meta["ground_grain"] == 1.0 and smooth.meta["ground_grain"] == 0.0
    for name in ("instance", "roof_class", "building"):
        assert np.array_equal(getattr(grainy, name), getattr(smooth, name))
    px, gsd = 192, 0.6
    layout, (rect,) = layout_for_tiles(SEED, 1, px * gsd, LayoutParams())
    roads = _rasterise_polygons([r.polygon for r in layout.roads], rect, px, gsd)
    crowns = _rasterise_polygons([polygons_disc(t) for t in layout.trees], rect, px, gsd)
    bare = _erode((smooth.building == 0) & ~roads & ~crowns, 2)
    roofs = _erode(smooth.building > 0, 4)
    assert bare.sum() > 2000 and roofs.sum() > 300
    step = [np.abs(np.diff(linear_luma(t.rgb), axis=1))[:, :-1] for t in (smooth, grainy)]  # left-right changes
    inner = bare[:, :-1] & bare[:, 1:]
    assert np.median(step[1][inner[:, :-1]]) > 1.5 * np.median(step[0][inner[:, :-1]])
    # the roofs' pixels are their own (FXAA blends a few along the outlines with the busier ground beside)
    assert (np.abs(grainy.rgb[roofs] - smooth.rgb[roofs]).max(axis=-1) < 2e-3).mean() > 0.97


DUST = {"name": "dust", "type": "continuous", "appearance": "road_dust", "low": 0.0, "high": 1.0}


def test_a_declared_road_dust_lightens_the_roads_and_leaves_roofs_and_labels(space, bank, tmp_path):
    """A design's road dust takes the roads towards dust's light grey-beige in the scene; roofs and labels
    stay as they were, and the header records it."""
    from meta_sim.sim.surfaces import ROAD_DUST

    dust_space = DesignSpace.from_dict({**space.to_dict(), "name": "dust",
                                        "parameters": [*space.to_dict()["parameters"], DUST]})
    design = space.validate(_design(space, 5, 9))
    settings = RenderSettings(space=dust_space, banks=[bank], preset=get_preset("fast"), out_dir=tmp_path / "d",
                              n_tiles=1, tile_px=192, pixel_size_m=0.6)
    jobs = [single_job(dust_space, {**design, "dust": d}, SEED) for d in (0.0, 1.0)]
    assert render_jobs(jobs, settings).cities == 2
    clean, dusty = (tiles.read_tile(tmp_path / "d" / f"{job.name}_t00.exr") for job in jobs)
    assert dusty.meta["road_dust"] == 1.0
    for name in ("instance", "roof_class", "building"):
        assert np.array_equal(getattr(dusty, name), getattr(clean, name))
    layout, (rect,) = layout_for_tiles(SEED, 1, 192 * 0.6, LayoutParams())
    roads = _rasterise_polygons([r.polygon for r in layout.roads], rect, 192, 0.6)
    crowns = _rasterise_polygons([polygons_disc(t) for t in layout.trees], rect, 192, 0.6)
    road = _erode(roads & ~crowns & (clean.building == 0), 2)
    roofs = _erode(clean.building > 0, 4)
    assert road.sum() > 500 and roofs.sum() > 300
    lit = road & (linear_luma(clean.rgb) > np.median(linear_luma(clean.rgb)[road]))  # out of the shadows
    ratio = np.median(linear_luma(dusty.rgb)[lit]) / np.median(linear_luma(clean.rgb)[lit])
    dust_luma = float(linear_luma(np.array(ROAD_DUST, np.float32)))
    assert ratio > 0.8 * dust_luma / 0.09  # today's grey road is 0.09 (the tone curve bends the brightest)
    assert (np.abs(dusty.rgb[roofs] - clean.rgb[roofs]).max(axis=-1) < 2e-3).mean() > 0.97


RED = {"name": "red", "type": "continuous", "appearance": "soil_redness", "low": 0.0, "high": 1.0}


def test_a_declared_soil_redness_reddens_the_bare_ground_and_leaves_roofs_and_labels(space, bank, tmp_path):
    """A design's soil redness takes the arid ground's soil and sand towards laterite in the scene: the bare
    ground's red over green rises; roofs and labels stay as they were, and the header records it."""
    red_space = DesignSpace.from_dict({**space.to_dict(), "name": "red",
                                       "parameters": [*space.to_dict()["parameters"], RED]})
    design = space.validate(_design(space, 5, 9))
    settings = RenderSettings(space=red_space, banks=[bank], preset=get_preset("fast"), out_dir=tmp_path / "r",
                              n_tiles=1, ground="arid", tile_px=192, pixel_size_m=0.6)
    jobs = [single_job(red_space, {**design, "red": r}, SEED) for r in (0.0, 1.0)]
    assert render_jobs(jobs, settings).cities == 2  # the soil's colour is built into the scene
    plain, red = (tiles.read_tile(tmp_path / "r" / f"{job.name}_t00.exr") for job in jobs)
    assert red.meta["soil_redness"] == 1.0 and plain.meta["soil_redness"] == 0.0
    for name in ("instance", "roof_class", "building"):
        assert np.array_equal(getattr(red, name), getattr(plain, name))
    layout, (rect,) = layout_for_tiles(SEED, 1, 192 * 0.6, LayoutParams())
    roads = _rasterise_polygons([r.polygon for r in layout.roads], rect, 192, 0.6)
    crowns = _rasterise_polygons([polygons_disc(t) for t in layout.trees], rect, 192, 0.6)
    bare = _erode((plain.building == 0) & ~roads & ~crowns, 2)
    roofs = _erode(plain.building > 0, 4)
    assert bare.sum() > 2000 and roofs.sum() > 300

    def redness(tile):
        return np.median(tile.rgb[bare][:, 0] / np.maximum(tile.rgb[bare][:, 1], 1e-4))

    assert redness(red) > 1.15 * redness(plain)
    assert (np.abs(red.rgb[roofs] - plain.rgb[roofs]).max(axis=-1) < 2e-3).mean() > 0.97


def test_a_view_below_the_tallest_roof_in_view_is_refused_before_anything_is_built(space, bank, tmp_path):
    """A drone flies over the roofs it photographs: a view height within VIEW_CLEARANCE_M of the tallest ridge
    in the tiles is a clear error naming the height to give, before the scene is built; the render says whose."""
    from meta_sim.blender.scene import VIEW_CLEARANCE_M, CityScene

    layout, rects = layout_for_tiles(5, 1, 115.2, LayoutParams())  # a 97 m tower in its downtown
    tallest = max(b.ridge_height_m for b in layout.buildings_in_rect(*rects[0]))
    assert tallest > 90.0
    needed = math.ceil(tallest + VIEW_CLEARANCE_M)
    with pytest.raises(MetaSimError, match=rf"tallest roof in view \({tallest:.1f} m\).*at least {needed} m"):
        CityScene(layout, rects, pixel_size_m=1.2, view_height_m=tallest)
    view_space = DesignSpace.from_dict({**space.to_dict(), "name": "view",
                                        "parameters": [*space.to_dict()["parameters"], VIEW]})
    settings = RenderSettings(space=view_space, banks=[bank], preset=get_preset("fast"), out_dir=tmp_path,
                              n_tiles=1, tile_px=96, pixel_size_m=1.2)
    job = single_job(view_space, {**space.validate(_design(space, 5, 9)), "view_height": 60.0}, 5)
    with pytest.raises(MetaSimError, match=re.escape(f"job {job.name} (city seed 5): a view from 60 m")):
        render_jobs([job], settings)

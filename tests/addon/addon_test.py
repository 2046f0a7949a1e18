"""The Blender extension, headless with the bpy module: manifest, zip, lifecycle, every operator, panel draws.

The add-on under test is the built zip, installed into a private extension repository
(as Blender installs it), with its user folder in a temporary directory.
"""

import ast
import importlib.util
import json
import os
import shlex
import subprocess
import sys
import tomllib
import zipfile
from pathlib import Path
from types import SimpleNamespace

import pytest

from meta_sim.render.options import RENDER_OPTIONS
from meta_sim.render.worker import build_argparser
from meta_sim.sim import tiles
from meta_sim.sim.design import DesignSpace, builtin_spaces
from meta_sim.sim.presets import DesignPreset, load_preset, population, save_preset

ROOT = Path(__file__).resolve().parents[2]
REPO = "metasim_test"
MODULE = f"bl_ext.{REPO}.meta_sim"
SMALL = {"seed": 2, "city_tiles": 1, "tile_px": 64, "gsd": 1.8}  # one 115 m tile at 64 px: quick renders
# What the extension zip ships besides its entry point: the add-on and the layers it imports.
SHIPPED = ("blender_addon", "meta_sim/core", "meta_sim/sim", "meta_sim/blender", "meta_sim/render")

INSTALL = """
import os, sys, zipfile
import bpy, addon_utils

def install(zip_path, repo_dir, repo, module):
    with zipfile.ZipFile(zip_path) as archive:
        archive.extractall(os.path.join(repo_dir, "meta_sim"))
    bpy.context.preferences.extensions.repos.new(name=repo, module=repo, custom_directory=repo_dir, source="USER")
    addon_utils.enable(module, default_set=True, handle_error=lambda exc: (_ for _ in ()).throw(exc))
    return sys.modules[module]
"""


def _blender_ext() -> Path:
    spec = importlib.util.spec_from_file_location("build_addon", ROOT / "jobs" / "build_addon.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module.blender_ext()


@pytest.fixture(scope="module")
def zip_path(tmp_path_factory):
    out = tmp_path_factory.mktemp("dist")
    done = subprocess.run([sys.executable, str(ROOT / "jobs" / "build_addon.py"), "--out", str(out)],
                          capture_output=True, text=True)
    assert done.returncode == 0, done.stdout + done.stderr
    return next(out.glob("meta_sim-*.zip"))


def test_manifest_passes_blenders_validator():
    done = subprocess.run([sys.executable, str(_blender_ext()), "validate", str(ROOT)], capture_output=True, text=True)
    assert done.returncode == 0 and "Success" in done.stdout, done.stdout + done.stderr
    manifest = tomllib.loads((ROOT / "blender_manifest.toml").read_text())
    assert manifest["permissions"]["files"]
    assert "bl_info" not in (ROOT / "__init__.py").read_text()


def test_manifest_has_what_the_extension_platform_asks_for():
    manifest = tomllib.loads((ROOT / "blender_manifest.toml").read_text())
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    assert manifest["license"] == ["SPDX:GPL-3.0-or-later"] and project["license"] == "GPL-3.0-or-later"
    assert (ROOT / "LICENSE").read_text().lstrip().startswith("GNU GENERAL PUBLIC LICENSE\n                       "
                                                               "Version 3, 29 June 2007")
    assert manifest["website"].startswith("https://")
    assert all(line.split(" ", 1)[0].isdigit() and line.split(" ", 1)[1] for line in manifest["copyright"])
    assert "<" in manifest["maintainer"] and "@" in manifest["maintainer"].split("<")[1]  # a contact address
    # the platform shows each permission's reason before install: a short phrase, no trailing full stop
    assert all(0 < len(why) <= 64 and not why.endswith(".") for why in manifest["permissions"].values())


def _imported_modules(source: str) -> set[str]:
    names = set()
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            names |= {a.name for a in node.names}
        elif isinstance(node, ast.ImportFrom) and node.level == 0:
            names.add(node.module)
    return names


def test_zip_holds_exactly_the_addon_and_the_pure_layers(zip_path):
    with zipfile.ZipFile(zip_path) as archive:
        names = set(archive.namelist())
        sources = {n: archive.read(n).decode() for n in names if n.endswith(".py")}
    shipped = {str(p.relative_to(ROOT)) for folder in SHIPPED for p in (ROOT / folder).rglob("*")
               if p.is_file() and "__pycache__" not in p.parts and "docs" not in p.parts}
    assert names == {"blender_manifest.toml", "LICENSE", "__init__.py", "meta_sim/__init__.py", *shipped}
    assert {n.split("/")[1] for n in names if n.startswith("meta_sim/") and n.count("/") > 1} == {
        "core", "sim", "blender", "render"}
    imported = {n: {m.split(".")[0] for m in _imported_modules(text)} for n, text in sources.items()}
    assert not [n for n, modules in imported.items() if modules & {"torch", "click", "tqdm", "meta_sim"}]
    assert not [n for n, text in sources.items() if "bl_info" in text]


@pytest.fixture(scope="module")
def addon(zip_path, tmp_path_factory, bank, heldout_bank):
    import bpy  # isort: skip (first: it puts Blender's script modules, addon_utils among them, on the path)
    import addon_utils  # isort: skip

    from meta_sim.blender.scene import remove_city

    remove_city("worker")  # a render test before these leaves its worker city in the session, under the add-on's
    tmp = tmp_path_factory.mktemp("addon")
    saved = os.environ.get("BLENDER_USER_RESOURCES")
    os.environ["BLENDER_USER_RESOURCES"] = str(tmp / "user")  # extension_path_user lands here
    namespace = {}
    exec(INSTALL, namespace)  # the same install code the subprocess test runs
    module = namespace["install"](str(zip_path), str(tmp / "repo"), REPO, MODULE)
    user = bpy.data.objects.new("user's object", bpy.data.meshes.new("user's mesh"))
    bpy.context.scene.collection.objects.link(user)
    yield module
    addon_utils.disable(MODULE, default_set=True)
    repos = bpy.context.preferences.extensions.repos
    repos.remove(next(r for r in repos if r.module == REPO))
    if saved is None:
        os.environ.pop("BLENDER_USER_RESOURCES")
    else:
        os.environ["BLENDER_USER_RESOURCES"] = saved


@pytest.fixture
def settings(addon):
    import bpy

    s = bpy.context.scene.meta_sim
    for name, value in SMALL.items():
        setattr(s, name, value)
    s.bank_source = "DEFAULT"
    s.render_preset = "fast"
    s.job_designs = "CURRENT"
    bpy.ops.meta_sim.load_bank()
    return s


def _pick(settings, **values):
    """Choose values in the panel's design (a categorical parameter's menu or picker, a continuous one's number)."""
    for name, value in values.items():
        row = settings.design[name]
        if isinstance(value, str):
            row.choice = value
        else:
            row.value = value


def _picked(settings) -> dict:
    return {row.name: row.choice for row in settings.design}


def _counts():
    import bpy

    return {name: len(getattr(bpy.data, name)) for name in
            ("objects", "meshes", "materials", "images", "collections", "scenes", "cameras", "lights", "worlds")}


def test_register_unregister_twice(addon):
    import bpy

    for _ in range(2):
        addon.unregister()
        assert not hasattr(bpy.types.Scene, "meta_sim")
        for cls in addon.blender_addon.CLASSES:
            assert not getattr(cls, "is_registered", False), cls
        assert not hasattr(bpy.ops.meta_sim, "generate_city") or not _op_exists("meta_sim.generate_city")
        assert addon.blender_addon.previews._collections == {}
        addon.register()
        assert _op_exists("meta_sim.generate_city") and hasattr(bpy.context.scene, "meta_sim")


def _op_exists(idname: str) -> bool:
    import bpy

    category, name = idname.split(".")
    try:
        getattr(getattr(bpy.ops, category), name).get_rna_type()
    except (AttributeError, KeyError):
        return False
    return True


def test_no_torch_when_blender_imports_and_uses_the_addon(zip_path, tmp_path, bank):
    script = INSTALL + f"""
os.environ["BLENDER_USER_RESOURCES"] = {str(tmp_path / "user")!r}
module = install({str(zip_path)!r}, {str(tmp_path / "repo")!r}, {REPO!r}, {MODULE!r})
module.unregister(); module.register()
s = bpy.context.scene.meta_sim
s.city_tiles, s.tile_px, s.gsd = 1, 64, 1.8
assert bpy.ops.meta_sim.load_bank() == {{"FINISHED"}}
assert bpy.ops.meta_sim.generate_city() == {{"FINISHED"}}
print("TORCH", "torch" in sys.modules)
"""
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, env=os.environ.copy())
    assert done.returncode == 0, done.stderr[-3000:]
    assert "TORCH False" in done.stdout


def test_regenerating_replaces_the_city_without_orphans(settings):
    import bpy

    bpy.ops.meta_sim.generate_city()
    first = _counts()
    for seed in (5, 6):
        settings.seed = seed
        assert bpy.ops.meta_sim.generate_city() == {"FINISHED"}
        assert _counts() == first
    assert "user's object" in bpy.data.objects
    assert bpy.ops.meta_sim.remove_city() == {"FINISHED"}
    assert "user's object" in bpy.data.objects and settings.city_key == ""
    assert not [c for c in bpy.data.collections if c.name.startswith("Meta-Sim")]


def _roof_images_on_polygons(addon):
    """Slot -> image path, read from the building polygons' materials (what a render shows)."""
    import bpy

    city = addon.blender_addon.city
    scene_module = sys.modules[f"{MODULE}.meta_sim.blender.scene"]
    obj = scene_module.city_buildings(bpy.context.scene.meta_sim.city_key)
    used = {p.material_index for p in obj.data.polygons}
    out = {}
    for slot in used - {0}:
        nodes = obj.data.materials[slot].node_tree.nodes
        out[slot] = bpy.path.abspath(next(n.image.filepath for n in nodes if n.type == "TEX_IMAGE"))
    assert out == {k: v for k, v in city.roof_images(bpy.context.scene.meta_sim).items() if k in used}
    return out


def test_picked_textures_go_on_the_matching_roofs(addon, settings, bank):
    import bpy

    bpy.ops.meta_sim.generate_city()
    _pick(settings, flat_roof=bank.ids("flat")[3], sloped_roof=bank.ids("sloped")[7])
    before = _counts()
    assert bpy.ops.meta_sim.apply_design() == {"FINISHED"}
    images = _roof_images_on_polygons(addon)
    assert images == {1: str(bank.image_path(bank.ids("flat")[3])), 2: str(bank.image_path(bank.ids("sloped")[7]))}
    _pick(settings, flat_roof=bank.ids("flat")[4])
    bpy.ops.meta_sim.apply_design()
    assert _counts() == before  # the replaced roof material and its image are gone
    assert _roof_images_on_polygons(addon)[1] == str(bank.image_path(bank.ids("flat")[4]))


@pytest.fixture
def preset_folder(tmp_path, bank):
    space = DesignSpace.load()
    flat, sloped = bank.ids("flat"), bank.ids("sloped")
    groups = [DesignPreset(kind="group", name=f"kampala-{k:03d}", design_space=space.name,
                           design={"flat_roof": flat[k], "sloped_roof": sloped[2]},
                           vote_shares={"flat_roof": {flat[k]: 0.62, flat[9]: 0.38}, "sloped_roof": {sloped[2]: 0.5}},
                           source_images=[f"/data/kampala/t{k}{j}.png" for j in range(3)], model_id="abc",
                           search={"roof_pixels_flat": share, "roof_pixels_sloped": 0.2,
                                   "roof_pixels_low_flat": 0.03, "roof_pixels_high_flat": 0.4,
                                   "roof_pixels_low_sloped": 0.05, "roof_pixels_high_sloped": 0.3})
              for k, share in ((5, 0.12), (6, 0.004))]
    for preset in groups:
        save_preset(tmp_path / f"{preset.name}.json", preset)
    save_preset(tmp_path / "population.json", population(groups + groups[:1], space, "population"))
    (tmp_path / "broken.json").write_text("{not json")
    future = groups[0].to_dict() | {"version": 99}
    (tmp_path / "future.json").write_text(json.dumps(future))
    unknown = groups[0].to_dict() | {"design": {"flat_roof": "flat-no-such-texture", "sloped_roof": sloped[0]}}
    (tmp_path / "unknown.json").write_text(json.dumps(unknown))
    return tmp_path


def test_presets_browser_applies_good_presets_and_rejects_bad_ones(addon, settings, preset_folder, bank):
    import bpy

    bpy.ops.meta_sim.generate_city()
    settings.presets_folder = str(preset_folder)
    assert bpy.ops.meta_sim.load_presets() == {"FINISHED"}
    rows = {row.path.rsplit("/", 1)[-1]: row for row in settings.presets}
    assert "not valid JSON" in rows["broken.json"].error
    assert "newer" in rows["future.json"].error
    assert "flat-no-such-texture" in rows["unknown.json"].error
    good = rows["kampala-005.json"]
    assert not good.error and good.flat == bank.ids("flat")[5] and abs(good.flat_share - 0.62) < 1e-6
    assert good.target == "3 images in /data/kampala"
    # Roof evidence: kampala-006's flat roofs rest on fewer pixels than the model's training cities show.
    assert abs(good.flat_evidence - 0.12) < 1e-6 and not good.flat_evidence_outside
    assert not good.sloped_evidence_outside
    assert rows["kampala-006.json"].flat_evidence_outside == "low"
    assert not rows["kampala-006.json"].sloped_evidence_outside
    assert rows["population.json"].flat_evidence == -1.0  # a population records none
    shares = json.loads(rows["population.json"].distribution)["flat_roof"]
    assert shares[0][0] == bank.ids("flat")[5] and abs(shares[0][1] - 2 / 3) < 1e-6

    settings.presets_index = list(settings.presets).index(good)
    assert bpy.ops.meta_sim.apply_preset() == {"FINISHED"}
    applied = _roof_images_on_polygons(addon)
    assert applied[1] == str(bank.image_path(bank.ids("flat")[5]))
    assert _picked(settings)["flat_roof"] == bank.ids("flat")[5]
    for name, message in (("broken.json", "not valid JSON"), ("future.json", "newer"),
                          ("unknown.json", "flat-no-such-texture")):
        settings.presets_index = list(settings.presets).index(rows[name])
        with pytest.raises(RuntimeError, match=message):  # the button is greyed out, saying why
            bpy.ops.meta_sim.apply_preset()
        assert _roof_images_on_polygons(addon) == applied and _picked(settings)["flat_roof"] == bank.ids("flat")[5]


def test_save_preset_writes_the_infer_format(settings, tmp_path, bank):
    import bpy

    _pick(settings, flat_roof=bank.ids("flat")[1], sloped_roof=bank.ids("sloped")[2])
    assert bpy.ops.meta_sim.save_preset(filepath=str(tmp_path / "mine.json")) == {"FINISHED"}
    preset = load_preset(tmp_path / "mine.json", DesignSpace.load())
    assert preset.kind == "group" and preset.name == "mine"
    assert preset.design == {"flat_roof": bank.ids("flat")[1], "sloped_roof": bank.ids("sloped")[2]}


def test_render_preview_tile_and_its_labels(settings):
    import bpy
    import numpy as np

    bpy.ops.meta_sim.generate_city()
    before = _counts()
    assert bpy.ops.meta_sim.render_preview() == {"FINISHED"}
    rgb, labels = bpy.data.images["Meta-Sim Preview"], bpy.data.images["Meta-Sim Preview Labels"]
    assert tuple(rgb.size) == tuple(labels.size) == (64, 64)
    pixels = np.asarray(labels.pixels[:]).reshape(64, 64, 4)[..., :3]
    assert (pixels.max(axis=-1) > 0).mean() > 0.02  # buildings are labelled
    assert np.asarray(rgb.pixels[:]).std() > 0.01
    bpy.ops.meta_sim.render_preview()  # again: the same two images, no leftovers of the temporary tile
    after = _counts()
    assert after == {**before, "images": before["images"] + 2}


def test_exported_job_runs_on_the_render_worker_and_the_preview_matches_it(settings, tmp_path):
    import bpy

    from meta_sim.sim.imageio import read_rgb8

    settings.seed, settings.sloped_share, settings.tree_density = 7, 0.2, 0.0
    settings.render_preset = "balanced"  # Cycles: the preview's private scene must sample as the farm does
    bpy.ops.meta_sim.generate_city()
    settings.job_dir = str(tmp_path / "job")
    assert bpy.ops.meta_sim.export_job() == {"FINISHED"}
    job = json.loads((tmp_path / "job" / "render-job.json").read_text())
    assert set(job["options"]) <= {opt.dest for opt in RENDER_OPTIONS}
    assert vars(build_argparser().parse_args(job["argv"]))["seed"] == 7
    assert job["command"].startswith("python -m meta_sim.render.worker --design ")
    done = subprocess.run([sys.executable, "-m", "meta_sim.render.worker", *job["argv"], "--preview"], cwd=ROOT,
                          capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    first = next((tmp_path / "job" / "tiles").glob("*_t00.exr"))
    tile = tiles.read_tile(first)
    assert tile.meta["design"] == job["design"] and tile.meta["city_seed"] == 7
    settings.preview_tile = 0
    bpy.ops.meta_sim.render_preview()
    preview = bpy.path.abspath(bpy.data.images["Meta-Sim Preview"].filepath)
    assert (read_rgb8(preview) == read_rgb8(first.with_suffix(".png"))).all()
    settings.sloped_share, settings.tree_density, settings.render_preset = 0.6, 0.4, "fast"


def _population_job(settings, job_dir: Path, images: int, r: float, seed: int = 3) -> tuple[dict, list]:
    """Export a job from the loaded population; its render-job.json and the jobs of its designs.json."""
    import bpy

    settings.seed, settings.job_images, settings.job_rejection = seed, images, r
    settings.job_designs, settings.job_dir = "POPULATION", str(job_dir)
    assert bpy.ops.meta_sim.export_job() == {"FINISHED"}
    job = json.loads((job_dir / "render-job.json").read_text())
    return job, json.loads(Path(job["designs_file"]).read_text())["jobs"]


def test_export_from_the_loaded_population_samples_its_designs(addon, settings, preset_folder, tmp_path):
    import bpy

    settings.presets_folder = str(preset_folder)
    bpy.ops.meta_sim.load_presets()
    settings.job_cities = 3
    members = [entry["design"] for entry in load_preset(preset_folder / "population.json").designs]
    job, jobs = _population_job(settings, tmp_path / "r0", 12, 0.0)
    assert [j["design"] in members for j in jobs] == [True] * 12  # r = 0: every design is the population's
    assert len({json.dumps(j["design"]) for j in jobs}) == 2
    assert [j["city_seed"] for j in jobs] == [3 + k % 3 for k in range(12)]
    assert job["designs_file"] == str(tmp_path / "r0" / "tiles" / "designs.json")
    assert load_preset(job["options"]["population"]).designs == load_preset(preset_folder / "population.json").designs
    assert vars(build_argparser().parse_args(job["argv"]))["population"] == Path(job["options"]["population"])

    _population_job(settings, tmp_path / "again", 12, 0.0)
    assert (tmp_path / "again" / "tiles" / "designs.json").read_bytes() == Path(job["designs_file"]).read_bytes()

    _, uniform = _population_job(settings, tmp_path / "r1", 40, 1.0)  # r = 1: every design a uniform draw
    designs = [j["design"] for j in uniform]
    assert sum(d in members for d in designs) <= 2 and len({json.dumps(d) for d in designs}) > 30
    space = DesignSpace.load()
    assert all(space.validate(d) == d for d in designs)
    _, reseeded = _population_job(settings, tmp_path / "s4", 40, 1.0, seed=4)
    assert [j["design"] for j in reseeded] != designs

    calls = _draw_all(addon)
    assert {"job_images", "job_rejection", "job_cities"} <= {args[1] for name, args, _ in calls if name == "prop"}


def test_population_job_matches_what_the_cli_plans_and_renders(settings, preset_folder, tmp_path):
    import bpy

    settings.presets_folder = str(preset_folder)
    bpy.ops.meta_sim.load_presets()
    settings.job_cities = 2
    job, jobs = _population_job(settings, tmp_path / "job", 4, 0.5)
    # `meta-sim render` with the job's options (its --population, --images, -r, --seed, ...) records the same file
    argv = job["argv"]
    argv[argv.index("--out") + 1] = str(tmp_path / "cli")
    done = subprocess.run([sys.executable, "-m", "meta_sim.cli", "render", *argv], cwd=ROOT,
                          capture_output=True, text=True)
    assert done.returncode == 0, done.stdout + done.stderr
    assert (tmp_path / "cli" / "designs.json").read_bytes() == Path(job["designs_file"]).read_bytes()
    # the job's `meta-sim jobs plan` command plans the same designs in the same cities for the farm
    plan = shlex.split(job["plan_command"])
    assert plan[:3] == ["meta-sim", "jobs", "plan"]
    done = subprocess.run([sys.executable, "-m", "meta_sim.cli", *plan[1:]], cwd=ROOT, capture_output=True, text=True)
    assert done.returncode == 0, done.stdout + done.stderr
    farm = json.loads((tmp_path / "job" / "farm-job.json").read_text())
    pairs = list(dict.fromkeys(json.dumps([j["design"], j["city_seed"]]) for j in jobs))  # farm plans a pair once
    assert [json.dumps([t["design"], t["city_seed"]]) for t in farm["tasks"]] == pairs
    assert farm["out_dir"] == "tiles"
    assert farm["space"] == json.loads((tmp_path / "job" / "design-space.json").read_text())


def test_export_is_disabled_while_no_population_is_loaded(settings, preset_folder):
    import bpy

    settings.presets.clear()
    settings.job_designs = "POPULATION"
    assert not bpy.ops.meta_sim.export_job.poll()
    with pytest.raises(RuntimeError, match="No population loaded"):
        bpy.ops.meta_sim.export_job()
    settings.presets_folder = str(preset_folder)
    bpy.ops.meta_sim.load_presets()
    assert bpy.ops.meta_sim.export_job.poll()
    settings.presets.remove(next(k for k, row in enumerate(settings.presets) if row.kind == "population"))
    assert not bpy.ops.meta_sim.export_job.poll()  # group presets alone are no population
    settings.job_designs = "CURRENT"
    assert bpy.ops.meta_sim.export_job.poll()


def test_user_errors_are_reported_not_raised_as_tracebacks(settings, tmp_path):
    import bpy

    settings.job_dir = ""
    bpy.ops.meta_sim.generate_city()
    with pytest.raises(RuntimeError, match="Choose a job folder"):
        bpy.ops.meta_sim.export_job()
    settings.presets_folder = str(tmp_path / "missing")
    with pytest.raises(RuntimeError, match="does not exist"):
        bpy.ops.meta_sim.load_presets()
    settings.bank_source, settings.bank_folder = "FOLDER", str(tmp_path)
    with pytest.raises(RuntimeError, match="not a texture bank"):
        bpy.ops.meta_sim.generate_city()
    settings.bank_source = "DEFAULT"
    settings.space, settings.space_file = "FILE", str(tmp_path / "no-such-space.json")
    with pytest.raises(RuntimeError, match="no-such-space.json does not exist"):
        bpy.ops.meta_sim.load_bank()
    (tmp_path / "space.json").write_text('{"format": "meta-sim-design-space", "version": 1, "parameters": [')
    settings.space_file = str(tmp_path / "space.json")
    with pytest.raises(RuntimeError, match="not valid JSON"):
        bpy.ops.meta_sim.generate_city()
    (tmp_path / "space.json").write_text(json.dumps({"format": "meta-sim-design-space", "version": 1, "parameters": [
        {"name": "sun", "type": "continuous", "low": 20, "high": 70, "appearance": "__import__('os')"}]}))
    with pytest.raises(RuntimeError, match="appearance must be a field name"):
        bpy.ops.meta_sim.load_bank()
    settings.space = "BANK"


class RecordingLayout:
    """Stands in for ``UILayout``: records calls, returns itself, and checks what a real layout would."""

    def __init__(self, calls=None):
        self.calls = [] if calls is None else calls

    def __getattr__(self, name):
        def call(*args, **kwargs):
            self._check(name, args, kwargs)
            self.calls.append((name, args, kwargs))
            return self
        return call

    @staticmethod
    def _check(name, args, kwargs):
        import bpy

        if name in ("prop", "template_icon_view"):
            data, prop = args[:2]
            assert prop in data.bl_rna.properties, f"{name}: no property {prop!r}"
        if name == "operator":
            assert _op_exists(args[0]), f"no operator {args[0]}"
        if name == "template_list":
            assert getattr(bpy.types, args[0], None) is not None, f"no list {args[0]}"
            assert args[3] in args[2].bl_rna.properties and args[5] in args[4].bl_rna.properties
        if "icon_value" in kwargs:
            assert isinstance(kwargs["icon_value"], int)


def _draw_all(addon):
    import bpy

    calls = []
    for panel in addon.blender_addon.panels.CLASSES:
        panel.draw(SimpleNamespace(layout=RecordingLayout(calls)), bpy.context)
    settings = bpy.context.scene.meta_sim
    for item in settings.presets:
        addon.blender_addon.presets_ui.META_SIM_UL_presets.draw_item(
            None, bpy.context, RecordingLayout(calls), settings, item, 0, settings, "presets_index", 0)
    return calls


def test_panels_draw_in_every_state(addon, settings, preset_folder, tmp_path):
    import bpy

    settings.bank_source, settings.bank_folder = "FOLDER", str(tmp_path)  # no bank: offers to load one
    assert ("operator", ("meta_sim.load_bank",), {"icon": "IMPORT"}) in _draw_all(addon)
    settings.bank_source = "DEFAULT"
    bpy.ops.meta_sim.generate_city()
    bpy.ops.meta_sim.render_preview()
    settings.presets_folder = str(preset_folder)
    bpy.ops.meta_sim.load_presets()
    for index in range(len(settings.presets)):  # each row selected: errors, a group, the population
        settings.presets_index = index
        calls = _draw_all(addon)
        labels = [kw.get("text", args[0] if args else "") for name, args, kw in calls if name == "label"]
        row = settings.presets[index]
        if row.error:
            assert row.error in labels
        elif row.distribution:
            assert "Distribution over the target's groups:" in labels
        elif row.flat_evidence_outside:  # the group whose flat roof rests on too few pixels says so
            assert "roof pixels 0.4%: too few, unreliable" in labels
        else:
            assert "roof pixels 12.0%" in labels
    names = {name for name, _, _ in calls}
    assert {"template_icon_view", "template_list", "template_icon", "operator", "prop"} <= names


@pytest.fixture
def prefs(addon):
    """The add-on's preferences, back to their defaults afterwards."""
    import bpy

    yield bpy.context.preferences.addons[MODULE].preferences
    prefs = bpy.context.preferences.addons[MODULE].preferences  # read again: reading the preferences frees the old
    prefs.cache_folder = prefs.bank_folder = ""
    prefs.preview_quality = "fast"


def test_preferences_round_trip_through_the_saved_preferences(prefs, tmp_path, heldout_bank):
    import bpy

    prefs.cache_folder, prefs.bank_folder, prefs.preview_quality = str(tmp_path), str(heldout_bank.root), "balanced"
    assert bpy.ops.wm.save_userpref() == {"FINISHED"}
    prefs.cache_folder, prefs.bank_folder, prefs.preview_quality = "", "", "quality"
    assert bpy.ops.wm.read_userpref() == {"FINISHED"}
    prefs = bpy.context.preferences.addons[MODULE].preferences
    assert (prefs.cache_folder, prefs.bank_folder, prefs.preview_quality) == (
        str(tmp_path), str(heldout_bank.root), "balanced")


def test_preferences_are_used_where_the_environment_variable_was(addon, settings, prefs, tmp_path, heldout_bank):
    import bpy

    library = addon.blender_addon.library
    preferences = addon.blender_addon.preferences
    assert preferences.cache_dir_and_source() == (Path(os.environ["META_SIM_CACHE"]), "$META_SIM_CACHE")  # farms
    prefs.cache_folder = str(tmp_path / "cache")
    assert preferences.cache_dir_and_source() == (tmp_path / "cache", "preferences")
    assert library._folder(settings).parent == tmp_path / "cache" / "banks"  # where Load would build the bank
    prefs.cache_folder = ""

    settings.bank_source, settings.bank_folder = "FOLDER", ""
    with pytest.raises(RuntimeError, match="default bank folder in the add-on's preferences"):
        bpy.ops.meta_sim.load_bank()
    prefs.bank_folder = str(heldout_bank.root)
    assert bpy.ops.meta_sim.load_bank() == {"FINISHED"}
    assert library.require(settings).bank.root == heldout_bank.root
    settings.bank_source = "DEFAULT"

    settings.render_preset = "DEFAULT"
    prefs.preview_quality = "balanced"
    assert preferences.quality(settings) == "balanced"
    bpy.ops.meta_sim.generate_city()
    settings.job_dir = str(tmp_path / "job")
    bpy.ops.meta_sim.export_job()
    assert json.loads((tmp_path / "job" / "render-job.json").read_text())["options"]["preset"] == "balanced"
    settings.render_preset = "quality"  # a scene's own quality wins over the default
    assert preferences.quality(settings) == "quality"


def _poll_message(name: str) -> str | None:
    """None when the operator can run, else the message its greyed-out button shows."""
    import bpy

    operator = getattr(bpy.ops.meta_sim, name)
    if operator.poll():
        return None
    with pytest.raises(RuntimeError) as raised:
        operator()
    return str(raised.value)


def test_every_operator_polls_and_says_why_it_is_disabled(addon, settings, preset_folder, tmp_path):
    import bpy

    operators, tasks = addon.blender_addon.operators, addon.blender_addon.tasks
    names = [cls.bl_idname.split(".")[1] for cls in operators.CLASSES]
    every = [cls for cls in addon.blender_addon.CLASSES if issubclass(cls, bpy.types.Operator)]
    assert len(every) == 12 and all("poll" in vars(cls) for cls in every)  # the asset ones: their own test

    def disabled() -> dict:
        return {name: message for name in names if (message := _poll_message(name)) is not None}

    settings.job_dir, settings.presets_folder = "", ""
    settings.presets.clear()
    bpy.ops.meta_sim.generate_city()
    bpy.ops.meta_sim.remove_city()
    settings.job_designs = "CURRENT"
    states = disabled()  # a bank, but no city, no job folder, no presets folder, no preset
    assert set(states) == {"remove_city", "apply_design", "export_job", "load_presets", "apply_preset"}
    assert "Generate a city first" in states["remove_city"] and "Generate a city first" in states["apply_design"]
    assert "Choose a job folder" in states["export_job"]
    assert "Choose a presets folder" in states["load_presets"]
    assert "select a preset" in states["apply_preset"]

    settings.job_dir = str(tmp_path / "job")
    assert "Generate a city first: the job renders the current city" in disabled()["export_job"]
    settings.presets_folder = str(preset_folder)
    bpy.ops.meta_sim.load_presets()
    settings.presets_index = next(k for k, row in enumerate(settings.presets) if row.error)
    assert "The selected preset cannot be applied: " in disabled()["apply_preset"]
    bpy.ops.meta_sim.generate_city()
    settings.presets_index = next(k for k, row in enumerate(settings.presets) if not row.error)
    assert disabled() == {}

    settings.bank_source, settings.bank_folder = "FOLDER", str(tmp_path)  # not a bank: nothing loaded from it
    states = disabled()
    assert set(states) == set(names) - {"load_bank", "generate_city", "remove_city"}
    assert all("Load a texture bank first" in message for message in states.values())
    settings.bank_folder = ""  # no folder at all: nothing to load a bank from either
    assert "Choose a texture bank folder" in disabled()["load_bank"]
    assert "Choose a texture bank folder" in disabled()["generate_city"]
    settings.bank_source = "DEFAULT"

    tasks._running["meta_sim.test"] = "rendering the tile"  # while a long operation runs, nothing else can
    try:
        states = disabled()
        assert set(states) == set(names)
        assert all("Wait until Meta-Sim has finished (rendering the tile)" in m for m in states.values())
    finally:
        tasks._running.clear()
    bpy.ops.meta_sim.remove_city()


def _step_through(steps, n: int):
    """Advance a generator of steps ``n`` times (or to its end); True when it ended."""
    for _ in range(n):
        try:
            next(steps)
        except StopIteration:
            return True
    return False


def test_cancelling_a_city_build_at_any_step_keeps_the_old_city(addon, settings):
    import bpy

    city, libraries = addon.blender_addon.city, addon.blender_addon.library
    bpy.ops.meta_sim.generate_city()
    old_key, before = settings.city_key, _counts()
    settings.seed = 11
    for n in range(1, 100):
        steps = city.generate_steps(bpy.context.scene, settings, libraries.require(settings))
        if _step_through(steps, n):
            break
        steps.close()  # Esc
        assert settings.city_key == old_key and _counts() == before, n
    assert n >= 3 and settings.city_key != old_key and _counts() == before  # the last run went to the end
    bpy.ops.meta_sim.remove_city()


def test_cancelling_a_preview_at_any_step_leaves_nothing(addon, settings):
    import bpy

    city, libraries = addon.blender_addon.city, addon.blender_addon.library
    settings.render_preset = "balanced"  # Cycles: rendered in strips, Esc between them
    settings.tile_px, settings.gsd = 160, 0.72
    bpy.ops.meta_sim.generate_city()
    for image in [bpy.data.images.get(name) for name in city.PREVIEW_IMAGES]:
        if image is not None:
            bpy.data.images.remove(image)
    before = _counts()
    for n in range(1, 100):
        steps = city.render_preview_steps(settings, libraries.require(settings))
        if _step_through(steps, n):
            break
        steps.close()
        assert _counts() == before and not any(bpy.data.images.get(name) for name in city.PREVIEW_IMAGES), n
    assert n > 4 and bpy.data.images.get(city.PREVIEW_IMAGES[0]).size[:] == (160, 160)
    settings.render_preset = "fast"
    bpy.ops.meta_sim.remove_city()


def test_cancelling_the_default_bank_build_leaves_no_bank(addon, settings, prefs, tmp_path):
    import time

    libraries = addon.blender_addon.library
    prefs.cache_folder = str(tmp_path)
    steps = libraries.load_steps(settings)
    share, text = next(steps)
    assert text == "building the default texture bank" and 0 <= share < 1
    steps.close()  # the build stops at its next texture and removes its temporary folder
    for _ in range(300):  # the UI waits a second for that; a busy machine may take longer
        if not [p for p in tmp_path.rglob("*") if p.is_file()]:
            break
        time.sleep(0.1)
    assert not list((tmp_path / "banks").iterdir())


class _FakeWindowManager:
    def __init__(self):
        self.calls = []

    def __getattr__(self, name):
        return lambda *args, **kwargs: self.calls.append(name) or name


def test_a_long_operation_shows_progress_and_esc_undoes_it(addon, monkeypatch):
    """The modal side of `tasks.Stepped`, driven by hand with timer events and Esc (no window headless)."""
    import time

    tasks = addon.blender_addon.tasks
    monkeypatch.setattr(tasks, "interactive", lambda context: True)  # as in Blender with a window
    built = []

    class Operation(tasks.Stepped):
        bl_idname, bl_label = "meta_sim.test", "Test Operation"

        def __init__(self):
            self.reports = []

        def report(self, kind, message):
            self.reports.append((kind, message))

        def steps(self, context, settings):
            try:
                for k in range(6):
                    built.append(k)
                    time.sleep(tasks.SLICE / 2.5)  # about three steps per timer event
                    yield (k + 1) / 6, f"step {k}"
            except GeneratorExit:
                built.clear()  # what a cancelled operation does: remove what it built
                raise
            return "done"

    status = []
    context = SimpleNamespace(window=object(), window_manager=_FakeWindowManager(),
                              scene=SimpleNamespace(meta_sim=None),
                              workspace=SimpleNamespace(status_text_set=status.append))
    op = Operation()
    assert op.invoke(context, None) == {"RUNNING_MODAL"} and tasks.busy() == "test operation"
    timer = SimpleNamespace(type="TIMER", value="NOTHING", timer=op._timer)
    assert op.modal(context, SimpleNamespace(type="LEFTMOUSE", value="PRESS", timer=None)) == {"RUNNING_MODAL"}
    assert op.modal(context, SimpleNamespace(type="WHEELUPMOUSE", value="PRESS", timer=None)) == {"PASS_THROUGH"}
    assert op.modal(context, timer) == {"RUNNING_MODAL"} and 0 < len(built) < 6
    assert status[-1].startswith("Meta-Sim: step ") and "Esc to cancel" in status[-1]
    assert tasks.busy().startswith("step ")
    assert op.modal(context, SimpleNamespace(type="ESC", value="PRESS", timer=None)) == {"CANCELLED"}
    assert built == [] and tasks.busy() is None and status[-1] is None
    assert {"event_timer_remove", "progress_end"} <= set(context.window_manager.calls)
    assert op.reports == [({"WARNING"}, "Test Operation cancelled: nothing was changed")]

    op = Operation()  # Blender cancels it (a file is loaded): the same clean-up
    op.invoke(context, None)
    op.modal(context, timer)
    op.cancel(context)
    assert built == [] and tasks.busy() is None and status[-1] is None

    op = Operation()
    op.invoke(context, None)
    while (result := op.modal(context, timer)) == {"RUNNING_MODAL"}:
        pass
    assert result == {"FINISHED"} and built == list(range(6)) and op.reports[-1] == ({"INFO"}, "done")
    assert tasks.busy() is None


def _library_assets(blend: Path) -> dict:
    """The assets of a library file as read back: name -> metadata, tags, description, catalog, preview."""
    import bpy
    import numpy as np

    out = {}
    with bpy.data.temp_data() as data:
        with data.libraries.load(str(blend), assets_only=True) as (source, target):
            target.scenes = source.scenes
        for scene in target.scenes:
            meta, preview = scene.asset_data, scene.preview
            width, height = preview.image_size
            pixels = np.asarray(preview.image_pixels_float[:], dtype=np.float32).reshape(height, width, 4)
            out[scene.name] = SimpleNamespace(
                name=scene.name, full_library_path=str(blend), metadata={k: meta[k] for k in meta.keys()},
                tags={t.name for t in meta.tags}, description=meta.description, catalog_id=meta.catalog_id,
                size=(width, height), pixels=pixels[::-1])  # top row first, as the PNGs
    return out


@pytest.fixture
def infer_folder(preset_folder, tmp_path_factory, bank):
    """A `meta-sim infer` output: population.json and report.json at the top, group presets in presets/,
    and the bad files of ``preset_folder``; the asset library it gets is unlisted afterwards."""
    import shutil

    import bpy

    folder = tmp_path_factory.mktemp("inferred")
    (folder / "presets").mkdir()
    for path in preset_folder.glob("*.json"):
        shutil.copy(path, folder / ("presets" if path.name.startswith("kampala") else ".") / path.name)
    (folder / "report.json").write_text(json.dumps({"target_dir": "/data/kampala", "groups": []}))
    yield folder
    libraries = bpy.context.preferences.filepaths.asset_libraries
    for entry in [e for e in libraries if Path(e.path).resolve() == (folder / "meta-sim-assets").resolve()]:
        libraries.remove(entry)


def test_a_presets_folder_becomes_an_asset_library(addon, settings, infer_folder, bank):
    import bpy
    import numpy as np

    from meta_sim.sim.imageio import read_rgb8

    assets, tasks = addon.blender_addon.assets, addon.blender_addon.tasks
    settings.tile_px, settings.gsd = 256, 0.45  # the preview's pixels: a preview tile renders the same
    bpy.ops.meta_sim.generate_city()
    settings.presets_folder = str(infer_folder)
    assert bpy.ops.meta_sim.build_assets() == {"FINISHED"}
    blend = infer_folder / "meta-sim-assets" / "meta-sim-designs.blend"
    found = _library_assets(blend)
    assert set(found) == {"kampala-005", "kampala-006", "population"}  # report.json and the bad files: none
    assert [Path(e.path).resolve() for e in bpy.context.preferences.filepaths.asset_libraries].count(
        blend.parent.resolve()) == 1
    for asset in found.values():
        assert asset.size == (256, 256) and (asset.pixels[..., 3] == 1).all() and asset.pixels.std() > 0.02
        assert assets.is_design(asset) and "Meta-Sim" in asset.tags

    group = found["kampala-005"]  # its preview is a rendered tile of its design
    bpy.ops.meta_sim.build_assets()  # again: the same library (previews from the cache), listed once
    assert (_library_assets(blend)["kampala-005"].pixels == group.pixels).all()
    assert [Path(e.path).resolve() for e in bpy.context.preferences.filepaths.asset_libraries].count(
        blend.parent.resolve()) == 1
    _pick(settings, flat_roof=bank.ids("flat")[5], sloped_roof=bank.ids("sloped")[2])
    settings.render_preset = "fast"
    bpy.ops.meta_sim.render_preview()
    tile = read_rgb8(bpy.path.abspath(bpy.data.images["Meta-Sim Preview"].filepath))
    assert (np.round(group.pixels[..., :3] * 255) == tile).all()
    assert np.abs(found["kampala-006"].pixels - group.pixels).mean() > 0.005  # another flat roof, another tile

    metadata = group.metadata
    assert metadata["preset"] == "presets/kampala-005.json" and metadata["model_id"] == "abc"
    assert json.loads(metadata["vote_shares"])["flat_roof"][bank.ids("flat")[5]] == 0.62
    assert metadata["source_images"] == 3 and metadata["target"] == "3 images in /data/kampala"
    assert json.loads(metadata["design"]) == {"flat_roof": bank.ids("flat")[5], "sloped_roof": bank.ids("sloped")[2]}
    assert f"flat_roof {bank.ids('flat')[5]} (62% of votes)" in group.description
    assert {"group", bank.ids("flat")[5], bank.ids("sloped")[2]} <= group.tags
    assert "population" in found["population"].tags and found["population"].metadata["kind"] == "population"
    catalogs = (blend.parent / "blender_assets.cats.txt").read_text()
    assert f"{group.catalog_id}:Meta-Sim/kampala:Meta-Sim-kampala" in catalogs.splitlines()
    assert {a.catalog_id for a in found.values()} == {group.catalog_id}

    library = addon.blender_addon.library.require(settings)
    built, bad = tasks.run(assets.build_steps(settings, library, infer_folder))
    reasons = {path.name: why for path, why in bad}
    assert set(reasons) == {"broken.json", "future.json", "unknown.json"}
    assert "not valid JSON" in reasons["broken.json"] and "newer" in reasons["future.json"]
    assert "flat-no-such-texture" in reasons["unknown.json"]
    assert len(built) == 3


def _materials():
    """Every object's material slots, by name, and the datablock counts."""
    import bpy

    return {o.name: [m.name if m else None for m in getattr(o.data, "materials", [])] for o in bpy.data.objects}


def test_applying_an_asset_changes_exactly_the_roof_materials(addon, settings, infer_folder, bank):
    import bpy

    from meta_sim.sim.presets import save_preset

    assets = addon.blender_addon.assets
    bpy.ops.meta_sim.generate_city()
    _pick(settings, flat_roof=bank.ids("flat")[1], sloped_roof=bank.ids("sloped")[1])
    bpy.ops.meta_sim.apply_design()
    settings.presets_folder = str(infer_folder)
    bpy.ops.meta_sim.build_assets()
    asset = _library_assets(infer_folder / "meta-sim-assets" / "meta-sim-designs.blend")["kampala-006"]
    library = addon.blender_addon.library.require(settings)
    before, counts = _materials(), _counts()
    buildings = sys.modules[f"{MODULE}.meta_sim.blender.scene"].city_buildings(settings.city_key).name

    assets.apply_asset(bpy.context.scene, settings, library, asset)
    after = _materials()
    changed = {(name, slot) for name in before for slot, (a, b) in enumerate(zip(before[name], after[name])) if a != b}
    assert changed == {(buildings, 1), (buildings, 2)} and _counts() == counts  # the old roofs are gone
    assert after[buildings][1:] == [f"roof:{bank.ids('flat')[6]}", f"roof:{bank.ids('sloped')[2]}"]
    assert _picked(settings) == {"flat_roof": bank.ids("flat")[6], "sloped_roof": bank.ids("sloped")[2]}
    assert addon.blender_addon.assets_ui.META_SIM_OT_apply_asset.bl_options >= {"UNDO"}

    # the preset file is the truth: edited, the asset applies the edit; broken or gone, nothing changes
    preset = load_preset(infer_folder / "presets" / "kampala-006.json")
    preset.design = {"flat_roof": bank.ids("flat")[8], "sloped_roof": bank.ids("sloped")[2]}
    save_preset(infer_folder / "presets" / "kampala-006.json", preset)
    assets.apply_asset(bpy.context.scene, settings, library, asset)
    assert _materials()[buildings][1] == f"roof:{bank.ids('flat')[8]}"
    applied = _materials()
    (infer_folder / "presets" / "kampala-006.json").write_text("{")
    with pytest.raises(Exception, match="not valid JSON"):
        assets.apply_asset(bpy.context.scene, settings, library, asset)
    (infer_folder / "presets" / "kampala-006.json").unlink()
    with pytest.raises(Exception, match="is gone; rebuild the asset library"):
        assets.apply_asset(bpy.context.scene, settings, library, asset)
    escaping = SimpleNamespace(full_library_path=asset.full_library_path,
                               metadata={**asset.metadata, "preset": "../../outside.json"})
    with pytest.raises(Exception, match="points outside its folder"):
        assets.apply_asset(bpy.context.scene, settings, library, escaping)
    assert _materials() == applied and _picked(settings)["flat_roof"] == bank.ids("flat")[8]


def test_saving_a_preset_adds_it_to_the_folders_asset_library(addon, settings, infer_folder, bank):
    import bpy

    bpy.ops.meta_sim.generate_city()
    settings.presets_folder = str(infer_folder)
    bpy.ops.meta_sim.load_presets()
    bpy.ops.meta_sim.build_assets()
    library_dir = infer_folder / "meta-sim-assets"
    previews = {p: p.stat().st_mtime_ns for p in (library_dir / "previews").iterdir()}
    settings.seed += 1  # a new city in the panel: the library keeps the city its previews show
    bpy.ops.meta_sim.generate_city()
    _pick(settings, flat_roof=bank.ids("flat")[7], sloped_roof=bank.ids("sloped")[3])
    assert bpy.ops.meta_sim.save_preset(filepath=str(infer_folder / "presets" / "mine.json")) == {"FINISHED"}
    found = _library_assets(library_dir / "meta-sim-designs.blend")
    assert set(found) == {"kampala-005", "kampala-006", "population", "mine"}
    assert json.loads(found["mine"].metadata["design"]) == {"flat_roof": bank.ids("flat")[7],
                                                            "sloped_roof": bank.ids("sloped")[3]}
    now = {p: p.stat().st_mtime_ns for p in (library_dir / "previews").iterdir()}
    assert len(now) == len(previews) + 1 and all(now[p] == t for p, t in previews.items())  # one new render
    assert "mine" in {row.name for row in settings.presets}  # the presets list shows it too

    elsewhere = infer_folder.parent / f"{infer_folder.name}-elsewhere"
    elsewhere.mkdir()
    bpy.ops.meta_sim.save_preset(filepath=str(elsewhere / "other.json"))  # a folder without a library: none made
    assert (elsewhere / "other.json").is_file() and not (elsewhere / "meta-sim-assets").exists()


def test_the_asset_operators_poll_and_the_shelf_shows_only_design_assets(addon, settings, infer_folder):
    import bpy

    assets_ui = addon.blender_addon.assets_ui
    for name in ("apply_asset", "drop_asset"):  # no asset in the context (as outside the Asset Browser)
        assert "Select a Meta-Sim design asset" in _poll_message(name)
    settings.presets_folder = ""
    assert "Choose a presets folder" in _poll_message("build_assets")
    settings.presets_folder = str(infer_folder)
    assert _poll_message("build_assets") is None
    settings.bank_source, settings.bank_folder = "FOLDER", str(infer_folder)
    assert "Load a texture bank first" in _poll_message("build_assets")
    settings.bank_source = "DEFAULT"

    shelf = assets_ui.META_SIM_AST_designs
    bpy.ops.meta_sim.build_assets()
    design = _library_assets(infer_folder / "meta-sim-assets" / "meta-sim-designs.blend")["population"]
    assert shelf.asset_poll(design)
    assert not shelf.asset_poll(SimpleNamespace(metadata={}))  # the shelf lists no other assets
    assert not shelf.asset_poll(SimpleNamespace(metadata={"meta_sim_format": "something else"}))
    if addon.blender_addon.city.find(settings) is not None:
        bpy.ops.meta_sim.remove_city()
    assert not shelf.poll(bpy.context)  # the shelf shows while there is a city to drop designs on
    bpy.ops.meta_sim.generate_city()
    assert shelf.poll(bpy.context)


def test_a_design_dropped_applies_only_over_the_city(addon, settings):
    import bpy
    from mathutils import Vector

    assets_ui = addon.blender_addon.assets_ui
    bpy.ops.meta_sim.generate_city()
    scene, depsgraph = bpy.context.scene, bpy.context.evaluated_depsgraph_get()
    down = Vector((0.0, 0.0, -1.0))
    buildings = sys.modules[f"{MODULE}.meta_sim.blender.scene"].city_buildings(settings.city_key)
    centre = sum((buildings.matrix_world @ Vector(corner) for corner in buildings.bound_box), Vector()) / 8
    assert assets_ui.hits_city(scene, depsgraph, Vector((centre.x, centre.y, 500.0)), down, settings)
    assert not assets_ui.hits_city(scene, depsgraph, Vector((1e5, 1e5, 500.0)), down, settings)
    cube = bpy.data.objects.new("user's cube", bpy.data.meshes.new("user's cube"))
    cube.data.from_pydata([(-1, -1, 0), (1, -1, 0), (1, 1, 0), (-1, 1, 0)], [], [(0, 1, 2, 3)])
    cube.location = (1e5, 1e5, 10.0)
    scene.collection.objects.link(cube)
    try:
        depsgraph = bpy.context.evaluated_depsgraph_get()
        assert not assets_ui.hits_city(scene, depsgraph, Vector((1e5, 1e5, 500.0)), down, settings)
    finally:
        bpy.data.objects.remove(cube)


# Every shipped space; and three cities of four tiles (previewing the last): orthographic ones the worker renders
# as one 2 x 2 block and cuts (the preview path-traces only the tile's part of it with Cycles), and one seen in
# perspective with a sensor, rendered tile by tile.
MATRIX = [(name, 1, "fast") for name in builtin_spaces()] + [
    ("overhead-v3", 4, "fast"), ("overhead-v3", 4, "balanced"), ("overhead-towns-v12", 4, "fast")]
RENDER_ALL = """
import json, sys
from meta_sim.cli import main
for argv in json.load(open(sys.argv[1])):
    try:
        main(argv, standalone_mode=False)
    except SystemExit as exc:
        if exc.code:
            raise
"""


def test_a_preview_tile_of_any_design_in_any_shipped_space_is_the_farms(addon, settings, tmp_path):
    _check_previews(addon, settings, tmp_path, MATRIX)


@pytest.mark.slow
def test_a_path_traced_preview_in_a_city_of_nine_tiles_in_any_shipped_space_is_the_farms(addon, settings, tmp_path):
    _check_previews(addon, settings, tmp_path, [(name, 9, "balanced") for name in builtin_spaces()])


def _check_previews(addon, settings, tmp_path, matrix):
    """For each (space, tiles, quality): a random design picked in the panel's controls, a city generated, the
    preview of its last tile; `meta-sim render` of the exported job, and of the same design in the shipped
    space, write the same pixels."""
    import bpy
    import numpy as np

    from meta_sim.sim.imageio import read_rgb8

    runs, cases = [], []
    for k, (name, n_tiles, quality) in enumerate(matrix):
        space = DesignSpace.load(name)
        settings.space, settings.city_tiles, settings.preview_tile = name, n_tiles, n_tiles - 1
        settings.render_preset = quality
        assert bpy.ops.meta_sim.load_bank() == {"FINISHED"}
        design = space.sample(np.random.default_rng([55, k]), 1)[0]
        _pick(settings, **design)
        picked = addon.blender_addon.design_values.design(settings, addon.blender_addon.library.require(settings).space)
        assert set(picked) == set(space.names) and all(
            picked[n] == design[n] if isinstance(design[n], str) else abs(picked[n] - design[n]) < 1e-4 * (
                1 + abs(design[n])) for n in space.names)
        assert bpy.ops.meta_sim.generate_city() == {"FINISHED"}, name
        job_dir = tmp_path / f"{name}-{n_tiles}-{quality}"
        settings.job_dir = str(job_dir)
        assert bpy.ops.meta_sim.export_job() == {"FINISHED"}
        bpy.ops.meta_sim.render_preview()
        preview = read_rgb8(bpy.path.abspath(bpy.data.images["Meta-Sim Preview"].filepath))
        job = json.loads((job_dir / "render-job.json").read_text())
        assert job["design"] == picked and job["design_space"] == name
        plain = ["render", "--space", name, "--design", space.format(picked), "--seed", str(SMALL["seed"]),
                 "--tiles", str(n_tiles), "--tile-px", "64", "--gsd", "1.8", "--preset", quality,
                 "--out", str(job_dir / "cli"), "--preview"]
        runs += [["render", *job["argv"], "--preview"], plain]
        cases.append((f"{name} ({n_tiles} tiles, {quality})", n_tiles, picked, preview, job_dir))
    (tmp_path / "runs.json").write_text(json.dumps(runs))
    done = subprocess.run([sys.executable, "-c", RENDER_ALL, str(tmp_path / "runs.json")], cwd=ROOT,
                          capture_output=True, text=True)
    assert done.returncode == 0, done.stdout[-2000:] + done.stderr[-3000:]
    differ = []
    for case, n_tiles, picked, preview, job_dir in cases:
        for where in (job_dir / "tiles", job_dir / "cli"):
            exr = next(where.glob(f"*_t{n_tiles - 1:02d}.exr"))
            assert tiles.read_tile(exr).meta["design"] == picked
            if not (read_rgb8(exr.with_suffix(".png")) == preview).all():
                differ.append(f"{case}, {where.name}")
    assert not differ, f"the preview is not the farm's tile in {', '.join(differ)}"
    settings.space, settings.city_tiles, settings.preview_tile = "BANK", SMALL["city_tiles"], 0
    settings.render_preset = "fast"
    bpy.ops.meta_sim.load_bank()
    bpy.ops.meta_sim.remove_city()


@pytest.fixture
def spaces_folder(tmp_path_factory):
    """A group preset of a random design in every shipped space, a population of overhead-towns-v5, and two bad
    ones: of a space meta-sim does not ship, and with a value outside its parameter's range."""
    import numpy as np

    folder = tmp_path_factory.mktemp("spaces")
    designs = {}
    for k, name in enumerate(builtin_spaces()):
        space = DesignSpace.load(name)
        designs[name] = space.sample(np.random.default_rng([56, k]), 1)[0]
        save_preset(folder / f"{name}.json", DesignPreset(kind="group", name=name, design_space=name,
                                                          design=designs[name], model_id="m"))
    towns = DesignSpace.load("overhead-towns-v5")
    groups = [DesignPreset(kind="group", name=f"g{k}", design_space=towns.name, design=d)
              for k, d in enumerate(towns.sample(np.random.default_rng(57), 3))]
    save_preset(folder / "population.json", population(groups, towns, "towns-population"))
    save_preset(folder / "unknown-space.json", DesignPreset(kind="group", name="mine", design_space="my-towns-v1",
                                                            design=designs["overhead-towns-v5"]))
    bright = towns.parameter("brightness")
    save_preset(folder / "too-bright.json", DesignPreset(
        kind="group", name="too-bright", design_space=towns.name,
        design={**designs["overhead-towns-v5"], "brightness": bright.high + 1.0}))
    return folder, designs


def _design(addon, settings) -> dict:
    return addon.blender_addon.design_values.design(settings, addon.blender_addon.library.require(settings).space)


def test_presets_of_every_shipped_space_load_and_apply_whole(addon, settings, spaces_folder, bank):
    import bpy

    folder, designs = spaces_folder
    bpy.ops.meta_sim.generate_city()
    settings.presets_folder = str(folder)
    assert bpy.ops.meta_sim.load_presets() == {"FINISHED"}
    rows = {Path(row.path).stem: row for row in settings.presets}
    assert "'my-towns-v1' is not one meta-sim ships" in rows["unknown-space"].error
    assert "brightness" in rows["too-bright"].error and "out of range" in rows["too-bright"].error
    assert not [name for name in designs if rows[name].error]
    towns = rows["overhead-towns-v5"]
    assert towns.design_space == "overhead-towns-v5" and towns.flat == designs["overhead-towns-v5"]["flat_roof"]
    values = dict(json.loads(towns.values))
    assert values["sensor"] == designs["overhead-towns-v5"]["sensor"] and "flat_roof" not in values
    assert values["brightness"] == designs["overhead-towns-v5"]["brightness"]  # the values themselves, as written
    assert rows["population"].kind == "population" and not rows["population"].error
    calls = _draw_all(addon)  # every row draws, each selected in turn below
    assert any(name == "label" and kw.get("text") == "overhead-towns-v5" for name, args, kw in calls)

    for name in [*designs, "rooftops-v1"]:  # back to the roofs-only space at the end
        settings.presets_index = list(settings.presets).index(rows[name])
        assert bpy.ops.meta_sim.apply_preset() == {"FINISHED"}, name
        assert addon.blender_addon.library.require(settings).space.name == name
        assert _design(addon, settings) == designs[name]  # every parameter, exactly
        assert _roof_images_on_polygons(addon)[1] == str(bank.image_path(designs[name]["flat_roof"]))
        city, space = addon.blender_addon.city, addon.blender_addon.library.require(settings).space
        assert city.find(settings)[city.SCENE_TAG] == city.scene_key(space, city.city_knobs(settings), designs[name])
        _draw_all(addon)
    applied, city_key = _design(addon, settings), settings.city_key
    for name in ("unknown-space", "too-bright"):
        settings.presets_index = list(settings.presets).index(rows[name])
        with pytest.raises(RuntimeError, match="cannot be applied"):
            bpy.ops.meta_sim.apply_preset()
        assert _design(addon, settings) == applied and settings.city_key == city_key
    settings.space = "BANK"
    bpy.ops.meta_sim.load_bank()


def test_assets_preview_and_farm_jobs_are_in_each_presets_own_space(addon, settings, spaces_folder, tmp_path):
    import shutil

    import bpy
    import numpy as np

    from meta_sim.sim.imageio import read_rgb8

    source, designs = spaces_folder
    folder = tmp_path / "presets"
    folder.mkdir()
    for name in ("rooftops-v1", "overhead-towns-v12", "population"):
        shutil.copy(source / f"{name}.json", folder)
    settings.tile_px, settings.gsd = 256, 0.45  # the asset previews' pixels: a preview tile renders the same
    bpy.ops.meta_sim.generate_city()
    settings.presets_folder = str(folder)
    bpy.ops.meta_sim.load_presets()
    assert bpy.ops.meta_sim.build_assets() == {"FINISHED"}
    found = _library_assets(folder / "meta-sim-assets" / "meta-sim-designs.blend")
    assert set(found) == {"rooftops-v1", "overhead-towns-v12", "towns-population"}
    assert "overhead-towns-v12" in found["overhead-towns-v12"].tags
    addon.blender_addon.assets.apply_asset(bpy.context.scene, settings, addon.blender_addon.library.require(settings),
                                           found["overhead-towns-v12"])
    assert settings.space == "overhead-towns-v12" and _design(addon, settings) == designs["overhead-towns-v12"]
    bpy.ops.meta_sim.render_preview()  # the design's own look: its view from a drone, its sensor
    tile = read_rgb8(bpy.path.abspath(bpy.data.images["Meta-Sim Preview"].filepath))
    assert (np.round(found["overhead-towns-v12"].pixels[..., :3] * 255) == tile).all()

    settings.tile_px, settings.gsd = SMALL["tile_px"], SMALL["gsd"]
    bpy.ops.meta_sim.generate_city()
    for kind in ("CURRENT", "POPULATION"):  # the job carries the space; `meta-sim jobs plan` takes its command
        settings.presets_index = next(k for k, row in enumerate(settings.presets) if row.kind == "population")
        job_dir = tmp_path / kind
        settings.job_designs, settings.job_dir, settings.job_images, settings.job_cities = kind, str(job_dir), 3, 2
        assert bpy.ops.meta_sim.export_job() == {"FINISHED"}
        job = json.loads((job_dir / "render-job.json").read_text())
        space = json.loads((job_dir / "design-space.json").read_text())
        expected = "overhead-towns-v12" if kind == "CURRENT" else "overhead-towns-v5"
        assert job["design_space"] == expected and space["name"] == f"{expected}+city-s{SMALL['seed']}"
        plan = shlex.split(job["plan_command"])
        done = subprocess.run([sys.executable, "-m", "meta_sim.cli", *plan[1:]], cwd=ROOT, capture_output=True,
                              text=True)
        assert done.returncode == 0, done.stdout + done.stderr
        farm = json.loads((job_dir / "farm-job.json").read_text())
        assert farm["space"] == space
        if kind == "CURRENT":
            assert [t["design"] for t in farm["tasks"]] == [job["design"]]
        else:
            jobs = json.loads(Path(job["designs_file"]).read_text())["jobs"]
            pairs = list(dict.fromkeys(json.dumps([j["design"], j["city_seed"]], sort_keys=True) for j in jobs))
            assert [json.dumps([t["design"], t["city_seed"]], sort_keys=True) for t in farm["tasks"]] == pairs
            member = [entry["design"] for entry in load_preset(folder / "population.json").designs]
            assert load_preset(job["options"]["population"]).designs == load_preset(
                folder / "population.json").designs and any(j["design"] in member for j in jobs)
    settings.job_designs, settings.space = "CURRENT", "BANK"
    bpy.ops.meta_sim.load_bank()
    bpy.ops.meta_sim.remove_city()


def test_a_space_naming_held_out_textures_builds_only_their_bank_with_progress(addon, settings, prefs, tmp_path,
                                                                              bank, heldout_bank):
    import bpy

    library = addon.blender_addon.library
    held = heldout_bank.ids("flat")[0]
    space = {"format": "meta-sim-design-space", "version": 1, "name": "with-held-out", "parameters": [
        {"name": "flat_roof", "type": "categorical", "texture_kind": "flat", "choices": [bank.ids("flat")[0], held]},
        {"name": "sun", "type": "continuous", "low": 20.0, "high": 70.0, "appearance": "sun_elevation_deg"}],
        "layout": {"sloped_share": 0.0}}
    (tmp_path / "space.json").write_text(json.dumps(space))
    prefs.cache_folder = str(tmp_path / "cache")  # a fresh cache: the held-out bank is still to be built
    settings.bank_source, settings.bank_folder = "FOLDER", str(bank.root)
    settings.space, settings.space_file = "FILE", str(tmp_path / "space.json")
    assert library.get(settings) is None  # drawing never builds: the panel offers Load
    steps, texts = library.load_steps(settings), set()
    while True:
        try:
            texts.add(next(steps)[1])
        except StopIteration as done:
            loaded = done.value
            break
    assert texts == {"building the texture bank heldout-v1 (design space with-held-out names its textures)"}
    assert sorted(p.name for p in (tmp_path / "cache" / "banks").iterdir()) == ["heldout-v1-256"]
    assert loaded.bank_of(held).name == "heldout-v1" and loaded.space.name == "with-held-out"
    bpy.ops.meta_sim.load_bank()
    assert [row.name for row in settings.design] == ["flat_roof", "sun"]
    _pick(settings, flat_roof=held, sun=31.5)
    assert bpy.ops.meta_sim.generate_city() == {"FINISHED"}
    assert _roof_images_on_polygons(addon)[1] == str(loaded.bank_of(held).image_path(held))
    assert _design(addon, settings) == {"flat_roof": held, "sun": 31.5}
    calls = _draw_all(addon)
    assert {("share", "Sun"), ("value", "")} <= {(args[1], kw.get("text")) for name, args, kw in calls
                                                  if name == "prop" and len(args) > 1}
    bpy.ops.meta_sim.remove_city()

    # A shipped space with a bank of other textures: found in the default bank, but a job names one bank.
    prefs.cache_folder = ""
    settings.bank_folder, settings.space = str(heldout_bank.root), "rooftops-v1"
    assert bpy.ops.meta_sim.load_bank() == {"FINISHED"} and bpy.ops.meta_sim.generate_city() == {"FINISHED"}
    assert _roof_images_on_polygons(addon)[1] == str(bank.image_path(_picked(settings)["flat_roof"]))
    settings.job_dir = str(tmp_path / "job")
    with pytest.raises(RuntimeError, match="choose the Default texture bank to export it"):
        bpy.ops.meta_sim.export_job()
    assert not (tmp_path / "job").exists()
    bpy.ops.meta_sim.remove_city()
    settings.space, settings.bank_source, settings.bank_folder = "BANK", "DEFAULT", ""

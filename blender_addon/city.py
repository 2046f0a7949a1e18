"""The add-on's city in the user's file: generate, put a design on it, preview a tile, export a farm job.

Pure bpy work without UI; operators call these and report MetaSimError to the user.
The city is one collection; every datablock it made carries its key (see
``meta_sim.blender.scene``), so regenerating removes the old one completely.
"""

from __future__ import annotations

import contextlib
import json
import shlex
import uuid
from dataclasses import astuple, replace
from pathlib import Path

import bpy

from ..meta_sim.blender.scene import CITY_TAG, bounding_rect, city_buildings, remove_city, set_roofs
from ..meta_sim.core.errors import MetaSimError
from ..meta_sim.core.fileio import write_text_atomic
from ..meta_sim.render.jobs import Job, RenderSettings, design_jobs, sample_population, write_job_manifest
from ..meta_sim.render.loop import build_city, finish_tile, layout_params, resolve_textures, tile_blocks, tile_cut
from ..meta_sim.render.options import RENDER_OPTIONS
from ..meta_sim.sim import meshes
from ..meta_sim.sim.design import DesignSpace
from ..meta_sim.sim.layout import layout_for_tiles
from ..meta_sim.sim.presets import DesignPreset, save_preset
from ..meta_sim.sim.preview import label_image, to_srgb8
from ..meta_sim.sim.quality import get_preset
from ..meta_sim.sim.textures import default_bank_dir, write_png
from . import design_values, preferences, previews, tasks

COLLECTION_NAME = "Meta-Sim City"
PARAMS_TAG = "meta_sim_params"  # on the city collection: the knobs it was generated with (JSON)
SCENE_TAG = "meta_sim_scene"  # on the city collection: what its scene depends on besides the knobs
LAYOUT_KNOBS = ("building_density", "sloped_share", "tree_density")  # the panel's layout fields
PREVIEW_IMAGES = ("Meta-Sim Preview", "Meta-Sim Preview Labels")
JOB_FORMAT = "meta-sim-render-request"
JOB_FILE = "render-job.json"
FARM_JOB_FILE = "farm-job.json"  # where the job's `meta-sim jobs plan` command puts the farm manifest


def knobs(settings) -> dict:
    return {"seed": settings.seed, "tiles": settings.city_tiles, "tile_px": settings.tile_px,
            "gsd": round(settings.gsd, 6), "building_density": round(settings.building_density, 6),
            "sloped_share": round(settings.sloped_share, 6), "tree_density": round(settings.tree_density, 6)}


def city_space(space: DesignSpace, params: dict) -> DesignSpace:
    """``space`` with the city's knobs as fixed layout beneath its own (the space's layout and a design's
    layout parameters win): the design space an exported job hands the render worker."""
    return replace(space, layout={**{name: params[name] for name in LAYOUT_KNOBS}, **space.layout})


def look(space: DesignSpace, params: dict, chosen: dict):
    """How the city of the knobs looks wearing a design of ``space`` (``RenderSettings.appearance``: the render
    worker's look of the job the add-on would export)."""
    settings = RenderSettings(space=city_space(space, params), banks=[], preset=get_preset("fast"), out_dir=Path(),
                              n_tiles=params["tiles"], tile_px=params["tile_px"], pixel_size_m=params["gsd"])
    return settings.appearance(Job(chosen, params["seed"], "preview"))


def scene_key(space: DesignSpace, params: dict, chosen: dict) -> str:
    """What the Blender scene of the city wearing a design depends on besides the knobs: its layout fields and
    the look's scene part (designs with the same key differ only in roofs and post-processing)."""
    return repr((layout_params(city_space(space, params), chosen), look(space, params, chosen).scene_key()))


def _city(space: DesignSpace, params: dict, chosen: dict):
    """The city of the knobs wearing a design of ``space``, as the render worker plans it: its layout, the
    rectangles of all its tiles and its look."""
    fields = layout_params(city_space(space, params), chosen)
    layout, rects = layout_for_tiles(params["seed"], params["tiles"], params["tile_px"] * params["gsd"], fields)
    return layout, rects, look(space, params, chosen)


def find(settings) -> bpy.types.Collection | None:
    key = settings.city_key
    return next((c for c in bpy.data.collections if key and c.get(CITY_TAG) == key), None)


def city_knobs(settings) -> dict | None:
    collection = find(settings)
    return json.loads(collection[PARAMS_TAG]) if collection is not None else None


def generate_steps(scene: bpy.types.Scene, settings, library, params: dict | None = None):
    """Steps (see ``tasks``): a new city of the panel's knobs (or ``params``) wearing the scene's design (its
    layout, ground, greenness, sun, ... and roofs, as the render worker builds it) replaces the scene's city;
    returns the report. The old city goes only once the new one is complete: cancelled, the half-built one is
    removed and the old one stays."""
    chosen = design_values.design(settings, library.space)
    params = params or knobs(settings)
    textures = resolve_textures(library.space, chosen, library.banks)
    layout, rects, city_look = yield from tasks.Threaded(
        lambda progress: _city(library.space, params, chosen)).wait("laying out the city", 0.0, 0.4)
    key = f"meta-sim-{uuid.uuid4().hex[:12]}"
    collection = bpy.data.collections.new(COLLECTION_NAME)
    collection[CITY_TAG] = key
    try:
        scene.collection.children.link(collection)
        yield 0.4, "building the city"
        city = build_city(layout, rects, params["gsd"], city_look, collection=collection, key=key)
        city.close()
        collection[PARAMS_TAG] = json.dumps(params)
        collection[SCENE_TAG] = scene_key(library.space, params, chosen)
        yield 0.9, "putting the roofs on"
        _put_roofs(key, textures)
    except BaseException:
        remove_city(key)  # a half-built city must not stay behind as orphans
        raise
    remove(settings)
    settings.city_key = key
    return f"city {layout.width_m:.0f} m wide: {len(city.buildings)} buildings, {city.n_trees} trees"


def remove(settings) -> int:
    """Delete the generated city; returns how many datablocks went."""
    count = remove_city(settings.city_key) if settings.city_key else 0
    settings.city_key = ""
    return count


def apply_design(scene: bpy.types.Scene, settings, library, chosen: dict) -> bool:
    """Make a design of the library's space the scene's and put it on the city: its roofs, and when it changes
    the city's layout or look, the city built again from the same knobs. False when there is no city or it
    has no buildings to put roofs on; nothing changes when the design does not fit the space."""
    design_values.set_design(settings, library.space, chosen)
    collection = find(settings)
    if collection is None:
        return False
    params = json.loads(collection[PARAMS_TAG])
    if collection.get(SCENE_TAG) == scene_key(library.space, params, design_values.design(settings, library.space)):
        return _put_roofs(settings.city_key, resolve_textures(library.space, chosen, library.banks))
    tasks.run(generate_steps(scene, settings, library, params))
    return True


def _put_roofs(key: str, textures: dict) -> bool:
    buildings = city_buildings(key)
    if buildings is None:
        return False
    set_roofs(buildings, textures, drop_unused=True)
    return True


def roof_images(settings) -> dict:
    """Roof slot -> image file path of the texture on it (for the panel and tests)."""
    buildings = city_buildings(settings.city_key) if settings.city_key else None
    out = {}
    if buildings is not None:
        for slot in (meshes.FLAT_ROOF, meshes.SLOPED_ROOF):
            material = buildings.data.materials[slot]
            images = [n.image for n in material.node_tree.nodes if n.type == "TEX_IMAGE" and n.image]
            if images and images[0].filepath:
                out[slot] = bpy.path.abspath(images[0].filepath)
    return out


def render_preview_steps(settings, library):
    """Steps (see ``tasks``): render one tile of the city (or of the panel's knobs before a city exists) wearing
    the scene's design, as the render worker renders it; returns the two images (RGB and the colour-coded
    label pass).

    The city is rebuilt in a private, temporary collection and removed afterwards (also when cancelled); the
    images are PNGs in the extension's user folder, written at the end.
    """
    params = city_knobs(settings) or knobs(settings)
    tile = min(settings.preview_tile, params["tiles"] - 1)
    chosen = design_values.design(settings, library.space)
    textures = resolve_textures(library.space, chosen, library.banks)
    preset = get_preset(preferences.quality(settings))
    with tile_city(library.space, params, chosen) as (city, look):
        yield 0.05, "building the preview tile"
        city.set_roofs(textures)
        image, instance, roof_class = yield from render_tile_steps(
            city, look, tile, params, params["tile_px"], preset, f"rendering the tile ({preset.name})", 0.1, 1.0)
    folder = preferences.user_dir("preview")
    paths = (folder / "preview.png", folder / "preview_labels.png")
    write_png(paths[0], to_srgb8(image))
    write_png(paths[1], label_image(instance, roof_class))
    return tuple(_show(name, path) for name, path in zip(PREVIEW_IMAGES, paths))


def render_tile_steps(city, look, tile: int, params: dict, tile_px: int, preset, text: str, start: float,
                      end: float):
    """Steps (progress from ``start`` to ``end``): tile ``tile`` of a built city of the knobs ``params``, ``tile_px``
    pixels square, as the render worker renders it: the block the worker renders it in, cut as the worker cuts
    it (a tile rendered alone differs at its edges), finished by ``look``; returns it with its labels."""
    block = bounding_rect([city.rects[j] for j in tile_blocks([astuple(r) for r in city.rects], look, [tile])[0]])
    cut = tile_cut(block, city.rects[tile], city.pixel_size_m, tile_px)
    instance, roof_class = (labels[cut] for labels in city.render_labels(block))
    rgb = yield from tasks.scaled(city.render_rgb_in_strips(block, preset, cut=cut), text, start, end)
    return finish_tile(look, rgb, instance, roof_class, params["seed"], tile, preset), instance, roof_class


@contextlib.contextmanager
def tile_city(space: DesignSpace, params: dict, chosen: dict, pixel_size_m: float | None = None):
    """The city of ``params`` wearing a design of ``space``, with every tile the render worker's scene holds,
    in a private, temporary collection (its own render scene) removed when the block ends, and its look;
    ``pixel_size_m`` renders it at another resolution than the knobs'."""
    layout, rects, city_look = _city(space, params, chosen)
    key = f"meta-sim-preview-{uuid.uuid4().hex[:8]}"
    collection = bpy.data.collections.new("Meta-Sim Preview Tile")
    collection[CITY_TAG] = key
    city = None
    try:
        city = build_city(layout, rects, pixel_size_m or params["gsd"], city_look, collection=collection, key=key)
        yield city, city_look
    finally:
        if city is not None:
            city.close()
        remove_city(key)


def _show(name: str, path: Path) -> bpy.types.Image:
    """The named image, (re)loaded from ``path``; its thumbnail refreshed for the panel."""
    image = bpy.data.images.get(name)
    if image is None:
        image = bpy.data.images.load(str(path))
        image.name = name
    else:
        image.filepath = str(path)
        image.reload()
    previews.icon_for_file(str(path), reload=True)
    return image


def export_job(settings, library, job_dir: Path, population: DesignPreset | None = None,
               population_space: DesignSpace | None = None) -> Path:
    """Write ``render-job.json`` (and the design space with the city's layout) for the render worker.

    The worker has no options for the city knobs, but a design space may fix layout fields: the job's
    ``design-space.json`` is the scene's design space (or the population's, ``population_space``) with the
    city's knobs beneath its own layout, so the farm renders the same city the artist sees.

    Without ``population`` the job renders the current city with the scene's design. With it, the job
    renders ``job_images`` designs drawn from the population (copied into the job as ``population.json``,
    in the job's space) in ``job_cities`` cities of the panel's knobs, seeds ``seed``, ``seed + 1``, ...;
    the worker draws the same designs from the same seed, and ``tiles/designs.json`` records them
    already, as `meta-sim render --population` writes it.
    """
    if population is None:
        params = city_knobs(settings)
        if params is None:
            raise MetaSimError("generate a city first: the job renders the current city")
    else:
        params = knobs(settings)
    default = default_bank_dir(cache_dir=preferences.cache_dir())
    if settings.bank_source != "DEFAULT" and any(bank.root == default for bank in library.banks[1:]):
        raise MetaSimError(f"design space {library.space.name!r} takes textures of the default bank, and a render "
                           "job names one bank: choose the Default texture bank to export it")
    job_dir = Path(job_dir)
    base = population_space or library.space
    space = city_space(base, params).to_dict()
    space["name"] = f"{base.name}+city-s{params['seed']}"
    space_path, out = job_dir / "design-space.json", job_dir / "tiles"
    options = {"seed": params["seed"], "tiles": params["tiles"], "preset": preferences.quality(settings),
               "out": str(out), "space": str(space_path), "tile_px": params["tile_px"], "gsd": params["gsd"],
               "bank": None if settings.bank_source == "DEFAULT" else str(library.bank.root)}
    if population is None:
        chosen = design_values.design(settings, library.space)
        options["design"] = library.space.format(chosen)
        what = {"design": chosen}
    else:
        population = replace(population, design_space=space["name"])  # the job's space: the knobs are its layout
        options.update(population=str(job_dir / "population.json"), images=settings.job_images,
                       r=round(settings.job_rejection, 6), cities=settings.job_cities)
        jobs, render_settings = _population_jobs(DesignSpace.from_dict(space), population, options)
        what = {"population": population.name}
    try:
        job_dir.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise MetaSimError(f"cannot create job folder {job_dir}: {exc.strerror}; choose another") from None
    argv = _argv(options)
    plan_argv = [*_argv({**options, "out": None}), "--out", str(job_dir / FARM_JOB_FILE), "--out-dir", str(out)]
    path = job_dir / JOB_FILE
    try:
        write_text_atomic(space_path, json.dumps(space, indent=1) + "\n")
        if population is not None:
            save_preset(options["population"], population)
            what["designs_file"] = str(write_job_manifest(out, jobs, render_settings))
        job = {"format": JOB_FORMAT, "version": 1, "options": options, "argv": argv,
               "command": shlex.join(["python", "-m", "meta_sim.render.worker", *argv]),
               "blender_command": shlex.join(["blender", "-b", "--python-exit-code", "1", "--python",
                                              "jobs/render_tiles.py", "--", *argv]),
               "plan_command": shlex.join(["meta-sim", "jobs", "plan", *plan_argv]),
               "design_space": base.name, **what, "city": params}
        write_text_atomic(path, json.dumps(job, indent=1) + "\n")
    except OSError as exc:
        raise MetaSimError(f"cannot write the job into {job_dir}: {exc.strerror}; choose another folder") from None
    return path


def _argv(options: dict) -> list[str]:
    """The render worker's command-line arguments for ``options`` (those that are set)."""
    return [item for opt in RENDER_OPTIONS if options.get(opt.dest) is not None
            for item in (opt.flag, str(options[opt.dest]))]


def _population_jobs(space: DesignSpace, population: DesignPreset, options: dict) -> tuple[list, RenderSettings]:
    """The jobs and settings ``meta_sim.render.plan`` makes of a population job's options (the same
    designs from the same seed), without building the texture banks it would check them against."""
    try:
        designs = [space.validate(entry["design"]) for entry in population.designs]
    except MetaSimError as exc:
        raise MetaSimError(f"population {population.name!r}: {exc}") from None
    sampled = sample_population(space, designs, [entry["count"] for entry in population.designs],
                                options["images"], options["r"], options["seed"])
    settings = RenderSettings(space=space, banks=[], preset=get_preset(options["preset"]),
                              out_dir=Path(options["out"]), n_tiles=options["tiles"],
                              tile_px=options["tile_px"], pixel_size_m=options["gsd"])
    return design_jobs(space, sampled, options["seed"], options["cities"]), settings

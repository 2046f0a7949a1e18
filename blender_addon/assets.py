"""Designs in Blender's Asset Browser: a folder of presets becomes an asset library, and an asset applies its design.

What the library holds is decided in ``meta_sim.sim.design_assets``; here it is written with
``bpy``: one Scene datablock per preset (a type that nothing in the 3D Viewport acts on when
dropped, so only the add-on's own drag and Apply do anything with it), marked as an asset with a
preview (a tile of a small city wearing the design, rendered as the panel's preview is), a
description, tags, custom properties and a catalog. The datablocks are made in a temporary
database (``bpy.data.temp_data``), so the user's file never holds them, and written with
``libraries.write`` to a temporary file renamed into place. ``library.json`` beside it records the
city, tile and quality the previews show, so adding a preset later renders only the new design.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import bpy
import numpy as np

from ..meta_sim.core.errors import MetaSimError
from ..meta_sim.core.fileio import atomic_path, write_text_atomic
from ..meta_sim.render.loop import resolve_textures
from ..meta_sim.sim import design_assets as lib
from ..meta_sim.sim.design import DesignSpace
from ..meta_sim.sim.imageio import read_rgb8
from ..meta_sim.sim.presets import DesignPreset
from ..meta_sim.sim.preview import to_srgb8
from ..meta_sim.sim.quality import PRESETS, get_preset
from ..meta_sim.sim.textures import write_png
from . import city, preferences
from . import library as libraries

SETTINGS_FILE = "library.json"
SETTINGS_FORMAT = "meta-sim-design-library"
NAME_PREFIX = "Meta-Sim: "
# The city knobs a library's previews were rendered with, and the range each may take (as the panel's).
KNOB_RANGES = {"seed": (0, 2**31 - 1), "tiles": (1, 64), "tile_px": (16, 4096), "gsd": (0.01, 10.0),
               "building_density": (0.0, 1.0), "sloped_share": (0.0, 1.0), "tree_density": (0.0, 1.0)}


def library_dir(folder: Path) -> Path:
    return Path(folder) / lib.LIBRARY_DIR


def _read_settings(out: Path) -> dict | None:
    """The render settings a library recorded, validated (the file comes from disk); None when absent or bad."""
    try:
        data = json.loads((out / SETTINGS_FILE).read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError):
        return None
    if not isinstance(data, dict) or data.get("format") != SETTINGS_FORMAT or data.get("version") != 1:
        return None
    knobs, tile, quality = data.get("city"), data.get("tile"), data.get("quality")
    if not isinstance(knobs, dict) or set(knobs) != set(KNOB_RANGES) or quality not in PRESETS:
        return None
    for name, (lo, hi) in KNOB_RANGES.items():
        value, integer = knobs[name], isinstance(lo, int)
        if isinstance(value, bool) or not isinstance(value, int if integer else (int, float)):
            return None
        if not (math.isfinite(value) and lo <= value <= hi):
            return None
    if isinstance(tile, bool) or not isinstance(tile, int) or not 0 <= tile < knobs["tiles"]:
        return None
    return {"city": knobs, "tile": tile, "quality": quality}


def build_steps(settings, library, folder: Path, keep_settings: bool = False):
    """Steps (see ``tasks``): (re)build the asset library of a presets folder; returns (assets, bad files).

    Previews show the city of the panel's knobs (the current city's when there is one) at the panel's
    preview tile and quality; ``keep_settings`` keeps those the library was built with before (adding a
    preset then renders only its design). Nothing is written before every preview is rendered: cancelled,
    the folder is as it was.
    """
    folder = Path(folder).resolve()
    found, bad = lib.scan(folder, library.space)
    if not found:
        raise MetaSimError(f"no preset in {folder} can be applied (first: {bad[0][0].name}: {bad[0][1]})")
    out = library_dir(folder)
    recorded = _read_settings(out) if keep_settings else None
    if recorded is None:
        knobs = city.city_knobs(settings) or city.knobs(settings)
        recorded = {"city": knobs, "tile": min(settings.preview_tile, knobs["tiles"] - 1),
                    "quality": preferences.quality(settings)}
    shown = [[(f.space, d) for d in (lib.population_designs(f.preset) if f.preset.kind == "population"
                                     else [f.preset.design])] for f in found]
    keys = {_shown_key(space, d): lib.preview_key(d, space, recorded["city"], recorded["quality"], library.bank.name)
            for ds in shown for space, d in ds}
    cached = {key: out / lib.PREVIEWS_DIR / f"{key}.png" for key in keys.values()}
    rendered = {}
    missing = {text: pair for ds in shown for pair in ds
               if not cached[keys[text := _shown_key(*pair)]].is_file()}
    if missing:
        rendered = yield from _render_previews(library, recorded, list(missing.values()), keys)
    yield 0.95, "writing the asset library"
    tiles = {key: rendered[key] if key in rendered else read_rgb8(cached[key]) for key in keys.values()}
    previews = [lib.mosaic([tiles[keys[_shown_key(*pair)]].astype(np.float32) / 255 for pair in ds])
                for ds in shown]
    for key, rgb in rendered.items():
        write_png(cached[key], rgb)
    write_text_atomic(out / SETTINGS_FILE, json.dumps({"format": SETTINGS_FORMAT, "version": 1, **recorded},
                                                      indent=1) + "\n")
    _write_library(out, found, previews)
    register_library(folder)
    return found, bad


def _shown_key(space, design: dict) -> str:
    """A design to preview in its space, as text (a key before its preview key is known)."""
    return json.dumps([space.to_dict(), design], sort_keys=True)


def _render_previews(library, recorded: dict, shown: list[tuple], keys: dict):
    """Steps: a finished tile (``PREVIEW_PX`` square, sRGB) of each (space, design), each in its own space as the
    render worker renders it, by preview key; designs whose city is the same scene share it."""
    knobs, quality = recorded["city"], get_preset(recorded["quality"])
    pixel_size = knobs["tile_px"] * knobs["gsd"] / lib.PREVIEW_PX  # the tile's ground at the preview's pixels
    tile, out = recorded["tile"], {}
    by_scene: dict = {}
    for space, chosen in shown:
        by_scene.setdefault(city.scene_key(space, knobs, chosen), []).append((space, chosen))
    done = 0
    for group in by_scene.values():
        with city.tile_city(group[0][0], knobs, group[0][1], pixel_size_m=pixel_size) as (scene, _):
            for space, chosen in group:
                scene.set_roofs(resolve_textures(space, chosen, library.banks))
                text = f"rendering preview {done + 1} of {len(shown)} ({quality.name})"
                image, _, _ = yield from city.render_tile_steps(
                    scene, city.look(space, knobs, chosen), tile, knobs, lib.PREVIEW_PX, quality, text,
                    0.9 * done / len(shown), 0.9 * (done + 1) / len(shown))
                out[keys[_shown_key(space, chosen)]] = to_srgb8(image)
                done += 1
    return out


def _write_library(out: Path, found: list, previews: list[np.ndarray]) -> None:
    """The catalogs file, then the .blend of the assets (each written to a temporary file, then renamed)."""
    write_text_atomic(out / lib.CATALOG_FILE, lib.catalogs_text(lib.catalog_path(f.preset) for f in found))
    with bpy.data.temp_data() as data:
        scenes = set()
        for entry, name, rgb in zip(found, lib.asset_names(found), previews):
            scene = data.scenes.new(name)
            scene.asset_mark()
            meta = scene.asset_data
            meta.description = lib.description(entry.preset, entry.space)
            meta.catalog_id = lib.catalog_id(lib.catalog_path(entry.preset))
            meta.author = "Meta-Sim"
            for tag in lib.tags(entry.preset, entry.space):
                meta.tags.new(tag, skip_if_exists=True)
            for key, value in lib.properties(entry).items():
                meta[key] = value
            preview = scene.preview_ensure()
            preview.image_size = rgb.shape[1], rgb.shape[0]
            rgba = np.ones(rgb.shape[:2] + (4,), dtype=np.float32)
            rgba[..., :3] = rgb[::-1]  # previews store their bottom row first
            preview.image_pixels_float.foreach_set(rgba.ravel())
            scenes.add(scene)
        with atomic_path(out / lib.BLEND_FILE) as tmp:
            data.libraries.write(str(tmp), scenes, fake_user=True)


def find_library(folder: Path):
    """The asset library of Blender's preferences that points at the folder's library, or None."""
    out = library_dir(folder).resolve()
    for entry in bpy.context.preferences.filepaths.asset_libraries:
        if entry.path and Path(bpy.path.abspath(entry.path)).resolve() == out:
            return entry
    return None


def register_library(folder: Path):
    """List the folder's library in Blender's preferences (once) and refresh open Asset Browsers."""
    entry = find_library(folder)
    if entry is None:
        entry = bpy.context.preferences.filepaths.asset_libraries.new(
            name=f"{NAME_PREFIX}{Path(folder).name}", directory=str(library_dir(folder).resolve()))
        bpy.context.preferences.is_dirty = True  # saved with the preferences
    for window in bpy.context.window_manager.windows:
        for area in window.screen.areas:
            if area.type == "FILE_BROWSER" and area.ui_type == "ASSETS":
                with bpy.context.temp_override(window=window, area=area):
                    if bpy.ops.asset.library_refresh.poll():
                        bpy.ops.asset.library_refresh()
    return entry


def has_library(folder: Path) -> bool:
    return (library_dir(folder) / lib.BLEND_FILE).is_file()


def asset_preset(asset, library) -> tuple[DesignPreset, DesignSpace]:
    """The preset behind an asset (an ``AssetRepresentation``, or anything with its ``full_library_path`` and
    ``metadata``), read from its file, and its design space (``design_assets.load_in_own_space``)."""
    if not asset.full_library_path:
        raise MetaSimError("this design asset is a copy in the current file; apply it from its Meta-Sim library")
    return lib.load_in_own_space(lib.preset_of_asset(asset.full_library_path, asset.metadata), library.space)


def apply_asset(scene, settings, library, asset) -> DesignPreset:
    """Make an asset's design space and design the scene's and put the design on the city (nothing changes when
    its preset does not load)."""
    preset, space = asset_preset(asset, library)
    if city.find(settings) is None:
        raise MetaSimError("generate a city first: a design applies to its roofs")
    if not city.apply_design(scene, settings, libraries.switch(settings, space), preset.design):
        raise MetaSimError("the city has no buildings to put roofs on")
    return preset


def is_design(asset) -> bool:
    return asset is not None and lib.is_design_asset(asset.metadata)

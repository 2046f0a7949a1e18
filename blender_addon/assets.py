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
from ..meta_sim.sim.imageio import read_rgb8
from ..meta_sim.sim.presets import DesignPreset, load_preset
from ..meta_sim.sim.preview import to_srgb8
from ..meta_sim.sim.quality import PRESETS, get_preset
from ..meta_sim.sim.textures import write_png
from . import city, preferences, tasks

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
    shown = [lib.population_designs(f.preset) if f.preset.kind == "population" else [f.preset.design]
             for f in found]
    keys = {json.dumps(d, sort_keys=True): lib.preview_key(d, recorded["city"], recorded["quality"],
                                                             library.bank.name) for ds in shown for d in ds}
    cached = {key: out / lib.PREVIEWS_DIR / f"{key}.png" for key in keys.values()}
    rendered = {}
    missing = [json.loads(text) for text, key in keys.items() if not cached[key].is_file()]
    if missing:
        rendered = yield from _render_previews(library, recorded, missing, keys)
    yield 0.95, "writing the asset library"
    tiles = {key: rendered[key] if key in rendered else read_rgb8(cached[key]) for key in keys.values()}
    previews = [lib.mosaic([tiles[keys[json.dumps(d, sort_keys=True)]].astype(np.float32) / 255 for d in ds])
                for ds in shown]
    for key, rgb in rendered.items():
        write_png(cached[key], rgb)
    write_text_atomic(out / SETTINGS_FILE, json.dumps({"format": SETTINGS_FORMAT, "version": 1, **recorded},
                                                      indent=1) + "\n")
    _write_library(out, found, previews, library.space)
    register_library(folder)
    return found, bad


def _render_previews(library, recorded: dict, designs: list[dict], keys: dict):
    """Steps: a tile of each design (sRGB, ``PREVIEW_PX`` square), by preview key."""
    knobs, quality = recorded["city"], get_preset(recorded["quality"])
    pixel_size = knobs["tile_px"] * knobs["gsd"] / lib.PREVIEW_PX  # the tile's ground at the preview's pixels
    out = {}
    with city.tile_city(library, knobs, recorded["tile"], pixel_size_m=pixel_size) as tile:
        for k, chosen in enumerate(designs):
            tile.set_roofs(resolve_textures(library.space, chosen, [library.bank]))
            text = f"rendering preview {k + 1} of {len(designs)} ({quality.name})"
            rgb = yield from tasks.scaled(tile.render_rgb_in_strips(tile.rects[0], quality), text,
                                          0.9 * k / len(designs), 0.9 * (k + 1) / len(designs))
            out[keys[json.dumps(chosen, sort_keys=True)]] = to_srgb8(quality.tone_map(rgb))
    return out


def _write_library(out: Path, found: list, previews: list[np.ndarray], space) -> None:
    """The catalogs file, then the .blend of the assets (each written to a temporary file, then renamed)."""
    write_text_atomic(out / lib.CATALOG_FILE, lib.catalogs_text(lib.catalog_path(f.preset) for f in found))
    with bpy.data.temp_data() as data:
        scenes = set()
        for entry, name, rgb in zip(found, lib.asset_names(found), previews):
            scene = data.scenes.new(name)
            scene.asset_mark()
            meta = scene.asset_data
            meta.description = lib.description(entry.preset, space)
            meta.catalog_id = lib.catalog_id(lib.catalog_path(entry.preset))
            meta.author = "Meta-Sim"
            for tag in lib.tags(entry.preset, space):
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


def asset_preset(asset, library) -> DesignPreset:
    """The preset behind an asset (an ``AssetRepresentation``, or anything with its ``full_library_path`` and
    ``metadata``), read from its file and checked against the loaded bank's design space."""
    if not asset.full_library_path:
        raise MetaSimError("this design asset is a copy in the current file; apply it from its Meta-Sim library")
    return load_preset(lib.preset_of_asset(asset.full_library_path, asset.metadata), library.space)


def apply_asset(settings, library, asset) -> DesignPreset:
    """Put an asset's design on the city and the roof pickers (nothing changes when its preset does not load)."""
    preset = asset_preset(asset, library)
    if not city.apply_design(settings, library, preset.design):
        raise MetaSimError("generate a city first: a design applies to its roofs")
    city.set_design(settings, library, preset.design)
    return preset


def is_design(asset) -> bool:
    return asset is not None and lib.is_design_asset(asset.metadata)

"""The add-on's preferences (Edit > Preferences > Add-ons > Meta-Sim): cache folder, default bank, preview quality.

Artists set these once; every scene uses them. ``$META_SIM_CACHE`` still works where
no cache folder is set (render farms start Blender with factory preferences), so the
command line, a farm and the add-on can share one cache.
"""

from __future__ import annotations

import os
from pathlib import Path

import bpy
from bpy.props import EnumProperty, StringProperty

from ..meta_sim.sim.quality import PRESETS

# The extension's root package (``bl_ext.<repository>.meta_sim``): Blender keys user folders and preferences by it.
EXTENSION = __package__.rpartition(".")[0]
DEFAULT_QUALITY = "fast"
QUALITY_ITEMS = [(p.name, p.name.title(), p.description) for p in PRESETS.values()]


def user_dir(sub: str = "") -> Path:
    return Path(bpy.utils.extension_path_user(EXTENSION, path=sub, create=True))


class MetaSimPreferences(bpy.types.AddonPreferences):
    bl_idname = EXTENSION

    cache_folder: StringProperty(
        name="Cache Folder", subtype="DIR_PATH",
        description="Where the default texture bank is built and kept; the same folder as the command line's "
                    "cache shares it. Empty: $META_SIM_CACHE when set, else the extension's user folder")
    bank_folder: StringProperty(
        name="Default Bank Folder", subtype="DIR_PATH",
        description="The texture bank (written by `meta-sim textures build --from PHOTOS`) that a scene's "
                    "Folder source uses when the scene names no folder of its own")
    preview_quality: EnumProperty(
        name="Default Preview Quality", items=QUALITY_ITEMS, default=DEFAULT_QUALITY,
        description="Render quality of preview tiles and asset previews when a scene's quality is Default")

    def draw(self, context):
        layout = self.layout
        layout.use_property_split = True
        layout.prop(self, "cache_folder")
        folder, source = cache_dir_and_source()
        layout.label(text=f"Cache in use: {folder} ({source})", icon="INFO")
        layout.prop(self, "bank_folder")
        layout.prop(self, "preview_quality")


def get() -> MetaSimPreferences | None:
    """The preferences, or None when the add-on is not enabled through Blender's add-on system."""
    addon = bpy.context.preferences.addons.get(EXTENSION)
    return addon.preferences if addon is not None else None


def _path(value: str) -> Path | None:
    return Path(bpy.path.abspath(value)).resolve() if value.strip() else None


def cache_dir_and_source() -> tuple[Path, str]:
    """The cache folder and what set it: the preferences, else ``$META_SIM_CACHE``, else the user folder."""
    prefs = get()
    folder = _path(prefs.cache_folder) if prefs is not None else None
    if folder is not None:
        return folder, "preferences"
    env = os.environ.get("META_SIM_CACHE")
    if env:
        return Path(env), "$META_SIM_CACHE"
    return user_dir(), "extension user folder"


def cache_dir() -> Path:
    return cache_dir_and_source()[0]


def default_bank_folder() -> Path | None:
    prefs = get()
    return _path(prefs.bank_folder) if prefs is not None else None


def quality(settings) -> str:
    """The render quality a scene asks for: its own, or the preferences' default."""
    if settings.render_preset != "DEFAULT":
        return settings.render_preset
    prefs = get()
    return prefs.preview_quality if prefs is not None else DEFAULT_QUALITY


CLASSES = (MetaSimPreferences,)

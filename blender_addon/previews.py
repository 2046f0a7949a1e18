"""Thumbnails: texture previews for the roof pickers and preset rows, and the rendered preview tile."""

from __future__ import annotations

import bpy
import bpy.utils.previews

_collections: dict = {}
# Blender keeps only pointers into the strings of dynamic enum items: they must outlive the draw.
_enum_items: dict = {}


def register() -> None:
    _collections["main"] = bpy.utils.previews.new()


def unregister() -> None:
    for pcoll in _collections.values():
        bpy.utils.previews.remove(pcoll)
    _collections.clear()
    _enum_items.clear()


def icon_for_file(path: str, reload: bool = False) -> int:
    """Icon id of an image file's thumbnail (0 before register)."""
    pcoll = _collections.get("main")
    if pcoll is None:
        return 0
    if path not in pcoll:
        pcoll.load(path, path, "IMAGE")
    elif reload:
        pcoll[path].reload()
    return pcoll[path].icon_id


def texture_icon(library, texture_id: str) -> int:
    """Thumbnail of a bank texture, 0 when the library does not hold it."""
    if library is None or not library.bank.contains(texture_id):
        return 0
    return icon_for_file(str(library.bank.image_path(texture_id)))


def texture_items(library, kind: str) -> list:
    """EnumProperty items (id, name, description, icon, number) for the textures a roof parameter allows."""
    parameter = library.texture_parameter(kind) if library is not None else None
    if parameter is None:
        return _enum_items.setdefault(("none", kind), [("NONE", "No textures", f"the bank has no {kind} textures",
                                                        "ERROR", 0)])
    key = (str(library.bank.root), kind)
    if key not in _enum_items:
        items = []
        for number, texture_id in enumerate(parameter.choices):
            entry = library.bank.by_id(texture_id)
            items.append((texture_id, entry.name, f"{texture_id}: repeats every {entry.repeat_m:g} m",
                          texture_icon(library, texture_id), number))
        _enum_items[key] = items
    return _enum_items[key]

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
    """Thumbnail of a texture of the library's banks, 0 when none holds it."""
    bank = library.bank_of(texture_id) if library is not None else None
    return icon_for_file(str(bank.image_path(texture_id))) if bank is not None else 0


def choice_items(library, parameter) -> list:
    """EnumProperty items (id, name, description, icon, number) for a categorical parameter's choices: a roof
    texture parameter's with their thumbnails (once its library is loaded)."""
    if parameter is None or not hasattr(parameter, "choices"):
        return _enum_items.setdefault(("none",), [("NONE", "None", "the design space is not loaded", "ERROR", 0)])
    textures = library if parameter.texture_kind else None
    key = (parameter, None if textures is None else tuple(str(bank.root) for bank in textures.banks))
    if key not in _enum_items:
        items = []
        for number, choice in enumerate(parameter.choices):
            bank = textures.bank_of(choice) if textures is not None else None
            if bank is None:
                items.append((choice, choice, f"{parameter.name} = {choice}", 0, number))
            else:
                entry = bank.by_id(choice)
                items.append((choice, entry.name, f"{choice}: repeats every {entry.repeat_m:g} m",
                              texture_icon(textures, choice), number))
        _enum_items[key] = items
    return _enum_items[key]

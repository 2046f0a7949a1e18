"""The design presets browser: a folder of `meta-sim infer` presets as list rows, and the list that draws them.

Presets are JSON data read by ``meta_sim.presets`` (never executed, unlike
Blender's own ``AddPresetBase`` presets), each in the design space it names (the
scene's, or one meta-sim ships). A file that does not load, is from a newer
meta-sim, names a space meta-sim does not ship or a value its space does not
allow becomes a row with its error, and is never applied.
"""

from __future__ import annotations

import json
from pathlib import Path

import bpy

from ..meta_sim.core.errors import MetaSimError
from ..meta_sim.sim.design import DesignSpace
from ..meta_sim.sim.design_assets import load_in_own_space, preset_files
from ..meta_sim.sim.presets import DesignPreset
from . import library as libraries
from . import previews

TOP_CHOICES = 3  # of a population's distribution, per parameter


def read_folder(folder: Path, library) -> list[dict]:
    """One row per preset file of the folder (``design_assets.preset_files``), each validated in its own space."""
    return [_row(path, library) for path in preset_files(folder)]


def load(path: str, library) -> tuple[DesignPreset, DesignSpace]:
    """A preset and its design space (the scene's when it names it), checked: every value must be one its
    space allows."""
    return load_in_own_space(path, library.space)


def population_row(settings):
    """The loaded population preset's row (the selected one if it is a population, else the first
    loadable population of the folder), or None when no population is loaded."""
    rows = list(settings.presets)
    selected = [rows[settings.presets_index]] if 0 <= settings.presets_index < len(rows) else []
    return next((row for row in selected + rows if row.kind == "population" and not row.error), None)


def load_population(row, library) -> tuple[DesignPreset, DesignSpace]:
    """The population preset of ``row`` and its space, read again (the file may have changed since the list
    was loaded)."""
    preset, space = load(row.path, library)
    if preset.kind != "population" or not preset.designs:
        raise MetaSimError(f"{row.path} is no longer a population preset; load the preset folder again")
    return preset, space


def _row(path: Path, library) -> dict:
    row = {"name": path.stem, "path": str(path)}
    try:
        preset, space = load(str(path), library)
    except MetaSimError as exc:
        return {**row, "error": str(exc).replace(f"{path}: ", "")}
    names = {kind: space.texture_parameter(kind) for kind in ("flat", "sloped")}
    row.update(name=preset.name or path.stem, kind=preset.kind, target=preset.target(), design_space=space.name)
    for kind, parameter in names.items():
        if parameter is not None:
            row[kind] = str(preset.design[parameter.name])
            row[f"{kind}_share"] = preset.confidence(parameter.name)
    textures = {p.name for p in names.values() if p is not None}
    row["values"] = json.dumps([[name, preset.design[name]] for name in space.names if name not in textures])
    for kind, evidence in preset.roof_evidence().items():
        if kind in names:
            row[f"{kind}_evidence"], row[f"{kind}_evidence_outside"] = evidence["share"], evidence["outside"] or ""
    if preset.kind == "population":
        top = {name: sorted(((str(c), float(s)) for c, s in shares.items()), key=lambda cs: -cs[1])[:TOP_CHOICES]
               for name, shares in preset.distribution.items()}
        row["distribution"] = json.dumps(top)
    return row


def fill(settings, rows: list[dict]) -> None:
    settings.presets.clear()
    for values in rows:
        item = settings.presets.add()
        for key, value in values.items():
            setattr(item, key, value)
    settings.presets_index = 0


class META_SIM_UL_presets(bpy.types.UIList):
    """Flat and sloped thumbnails, name, vote shares, design space and target of each preset; the error of a
    bad one."""

    bl_idname = "META_SIM_UL_presets"

    def draw_item(self, context, layout, data, item, icon, active_data, active_propname, index=0):
        if item.error:
            layout.label(text=f"{item.name}: {item.error}", icon="ERROR")
            return
        library = libraries.get_quietly(data)
        row = layout.row(align=True)
        for kind in ("flat", "sloped"):
            texture = getattr(item, kind)
            if texture:
                row.label(text="", icon_value=previews.texture_icon(library, texture))
        row.label(text=item.name, icon="COMMUNITY" if item.kind == "population" else "NONE")
        shares = [f"{getattr(item, f'{kind}_share'):.0%}" for kind in ("flat", "sloped") if getattr(item, kind)]
        outside = any(getattr(item, f"{kind}_evidence_outside") for kind in ("flat", "sloped"))
        row.label(text=" / ".join(shares), icon="ERROR" if outside else "NONE")
        row.label(text=item.design_space)
        row.label(text=item.target)


CLASSES = (META_SIM_UL_presets,)

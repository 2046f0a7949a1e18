"""The Meta-Sim tab of the 3D Viewport sidebar: city, textures, preview and farm job, design presets."""

from __future__ import annotations

import json
from pathlib import Path

import bpy

from . import assets, city, design_values, preferences, presets_ui, previews
from . import library as libraries


class _MetaSimPanel:
    bl_space_type = "VIEW_3D"
    bl_region_type = "UI"
    bl_category = "Meta-Sim"


class META_SIM_PT_city(_MetaSimPanel, bpy.types.Panel):
    bl_idname = "META_SIM_PT_city"
    bl_label = "City"

    def draw(self, context):
        layout = self.layout
        settings = context.scene.meta_sim
        layout.prop(settings, "space")
        if settings.space == libraries.FILE_SPACE:
            layout.prop(settings, "space_file", text="")
        space = libraries.space_quietly(settings)
        bound = {p.layout_field for p in space.parameters if p.layout_field} | set(space.layout) if space else set()
        column = layout.column(align=True)
        column.prop(settings, "seed")
        column.prop(settings, "city_tiles")
        for name in city.LAYOUT_KNOBS:
            line = column.row(align=True)
            line.enabled = name not in bound  # the design space sets it
            line.prop(settings, name)
        if bound & set(city.LAYOUT_KNOBS):
            layout.label(text=f"Greyed out: set by the design space {space.name}", icon="INFO")
        column = layout.column(align=True)
        column.prop(settings, "tile_px")
        column.prop(settings, "gsd")
        tile_m = settings.tile_px * settings.gsd
        layout.label(text=f"Tiles of {tile_m:.1f} m", icon="MESH_GRID")
        row = layout.row(align=True)
        row.operator("meta_sim.generate_city", icon="FILE_REFRESH")
        row.operator("meta_sim.remove_city", text="", icon="TRASH")
        knobs = city.city_knobs(settings)
        if knobs is not None:
            layout.label(text=f"Current city: seed {knobs['seed']}, {knobs['tiles']} tiles", icon="CHECKMARK")


class META_SIM_PT_textures(_MetaSimPanel, bpy.types.Panel):
    bl_idname = "META_SIM_PT_textures"
    bl_label = "Design"
    bl_parent_id = "META_SIM_PT_city"

    def draw(self, context):
        layout = self.layout
        settings = context.scene.meta_sim
        layout.prop(settings, "bank_source", expand=True)
        if settings.bank_source == "FOLDER":
            layout.prop(settings, "bank_folder")
            default = libraries.bank_folder(settings) if not settings.bank_folder.strip() else None
            if default is not None:
                layout.label(text=f"Default from the preferences: {default}", icon="PREFERENCES")
        library = libraries.get_quietly(settings)
        if library is None or not design_values.fits(settings, library.space):
            layout.operator("meta_sim.load_bank", icon="IMPORT")
            return
        layout.label(text=f"Bank {library.bank.name}: {len(library.bank)} textures; space {library.space.name}")
        design_values.draw(layout, settings, library)
        layout.operator("meta_sim.apply_design", icon="MATERIAL")


class META_SIM_PT_render(_MetaSimPanel, bpy.types.Panel):
    bl_idname = "META_SIM_PT_render"
    bl_label = "Preview and Farm Job"
    bl_parent_id = "META_SIM_PT_city"

    def draw(self, context):
        layout = self.layout
        settings = context.scene.meta_sim
        row = layout.row(align=True)
        row.prop(settings, "render_preset")
        if settings.render_preset == "DEFAULT":
            row.label(text=preferences.quality(settings).title())
        row.prop(settings, "preview_tile")
        layout.operator("meta_sim.render_preview", icon="RENDER_STILL")
        shown = [bpy.data.images.get(name) for name in city.PREVIEW_IMAGES]
        if all(shown):
            row = layout.row()
            for image in shown:
                column = row.column()
                column.template_icon(icon_value=previews.icon_for_file(bpy.path.abspath(image.filepath)), scale=6.0)
                column.label(text=image.name)
        layout.separator()
        layout.prop(settings, "job_dir")
        population = presets_ui.population_row(settings)
        row = layout.row()
        row.enabled = population is not None or settings.job_designs == "POPULATION"  # never stuck on it
        row.prop(settings, "job_designs", expand=True)
        if settings.job_designs == "POPULATION":
            column = layout.column(align=True)
            for name in ("job_images", "job_rejection", "job_cities"):
                column.prop(settings, name)
            if population is not None:
                layout.label(text=f"From {population.name}, cities from seed {settings.seed}", icon="COMMUNITY")
        layout.operator("meta_sim.export_job", icon="EXPORT")


class META_SIM_PT_presets(_MetaSimPanel, bpy.types.Panel):
    bl_idname = "META_SIM_PT_presets"
    bl_label = "Design Presets"

    def draw(self, context):
        layout = self.layout
        settings = context.scene.meta_sim
        row = layout.row(align=True)
        row.prop(settings, "presets_folder", text="")
        row.operator("meta_sim.load_presets", text="", icon="FILE_REFRESH")
        layout.template_list("META_SIM_UL_presets", "", settings, "presets", settings, "presets_index", rows=4)
        if 0 <= settings.presets_index < len(settings.presets):
            draw_preset_details(layout.box(), settings, settings.presets[settings.presets_index])
        row = layout.row(align=True)
        row.operator("meta_sim.apply_preset", icon="CHECKMARK")
        row.operator("meta_sim.save_preset", icon="FILE_TICK")
        layout.operator("meta_sim.build_assets", icon="ASSET_MANAGER")
        if settings.presets_folder.strip():
            entry = assets.find_library(Path(bpy.path.abspath(settings.presets_folder)))
            if entry is not None:
                layout.label(text=f"In the Asset Browser as {entry.name!r}", icon="CHECKMARK")


# What a group's roof evidence outside its model's training range means (``DesignPreset.roof_evidence``).
OUTSIDE = {"low": "too few", "high": "roofs everywhere"}


def draw_preset_details(box, settings, item):
    """The selected preset: its design space, its textures large with vote shares and roof evidence, its other
    values, target; a population's distribution."""
    if item.error:
        box.label(text="Cannot apply this preset:", icon="ERROR")
        box.label(text=item.error)
        return
    library = libraries.get_quietly(settings)
    box.label(text=f"Design space {item.design_space}", icon="PRESET")
    row = box.row()
    for kind in ("flat", "sloped"):
        texture = getattr(item, kind)
        if texture:
            column = row.column()
            column.template_icon(icon_value=previews.texture_icon(library, texture), scale=4.0)
            column.label(text=texture)
            column.label(text=f"vote share {getattr(item, f'{kind}_share'):.0%}")
            evidence = getattr(item, f"{kind}_evidence")
            if evidence >= 0:
                outside = getattr(item, f"{kind}_evidence_outside")
                column.label(text=f"roof pixels {evidence:.1%}" + (f": {OUTSIDE[outside]}, unreliable" if outside
                                                                    else ""), icon="ERROR" if outside else "NONE")
    if item.values:
        column = box.column(align=True)
        for name, value in json.loads(item.values):
            column.label(text=f"{name}: {value:.4g}" if isinstance(value, float) else f"{name}: {value}")
    box.label(text=f"Target: {item.target}", icon="IMAGE_DATA")
    if item.distribution:
        box.label(text="Distribution over the target's groups:")
        for parameter, choices in json.loads(item.distribution).items():
            column = box.column(align=True)
            column.label(text=parameter)
            for choice, share in choices:
                column.label(text=f"{share:.0%}  {choice}", icon_value=previews.texture_icon(library, choice))


CLASSES = (META_SIM_PT_city, META_SIM_PT_textures, META_SIM_PT_render, META_SIM_PT_presets)

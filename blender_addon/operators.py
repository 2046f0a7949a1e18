"""Operators of the Meta-Sim panel. Each reports a user's mistake in the UI (never a traceback)."""

from __future__ import annotations

from pathlib import Path

import bpy
from bpy.props import IntProperty, StringProperty
from bpy_extras.io_utils import ExportHelper

from ..meta_sim.core.errors import MetaSimError
from ..meta_sim.sim.presets import DesignPreset, save_preset
from . import city, presets_ui
from . import library as libraries


class _Reporting:
    """``execute`` runs ``run`` and turns MetaSimError and file-system errors into an error report."""

    def execute(self, context):
        try:
            return self.run(context, context.scene.meta_sim)
        except MetaSimError as exc:
            self.report({"ERROR"}, str(exc))
        except OSError as exc:
            self.report({"ERROR"}, f"{exc.filename or 'file'}: {exc.strerror}")
        return {"CANCELLED"}


def _folder(path: str, what: str) -> Path:
    if not path.strip():
        raise MetaSimError(f"choose a {what} folder first")
    return Path(bpy.path.abspath(path))


class META_SIM_OT_load_bank(_Reporting, bpy.types.Operator):
    """Load the chosen texture bank (the default one is built on first use, a few seconds)"""

    bl_idname = "meta_sim.load_bank"
    bl_label = "Load Texture Bank"
    bl_options = {"REGISTER"}

    def run(self, context, settings):
        library = libraries.get(settings, build=True)
        self.report({"INFO"}, f"texture bank {library.bank.name}: {len(library.bank.ids('flat'))} flat, "
                              f"{len(library.bank.ids('sloped'))} sloped textures")
        return {"FINISHED"}


class META_SIM_OT_generate_city(_Reporting, bpy.types.Operator):
    """Build a city from the seed and knobs, replacing the one generated before"""

    bl_idname = "meta_sim.generate_city"
    bl_label = "Generate City"
    bl_options = {"REGISTER", "UNDO"}

    def run(self, context, settings):
        library = libraries.get(settings, build=True)
        summary = city.generate(context.scene, settings, library)
        self.report({"INFO"}, f"city {summary['size_m']:.0f} m wide: {summary['buildings']} buildings, "
                              f"{summary['trees']} trees")
        return {"FINISHED"}


class META_SIM_OT_remove_city(_Reporting, bpy.types.Operator):
    """Delete the generated city and everything it made"""

    bl_idname = "meta_sim.remove_city"
    bl_label = "Remove City"
    bl_options = {"REGISTER", "UNDO"}

    def run(self, context, settings):
        if not city.remove(settings):
            self.report({"WARNING"}, "there is no generated city")
            return {"CANCELLED"}
        return {"FINISHED"}


class META_SIM_OT_apply_roofs(_Reporting, bpy.types.Operator):
    """Put the picked flat and sloped roof textures on the city"""

    bl_idname = "meta_sim.apply_roofs"
    bl_label = "Apply Roofs"
    bl_options = {"REGISTER", "UNDO"}

    def run(self, context, settings):
        library = libraries.require(settings)
        if not city.apply_design(settings, library, city.design(settings, library)):
            raise MetaSimError("generate a city first")
        return {"FINISHED"}


class META_SIM_OT_render_preview(_Reporting, bpy.types.Operator):
    """Render one tile with the chosen quality into the images 'Meta-Sim Preview' and '... Labels'"""

    bl_idname = "meta_sim.render_preview"
    bl_label = "Render Preview Tile"
    bl_options = {"REGISTER", "UNDO"}

    def run(self, context, settings):
        rgb, labels = city.render_preview(settings, libraries.require(settings))
        for area in context.screen.areas if context.screen else ():
            if area.type == "IMAGE_EDITOR":
                area.spaces.active.image = rgb
                break
        self.report({"INFO"}, f"rendered into images {rgb.name!r} and {labels.name!r}")
        return {"FINISHED"}


class META_SIM_OT_export_job(_Reporting, bpy.types.Operator):
    """Write a render job for the farm: the current city and design, or designs sampled from the loaded population"""

    bl_idname = "meta_sim.export_job"
    bl_label = "Export Render Job"
    bl_options = {"REGISTER"}

    @classmethod
    def poll(cls, context):
        settings = context.scene.meta_sim
        if settings.job_designs == "POPULATION" and presets_ui.population_row(settings) is None:
            cls.poll_message_set("No population loaded: load a `meta-sim infer` folder with a population.json "
                                 "(Design Presets), or choose Current Design")
            return False
        return True

    def run(self, context, settings):
        library = libraries.require(settings)
        job_dir = _folder(settings.job_dir, "job")
        population = None
        if settings.job_designs == "POPULATION":
            population = presets_ui.load_population(presets_ui.population_row(settings), library)
        path = city.export_job(settings, library, job_dir, population)
        what = "" if population is None else f" of {settings.job_images} designs sampled from the population"
        self.report({"INFO"}, f"render job{what} written to {path}")
        return {"FINISHED"}


class META_SIM_OT_load_presets(_Reporting, bpy.types.Operator):
    """Read the design presets of a `meta-sim infer` output folder"""

    bl_idname = "meta_sim.load_presets"
    bl_label = "Load Presets"
    bl_options = {"REGISTER", "UNDO"}

    def run(self, context, settings):
        library = libraries.require(settings)
        rows = presets_ui.read_folder(_folder(settings.presets_folder, "preset"), library)
        presets_ui.fill(settings, rows)
        bad = sum(1 for r in rows if r.get("error"))
        self.report({"WARNING"} if bad else {"INFO"},
                    f"{len(rows)} presets, {bad} cannot be applied" if bad else f"{len(rows)} presets")
        return {"FINISHED"}


class META_SIM_OT_apply_preset(_Reporting, bpy.types.Operator):
    """Set the roof textures to the selected preset's design and put them on the city"""

    bl_idname = "meta_sim.apply_preset"
    bl_label = "Apply Preset"
    bl_options = {"REGISTER", "UNDO"}

    index: IntProperty(name="Preset", description="Row of the preset list (-1: the selected one)", default=-1)

    def run(self, context, settings):
        library = libraries.require(settings)
        index = settings.presets_index if self.index < 0 else self.index
        if not 0 <= index < len(settings.presets):
            raise MetaSimError("select a preset first (load a preset folder)")
        row = settings.presets[index]
        # Read again: the file may have changed since the list was loaded. Nothing is set before it validates.
        preset = presets_ui.load(row.path, library)
        applied = city.apply_design(settings, library, preset.design)
        city.set_design(settings, library, preset.design)
        if applied:
            self.report({"INFO"}, f"applied {preset.name or row.name}: {library.space.format(preset.design)}")
        else:
            self.report({"INFO"}, f"roof pickers set to {preset.name or row.name}; generate a city to see it")
        return {"FINISHED"}


class META_SIM_OT_save_preset(_Reporting, bpy.types.Operator, ExportHelper):
    """Save the picked roof textures as a design preset (the JSON format `meta-sim infer` writes)"""

    bl_idname = "meta_sim.save_preset"
    bl_label = "Save Design Preset"
    bl_options = {"REGISTER"}

    filename_ext = ".json"
    filter_glob: StringProperty(default="*.json", options={"HIDDEN"})

    def run(self, context, settings):
        library = libraries.require(settings)
        if not self.filepath.strip():
            raise MetaSimError("choose a file to save the preset to")
        path = Path(bpy.path.abspath(self.filepath))
        if path.suffix != ".json":
            path = path.with_suffix(".json")
        preset = DesignPreset(kind="group", name=path.stem, design_space=library.space.name,
                              design=city.design(settings, library), search={"method": "manual"})
        save_preset(path, preset)
        self.report({"INFO"}, f"design preset written to {path}")
        return {"FINISHED"}


CLASSES = (META_SIM_OT_load_bank, META_SIM_OT_generate_city, META_SIM_OT_remove_city, META_SIM_OT_apply_roofs,
           META_SIM_OT_render_preview, META_SIM_OT_export_job, META_SIM_OT_load_presets,
           META_SIM_OT_apply_preset, META_SIM_OT_save_preset)

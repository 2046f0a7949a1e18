"""Operators of the Meta-Sim panel. Each reports a user's mistake in the UI (never a traceback), and its
``poll`` greys its button out, saying why, while it cannot run. Long ones (`tasks.Stepped`) show progress
and cancel with Esc."""

from __future__ import annotations

from pathlib import Path

import bpy
from bpy.props import StringProperty
from bpy_extras.io_utils import ExportHelper

from ..meta_sim.core.errors import MetaSimError
from ..meta_sim.sim.design_assets import PRESETS_SUBDIR
from ..meta_sim.sim.presets import DesignPreset, save_preset
from . import assets, city, design_values, presets_ui, tasks
from . import library as libraries


def _folder(path: str, what: str) -> Path:
    if not path.strip():
        raise MetaSimError(f"choose a {what} folder first")
    return Path(bpy.path.abspath(path))


# --- poll: why a button is greyed out (each returns True or sets the message and returns False) ---------

def poll_bank_chosen(cls, settings) -> bool:
    if settings.bank_source == "FOLDER" and libraries.bank_folder(settings) is None:
        cls.poll_message_set("Choose a texture bank folder (Design > Folder), or a default bank folder in "
                             "the add-on's preferences")
        return False
    return True


def poll_bank_loaded(cls, settings) -> bool:
    if not poll_bank_chosen(cls, settings):
        return False
    if libraries.get_quietly(settings) is None:
        cls.poll_message_set("Load a texture bank first (Design > Load Texture Bank)")
        return False
    return True


def poll_has_city(cls, settings) -> bool:
    if city.find(settings) is None:
        cls.poll_message_set("Generate a city first (City > Generate City)")
        return False
    return True


class META_SIM_OT_load_bank(tasks.Stepped, bpy.types.Operator):
    """Load the chosen texture bank and design space (banks are built on first use, seconds)"""

    bl_idname = "meta_sim.load_bank"
    bl_label = "Load Texture Bank"
    bl_options = {"REGISTER"}

    @classmethod
    def poll(cls, context):
        return tasks.poll_idle(cls) and poll_bank_chosen(cls, context.scene.meta_sim)

    def steps(self, context, settings):
        library = yield from libraries.load_steps(settings)
        design_values.fit(settings, library.space)
        return (f"texture bank {library.bank.name}: {len(library.bank.ids('flat'))} flat, "
                f"{len(library.bank.ids('sloped'))} sloped textures; design space {library.space.name}")


class META_SIM_OT_generate_city(tasks.Stepped, bpy.types.Operator):
    """Build a city from the seed and knobs, replacing the one generated before (Esc cancels and keeps it)"""

    bl_idname = "meta_sim.generate_city"
    bl_label = "Generate City"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        return tasks.poll_idle(cls) and poll_bank_chosen(cls, context.scene.meta_sim)

    def steps(self, context, settings):
        library = yield from libraries.load_steps(settings)
        return (yield from city.generate_steps(context.scene, settings, library))


class META_SIM_OT_remove_city(tasks.Reporting, bpy.types.Operator):
    """Delete the generated city and everything it made"""

    bl_idname = "meta_sim.remove_city"
    bl_label = "Remove City"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        return tasks.poll_idle(cls) and poll_has_city(cls, context.scene.meta_sim)

    def run(self, context, settings):
        city.remove(settings)
        return {"FINISHED"}


class META_SIM_OT_apply_design(tasks.Reporting, bpy.types.Operator):
    """Put the panel's design on the city: its roofs, and the city built again when its layout or look changed"""

    bl_idname = "meta_sim.apply_design"
    bl_label = "Apply Design"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        settings = context.scene.meta_sim
        return tasks.poll_idle(cls) and poll_bank_loaded(cls, settings) and poll_has_city(cls, settings)

    def run(self, context, settings):
        library = libraries.require(settings)
        if not city.apply_design(context.scene, settings, library, design_values.design(settings, library.space)):
            raise MetaSimError("the city has no buildings to put roofs on")
        return {"FINISHED"}


class META_SIM_OT_render_preview(tasks.Stepped, bpy.types.Operator):
    """Render one tile with the chosen quality into the images 'Meta-Sim Preview' and '... Labels' (Esc cancels)"""

    bl_idname = "meta_sim.render_preview"
    bl_label = "Render Preview Tile"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        return tasks.poll_idle(cls) and poll_bank_loaded(cls, context.scene.meta_sim)

    def steps(self, context, settings):
        rgb, labels = yield from city.render_preview_steps(settings, libraries.require(settings))
        for area in context.screen.areas if context.screen else ():
            if area.type == "IMAGE_EDITOR":
                area.spaces.active.image = rgb
                break
        return f"rendered into images {rgb.name!r} and {labels.name!r}"


class META_SIM_OT_export_job(tasks.Reporting, bpy.types.Operator):
    """Write a render job for the farm: the current city and design, or designs sampled from the loaded population"""

    bl_idname = "meta_sim.export_job"
    bl_label = "Export Render Job"
    bl_options = {"REGISTER"}

    @classmethod
    def poll(cls, context):
        settings = context.scene.meta_sim
        if not (tasks.poll_idle(cls) and poll_bank_loaded(cls, settings)):
            return False
        if not settings.job_dir.strip():
            cls.poll_message_set("Choose a job folder (Preview and Farm Job > Job Folder)")
            return False
        if settings.job_designs == "POPULATION" and presets_ui.population_row(settings) is None:
            cls.poll_message_set("No population loaded: load a `meta-sim infer` folder with a population.json "
                                 "(Design Presets), or choose Current Design")
            return False
        if settings.job_designs == "CURRENT" and city.find(settings) is None:
            cls.poll_message_set("Generate a city first: the job renders the current city (or choose Loaded "
                                 "Population)")
            return False
        return True

    def run(self, context, settings):
        library = libraries.require(settings)
        job_dir = _folder(settings.job_dir, "job")
        population = space = None
        if settings.job_designs == "POPULATION":
            population, space = presets_ui.load_population(presets_ui.population_row(settings), library)
        path = city.export_job(settings, library, job_dir, population, space)
        what = "" if population is None else f" of {settings.job_images} designs sampled from the population"
        self.report({"INFO"}, f"render job{what} written to {path}")
        return {"FINISHED"}


class META_SIM_OT_load_presets(tasks.Reporting, bpy.types.Operator):
    """Read the design presets of a `meta-sim infer` output folder"""

    bl_idname = "meta_sim.load_presets"
    bl_label = "Load Presets"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        settings = context.scene.meta_sim
        if not (tasks.poll_idle(cls) and poll_bank_loaded(cls, settings)):
            return False
        if not settings.presets_folder.strip():
            cls.poll_message_set("Choose a presets folder (the --out folder of `meta-sim infer`)")
            return False
        return True

    def run(self, context, settings):
        library = libraries.require(settings)
        rows = presets_ui.read_folder(_folder(settings.presets_folder, "preset"), library)
        presets_ui.fill(settings, rows)
        bad = sum(1 for r in rows if r.get("error"))
        self.report({"WARNING"} if bad else {"INFO"},
                    f"{len(rows)} presets, {bad} cannot be applied" if bad else f"{len(rows)} presets")
        return {"FINISHED"}


class META_SIM_OT_apply_preset(tasks.Reporting, bpy.types.Operator):
    """Make the selected preset's design space and design the scene's, and put the design on the city"""

    bl_idname = "meta_sim.apply_preset"
    bl_label = "Apply Preset"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        settings = context.scene.meta_sim
        if not (tasks.poll_idle(cls) and poll_bank_loaded(cls, settings)):
            return False
        if not 0 <= settings.presets_index < len(settings.presets):
            cls.poll_message_set("Load a presets folder and select a preset")
            return False
        error = settings.presets[settings.presets_index].error
        if error:
            cls.poll_message_set(f"The selected preset cannot be applied: {error}")
            return False
        return True

    def run(self, context, settings):
        row = settings.presets[settings.presets_index]
        # Read again: the file may have changed since the list was loaded. Nothing is set before it validates.
        preset, space = presets_ui.load(row.path, libraries.require(settings))
        library = libraries.switch(settings, space)
        applied = city.apply_design(context.scene, settings, library, preset.design)
        name = preset.name or row.name
        if applied:
            self.report({"INFO"}, f"applied {name} ({space.name}): {space.format(preset.design)}")
        else:
            self.report({"INFO"}, f"design set to {name} ({space.name}); generate a city to see it")
        return {"FINISHED"}


class META_SIM_OT_save_preset(tasks.Reporting, bpy.types.Operator, ExportHelper):
    """Save the panel's design as a design preset (the JSON format `meta-sim infer` writes)"""

    bl_idname = "meta_sim.save_preset"
    bl_label = "Save Design Preset"
    bl_options = {"REGISTER"}

    filename_ext = ".json"
    filter_glob: StringProperty(default="*.json", options={"HIDDEN"})

    @classmethod
    def poll(cls, context):
        return tasks.poll_idle(cls) and poll_bank_loaded(cls, context.scene.meta_sim)

    def run(self, context, settings):
        library = libraries.require(settings)
        if not self.filepath.strip():
            raise MetaSimError("choose a file to save the preset to")
        path = Path(bpy.path.abspath(self.filepath))
        if path.suffix != ".json":
            path = path.with_suffix(".json")
        preset = DesignPreset(kind="group", name=path.stem, design_space=library.space.name,
                              design=design_values.design(settings, library.space), search={"method": "manual"})
        save_preset(path, preset)
        folder = _presets_folder_of(path, settings)
        added = ""
        if assets.has_library(folder):  # the folder is an asset library: the new design joins it
            tasks.run(assets.build_steps(settings, library, folder, keep_settings=True))
            added = f" and added to the asset library {assets.find_library(folder).name!r}"
        if settings.presets_folder.strip() and folder == Path(bpy.path.abspath(settings.presets_folder)).resolve():
            presets_ui.fill(settings, presets_ui.read_folder(folder, library))
        self.report({"INFO"}, f"design preset written to {path}{added}")
        return {"FINISHED"}


def _presets_folder_of(path: Path, settings) -> Path:
    """The presets folder a saved preset belongs to: the loaded one when it lies in it (or in its presets/
    subfolder, where `meta-sim infer` puts them), else its own folder."""
    parent = path.parent.resolve()
    if settings.presets_folder.strip():
        loaded = Path(bpy.path.abspath(settings.presets_folder)).resolve()
        if parent in (loaded, loaded / PRESETS_SUBDIR):
            return loaded
    return parent


CLASSES = (META_SIM_OT_load_bank, META_SIM_OT_generate_city, META_SIM_OT_remove_city, META_SIM_OT_apply_design,
           META_SIM_OT_render_preview, META_SIM_OT_export_job, META_SIM_OT_load_presets,
           META_SIM_OT_apply_preset, META_SIM_OT_save_preset)

"""Scene properties of the add-on: ``scene.meta_sim`` (city knobs, texture bank, design, preset rows)."""

from __future__ import annotations

import bpy
from bpy.props import (
    CollectionProperty,
    EnumProperty,
    FloatProperty,
    IntProperty,
    PointerProperty,
    StringProperty,
)

from ..meta_sim.render.options import RENDER_OPTIONS
from ..meta_sim.render.plan import LIMITS, MAX_DESIGNS
from ..meta_sim.sim.layout import LayoutParams
from . import design_values, library, preferences

_DEFAULTS = LayoutParams()
_RENDER_DEFAULTS = {opt.dest: opt.default for opt in RENDER_OPTIONS}  # a population job's, as the CLI's
_MAX_CITIES = {name: high for name, _, high in LIMITS}["cities"]


def _space_changed(self, context) -> None:
    """The design's rows follow the space chosen (a space that cannot be read yet: when it is loaded)."""
    space = library.space_quietly(self)
    if space is not None:
        design_values.fit(self, space)


class MetaSimPresetRow(bpy.types.PropertyGroup):
    """One design preset file as the browser shows it (filled by `presets_ui.read_folder`)."""

    path: StringProperty(name="File", subtype="FILE_PATH")
    kind: StringProperty(name="Kind")
    target: StringProperty(name="Target", description="The target imagery the design was inferred from")
    design_space: StringProperty(name="Design Space", description="The space the design was inferred in")
    values: StringProperty(name="Values", description="JSON, [[parameter, value], ...]: the design's values "
                           "other than its roof textures")
    flat: StringProperty(name="Flat Roof")
    sloped: StringProperty(name="Sloped Roof")
    flat_share: FloatProperty(name="Flat Vote Share", subtype="FACTOR")
    sloped_share: FloatProperty(name="Sloped Vote Share", subtype="FACTOR")
    # Roof evidence (group presets of `meta-sim infer`): the share of the group's pixels the roof finder saw
    # as each kind of roof, -1 when the preset records none; "low" or "high" when outside the range of the
    # model's training cities, else "".
    flat_evidence: FloatProperty(name="Flat Roof Pixels", default=-1.0)
    sloped_evidence: FloatProperty(name="Sloped Roof Pixels", default=-1.0)
    flat_evidence_outside: StringProperty(name="Flat Roof Evidence Outside The Training Range")
    sloped_evidence_outside: StringProperty(name="Sloped Roof Evidence Outside The Training Range")
    distribution: StringProperty(name="Distribution", description="Population presets: JSON, parameter -> "
                                 "[[choice, share], ...] (top choices)")
    error: StringProperty(name="Error", description="Why this preset cannot be applied")


class MetaSimSettings(bpy.types.PropertyGroup):
    seed: IntProperty(name="Seed", description="City seed: the same seed builds the same city", min=0, default=1)
    city_tiles: IntProperty(name="City Size", description="Tiles the city covers (a near-square grid), "
                            "as `--tiles` of the render worker", min=1, max=64, default=4)
    tile_px: IntProperty(name="Tile Pixels", description="Tile width and height in pixels", min=16, max=4096,
                         default=384, subtype="PIXEL")
    gsd: FloatProperty(name="Pixel Size", description="Ground sampling distance: metres per pixel",
                       min=0.01, max=10.0, default=0.3, precision=2, unit="LENGTH")
    building_density: FloatProperty(name="Building Density", description="Share of lots built on and how "
                                    "much of a lot a building fills", min=0.0, max=1.0,
                                    default=_DEFAULTS.building_density, subtype="FACTOR")
    sloped_share: FloatProperty(name="Sloped Roofs", description="Share of buildings with gable or hip roofs",
                                min=0.0, max=1.0, default=_DEFAULTS.sloped_share, subtype="FACTOR")
    tree_density: FloatProperty(name="Tree Density", description="Street and yard trees", min=0.0, max=1.0,
                                default=_DEFAULTS.tree_density, subtype="FACTOR")
    city_key: StringProperty(name="City", description="Key of the generated city's datablocks (internal)",
                             options={"HIDDEN"})

    bank_source: EnumProperty(name="Texture Bank", items=[
        ("DEFAULT", "Default", "The built-in procedural bank (built on first use)"),
        ("FOLDER", "Folder", "A bank folder written by `meta-sim textures build --from PHOTOS`"),
    ])
    bank_folder: StringProperty(name="Bank Folder", subtype="DIR_PATH")
    space: EnumProperty(name="Design Space", description="The parameters a design sets (as --space of "
                        "`meta-sim render`)", items=library.SPACE_ITEMS, update=_space_changed)
    space_file: StringProperty(name="Design Space File", description="A design space JSON file",
                               subtype="FILE_PATH", update=_space_changed)
    design: CollectionProperty(type=design_values.MetaSimDesignValue, name="Design",
                               description="The design: a value per parameter of the design space")

    render_preset: EnumProperty(name="Quality", items=[
        ("DEFAULT", "Default", "The default preview quality of the add-on's preferences"),
        *preferences.QUALITY_ITEMS])
    preview_tile: IntProperty(name="Tile", description="Which tile of the city to preview (0 = south-west)",
                              min=0, default=0)
    job_dir: StringProperty(name="Job Folder", description="Where the render job file goes; the farm "
                            "writes tiles into its tiles/ subfolder", subtype="DIR_PATH")
    job_designs: EnumProperty(name="Designs", description="What the exported render job renders", items=[
        ("CURRENT", "Current Design", "The roof pickers' design in the current city"),
        ("POPULATION", "Loaded Population", "Designs sampled from the population preset of the loaded "
         "preset folder, as `meta-sim render --population` samples them"),
    ])
    job_images: IntProperty(name="Images", description="Designs to sample from the population (each rendered "
                            "as City Size tiles), as --images", min=1, max=MAX_DESIGNS, soft_max=10_000,
                            default=_RENDER_DEFAULTS["images"])
    job_rejection: FloatProperty(name="Rejection Rate", description="Diversify with rejection (-r): the "
                                 "probability that a sampled design is replaced by a uniform one (the paper "
                                 "uses 0.25 on real imagery)", min=0.0, max=1.0, default=_RENDER_DEFAULTS["r"],
                                 subtype="FACTOR")
    job_cities: IntProperty(name="Cities", description="Sampled design k is rendered in the city of seed "
                            "Seed + (k mod Cities), as --cities", min=1, max=_MAX_CITIES,
                            default=_RENDER_DEFAULTS["cities"])

    presets_folder: StringProperty(name="Presets", description="A folder of design presets written by "
                                   "`meta-sim infer`", subtype="DIR_PATH")
    presets: CollectionProperty(type=MetaSimPresetRow)
    presets_index: IntProperty(name="Preset", default=0)


CLASSES = (*design_values.CLASSES, MetaSimPresetRow, MetaSimSettings)


def register() -> None:
    bpy.types.Scene.meta_sim = PointerProperty(type=MetaSimSettings)


def unregister() -> None:
    del bpy.types.Scene.meta_sim

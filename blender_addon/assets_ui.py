"""The design asset library in the interface: build it, apply an asset (Asset Browser context menu, the
3D Viewport's asset shelf: click, or drag and release over the city)."""

from __future__ import annotations

from pathlib import Path

import bpy
from bpy_extras import view3d_utils

from ..meta_sim.blender.scene import CITY_TAG
from . import assets, city, operators, tasks
from . import library as libraries


class META_SIM_OT_build_assets(tasks.Stepped, bpy.types.Operator):
    """Make the presets folder an asset library: one asset per preset with a rendered preview, in the Asset
    Browser and the 3D Viewport's asset shelf (Esc cancels)"""

    bl_idname = "meta_sim.build_assets"
    bl_label = "Build Asset Library"
    bl_options = {"REGISTER"}

    @classmethod
    def poll(cls, context):
        settings = context.scene.meta_sim
        if not (tasks.poll_idle(cls) and operators.poll_bank_loaded(cls, settings)):
            return False
        if not settings.presets_folder.strip():
            cls.poll_message_set("Choose a presets folder (the --out folder of `meta-sim infer`)")
            return False
        return True

    def steps(self, context, settings):
        folder = Path(bpy.path.abspath(settings.presets_folder))
        found, bad = yield from assets.build_steps(settings, libraries.require(settings), folder)
        name = assets.find_library(folder).name
        message = f"asset library {name!r}: {len(found)} designs"
        if not bad:
            return message
        skipped = "; ".join(f"{path.name}: {why}" for path, why in bad)
        return {"WARNING"}, f"{message}; {len(bad)} files skipped ({skipped})"


def poll_design_asset(cls, context) -> bool:
    settings = context.scene.meta_sim
    if not tasks.poll_idle(cls):
        return False
    if not assets.is_design(getattr(context, "asset", None)):
        cls.poll_message_set("Select a Meta-Sim design asset (Design Presets > Build Asset Library makes them)")
        return False
    return operators.poll_bank_loaded(cls, settings) and operators.poll_has_city(cls, settings)


class META_SIM_OT_apply_asset(tasks.Reporting, bpy.types.Operator):
    """Make the design asset's space and design the scene's and put it on the city (read from its preset file)"""

    bl_idname = "meta_sim.apply_asset"
    bl_label = "Apply Design to City"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        return poll_design_asset(cls, context)

    def run(self, context, settings):
        preset = assets.apply_asset(context.scene, settings, libraries.require(settings), context.asset)
        self.report({"INFO"}, f"applied {preset.name or context.asset.name}")
        return {"FINISHED"}


class _Held:
    """What a drag needs of the asset once the shelf has let go of it (``context.asset`` is gone by the drop)."""

    def __init__(self, asset):
        self.name = asset.name
        self.full_library_path = asset.full_library_path
        self.metadata = {key: asset.metadata[key] for key in asset.metadata.keys()}


class META_SIM_OT_drop_asset(tasks.Reporting, bpy.types.Operator):
    """Drag a design from the Meta-Sim asset shelf and release it over the city to apply it"""

    bl_idname = "meta_sim.drop_asset"
    bl_label = "Drop Design on City"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        return poll_design_asset(cls, context)

    def invoke(self, context, event):
        self._asset = _Held(context.asset)
        context.window_manager.modal_handler_add(self)
        context.window.cursor_modal_set("EYEDROPPER")
        context.workspace.status_text_set(f"Release over the city to apply {self._asset.name}; Esc cancels")
        return {"RUNNING_MODAL"}

    def modal(self, context, event):
        if event.type in {"ESC", "RIGHTMOUSE"} and event.value == "PRESS":
            self._end(context)
            return {"CANCELLED"}
        if event.type != "LEFTMOUSE" or event.value != "RELEASE":
            return {"RUNNING_MODAL"}
        self._end(context)
        settings = context.scene.meta_sim
        if not city_under_mouse(context, settings, event.mouse_x, event.mouse_y):
            self.report({"WARNING"}, "release the design over the city to apply it")
            return {"CANCELLED"}
        return self.guarded(lambda: self._apply(context, settings))

    def _apply(self, context, settings):
        preset = assets.apply_asset(context.scene, settings, libraries.require(settings), self._asset)
        self.report({"INFO"}, f"applied {preset.name or self._asset.name}")
        return {"FINISHED"}

    @staticmethod
    def _end(context) -> None:
        context.window.cursor_modal_restore()
        context.workspace.status_text_set(None)


def city_under_mouse(context, settings, x: int, y: int) -> bool:
    """Whether the window point (x, y) shows the city, in whichever 3D Viewport lies under it."""
    for area in context.window.screen.areas:
        if area.type != "VIEW_3D":
            continue
        for region in area.regions:
            if region.type == "WINDOW" and 0 <= x - region.x < region.width and 0 <= y - region.y < region.height:
                rv3d, point = area.spaces.active.region_3d, (x - region.x, y - region.y)
                origin = view3d_utils.region_2d_to_origin_3d(region, rv3d, point)
                direction = view3d_utils.region_2d_to_vector_3d(region, rv3d, point)
                return hits_city(context.scene, context.evaluated_depsgraph_get(), origin, direction, settings)
    return False


def hits_city(scene, depsgraph, origin, direction, settings) -> bool:
    """Whether a ray from ``origin`` first meets the scene's generated city."""
    hit, _, _, _, obj, _ = scene.ray_cast(depsgraph, origin, direction)
    return bool(hit and settings.city_key and obj.original.get(CITY_TAG) == settings.city_key)


class META_SIM_AST_designs(bpy.types.AssetShelf):
    """The design assets in the 3D Viewport while the scene has a Meta-Sim city: click or drag one onto it."""

    bl_space_type = "VIEW_3D"
    bl_idname = "META_SIM_AST_designs"
    bl_activate_operator = "META_SIM_OT_apply_asset"
    bl_drag_operator = "META_SIM_OT_drop_asset"
    bl_default_preview_size = 96
    filter_scene = True

    @classmethod
    def poll(cls, context):
        return context.mode == "OBJECT" and city.find(context.scene.meta_sim) is not None

    @classmethod
    def asset_poll(cls, asset):
        return assets.is_design(asset)

    @classmethod
    def draw_context_menu(cls, context, asset, layout):
        layout.operator("meta_sim.apply_asset", icon="MATERIAL")


def draw_asset_browser_menu(self, context) -> None:
    """The Asset Browser's context menu: Apply Design to City, on a Meta-Sim design."""
    if assets.is_design(getattr(context, "asset", None)):
        self.layout.separator()
        self.layout.operator("meta_sim.apply_asset", icon="MATERIAL")


CLASSES = (META_SIM_OT_build_assets, META_SIM_OT_apply_asset, META_SIM_OT_drop_asset, META_SIM_AST_designs)


def register() -> None:
    bpy.types.ASSETBROWSER_MT_context_menu.append(draw_asset_browser_menu)


def unregister() -> None:
    bpy.types.ASSETBROWSER_MT_context_menu.remove(draw_asset_browser_menu)


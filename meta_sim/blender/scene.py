"""A city layout as a Blender scene: built once, re-materialed per design, rendered in blocks.

Everything here touches ``bpy``; nothing here imports torch. The same code
runs inside ``blender -b`` and with the ``bpy`` module.

* Geometry is built once per city, and only what the requested tiles see
  (plus a margin for shadows cast into them). A design only swaps the
  materials of the flat-roof and sloped-roof slots and rescales their UVs to
  the texture's physical repeat size.
* Several adjacent tiles are rendered as one image and cut afterwards: an
  orthographic nadir camera makes that exact, and it spreads the per-render
  overhead over the tiles.
* Labels come from a separate Workbench render with flat shading, no
  anti-aliasing and the per-polygon label colours of ``meshes.label_color``:
  every pixel is one exact instance id and roof class, independent of the
  design, so they are rendered once per city.
"""

from __future__ import annotations

import contextlib
import math
import os
import sys
import tempfile
from dataclasses import dataclass

import bpy
import numpy as np
import OpenImageIO as oiio

from .. import meshes
from ..errors import MetaSimError
from ..render_presets import RenderPreset

LABEL_ATTRIBUTE = "label"
UV_NAME = "UVMap"


@dataclass(frozen=True)
class Rect:
    x0: float
    y0: float
    x1: float
    y1: float

    def grown(self, margin: float) -> "Rect":
        return Rect(self.x0 - margin, self.y0 - margin, self.x1 + margin, self.y1 + margin)


def bounding_rect(rects) -> Rect:
    return Rect(min(r.x0 for r in rects), min(r.y0 for r in rects),
                max(r.x1 for r in rects), max(r.y1 for r in rects))


def _new_mesh_object(arrays: meshes.MeshArrays, materials) -> bpy.types.Object:
    data = arrays.arrays()
    mesh = bpy.data.meshes.new(arrays.name)
    mesh.vertices.add(len(data["vertices"]))
    mesh.vertices.foreach_set("co", data["vertices"].ravel())
    mesh.loops.add(len(data["loop_vertex"]))
    mesh.loops.foreach_set("vertex_index", data["loop_vertex"])
    mesh.polygons.add(len(data["loop_start"]))
    mesh.polygons.foreach_set("loop_start", data["loop_start"])
    mesh.polygons.foreach_set("loop_total", data["loop_total"])
    mesh.polygons.foreach_set("material_index", data["material"])
    uv = mesh.uv_layers.new(name=UV_NAME)
    uv.data.foreach_set("uv", data["uv"].ravel())
    label = mesh.color_attributes.new(LABEL_ATTRIBUTE, "FLOAT_COLOR", "CORNER")
    label.data.foreach_set("color", data["label"].ravel())
    mesh.color_attributes.active_color = label
    mesh.update(calc_edges=True)
    mesh.validate(verbose=False)
    for material in materials:
        mesh.materials.append(material)
    obj = bpy.data.objects.new(arrays.name, mesh)
    bpy.context.scene.collection.objects.link(obj)
    return obj


def _image_material(name: str, image: bpy.types.Image, roughness: float = 0.85) -> bpy.types.Material:
    """A diffuse material whose base colour is one image (Workbench shows that image too)."""
    material = bpy.data.materials.new(name)
    tree = material.node_tree if material.node_tree else None
    if tree is None:  # Blender < 5 creates node trees only on request
        material.use_nodes = True
        tree = material.node_tree
    bsdf = next(n for n in tree.nodes if n.type == "BSDF_PRINCIPLED")
    bsdf.inputs["Roughness"].default_value = roughness
    tex = tree.nodes.new("ShaderNodeTexImage")
    tex.image = image
    tex.interpolation = "Linear"
    tree.nodes.active = tex
    tree.links.new(tex.outputs["Color"], bsdf.inputs["Base Color"])
    return material


def _noise_image(name: str, colour, amount: float, seed: int, size: int = 64) -> bpy.types.Image:
    """A small tileable speckle image for ground, roads, walls and trees."""
    rng = np.random.default_rng(seed)
    base = np.asarray(colour, dtype=np.float32)
    noise = rng.normal(0.0, amount, (size, size, 1)).astype(np.float32)
    rgba = np.ones((size, size, 4), dtype=np.float32)
    rgba[..., :3] = np.clip(base * (1.0 + noise), 0.0, 1.0)
    image = bpy.data.images.new(name, size, size, float_buffer=True)
    image.pixels.foreach_set(rgba.ravel())
    image.pack()
    return image


@contextlib.contextmanager
def _quiet(log_path: str):
    """Send Blender's per-frame chatter (and GL warnings) to a log file instead of the terminal.

    On failure the log's tail is attached to the error, so nothing useful is lost.
    """
    sys.stdout.flush()
    sys.stderr.flush()
    saved = os.dup(1), os.dup(2)
    with open(log_path, "w") as log:
        os.dup2(log.fileno(), 1)
        os.dup2(log.fileno(), 2)
        try:
            yield
        except RuntimeError as exc:
            os.dup2(saved[0], 1)
            os.dup2(saved[1], 2)
            with open(log_path) as text:
                tail = text.read()[-2000:]
            raise RuntimeError(f"{exc}\nBlender said:\n{tail}") from None
        finally:
            os.dup2(saved[0], 1)
            os.dup2(saved[1], 2)
            os.close(saved[0])
            os.close(saved[1])


class CityScene:
    """One city in the current Blender session (the scene is reset on construction)."""

    def __init__(self, layout, rects, *, pixel_size_m: float, shadow_margin_m: float = 40.0):
        self.layout = layout
        self.pixel_size_m = pixel_size_m
        self.rects = [Rect(*r) if not isinstance(r, Rect) else r for r in rects]
        bpy.ops.wm.read_factory_settings(use_empty=True)
        self.scene = bpy.context.scene
        self._materials: dict[str, bpy.types.Material] = {}
        self._tmp = tempfile.mkdtemp(prefix="meta-sim-", dir="/dev/shm" if os.path.isdir("/dev/shm") else None)
        self._build(shadow_margin_m)
        self._setup_camera_and_light()

    # --- construction ------------------------------------------------------
    def _visible(self, items_in_rect, margin: float):
        seen, out = set(), []
        for r in self.rects:
            g = r.grown(margin)
            for item in items_in_rect(g.x0, g.y0, g.x1, g.y1):
                if id(item) not in seen:
                    seen.add(id(item))
                    out.append(item)
        return out

    def _build(self, margin: float) -> None:
        lay = self.layout
        self.buildings = sorted(self._visible(lay.buildings_in_rect, margin), key=lambda b: b.id)
        roads = self._visible(lay.roads_in_rect, 0.0)
        trees = self._visible(lay.trees_in_rect, margin)
        region = bounding_rect(self.rects).grown(margin)
        seed = int(lay.seed)
        grey = _image_material("wall", _noise_image("wall", (0.45, 0.43, 0.40), 0.05, seed), 0.9)
        self._placeholder = {
            meshes.FLAT_ROOF: _image_material("flat-roof-unset", _noise_image("unset-f", (0.5, 0.5, 0.5), 0.0, 0)),
            meshes.SLOPED_ROOF: _image_material("sloped-roof-unset", _noise_image("unset-s", (0.5, 0.5, 0.5), 0.0, 0)),
        }
        ground = _image_material("ground", _noise_image("ground", (0.20, 0.26, 0.12), 0.25, seed + 1))
        road = _image_material("road", _noise_image("road", (0.09, 0.09, 0.095), 0.15, seed + 2))
        tree = _image_material("tree", _noise_image("tree", (0.05, 0.13, 0.035), 0.35, seed + 3))
        self.n_objects = 0
        building_arrays = meshes.building_mesh(self.buildings)
        self.buildings_obj = None
        if building_arrays.n_polygons:
            self.buildings_obj = _new_mesh_object(
                building_arrays,
                [grey, self._placeholder[meshes.FLAT_ROOF], self._placeholder[meshes.SLOPED_ROOF]])
            data = building_arrays.arrays()
            self._base_uv = data["uv"].copy()
            self._loop_slot = np.repeat(data["material"], data["loop_total"])
        _new_mesh_object(meshes.ground_mesh(region.x0, region.y0, region.x1, region.y1), [ground])
        if roads:
            _new_mesh_object(meshes.road_mesh(roads), [road])
        if trees:
            _new_mesh_object(meshes.tree_mesh(trees), [tree])
        self.n_trees, self.n_roads = len(trees), len(roads)

    def _setup_camera_and_light(self) -> None:
        scene = self.scene
        camera = bpy.data.cameras.new("nadir")
        camera.type = "ORTHO"
        camera.clip_start, camera.clip_end = 1.0, 2000.0
        self.camera = bpy.data.objects.new("nadir", camera)
        scene.collection.objects.link(self.camera)
        scene.camera = self.camera
        # Sun direction from the city seed: elevation 45 +- 15 degrees (Synthinel rules).
        rng = np.random.default_rng([int(self.layout.seed), 7])
        elevation = math.radians(float(rng.uniform(30.0, 60.0)))
        azimuth = float(rng.uniform(0.0, 2.0 * math.pi))
        sun = bpy.data.lights.new("sun", "SUN")
        sun.energy = 4.0
        sun.angle = math.radians(0.5)
        sun_obj = bpy.data.objects.new("sun", sun)
        sun_obj.rotation_euler = (math.pi / 2 - elevation, 0.0, azimuth)
        scene.collection.objects.link(sun_obj)
        world = bpy.data.worlds.new("sky")
        world.color = (0.45, 0.5, 0.6)
        scene.world = world
        if world.node_tree is None:
            world.use_nodes = True
        background = next(n for n in world.node_tree.nodes if n.type == "BACKGROUND")
        background.inputs["Color"].default_value = (0.45, 0.5, 0.6, 1.0)
        background.inputs["Strength"].default_value = 0.8
        direction = (math.cos(elevation) * math.sin(azimuth), -math.cos(elevation) * math.cos(azimuth),
                     math.sin(elevation))
        scene.display.light_direction = direction
        scene.view_settings.view_transform = "Standard"
        scene.view_settings.look = "None"
        scene.render.resolution_percentage = 100
        scene.render.use_persistent_data = True
        settings = scene.render.image_settings
        settings.file_format = "OPEN_EXR"
        settings.color_mode = "RGBA"
        settings.color_depth = "32"
        settings.exr_codec = "NONE"

    # --- designs -----------------------------------------------------------
    def _texture_material(self, entry, image_path: str) -> bpy.types.Material:
        key = f"roof:{entry.id}"
        if key not in self._materials:
            try:
                image = bpy.data.images.load(image_path, check_existing=True)
                image.pixels[0]  # force the load now, so a bad file fails here, by name
            except (RuntimeError, IndexError):
                raise MetaSimError(f"cannot read texture image {image_path} (texture {entry.id!r}); "
                                   "rebuild the bank with `meta-sim textures build`") from None
            self._materials[key] = _image_material(key, image)
        return self._materials[key]

    def set_roofs(self, textures: dict) -> None:
        """Put a texture on each roof slot: ``{meshes.FLAT_ROOF: (entry, path), ...}``.

        A slot not given keeps a neutral grey (a space without that roof kind).
        """
        if self.buildings_obj is None:
            return
        mesh = self.buildings_obj.data
        uv = self._base_uv.copy()
        for slot in (meshes.FLAT_ROOF, meshes.SLOPED_ROOF):
            if slot in textures:
                entry, path = textures[slot]
                mesh.materials[slot] = self._texture_material(entry, path)
                uv[self._loop_slot == slot] /= float(entry.repeat_m)
            else:
                mesh.materials[slot] = self._placeholder[slot]
        mesh.uv_layers[UV_NAME].data.foreach_set("uv", uv.ravel())
        mesh.update()

    # --- rendering ---------------------------------------------------------
    def _frame(self, rect: Rect) -> tuple[int, int]:
        width = int(round((rect.x1 - rect.x0) / self.pixel_size_m))
        height = int(round((rect.y1 - rect.y0) / self.pixel_size_m))
        render = self.scene.render
        render.resolution_x, render.resolution_y = width, height
        camera = self.camera.data
        camera.ortho_scale = max(width, height) * self.pixel_size_m
        self.camera.location = ((rect.x0 + rect.x1) / 2, (rect.y0 + rect.y1) / 2, 1000.0)
        self.camera.rotation_euler = (0.0, 0.0, 0.0)
        return width, height

    def _render_to_array(self, rect: Rect, name: str) -> np.ndarray:
        width, height = self._frame(rect)
        path = os.path.join(self._tmp, f"{name}.exr")
        self.scene.render.filepath = path
        with _quiet(os.path.join(self._tmp, "blender.log")):
            bpy.ops.render.render(write_still=True)
        image = oiio.ImageInput.open(path)
        if image is None:
            raise RuntimeError(f"Blender wrote no readable image: {oiio.geterror()}")
        try:
            pixels = image.read_image(format="float")
        finally:
            image.close()
            os.remove(path)
        if pixels is None or pixels.shape[:2] != (height, width):
            raise RuntimeError(f"render of {name} has an unexpected shape")
        return np.asarray(pixels, dtype=np.float32)

    def render_labels(self, rect: Rect) -> tuple[np.ndarray, np.ndarray]:
        """(instance id, roof class) images of a rectangle, row 0 at its north edge."""
        scene = self.scene
        scene.render.engine = "BLENDER_WORKBENCH"
        scene.render.film_transparent = True
        shading = scene.display.shading
        shading.light = "FLAT"
        shading.color_type = "VERTEX"
        for flag in ("show_shadows", "show_cavity", "show_object_outline", "show_specular_highlight",
                     "show_xray", "use_dof"):
            setattr(shading, flag, False)
        scene.display.render_aa = "OFF"
        pixels = self._render_to_array(rect, "labels")
        return meshes.decode_labels(pixels[..., :3])

    def render_rgb(self, rect: Rect, preset: RenderPreset) -> np.ndarray:
        """Linear RGB (float32) of a rectangle with a quality preset."""
        scene = self.scene
        scene.render.film_transparent = False
        if preset.engine == "BLENDER_WORKBENCH":
            scene.render.engine = "BLENDER_WORKBENCH"
            shading = scene.display.shading
            shading.light = "STUDIO"
            shading.color_type = "TEXTURE"
            shading.show_shadows = preset.shadows
            shading.shadow_intensity = 0.55
            shading.show_cavity = False
            shading.show_specular_highlight = False
            scene.display.render_aa = preset.antialiasing
        else:
            scene.render.engine = "CYCLES"
            cycles = scene.cycles
            cycles.device = "CPU"
            cycles.samples = preset.samples
            cycles.use_adaptive_sampling = False
            cycles.use_denoising = preset.denoise
            cycles.max_bounces = preset.bounces
            cycles.diffuse_bounces = preset.bounces
            cycles.glossy_bounces = 0
            cycles.transmission_bounces = 0
            cycles.transparent_max_bounces = 0
            cycles.caustics_reflective = cycles.caustics_refractive = False
            cycles.seed = int(self.layout.seed) % (2**31)
        return self._render_to_array(rect, "rgb")[..., :3]

    def close(self) -> None:
        for name in os.listdir(self._tmp):
            os.remove(os.path.join(self._tmp, name))
        os.rmdir(self._tmp)

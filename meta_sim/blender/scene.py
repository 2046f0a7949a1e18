"""A city layout as a Blender scene: built once, re-materialed per design, rendered in blocks.

Everything here touches ``bpy``; nothing here imports torch. The same code
runs inside ``blender -b`` and with the ``bpy`` module.

* Geometry is built once per city, and only what the requested tiles see
  (plus a margin for shadows cast into them). A design only swaps the
  materials of the flat-roof and sloped-roof slots and rescales their UVs to
  the texture's physical repeat size.
* Several adjacent tiles are rendered as one image and cut afterwards: an
  orthographic nadir camera makes the tiles join exactly, and it spreads the
  per-render overhead over the tiles. A tile cut from a block is not the tile
  rendered alone (anti-aliasing and shadows differ at its edges), so whatever
  must match the farm renders the same block (``render.loop.tile_blocks``).
  A city seen in perspective (``view_height_m``: a drone's photo) is rendered
  tile by tile, each from over its own centre.
* Labels come from a separate Workbench render with flat shading, no
  anti-aliasing and the per-polygon label colours of ``meshes.label_color``:
  every pixel is one exact instance id and roof class, independent of the
  design, so they are rendered once per city.
* Two homes for a city. The render worker owns its whole session and starts
  from an empty file. The add-on works inside a user's file: it passes a
  collection, the city is built into it and rendered through a private scene,
  and every datablock the city creates carries ``CITY_TAG`` so `remove_city`
  deletes it all (no orphans) even after undo or a file reload, when no Python
  object of the city survives. For the same reason `set_roofs` reads
  everything it needs from the mesh (metre UVs in a second UV map).
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

from ..core.errors import MetaSimError
from ..sim import meshes, surfaces
from ..sim.appearance import TREE_COLOUR, foliage_tint, ground_colours, vegetation_colour
from ..sim.clutter import TREE_HEIGHT_M
from ..sim.furniture import SURFACES, roof_furniture
from ..sim.ground import ground_image
from ..sim.quality import (
    SHADOW_DEPTH,
    SHADOW_FOCUS,
    SHADOW_SHIFT,
    SKY_COLOUR,
    RenderPreset,
    cycles_light,
    sun_studio_light,
    workbench_direction,
)
from ..sim.water import WATER_COLOURS

LABEL_ATTRIBUTE = "label"
UV_NAME = "UVMap"
UV_METRES = "UVMetres"  # the design-independent UVs; a design divides them by its textures' repeat sizes
CITY_TAG = "meta_sim_city"  # custom property: the key of the city a datablock belongs to
ROLE_TAG = "meta_sim_role"
TEXTURE_TAG = "meta_sim_texture"
# The nadir camera looks down from CAMERA_HEIGHT_M; nothing of a city lies below the ground (z = 0), so the far
# plane sits FAR_BELOW_GROUND_M under it. Workbench draws a shadow as a volume swept from each silhouette edge
# away from the sun: a far plane 1 km down let every volume fill the frame to its edge, one just under the
# ground cuts it where its shadow ends: far less to draw, the same shadows (``make bench-render``). A perspective
# camera (a city's ``view_height_m``) looks down from that height instead, its far plane as far under the ground.
CAMERA_HEIGHT_M = 1000.0
FAR_BELOW_GROUND_M = 1.0
VIEW_CLEARANCE_M = 5.0  # a perspective camera's least height over the tallest ridge in view (chimneys, stairs)


def blender_version() -> str:
    return bpy.app.version_string


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


def _tagged(datablock, key: str):
    datablock[CITY_TAG] = key
    return datablock


def _new_mesh_object(arrays: meshes.MeshArrays, materials, collection, key: str,
                     closed: bool = False, smooth: bool = False) -> bpy.types.Object:
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
    for name in (UV_NAME, UV_METRES):
        mesh.uv_layers.new(name=name).data.foreach_set("uv", data["uv"].ravel())
    mesh.uv_layers[UV_NAME].active = mesh.uv_layers[UV_NAME].active_render = True
    label = mesh.color_attributes.new(LABEL_ATTRIBUTE, "FLOAT_COLOR", "CORNER")
    label.data.foreach_set("color", data["label"].ravel())
    mesh.color_attributes.active_color = label
    mesh.update(calc_edges=True)
    mesh.validate(verbose=False)
    if closed:
        import bmesh  # importable only once bpy is loaded

        # MeshArrays gives every polygon its own corners: weld them, so each shell is closed (Workbench
        # draws the shadows of manifold meshes far faster) and smooth normals can round the foliage.
        shells = bmesh.new()
        shells.from_mesh(mesh)
        bmesh.ops.remove_doubles(shells, verts=shells.verts, dist=1e-4)
        shells.to_mesh(mesh)
        shells.free()
    if smooth:
        mesh.shade_smooth()
    for material in materials:
        mesh.materials.append(material)
    obj = bpy.data.objects.new(arrays.name, mesh)
    collection.objects.link(obj)
    _tagged(mesh, key)
    return _tagged(obj, key)


def _image_material(name: str, image: bpy.types.Image, key: str, roughness: float = 0.85) -> bpy.types.Material:
    """A diffuse material whose base colour is one image (Workbench shows that image too)."""
    material = _tagged(bpy.data.materials.new(name), key)
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


def _noise_image(name: str, colour, amount: float, seed: int, key: str, size: int = 64) -> bpy.types.Image:
    """A small tileable speckle image for ground, roads, walls and trees."""
    rng = np.random.default_rng(seed)
    base = np.asarray(colour, dtype=np.float32)
    noise = rng.normal(0.0, amount, (size, size, 1)).astype(np.float32)
    rgba = np.ones((size, size, 4), dtype=np.float32)
    rgba[..., :3] = np.clip(base * (1.0 + noise), 0.0, 1.0)
    image = _tagged(bpy.data.images.new(name, size, size, float_buffer=True), key)
    image.pixels.foreach_set(rgba.ravel())
    image.pack()
    return image


def _rgb_image(name: str, rgb: np.ndarray, key: str) -> bpy.types.Image:
    """A packed float image of a linear RGB array (row 0 at v = 0, as Blender stores images)."""
    h, w = rgb.shape[:2]
    rgba = np.ones((h, w, 4), dtype=np.float32)
    rgba[..., :3] = rgb
    image = _tagged(bpy.data.images.new(name, w, h, float_buffer=True), key)
    image.pixels.foreach_set(rgba.ravel())
    image.pack()
    return image


def _texture_material(key: str, entry, image_path: str) -> bpy.types.Material:
    """The city's material for one bank texture, made on first use (a design switch reuses it)."""
    for material in bpy.data.materials:
        if material.get(CITY_TAG) == key and material.get(TEXTURE_TAG) == entry.id:
            return material
    try:
        # Never shared with another city (check_existing=False): removing one city must not
        # take an image from under another.
        image = _tagged(bpy.data.images.load(image_path, check_existing=False), key)
    except RuntimeError:
        raise MetaSimError(f"cannot read texture image {image_path} (texture {entry.id!r}); "
                           "rebuild the bank with `meta-sim textures build`") from None
    try:
        image.pixels[0]  # force the load now, so a bad file fails here, by name
    except (RuntimeError, IndexError):
        bpy.data.images.remove(image)
        raise MetaSimError(f"cannot read texture image {image_path} (texture {entry.id!r}); "
                           "rebuild the bank with `meta-sim textures build`") from None
    material = _image_material(f"roof:{entry.id}", image, key)
    material[TEXTURE_TAG] = entry.id
    return material


def set_roofs(buildings: bpy.types.Object, textures: dict, placeholders: dict | None = None,
              drop_unused: bool = False) -> None:
    """Put a texture on each roof slot of a city's building object: ``{meshes.FLAT_ROOF: (entry, path), ...}``.

    A slot not given gets ``placeholders[slot]`` (a space without that roof kind) or keeps its material.
    With ``drop_unused``, texture materials of this city that no roof uses any more are removed with
    their images (the add-on's file must not fill up; the worker keeps them for the next design).
    """
    key = buildings[CITY_TAG]
    mesh = buildings.data
    slots = np.empty(len(mesh.polygons), dtype=np.int32)
    mesh.polygons.foreach_get("material_index", slots)
    totals = np.empty(len(mesh.polygons), dtype=np.int32)
    mesh.polygons.foreach_get("loop_total", totals)
    loop_slot = np.repeat(slots, totals)
    uv = np.empty(len(mesh.loops) * 2, dtype=np.float32)
    mesh.uv_layers[UV_METRES].data.foreach_get("uv", uv)
    uv = uv.reshape(-1, 2)
    for slot in (meshes.FLAT_ROOF, meshes.SLOPED_ROOF):
        if slot in textures:
            entry, path = textures[slot]
            mesh.materials[slot] = _texture_material(key, entry, path)
            uv[loop_slot == slot] /= float(entry.repeat_m)
        elif placeholders:
            mesh.materials[slot] = placeholders[slot]
    mesh.uv_layers[UV_NAME].data.foreach_set("uv", uv.ravel())
    mesh.update()
    if not drop_unused:
        return
    unused = [m for m in bpy.data.materials if m.get(CITY_TAG) == key and m.get(TEXTURE_TAG) and not m.users]
    images = [n.image for m in unused for n in m.node_tree.nodes if n.type == "TEX_IMAGE" and n.image]
    if unused:
        bpy.data.batch_remove(unused + images)


def city_ids(key: str) -> list:
    """Every datablock of one city (objects, meshes, materials, images, camera, light, world, scene, collection)."""
    pools = (bpy.data.objects, bpy.data.meshes, bpy.data.materials, bpy.data.images, bpy.data.cameras,
             bpy.data.lights, bpy.data.worlds, bpy.data.scenes, bpy.data.collections)
    return [datablock for pool in pools for datablock in pool if datablock.get(CITY_TAG) == key]


def remove_city(key: str) -> int:
    """Delete every datablock of one city; returns how many."""
    ids = city_ids(key)
    bpy.data.batch_remove(ids)
    return len(ids)


def city_buildings(key: str) -> bpy.types.Object | None:
    """The building object of a city, if it has buildings."""
    return next((o for o in bpy.data.objects if o.get(CITY_TAG) == key and o.get(ROLE_TAG) == "buildings"), None)


def _exposed(rgb: np.ndarray, preset: RenderPreset) -> np.ndarray:
    return rgb if preset.exposure == 1.0 else rgb * np.float32(preset.exposure)


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
    """One city in the current Blender session.

    Without ``collection`` (the render worker) the session is reset and the city fills its
    scene. With a collection (the add-on) the city is built into it, tagged with ``key``
    (default: the collection's name), and renders go through a private scene made on first use.
    """

    def __init__(self, layout, rects, *, pixel_size_m: float, shadow_margin_m: float = 40.0,
                 collection: bpy.types.Collection | None = None, key: str | None = None, ground: dict | None = None,
                 greenness: float | None = None, sun_elevation_deg: float | None = None,
                 ground_albedo: float | None = None, shadow_depth: float | None = None,
                 view_height_m: float | None = None, ground_grain: float | None = None,
                 road_dust: float | None = None, soil_redness: float | None = None):
        self.layout = layout
        self.ground_mix = ground  # ``sim.ground`` cover shares; None: the plain lawn
        self.greenness = greenness  # ``sim.appearance``: vegetation colour; None: today's lawn and trees
        self.sun_elevation_deg = sun_elevation_deg  # None: drawn from the city seed
        self.ground_albedo = ground_albedo  # ``sim.appearance.ground_colours``; None: today's ground
        self.ground_grain = ground_grain  # ``sim.ground.grain_field``'s strength; None: today's smooth ground
        self.road_dust = road_dust  # ``sim.surfaces.dusty``; None: today's roads and tracks
        self.soil_redness = soil_redness  # ``sim.appearance.ground_colours``; None: today's soil
        self.shadow_depth = shadow_depth  # share of the light a shadow takes; None: ``quality.SHADOW_DEPTH``
        if view_height_m is not None and not 1.0 < float(view_height_m) < math.inf:
            raise MetaSimError(f"a view height must be a number of metres above 1, not {view_height_m!r}")
        self.view_height_m = None if view_height_m is None else float(view_height_m)  # None: orthographic
        self.pixel_size_m = pixel_size_m
        self.rects = [Rect(*r) if not isinstance(r, Rect) else r for r in rects]
        if self.view_height_m is not None:  # a drone flies over the roofs it photographs, not among them
            tallest = max((b.ridge_height_m for b in self._visible(layout.buildings_in_rect, 0.0)), default=0.0)
            if self.view_height_m < tallest + VIEW_CLEARANCE_M:
                raise MetaSimError(f"a view from {self.view_height_m:g} m is not {VIEW_CLEARANCE_M:g} m above the "
                                   f"tallest roof in view ({tallest:.1f} m); give a view height of at least "
                                   f"{math.ceil(tallest + VIEW_CLEARANCE_M)} m")
        self._yard = None
        if collection is None:
            bpy.ops.wm.read_factory_settings(use_empty=True)
            self._scene = bpy.context.scene
            self.collection = self._scene.collection
            self.key = key or "worker"
        else:
            self._scene = None
            self.collection = collection
            self.key = key or collection.name
            _tagged(collection, self.key)
        self._tmp = tempfile.mkdtemp(prefix="meta-sim-", dir="/dev/shm" if os.path.isdir("/dev/shm") else None)
        # Sun direction from the city seed: elevation 45 +- 15 degrees (Synthinel rules).
        rng = np.random.default_rng([int(self.layout.seed), 7])
        self._elevation = math.radians(float(rng.uniform(30.0, 60.0)))
        self._azimuth = float(rng.uniform(0.0, 2.0 * math.pi))
        if self.sun_elevation_deg is not None:  # a design's sun; the azimuth stays the city's
            self._elevation = math.radians(float(self.sun_elevation_deg))
        # The fast preset lights a city of the richer scene with its sun and sky (``quality.sun_studio_light``).
        self.sun_lit = bool(layout.params.richer_scene)
        self._studio_light = None
        self._build(shadow_margin_m)
        self._add_camera_and_sun()

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
        paved = [lot for lot in self._visible(lay.lots_in_rect, 0.0) if lot.surface == "paved"]
        if lay.params.tree_size == "real":  # only trees whose shadow can reach the tiles: fewer shadow volumes
            trees = self._visible(lay.trees_in_rect, min(margin, self._shadow_reach(TREE_HEIGHT_M[1])))
        else:
            trees = self._visible(lay.trees_in_rect, margin)
        region = bounding_rect(self.rects).grown(margin)
        seed, key, params = int(lay.seed), self.key, lay.params
        grey = _image_material("wall", _noise_image("wall", (0.45, 0.43, 0.40), 0.05, seed, key), key, 0.9)
        self._placeholder = {
            meshes.FLAT_ROOF: _image_material(
                "flat-roof-unset", _noise_image("unset-f", (0.5, 0.5, 0.5), 0.0, 0, key), key),
            meshes.SLOPED_ROOF: _image_material(
                "sloped-roof-unset", _noise_image("unset-s", (0.5, 0.5, 0.5), 0.0, 0, key), key),
        }
        # The bare ground (lawn or cover mix, and the dirt tracks) in the design's colours and albedo:
        # a property of the scene, so shadows, trees and cars fall on it as on any ground.
        bare = ground_colours(self.greenness, self.ground_albedo, self.soil_redness)
        covers = self.ground_mix or ({"lawn": 1.0} if self.ground_grain else None)  # grain on the plain lawn too
        if covers:
            ground = _image_material("ground", self._ground_image(region, seed + 1, bare, covers), key)
        else:
            ground = _image_material("ground", _noise_image("ground", bare["lawn"], 0.25, seed + 1, key), key)
        dust = self.road_dust or 0.0
        if params.street_details:
            road = _image_material("road", _rgb_image("asphalt", surfaces.dusty(surfaces.asphalt_image(), dust), key),
                                   key)
        else:
            road = _image_material("road", _noise_image("road", surfaces.dusty((0.09, 0.09, 0.095), dust), 0.15,
                                                        seed + 2, key), key)
        dirt = _image_material("dirt", _noise_image("dirt", surfaces.dusty(bare["dirt"], dust), 0.18, seed + 4, key),
                               key)
        building_arrays = meshes.building_mesh(self.buildings)
        self.buildings_obj = None
        if building_arrays.n_polygons:
            self.buildings_obj = _new_mesh_object(
                building_arrays,
                [grey, self._placeholder[meshes.FLAT_ROOF], self._placeholder[meshes.SLOPED_ROOF]],
                self.collection, key)
            self.buildings_obj[ROLE_TAG] = "buildings"
        if params.roof_furniture > 0.0:
            self._build_furniture(params.roof_furniture)
        _new_mesh_object(meshes.ground_mesh(region.x0, region.y0, region.x1, region.y1, bool(covers)),
                         [ground], self.collection, key)
        if roads:
            repeat = surfaces.ASPHALT_REPEAT_M if params.street_details else 1.0
            _new_mesh_object(meshes.road_mesh(roads, repeat_m=repeat), [road, dirt], self.collection, key)
        if paved and params.street_details:  # the yards' weathered concrete, under the parking lots' asphalt
            _new_mesh_object(meshes.lot_mesh(paved, z=0.01, repeat_m=surfaces.CONCRETE_REPEAT_M),
                             [self._yard_material()], self.collection, key)
        elif paved:
            concrete = _image_material("paved", _noise_image("paved", (0.36, 0.36, 0.35), 0.08, seed + 5, key), key)
            _new_mesh_object(meshes.lot_mesh(paved), [concrete], self.collection, key)
        foliage = None
        if params.tree_size == "real" or params.shrub_density > 0:
            atlas = surfaces.foliage_atlas()
            tint = foliage_tint(self.greenness)
            if tint is not None:  # the atlas's greens turned as the design's vegetation colour is
                atlas = np.clip(atlas * np.asarray(tint, np.float32), 0.0, 1.0)
            foliage = _image_material("foliage", _rgb_image("foliage", atlas, key), key)
        if trees and params.tree_size == "real":
            _new_mesh_object(meshes.crown_mesh(trees), [foliage], self.collection, key, closed=True, smooth=True)
        elif trees:
            leaves = vegetation_colour("tree", self.greenness, TREE_COLOUR)
            tree = _image_material("tree", _noise_image("tree", leaves, 0.35, seed + 3, key), key)
            _new_mesh_object(meshes.tree_mesh(trees), [tree], self.collection, key)
        self.n_trees, self.n_roads = len(trees), len(roads)
        self._build_clutter(margin, len(roads), road, foliage)

    def _build_furniture(self, density: float) -> None:
        """The roof furniture (``sim/furniture.py``) of the buildings built, labelled as their roofs."""
        key = self.key
        lay = self.layout
        arrays = meshes.furniture_mesh([(b, roof_furniture(b, lay.seed, density, lay.style_of(b)))
                                        for b in self.buildings])
        if not arrays.n_polygons:
            return
        materials = []
        for name in SURFACES:
            rough = surfaces.FURNITURE_ROUGHNESS.get(name, 0.85)
            if name == "solar":
                image = _rgb_image("solar", surfaces.solar_image(), key)
            else:
                image = _noise_image(f"roof-{name}", surfaces.FURNITURE[name], 0.06, 12 + len(materials), key)
            materials.append(_image_material(f"roof-{name}", image, key, rough))
        lid = _image_material("hvac-lid", _rgb_image("hvac-lid", surfaces.fan_lid_image(), key), key,
                              surfaces.FURNITURE_ROUGHNESS["metal"])
        _new_mesh_object(arrays, [*materials, lid], self.collection, key, closed=True)

    def _yard_material(self) -> bpy.types.Material:
        """The paved yards' weathered concrete, made on first use."""
        if self._yard is None:
            image = _rgb_image("yard", surfaces.concrete_image() * np.float32(surfaces.YARD_SHADE), self.key)
            self._yard = _image_material("yard", image, self.key)
        return self._yard

    def _shadow_reach(self, height_m: float) -> float:
        """How far from its foot the shadow of something `height_m` tall falls in this city's sun."""
        return height_m / math.tan(self._elevation) + 0.5

    def _build_clutter(self, margin: float, n_roads: int, road, foliage) -> None:
        """Pavings, pools and markings (flat, so only what the tiles show), cars and shrubs (and what
        of them casts a shadow into the tiles)."""
        lay, key = self.layout, self.key
        flat = {name: self._visible(lambda *r, name=name: lay.details_in_rect(name, *r), 0.0)
                for name in ("pavings", "pools", "markings")}
        low = min(margin, self._shadow_reach(2.0))
        vehicles = meshes.TRUCK_HEIGHT_M if any(car.kind == "truck" for car in lay.cars) else 2.0
        cars = self._visible(lambda *r: lay.details_in_rect("cars", *r), min(margin, self._shadow_reach(vehicles)))
        shrubs = self._visible(lambda *r: lay.details_in_rect("shrubs", *r), low)
        self.n_details = {"cars": len(cars), "shrubs": len(shrubs), **{k: len(v) for k, v in flat.items()}}
        if any(flat.values()):
            materials = [None] * 6
            materials[meshes.CONCRETE] = _image_material(
                "concrete", _rgb_image("concrete", surfaces.concrete_image(), key), key)
            materials[meshes.ASPHALT] = road  # parking lots: the streets' asphalt
            materials[meshes.YARD] = self._yard_material()
            materials[meshes.PAINT] = _image_material(
                "paint", _noise_image("paint", surfaces.ROAD_PAINT, 0.08, 6, key), key)
            materials[meshes.WATER] = _image_material(
                "water", _rgb_image("water", surfaces.water_image(), key), key, roughness=0.1)
            materials[meshes.COPING] = _image_material(
                "coping", _noise_image("coping", surfaces.COPING, 0.06, 8, key), key)
            arrays = meshes.detail_mesh(flat["pavings"], flat["pools"], flat["markings"],
                                        meshes.road_top(n_roads) + 0.005)
            _new_mesh_object(arrays, materials, self.collection, key)
        waters = self._visible(lambda *r: lay.details_in_rect("waters", *r), 0.0)
        self.n_details["waters"] = len(waters)
        if waters:  # one colour per city (``sim/water.py``)
            lake = _image_material("lake", _rgb_image("lake", surfaces.lake_image(WATER_COLOURS[waters[0].colour]),
                                                      key), key, roughness=0.1)
            _new_mesh_object(meshes.water_mesh(waters, meshes.road_top(n_roads) + 0.015), [lake], self.collection,
                             key)
        if cars:
            paints = [_image_material(f"car-{name}", _noise_image(f"car-{name}", colour, 0.03, 9, key), key, 0.4)
                      for name, colour in surfaces.CAR_PAINT.items()]
            glass = _image_material("glass", _noise_image("glass", surfaces.GLASS, 0.05, 10, key), key, 0.1)
            _new_mesh_object(meshes.car_mesh(cars), [*paints, glass], self.collection, key, closed=True)
        if shrubs:
            _new_mesh_object(meshes.shrub_mesh(shrubs), [foliage], self.collection, key, closed=True, smooth=True)

    def _ground_image(self, region: Rect, seed: int, colours: dict, covers: dict) -> bpy.types.Image:
        """The region's ground of ``covers`` (``sim.ground``, in ``colours``, with the city's grain) as one
        image spanning the ground quad."""
        rgb = ground_image(region.x1 - region.x0, region.y1 - region.y0, seed, covers, colours,
                           self.ground_grain or 0.0)
        return _rgb_image("ground-cover", rgb, self.key)  # row 0 at the quad's south edge

    def _add_camera_and_sun(self) -> None:
        camera = _tagged(bpy.data.cameras.new("nadir"), self.key)
        camera.type = "ORTHO"
        camera.clip_start, camera.clip_end = 1.0, CAMERA_HEIGHT_M + FAR_BELOW_GROUND_M
        self.camera = _tagged(bpy.data.objects.new("nadir", camera), self.key)
        self.collection.objects.link(self.camera)
        sun = _tagged(bpy.data.lights.new("sun", "SUN"), self.key)
        sun.energy, _ = cycles_light(self._elevation, self.shadow_depth)  # and again per render (``_set_quality``)
        self._sun_light = sun
        sun.angle = math.radians(0.5)
        sun_obj = _tagged(bpy.data.objects.new("sun", sun), self.key)
        sun_obj.rotation_euler = (math.pi / 2 - self._elevation, 0.0, self._azimuth)
        self.collection.objects.link(sun_obj)

    @property
    def sun(self) -> dict:
        """The sun of this city (drawn from its seed), in degrees: recorded in each tile's header."""
        return {"elevation_deg": round(math.degrees(self._elevation), 4),
                "azimuth_deg": round(math.degrees(self._azimuth), 4)}

    @property
    def scene(self) -> bpy.types.Scene:
        """The scene renders go through: the worker's own, or the add-on's private one, set up on first use."""
        if self._scene is None:
            self._scene = _tagged(bpy.data.scenes.new(f"{self.key} (render)"), self.key)
            self._scene.collection.children.link(self.collection)
        if self._scene.camera is None:
            self._setup_render_scene()
        return self._scene

    def _setup_render_scene(self) -> None:
        scene, elevation, azimuth = self._scene, self._elevation, self._azimuth
        scene.camera = self.camera
        world = _tagged(bpy.data.worlds.new("sky"), self.key)
        world.color = SKY_COLOUR
        scene.world = world
        if world.node_tree is None:
            world.use_nodes = True
        background = next(n for n in world.node_tree.nodes if n.type == "BACKGROUND")
        background.inputs["Color"].default_value = (*SKY_COLOUR, 1.0)
        _, background.inputs["Strength"].default_value = cycles_light(elevation, self.shadow_depth)  # and per render
        self._sky = background
        scene.display.light_direction = workbench_direction(elevation, azimuth)
        scene.display.shadow_shift, scene.display.shadow_focus = SHADOW_SHIFT, SHADOW_FOCUS
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
    def set_roofs(self, textures: dict) -> None:
        """Put a texture on each roof slot: ``{meshes.FLAT_ROOF: (entry, path), ...}``.

        A slot not given keeps a neutral grey (a space without that roof kind).
        """
        if self.buildings_obj is not None:
            set_roofs(self.buildings_obj, textures, self._placeholder)

    # --- rendering ---------------------------------------------------------
    def _frame(self, rect: Rect) -> tuple[int, int]:
        width = int(round((rect.x1 - rect.x0) / self.pixel_size_m))
        height = int(round((rect.y1 - rect.y0) / self.pixel_size_m))
        render = self.scene.render
        render.resolution_x, render.resolution_y = width, height
        camera = self.camera.data
        span = max(width, height) * self.pixel_size_m
        if self.view_height_m is None:  # every pixel straight down: adjacent rectangles join exactly
            camera.type, camera.ortho_scale = "ORTHO", span
            z = CAMERA_HEIGHT_M
        else:  # a photo from over the rectangle's centre, the ground at its pixel size
            camera.type, camera.sensor_fit = "PERSP", "AUTO"
            camera.angle = 2.0 * math.atan(span / 2.0 / self.view_height_m)
            z = self.view_height_m
        camera.clip_end = z + FAR_BELOW_GROUND_M
        self.camera.location = ((rect.x0 + rect.x1) / 2, (rect.y0 + rect.y1) / 2, z)
        self.camera.rotation_euler = (0.0, 0.0, 0.0)
        return width, height

    def _render_to_array(self, rect: Rect, name: str, border: bool = False) -> np.ndarray:
        """The render of ``rect``; a ``border`` render is the size of its border (the caller checks it)."""
        width, height = self._frame(rect)
        path = os.path.join(self._tmp, f"{name}.exr")
        self.scene.render.filepath = path
        with _quiet(os.path.join(self._tmp, "blender.log")):
            bpy.ops.render.render(write_still=True, scene=self.scene.name)
        image = oiio.ImageInput.open(path)
        if image is None:
            raise RuntimeError(f"Blender wrote no readable image: {oiio.geterror()}")
        try:
            pixels = image.read_image(format="float")
        finally:
            image.close()
            os.remove(path)
        if pixels is None or (not border and pixels.shape[:2] != (height, width)):
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
        """Linear RGB (float32) of a rectangle with a quality preset, scaled by its exposure."""
        self._set_quality(preset)
        return _exposed(self._render_to_array(rect, "rgb")[..., :3], preset)

    def render_rgb_in_strips(self, rect: Rect, preset: RenderPreset, rows: int = 64, cut=None):
        """`render_rgb` as a generator that renders path-traced images in horizontal strips of about
        ``rows`` rows, yielding the share done after each, so a caller can show progress and stop between
        strips; returns the image, or with ``cut`` (its row and column slices, as ``render.loop.tile_cut``
        gives them) only that part of it, of which a path-traced render renders only that part. Cycles
        samples each pixel on its own, so strips and parts are the pixels of one whole render (not so with
        denoising, and Workbench is fast: both render whole)."""
        width, height = self._frame(rect)
        cut = cut or (slice(0, height), slice(0, width))
        top, bottom, left, right = cut[0].start, cut[0].stop, cut[1].start, cut[1].stop
        strips = -(-(bottom - top) // rows)
        whole = (bottom - top, right - left) == (height, width)
        if preset.engine != "CYCLES" or preset.denoise or (strips < 2 and whole):
            rgb = self.render_rgb(rect, preset)[top:bottom, left:right]
            yield 1.0
            return rgb
        self._set_quality(preset)
        render = self.scene.render
        render.use_border = render.use_crop_to_border = True
        parts = []
        try:
            edges = [top + round(k * (bottom - top) / strips) for k in range(strips + 1)]
            for k in range(strips):
                # Blender truncates border x size to whole pixels: half a pixel in keeps each edge on its pixel.
                render.border_min_x, render.border_max_x = (left + 0.5) / width, min(1.0, (right + 0.5) / width)
                render.border_min_y = (height - edges[k + 1] + 0.5) / height
                render.border_max_y = min(1.0, (height - edges[k] + 0.5) / height)
                parts.append(self._render_to_array(rect, "rgb", border=True)[..., :3])
                yield (k + 1) / strips
        finally:
            render.use_border = render.use_crop_to_border = False
        rgb = np.concatenate(parts)
        if rgb.shape[:2] != (bottom - top, right - left):
            raise RuntimeError("the strips of the render do not add up to the image")
        return _exposed(rgb, preset)

    def _set_quality(self, preset: RenderPreset) -> None:
        scene = self.scene
        scene.render.film_transparent = False
        if preset.engine == "BLENDER_WORKBENCH":
            scene.render.engine = "BLENDER_WORKBENCH"
            shading = scene.display.shading
            shading.light = "STUDIO"
            shading.use_world_space_lighting = self.sun_lit
            shading.studiolight_rotate_z = 0.0
            shading.studio_light = self._sun_studio_light() if self.sun_lit else "Default"
            shading.color_type = "TEXTURE"
            shading.show_shadows = preset.shadows
            shading.shadow_intensity = SHADOW_DEPTH if self.shadow_depth is None else self.shadow_depth
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
            # A sun and a sky: nothing for the light tree to choose among, so it only costs time.
            cycles.use_light_tree = False
            cycles.seed = int(self.layout.seed) % (2**31)
            # Spelled out: a new scene (the add-on's) would otherwise pick another pattern than the factory one
            # and its preview would not be the farm's pixels.
            cycles.sampling_pattern = "TABULATED_SOBOL"
            self._sun_light.energy, self._sky.inputs["Strength"].default_value = cycles_light(
                self._elevation, self.shadow_depth)

    def _sun_studio_light(self) -> str:
        """The name of this city's studio light of its sun and sky, loaded into the session on first use (a
        studio light is read from a file; ``close`` unloads it again)."""
        if self._studio_light is None:
            path = os.path.join(self._tmp, f"meta-sim-sun-{os.path.basename(self._tmp)}.sl")
            with open(path, "w", encoding="ascii") as handle:
                handle.write(sun_studio_light(self._elevation, self._azimuth))
            self._studio_light = bpy.context.preferences.studio_lights.load(path, "STUDIO")
        return self._studio_light.name

    def close(self) -> None:
        """Remove the temporary files and this city's studio light (the city itself stays; `remove_city`
        deletes it)."""
        if self._studio_light is not None:
            bpy.context.preferences.studio_lights.remove(self._studio_light)
            self._studio_light = None
        for name in os.listdir(self._tmp):
            os.remove(os.path.join(self._tmp, name))
        os.rmdir(self._tmp)

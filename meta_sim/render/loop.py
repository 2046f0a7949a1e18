"""The render loop: jobs x tiles -> one EXR per tile (RGB + exact labels + metadata).

Runs wherever ``bpy`` imports: the ``bpy`` module in a virtual environment
(``python -m meta_sim.render.worker``) or Blender's own Python
(``blender -b --python jobs/render_tiles.py -- ...``). No torch here.

Work is grouped by city: a city's geometry is built once and its labels are
rendered once; each design then only swaps the roof materials. Tiles are
rendered in blocks of up to 3 x 3 adjacent tiles and cut afterwards (one by one
when the design's view is a perspective one, see ``tile_blocks``). A tile
that already exists, reads back completely and carries the same metadata is
skipped, so a rerun resumes an interrupted job.
"""

from __future__ import annotations

import time
from collections import defaultdict
from pathlib import Path
from typing import Callable

import numpy as np

from ..core.errors import MetaSimError
from ..core.extras import require
from ..core.fileio import writable_dir
from ..sim import meshes, tiles
from ..sim.appearance import Appearance
from ..sim.design import DesignSpace
from ..sim.ground import get_mix
from ..sim.layout import LayoutParams, layout_for_tiles, parse_style
from ..sim.preview import write_mosaic, write_previews
from .jobs import Job, RenderSettings, RenderSummary, expected_meta, tile_path, write_job_manifest

BLOCK_TILES = 3  # tiles per block side: a 1152 px render amortises Blender's per-frame cost


def resolve_textures(space: DesignSpace, design: dict, banks) -> dict:
    """Roof slot -> (texture entry, image path) for a design's texture parameters."""
    out = {}
    for kind, slot in (("flat", meshes.FLAT_ROOF), ("sloped", meshes.SLOPED_ROOF)):
        param = space.texture_parameter(kind)
        if param is None:
            continue
        texture_id = design[param.name]
        for bank in banks:
            if bank.contains(texture_id):
                entry = bank.by_id(texture_id)
                if entry.kind != kind:
                    raise MetaSimError(f"{param.name}: texture {texture_id!r} is a {entry.kind} texture, "
                                       f"not a {kind} one")
                path = Path(bank.image_path(texture_id))
                if not path.is_file():
                    raise MetaSimError(f"texture file {path} of {texture_id!r} is missing; "
                                       "rebuild the bank with `meta-sim textures build`")
                out[slot] = (entry, str(path))
                break
        else:
            raise MetaSimError(f"{param.name}: texture {texture_id!r} is in none of the texture banks given")
    return out


def blocks_of(n_tiles: int, cols: int) -> list[list[int]]:
    """Tile indices grouped into blocks of up to BLOCK_TILES x BLOCK_TILES adjacent tiles."""
    groups = defaultdict(list)
    for index in range(n_tiles):
        row, col = divmod(index, cols)
        groups[(row // BLOCK_TILES, col // BLOCK_TILES)].append(index)
    return [groups[key] for key in sorted(groups)]


def layout_params(space: DesignSpace, design: dict, style: str = "suburban") -> LayoutParams:
    """The city's layout parameters: the design space's overrides, and the render's style if it has one."""
    overrides = space.layout_overrides(design)
    if style != "suburban":
        if "style" in overrides:
            raise MetaSimError(f"design space {space.name!r} declares a city style already; "
                               "drop --style or the space's layout style")
        overrides["style"] = parse_style(style)
    try:
        return LayoutParams(**overrides)
    except TypeError as exc:
        raise MetaSimError(f"design space {space.name!r} sets an unknown layout field: {exc}") from None


def build_city(layout, rects, pixel_size_m: float, look: Appearance, **home):
    """The Blender scene of a city laid out as ``layout`` holding the tiles ``rects``, as ``look`` builds it
    (its ground, greenness, sun, albedo, shadows, view, grain, dust and soil); ``home`` is the add-on's
    collection and key (``CityScene``). The render worker and the add-on build every city here, so a
    preview tile is the farm's. Needs ``bpy``; MetaSimError for a look the city cannot take."""
    from ..blender.scene import CityScene  # bpy only when rendering

    return CityScene(layout, rects, pixel_size_m=pixel_size_m, ground=get_mix(look.ground),
                     greenness=look.greenness, sun_elevation_deg=look.sun_elevation_deg,
                     ground_albedo=look.ground_albedo, shadow_depth=look.shadow_depth,
                     view_height_m=look.view_height_m, ground_grain=look.ground_grain,
                     road_dust=look.road_dust, soil_redness=look.soil_redness, **home)


def finish_tile(look: Appearance, rgb, instance, roof_class, city_seed: int, tile_index: int, preset) -> np.ndarray:
    """Tile ``tile_index`` of a city as ``look`` shows its linear render (``Appearance.apply``): the sensor sees
    each tile alone, its noise seeded by the city and the tile."""
    return look.apply(rgb, instance, roof_class, city_seed, [city_seed, tile_index], preset)


def render_jobs(jobs: list[Job], settings: RenderSettings,
                progress: Callable[[int], None] | None = None, record: bool = True) -> RenderSummary:
    """Render every missing tile of every job into ``settings.out_dir``; returns a RenderSummary
    (counts, stage timings and the paths written).

    Tiles that already exist with the same metadata are skipped; ``progress(n)`` is called with the
    tiles skipped or written as they are counted. ``record`` writes ``designs.json`` beside the
    tiles; a farm turns it off, since its manifest lists the folder's jobs and concurrent workers
    would race on that file. Needs ``bpy``. Raises MetaSimError when ``bpy`` is missing, the output
    folder cannot be written, or a design names a texture that no bank holds (or whose file is
    missing) or a layout field that does not exist; all of these are checked before anything renders.
    """
    require("bpy", "rendering")
    from ..blender.scene import Rect, blender_version, bounding_rect  # bpy only when rendering

    out_dir = Path(settings.out_dir)
    writable_dir(out_dir)
    software = tiles.software_versions(blender=blender_version())
    summary = RenderSummary()
    by_city: dict = defaultdict(list)
    for job in jobs:
        missing = [name for name in settings.space.names if name not in job.design]
        if missing:
            raise MetaSimError(f"job {job.name}: its design lacks {', '.join(missing)} of design space "
                               f"{settings.space.name!r}")
        params = layout_params(settings.space, job.design, settings.style)
        textures = resolve_textures(settings.space, job.design, settings.banks)  # fail early
        wanted = job.tile_indices(settings.n_tiles)
        pending = [j for j in wanted
                   if not tiles.is_valid_tile(tile_path(out_dir, job, j), expected_meta(settings, job, j))]
        summary.skipped += len(wanted) - len(pending)
        if progress and len(wanted) - len(pending):
            progress(len(wanted) - len(pending))
        if pending:
            look = settings.appearance(job)
            by_city[(job.city_seed, params, look.scene_key())].append((job, textures, pending, look))
    if record:
        write_job_manifest(out_dir, jobs, settings)

    for (city_seed, params, _), work in by_city.items():
        clock = time.perf_counter()
        layout, rects = layout_for_tiles(city_seed, settings.n_tiles, settings.tile_m, params)
        summary.seconds["layout"] += time.perf_counter() - clock
        needed = sorted({j for _, _, pending, _ in work for j in pending})
        look = work[0][3]  # the jobs of one scene share ground, its albedo, greenness, sun, shadows and view
        blocks = tile_blocks(rects, look, needed)
        clock = time.perf_counter()
        # The scene always holds every requested tile, whichever are pending, so a resumed
        # job renders the same pixels as an uninterrupted one.
        try:
            scene = build_city(layout, rects, settings.pixel_size_m, look)
        except MetaSimError as exc:  # a look this city cannot take (a view below its towers): say whose
            raise MetaSimError(f"job {work[0][0].name} (city seed {city_seed}): {exc}") from None
        summary.seconds["build"] += time.perf_counter() - clock
        summary.cities += 1
        try:
            block_rects = [bounding_rect([Rect(*rects[j]) for j in block]) for block in blocks]
            clock = time.perf_counter()
            labels = [scene.render_labels(rect) for rect in block_rects]
            summary.seconds["labels"] += time.perf_counter() - clock
            for job, textures, pending, look in work:
                scene.set_roofs(textures)
                for block, rect, (instance, roof_class) in zip(blocks, block_rects, labels):
                    todo = [j for j in block if j in pending]
                    if not todo:
                        continue
                    clock = time.perf_counter()
                    rgb = scene.render_rgb(rect, settings.preset)
                    summary.seconds["render"] += time.perf_counter() - clock
                    clock = time.perf_counter()
                    for j in todo:
                        cut = tile_cut(rect, Rect(*rects[j]), settings.pixel_size_m, settings.tile_px)
                        path = tile_path(out_dir, job, j)
                        meta = tiles.tile_metadata(
                            design=job.design, space=settings.space.name, city_seed=job.city_seed,
                            tile_index=j, origin_m=rects[j][:2], size_px=(settings.tile_px, settings.tile_px),
                            pixel_size_m=settings.pixel_size_m, preset=settings.preset,
                            software=software, appearance=settings.header(job), sun=scene.sun)
                        image = finish_tile(look, rgb[cut], instance[cut], roof_class[cut], job.city_seed, j,
                                            settings.preset)
                        tiles.write_tile(path, image, instance[cut], roof_class[cut], meta)
                        if settings.preview:
                            write_previews(path, image, instance[cut], roof_class[cut])
                        summary.written += 1
                        summary.paths.append(path)
                        if progress:
                            progress(1)
                    summary.seconds["write"] += time.perf_counter() - clock
                if settings.preview:
                    images = [tiles.read_tile(tile_path(out_dir, job, j)).rgb for j in range(settings.n_tiles)]
                    write_mosaic(out_dir / f"{job.name}_mosaic.png", images, rects, settings.pixel_size_m)
        finally:
            scene.close()
    return summary


def tile_blocks(rects, look: Appearance, needed) -> list[list[int]]:
    """The tiles rendered together, as one image cut afterwards, to make the tiles ``needed`` of a city whose
    tiles are ``rects``: the blocks of ``blocks_of`` that hold any, or for a perspective view (a photo over
    each tile's centre) each tile alone. A tile's pixels depend on the image it is cut from (anti-aliasing
    and shadows are not the same at another frame), so whatever renders a tile as the farm does renders its
    block."""
    if look.view_height_m is not None:
        return [[j] for j in needed]
    return [block for block in blocks_of(len(rects), _grid_columns(rects)) if set(block) & set(needed)]


def _grid_columns(rects) -> int:
    """Columns of the row-major tile grid (tiles of the first row share its y)."""
    first_y = rects[0][1]
    return sum(1 for r in rects if abs(r[1] - first_y) < 1e-6)


def tile_cut(block, tile, pixel_size_m: float, tile_px: int):
    """Row/column slices of ``tile`` inside the render of ``block`` (row 0 = north)."""
    col = int(round((tile.x0 - block.x0) / pixel_size_m))
    row = int(round((block.y1 - tile.y1) / pixel_size_m))
    return slice(row, row + tile_px), slice(col, col + tile_px)

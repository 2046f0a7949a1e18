"""The render worker: designs x tiles -> one EXR per tile (RGB + exact labels + metadata).

Runs wherever ``bpy`` imports: the ``bpy`` module in a virtual environment
(``python -m meta_sim.worker``) or Blender's own Python
(``blender -b --python jobs/render_tiles.py -- ...``). No torch here.

Work is grouped by city: a city's geometry is built once and its labels are
rendered once; each design then only swaps the roof materials. Tiles are
rendered in blocks of up to 3 x 3 adjacent tiles and cut afterwards. A tile
that already exists, reads back completely and carries the same metadata is
skipped, so a rerun resumes an interrupted job.
"""

from __future__ import annotations

import json
import tempfile
import time
from collections import defaultdict
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from . import meshes, tiles
from .design import DesignSpace
from .errors import MetaSimError
from .fileio import write_text_atomic
from .layout import LayoutParams, layout_for_tiles
from .preview import write_mosaic, write_previews
from .render_presets import RenderPreset

BLOCK_TILES = 3  # tiles per block side: a 1152 px render amortises Blender's per-frame cost


@dataclass(frozen=True)
class Job:
    """One design to render in one city: tiles ``{name}_t{j:02d}.exr``.

    ``tiles`` restricts the job to some tile indices (a farm task); None means all of them.
    """

    design: dict
    city_seed: int
    name: str
    tiles: tuple | None = None

    def tile_indices(self, n_tiles: int) -> tuple:
        return tuple(range(n_tiles)) if self.tiles is None else tuple(self.tiles)


@dataclass
class RenderSettings:
    space: DesignSpace
    banks: list  # TextureBank objects; a texture id is looked up in each in turn
    preset: RenderPreset
    out_dir: Path
    n_tiles: int = 9
    tile_px: int = 384
    pixel_size_m: float = 0.3
    preview: bool = False

    @property
    def tile_m(self) -> float:
        return self.tile_px * self.pixel_size_m


@dataclass
class RenderSummary:
    written: int = 0
    skipped: int = 0
    cities: int = 0
    seconds: dict = field(default_factory=lambda: defaultdict(float))
    paths: list = field(default_factory=list)


def tile_path(out_dir: Path, job: Job, index: int) -> Path:
    return Path(out_dir) / f"{job.name}_t{index:02d}.exr"


def expected_meta(settings: RenderSettings, job: Job, index: int) -> dict:
    """The metadata a valid tile of ``job`` carries (``tiles.is_valid_tile`` compares it)."""
    return {"design": job.design, "design_space": settings.space.name, "city_seed": job.city_seed,
            "tile_index": index, "tile_size_px": [settings.tile_px, settings.tile_px],
            "pixel_size_m": settings.pixel_size_m, "preset": settings.preset.name,
            "format_version": tiles.TILE_FORMAT_VERSION, **settings.preset.cache_fields()}


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


def _layout_params(space: DesignSpace, design: dict) -> LayoutParams:
    overrides = space.layout_overrides(design)
    try:
        return LayoutParams(**overrides)
    except TypeError as exc:
        raise MetaSimError(f"design space {space.name!r} sets an unknown layout field: {exc}") from None


def render_jobs(jobs: list[Job], settings: RenderSettings,
                progress: Callable[[int], None] | None = None, record: bool = True) -> RenderSummary:
    """Render every missing tile of every job; returns counts and stage timings.

    ``record`` writes ``designs.json`` beside the tiles; a farm turns it off, since its
    manifest lists the folder's jobs and concurrent workers would race on that file.
    """
    from .blender.scene import CityScene, Rect, bounding_rect  # bpy only when rendering

    out_dir = Path(settings.out_dir)
    _check_writable(out_dir)
    summary = RenderSummary()
    by_city: dict = defaultdict(list)
    for job in jobs:
        params = _layout_params(settings.space, job.design)
        textures = resolve_textures(settings.space, job.design, settings.banks)  # fail early
        wanted = job.tile_indices(settings.n_tiles)
        pending = [j for j in wanted
                   if not tiles.is_valid_tile(tile_path(out_dir, job, j), expected_meta(settings, job, j))]
        summary.skipped += len(wanted) - len(pending)
        if progress and len(wanted) - len(pending):
            progress(len(wanted) - len(pending))
        if pending:
            by_city[(job.city_seed, params)].append((job, textures, pending))
    if record:
        write_job_manifest(out_dir, jobs, settings)

    for (city_seed, params), work in by_city.items():
        clock = time.perf_counter()
        layout, rects = layout_for_tiles(city_seed, settings.n_tiles, settings.tile_m, params)
        summary.seconds["layout"] += time.perf_counter() - clock
        cols = _grid_columns(rects)
        needed = sorted({j for _, _, pending in work for j in pending})
        blocks = [b for b in blocks_of(settings.n_tiles, cols) if set(b) & set(needed)]
        clock = time.perf_counter()
        # The scene always holds every requested tile, whichever are pending, so a resumed
        # job renders the same pixels as an uninterrupted one.
        scene = CityScene(layout, rects, pixel_size_m=settings.pixel_size_m)
        summary.seconds["build"] += time.perf_counter() - clock
        summary.cities += 1
        try:
            block_rects = [bounding_rect([Rect(*rects[j]) for j in block]) for block in blocks]
            clock = time.perf_counter()
            labels = [scene.render_labels(rect) for rect in block_rects]
            summary.seconds["labels"] += time.perf_counter() - clock
            for job, textures, pending in work:
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
                        cut = _cut(rect, Rect(*rects[j]), settings)
                        path = tile_path(out_dir, job, j)
                        meta = tiles.tile_metadata(
                            design=job.design, space=settings.space.name, city_seed=job.city_seed,
                            tile_index=j, origin_m=rects[j][:2], size_px=(settings.tile_px, settings.tile_px),
                            pixel_size_m=settings.pixel_size_m, preset=settings.preset)
                        tiles.write_tile(path, rgb[cut], instance[cut], roof_class[cut], meta)
                        if settings.preview:
                            write_previews(path, rgb[cut], instance[cut], roof_class[cut])
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


def _grid_columns(rects) -> int:
    """Columns of the row-major tile grid (tiles of the first row share its y)."""
    first_y = rects[0][1]
    return sum(1 for r in rects if abs(r[1] - first_y) < 1e-6)


def _cut(block, tile, settings: RenderSettings):
    """Row/column slices of ``tile`` inside the render of ``block`` (row 0 = north)."""
    col = int(round((tile.x0 - block.x0) / settings.pixel_size_m))
    row = int(round((block.y1 - tile.y1) / settings.pixel_size_m))
    return slice(row, row + settings.tile_px), slice(col, col + settings.tile_px)


def _check_writable(out_dir: Path) -> None:
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryFile(dir=out_dir):  # a unique name: concurrent workers share the folder
            pass
    except OSError as exc:
        raise MetaSimError(f"cannot write to output folder {out_dir}: {exc.strerror}; "
                           "choose another --out") from None


def design_jobs(space: DesignSpace, designs: list[dict], seed: int, cities: int) -> list[Job]:
    """Jobs for a training set: design k is rendered in city ``seed + k % cities``."""
    return [Job(design, seed + k % cities, f"d{k:05d}") for k, design in enumerate(designs)]


def single_job(space: DesignSpace, design: dict, seed: int) -> Job:
    name = "+".join(str(design[n]) for n in space.names)
    return Job(design, seed, f"{name}_s{seed}")


def sample_designs(space: DesignSpace, n: int, seed: int) -> list[dict]:
    """``n`` uniform designs; the first k do not depend on n (a larger set extends a smaller)."""
    return space.sample(np.random.default_rng([seed, 1]), n)


def write_job_manifest(out_dir: Path, jobs: list[Job], settings: RenderSettings) -> Path:
    """``designs.json`` beside the tiles: every job rendered into the folder, with its design,
    city seed, settings and tile names (jobs already listed by an earlier run are kept)."""
    path = Path(out_dir) / "designs.json"
    entries = {}
    if path.is_file():
        try:
            entries = {e["name"]: e for e in json.loads(path.read_text()).get("jobs", [])}
        except (ValueError, KeyError, TypeError, AttributeError):
            entries = {}  # a damaged manifest is rebuilt from this run
    for job in jobs:
        entries[job.name] = {"name": job.name, "design": job.design, "city_seed": job.city_seed,
                             "design_space": settings.space.name, "preset": settings.preset.name,
                             "tile_px": settings.tile_px, "pixel_size_m": settings.pixel_size_m,
                             "tiles": [tile_path(out_dir, job, j).name for j in range(settings.n_tiles)]}
    data = {"format": "meta-sim-render-job", "version": 1, "jobs": [entries[k] for k in sorted(entries)]}
    return write_text_atomic(path, json.dumps(data, indent=1) + "\n")

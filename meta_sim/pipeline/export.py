"""Rendered tiles as a dataset other tools read: PNG image/mask pairs, or COCO instance segmentation.

``export_tiles`` reads the tiles (``*.exr``, name order) of a folder and writes, for ``png``::

    images/NAME.png       8-bit display sRGB (the previews' transfer curve)
    masks/NAME.png        8-bit grey, 255 on buildings, 0 elsewhere
    roof_class/NAME.png   8-bit grey, 0 background, 1 flat roof, 2 sloped roof
    manifest.json         format version and, per tile, its files, size and metadata

and for ``coco``::

    images/NAME.png       as above
    annotations.json      COCO instances: ``file_name`` is relative to ``images/``

COCO has one category, 1 "building"; each annotation also keeps its roof kind as ``roof_class`` (1 flat,
2 sloped, 0 none: the commonest among its pixels) and each image the tile's metadata, extra keys that
COCO readers ignore. ``segmentation`` holds one polygon per 4-connected part of the building, traced
along pixel edges (``mask_polygons``), so ``pycocotools`` rasterises it back to exactly the part's
pixels, except that holes (pixels of something else enclosed by the building) come back filled: COCO
polygons cannot leave them out. ``area`` counts the instance's own pixels and ``bbox`` is their
``[x, y, width, height]``; ``iscrowd`` is 0.

The output folder is built beside ``out`` and put in its place when complete, so it holds a whole export
or is left as it was.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from ..core.errors import MetaSimError
from ..core.fileio import atomic_dir, writable_dir, write_text_atomic
from ..core.names import safe_name
from ..core.progress import Bars
from ..sim.preview import to_srgb8
from ..sim.textures.pngio import write_png
from ..sim.tiles import read_tile

EXPORT_FORMAT_VERSION = 1
FORMATS = ("png", "coco")
# What of a tile's header the exported files keep, per tile.
META_KEYS = ("design", "design_space", "city_seed", "tile_index", "tile_origin_m", "pixel_size_m", "preset")
CATEGORIES = [{"id": 1, "name": "building", "supercategory": "building"}]

# The (x, y) steps of the directions along pixel edges (x right, y down): east, south, west, north.
_STEP = np.array([[1, 0], [0, 1], [-1, 0], [0, -1]])


def tile_paths(folder: str | Path) -> list[Path]:
    """The tiles of ``folder`` in name order (dot-files left out); MetaSimError when it is not a folder,
    holds none, or a tile's name is not a safe name (it becomes the exported files' names)."""
    folder = Path(folder)
    if not folder.is_dir():
        raise MetaSimError(f"{folder} is not a folder of rendered tiles; give the --out folder of `meta-sim render`")
    paths = sorted(p for p in folder.glob("*.exr") if not p.name.startswith("."))
    if not paths:
        raise MetaSimError(f"no rendered tiles (*.exr) in {folder}; render some with `meta-sim render`")
    for path in paths:
        safe_name(path.name, "tile file name")
    return paths


def export_tiles(folder: str | Path, out: str | Path, fmt: str = "png", bars: Bars | None = None,
                 overwrite: bool = False) -> dict:
    """Export the tiles of ``folder`` to ``out`` in format ``fmt`` ("png" or "coco"; see the module
    docstring) and return a summary: format, tile and annotation counts, ``out``, and the tiles skipped
    as unreadable, each with the reason (one damaged tile need not cost the export of the rest).

    An existing ``out`` with files in it is replaced only with ``overwrite``. MetaSimError, with ``out``
    left as it was, when the format is unknown, ``folder`` holds no tiles (see ``tile_paths``) or no
    readable one, ``out`` cannot be written or would replace ``folder``."""
    if fmt not in FORMATS:
        raise MetaSimError(f"format must be one of {', '.join(FORMATS)}, not {fmt!r}")
    paths = tile_paths(folder)
    out = Path(out)
    source = Path(folder).resolve()
    if out.resolve() == source or out.resolve() in source.parents:
        raise MetaSimError(f"--out {out} would replace the tiles in {folder}; choose a folder outside it")
    if out.exists() and not out.is_dir():
        raise MetaSimError(f"{out} is a file; choose a folder for --out")
    if out.is_dir() and any(out.iterdir()) and not overwrite:
        raise MetaSimError(f"{out} already holds files; pass --overwrite to replace them, or choose another --out")
    writable_dir(out.parent)
    progress = bars("export", len(paths)) if bars else None
    images, annotations, tiles, skipped = [], [], [], []
    with atomic_dir(out, replace=True) as tmp:
        for path in paths:
            if progress:
                progress(1)
            try:
                tile = read_tile(path)
            except MetaSimError as exc:
                skipped.append((path, str(exc).removeprefix(f"{path}: ")))
                continue
            height, width = tile.instance.shape
            if tile.rgb.shape[:2] != (height, width):
                skipped.append((path, "its colour and label parts differ in size"))
                continue
            name = path.stem + ".png"
            meta = {key: tile.meta.get(key) for key in META_KEYS}
            write_png(tmp / "images" / name, to_srgb8(tile.rgb))
            if fmt == "png":
                write_png(tmp / "masks" / name, np.where(tile.building > 0, 255, 0).astype(np.uint8))
                write_png(tmp / "roof_class" / name, np.clip(tile.roof_class, 0, 255).astype(np.uint8))
                tiles.append({"name": path.stem, "image": f"images/{name}", "mask": f"masks/{name}",
                              "roof_class": f"roof_class/{name}", "width": width, "height": height, **meta})
            else:
                images.append({"id": len(images) + 1, "file_name": name, "width": width, "height": height, **meta})
                annotations += _annotations(tile.instance, tile.roof_class, len(images), len(annotations) + 1)
        if len(skipped) == len(paths):
            listing = "; ".join(f"{p.name} ({why})" for p, why in skipped[:3])
            raise MetaSimError(f"no readable tiles in {folder}: {listing}; render them again")
        if fmt == "png":
            write_text_atomic(tmp / "manifest.json", json.dumps(
                {"format_version": EXPORT_FORMAT_VERSION, "format": "png", "tiles": tiles}, indent=2) + "\n")
        else:
            coco = {"info": {"description": "meta-sim rendered tiles", "version": str(EXPORT_FORMAT_VERSION)},
                    "images": images, "annotations": annotations, "categories": CATEGORIES}
            write_text_atomic(tmp / "annotations.json", json.dumps(coco, separators=(",", ":")) + "\n")
    return {"format": fmt, "tiles": len(paths) - len(skipped), "annotations": len(annotations), "out": out,
            "skipped": skipped}


def _annotations(instance: np.ndarray, roof_class: np.ndarray, image_id: int, first_id: int) -> list[dict]:
    """The COCO annotations of one tile's buildings, numbered from ``first_id``."""
    ids, areas = np.unique(instance[instance > 0], return_counts=True)
    pairs, counts = np.unique(instance.astype(np.int64) * 3 + np.clip(roof_class, 0, 2), return_counts=True)
    roof = {}  # instance -> (pixels, roof class) of its commonest roof class
    for pair, count in zip(pairs.tolist(), counts.tolist()):
        label, kind = divmod(pair, 3)
        if kind > 0 and count > roof.get(label, (0, 0))[0]:
            roof[label] = (count, kind)
    polygons = mask_polygons(instance)
    out = []
    for label, area in zip(ids.tolist(), areas.tolist()):
        parts = polygons[label]
        xs = [x for part in parts for x in part[0::2]]
        ys = [y for part in parts for y in part[1::2]]
        out.append({"id": first_id + len(out), "image_id": image_id, "category_id": 1, "segmentation": parts,
                    "area": area, "bbox": [min(xs), min(ys), max(xs) - min(xs), max(ys) - min(ys)], "iscrowd": 0,
                    "roof_class": roof.get(label, (0, 0))[1]})
    return out


def mask_polygons(labels: np.ndarray) -> dict[int, list[list[int]]]:
    """The outline of every labelled region of ``labels`` (H, W; 0 is none): for each label, one polygon
    ``[x1, y1, x2, y2, ...]`` per 4-connected part, parts in raster order of their top-left pixel.

    Polygons follow the pixel edges (corner (x, y) is the top-left of pixel row y, column x) with the
    part on their right, clockwise on screen, from the part's top-left corner, one vertex per corner
    (no collinear points). Filled, they cover exactly the part's pixels and its holes; where two pixels
    of a part touch only at a corner, the outline passes that corner twice."""
    height, width = labels.shape
    padded = np.pad(np.asarray(labels), 1)
    # Every pixel edge between two labels, once for each labelled side, as (x, y) of its start corner,
    # direction and the label on its right.
    above, below = padded[:-1, 1:-1], padded[1:, 1:-1]  # across the (H + 1) x W horizontal edges
    before, after = padded[1:-1, :-1], padded[1:-1, 1:]  # across the H x (W + 1) vertical edges
    parts = []
    for direction, mask, owner, dx, dy in ((0, (above != below) & (below != 0), below, 0, 0),
                                           (2, (above != below) & (above != 0), above, 1, 0),
                                           (1, (before != after) & (before != 0), before, 0, 0),
                                           (3, (before != after) & (after != 0), after, 0, 1)):
        y, x = np.nonzero(mask)
        parts.append((x + dx, y + dy, np.full(len(x), direction), owner[y, x].astype(np.int64)))
    x, y, d, owner = (np.concatenate(column) for column in zip(*parts))
    # Edges in raster order of their start corner, so each outline starts at its top-left corner.
    key = (y * (width + 1) + x) * 4 + d
    order = np.argsort(key)
    x, y, d, owner, key = x[order], y[order], d[order], owner[order], key[order]
    # The edge after each: at its end corner, the first of turn right, straight on, turn left that
    # belongs to the same label. Turning right first keeps pixels that touch only at a corner apart.
    ex, ey = x + _STEP[d, 0], y + _STEP[d, 1]
    following = np.full(len(d), -1, dtype=np.int64)
    for turn in (1, 0, 3):
        wanted = (ey * (width + 1) + ex) * 4 + (d + turn) % 4
        found = np.minimum(np.searchsorted(key, wanted), len(key) - 1)
        fits = (following < 0) & (key[found] == wanted) & (owner[found] == owner)
        following[fits] = found[fits]
    following, direction = following.tolist(), d.tolist()
    xs, ys, owners = x.tolist(), y.tolist(), owner.tolist()
    seen = bytearray(len(direction))
    polygons: dict[int, list[list[int]]] = {}
    for start in range(len(direction)):
        if seen[start]:
            continue
        corners, edge = [], start
        while not seen[edge]:
            seen[edge] = 1
            nxt = following[edge]
            if direction[nxt] != direction[edge]:
                corners.append((xs[nxt], ys[nxt]))
            edge = nxt
        corners = corners[-1:] + corners[:-1]  # the start corner, reached last, first
        twice_area = sum(x0 * y1 - x1 * y0 for (x0, y0), (x1, y1) in zip(corners, corners[1:] + corners[:1]))
        if twice_area > 0:  # an outer outline (holes run the other way round)
            polygons.setdefault(owners[start], []).append([v for corner in corners for v in corner])
    return polygons

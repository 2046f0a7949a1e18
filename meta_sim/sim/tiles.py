"""The EXR tile: the one file the renderer writes and the torch side reads.

One OpenEXR file per tile, written through OpenImageIO:

* part ``rgb``: channels ``R, G, B`` (half float, linear scene-referred RGB as rendered);
* part ``labels`` (uint32 channels): ``label.building`` (uint: 1 on building pixels, else 0),
  ``label.roof_class`` (uint: 0 background or a wall, 1 flat roof, 2 sloped roof; walls show only in a
  perspective view and belong to their building in the other two channels),
  ``label.instance`` (uint: building instance id, 0 where there is no building).
  Labels are exact: one value per pixel, never averaged or anti-aliased;
* header attributes ``metasim:*``: format version, design (JSON), design
  space, city seed, tile index, tile origin (south-west corner, metres),
  pixel size, render preset, software versions. Row 0 of every channel is
  the tile's north edge.

Files are written to a temporary name beside the target and renamed when
complete, so a reader never sees a half-written tile.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import OpenImageIO as oiio

from ..core.errors import MetaSimError
from ..core.fileio import atomic_path

TILE_FORMAT_VERSION = 1
RGB_CHANNELS = ("R", "G", "B")
# In the order OpenEXR stores them (sorted by name within a layer).
LABEL_CHANNELS = ("label.building", "label.instance", "label.roof_class")
PREFIX = "metasim:"


@dataclass
class Tile:
    rgb: np.ndarray  # float32 (H, W, 3), linear
    building: np.ndarray  # uint32 (H, W)
    roof_class: np.ndarray  # uint32 (H, W)
    instance: np.ndarray  # uint32 (H, W)
    meta: dict


def software_versions(**more: str) -> dict:
    """The versions a tile's header records; the renderer adds Blender's (``blender=...``)."""
    import platform

    from .. import __version__

    return {"meta_sim": __version__, "openimageio": oiio.VERSION_STRING,
            "python": platform.python_version(), "numpy": np.__version__, **more}


def tile_metadata(*, design: dict, space: str, city_seed: int, tile_index: int, origin_m, size_px,
                  pixel_size_m: float, preset, software: dict | None = None, appearance: dict | None = None,
                  sun: dict | None = None) -> dict:
    """A tile's header; ``preset`` is a ``RenderPreset`` or its name (its settings are recorded),
    ``software`` the versions that made it (default: ``software_versions()``), ``appearance`` what
    differs from a plain render (``Appearance.header()``: sensor, roof jitter, ground, ...)."""
    from .quality import get_preset

    preset = get_preset(preset) if isinstance(preset, str) else preset
    return {"format_version": TILE_FORMAT_VERSION, "design": design, "design_space": space,
            "city_seed": int(city_seed), "tile_index": int(tile_index),
            "tile_origin_m": [float(origin_m[0]), float(origin_m[1])],
            "tile_size_px": [int(size_px[0]), int(size_px[1])],
            "pixel_size_m": float(pixel_size_m), "preset": preset.name, "render": preset.to_dict(),
            "exposure": preset.exposure, **({"tone": list(preset.tone)} if preset.tone else {}),
            "software": software or software_versions(),
            **(appearance or {}), **({"sun": sun} if sun else {})}


def write_tile(path: str | Path, rgb: np.ndarray, instance: np.ndarray, roof_class: np.ndarray,
               meta: dict) -> None:
    path = Path(path)
    height, width = instance.shape
    color = oiio.ImageSpec(width, height, len(RGB_CHANNELS), oiio.HALF)
    color.channelnames = RGB_CHANNELS
    color.attribute("name", "rgb")
    for key, value in meta.items():  # JSON text keeps every value exact (no float32 rounding)
        color.attribute(PREFIX + key, json.dumps(value, sort_keys=True))
    labels = oiio.ImageSpec(width, height, len(LABEL_CHANNELS), oiio.UINT)
    labels.channelnames = LABEL_CHANNELS
    labels.attribute("name", "labels")
    for spec in (color, labels):
        spec.attribute("compression", "zip")
    label_pixels = np.stack([instance > 0, instance, roof_class], axis=-1).astype(np.uint32)
    out = oiio.ImageOutput.create("exr")
    try:
        with atomic_path(path) as tmp:
            ok = (out.open(str(tmp), (color, labels))
                  and out.write_image(np.ascontiguousarray(rgb, dtype=np.float32))
                  and out.open(str(tmp), labels, "AppendSubimage")
                  and out.write_image(label_pixels))
            error = out.geterror()
            out.close()
            if not ok:
                raise MetaSimError(f"cannot write {path}: {error or 'check the folder is writable'}")
    finally:
        out.close()


def read_meta(path: str | Path) -> dict:
    """The header metadata of a tile (no pixels read)."""
    image = oiio.ImageInput.open(str(path))
    if image is None:
        raise MetaSimError(f"{path}: not a readable EXR tile ({oiio.geterror()})")
    try:
        return _meta_from_spec(image.spec())
    finally:
        image.close()


def _meta_from_spec(spec) -> dict:
    meta = {}
    for attr in spec.extra_attribs:
        if attr.name.startswith(PREFIX):
            try:
                meta[attr.name[len(PREFIX):]] = json.loads(attr.value)
            except (TypeError, ValueError):
                meta[attr.name[len(PREFIX):]] = attr.value
    return meta


def read_tile(path: str | Path) -> Tile:
    image = oiio.ImageInput.open(str(path))
    if image is None:
        raise MetaSimError(f"{path}: not a readable EXR tile ({oiio.geterror()})")
    try:
        meta = _meta_from_spec(image.spec())
        rgb = _read_part(image, 0, RGB_CHANNELS, "float", path)
        labels = _read_part(image, 1, LABEL_CHANNELS, "uint", path)
    finally:
        image.close()
    return Tile(rgb=rgb, building=labels[..., 0], instance=labels[..., 1],
                roof_class=labels[..., 2], meta=meta)


def _read_part(image, index: int, channels: tuple, fmt: str, path) -> np.ndarray:
    if not image.seek_subimage(index, 0) or tuple(image.spec().channelnames) != channels:
        raise MetaSimError(f"{path}: part {index} does not hold the channels {channels} of a meta-sim tile")
    pixels = image.read_image(format=fmt)
    if pixels is None:
        raise MetaSimError(f"{path}: pixels unreadable (truncated?): {image.geterror()}")
    return np.asarray(pixels)


def is_valid_tile(path: str | Path, expected: dict) -> bool:
    """True if ``path`` is a complete tile whose metadata matches ``expected`` (a subset)."""
    path = Path(path)
    if not path.is_file():
        return False
    try:
        tile = read_tile(path)
    except MetaSimError:
        return False
    if not np.all(np.isfinite(tile.rgb)):
        return False
    size = expected.get("tile_size_px")
    if size and tile.rgb.shape[:2] != (size[1], size[0]):
        return False
    return all(tile.meta.get(key) == value for key, value in expected.items() if key != "software")

"""The one image reader and the one resampler: rendered EXR tiles, real target imagery, texture photos.

``read_image`` is what the torch side sees. Everything comes out as float32 ``(H, W, 3)`` display-referred sRGB in
[0, 1], so a rendered tile and a photo of the same scene land in the same
space:

* EXR and Radiance HDR hold linear light: the sRGB transfer curve is applied
  (``linear_to_srgb``, the one definition the PNG previews use too).
* Every other format OpenImageIO reads is taken as display values already:
  8-bit / 255, 16-bit / 65535 (OpenImageIO's normalisation), float TIFFs as
  they are.
* Channels: ``R, G, B`` by name when present (the first layer that has
  them, so our tiles' part 0 and multi-layer EXRs work), else ``Y`` (grey);
  otherwise by position: 1 channel is grey, 2 are grey + alpha, 3 or more
  give the first three. Alpha is not composited: OpenImageIO is asked not
  to premultiply (``oiio:UnassociatedAlpha``), so RGB is the colour as
  stored; ``image_tiles`` uses alpha (and a TIFF's GDAL_NODATA value) to
  leave out tiles that are mostly no-data and fill the specks in others.
* NaN becomes 0, +Inf 1, -Inf 0, then everything is clipped to [0, 1]
  (HDR highlights saturate): the result is always finite.

``read_rgb8`` reads the same files with the same checks as uint8 values as stored (no transfer
curve), for texture banks and pictures. ``resize`` and ``resample`` are the one resampler.

Only numpy and OpenImageIO: Blender's Python may import this module.
"""

from __future__ import annotations

import json
import math
import struct
from collections.abc import Iterator
from pathlib import Path
from typing import Callable

import numpy as np
import OpenImageIO as oiio

from ..core.errors import MetaSimError

RENDER_PIXEL_SIZE_M = 0.3
# The smallest side the feature extractors accept; a crop below it carries too little texture.
MIN_TILE_PX = 16
_LINEAR_FORMATS = ("openexr", "hdr")
# Resampling beyond this side length means a wrong pixel size, not a real image.
_MAX_SIDE_PX = 32768
# Images up to this many pixels are read whole (a 40-megapixel float image is about 0.5 GB); larger
# targets are read in windows (``image_tiles``), and readers that cannot window refuse them.
MAX_WHOLE_PIXELS = 40_000_000


def linear_to_srgb(linear: np.ndarray, dtype=np.float64) -> np.ndarray:
    """Linear RGB -> sRGB-encoded values in [0, 1] (the standard transfer curve), computed in ``dtype``
    (float32 where 8-bit quantisation follows: twice as fast).

    NaN -> 0 and the input is clipped to [0, 1] first (+Inf -> 1, -Inf -> 0).
    """
    x = np.clip(np.nan_to_num(np.asarray(linear, dtype=dtype), nan=0.0), 0.0, 1.0)
    low = x <= dtype(0.0031308)
    out = dtype(1.055) * np.power(x, dtype(1.0) / dtype(2.4)) - dtype(0.055)
    out[low] = dtype(12.92) * x[low]
    return out


def read_image(path: str | Path) -> np.ndarray:
    """The image at ``path`` as float32 (H, W, 3) sRGB in [0, 1] (see the module docstring).
    MetaSimError for an image of more than ``MAX_WHOLE_PIXELS`` pixels: ``image_tiles`` reads
    those in windows."""
    pixels, names, fmt = _read_pixels(Path(path), "float")
    return _display(pixels, names, fmt)


def _display(pixels: np.ndarray, names: tuple, fmt: str) -> np.ndarray:
    rgb = _pick_rgb(pixels, names)
    if fmt in _LINEAR_FORMATS:
        return linear_to_srgb(rgb).astype(np.float32)
    return np.clip(np.nan_to_num(rgb, nan=0.0, posinf=1.0, neginf=0.0), 0.0, 1.0).astype(np.float32)


def read_rgb8(path: str | Path) -> np.ndarray:
    """The image at ``path`` as uint8 (H, W, 3), values as stored (OpenImageIO scales 16-bit and
    float to 8 bit); channels are picked as for ``read_image``. MetaSimError beyond
    ``MAX_WHOLE_PIXELS``."""
    pixels, names, _ = _read_pixels(Path(path), "uint8")
    return np.ascontiguousarray(_pick_rgb(pixels, names), dtype=np.uint8)


def read_rgb8_square(path: str | Path, size: int) -> np.ndarray:
    """The centre square of the image at ``path`` resized to ``size`` x ``size``, uint8 (H, W, 3) (what
    a texture bank keeps of a photo). A photo of up to ``MAX_WHOLE_PIXELS`` is read whole; a larger one
    a band of rows at a time, so memory stays bounded (the pixels are the same)."""
    path = Path(path)
    width, height = image_size(path)
    side = min(width, height)
    top, left = (height - side) // 2, (width - side) // 2
    if width * height <= MAX_WHOLE_PIXELS:
        return resize(read_rgb8(path)[top: top + side, left: left + side], size, size)
    scale = size / side
    row_index, row_weight = _resample_weights(side, scale, size)
    out = np.zeros((size, size, 3), np.uint8)
    image = _open(path)
    try:
        spec = image.spec()
        names = tuple(spec.channelnames)
        for r0 in range(0, size, 64):
            r1 = min(size, r0 + 64)
            y0, y1 = int(row_index[r0:r1].min()), int(row_index[r0:r1].max()) + 1
            pixels = image.read_scanlines(0, 0, top + y0, top + y1, 0, 0, spec.nchannels, "uint8")
            error = image.geterror()
            if pixels is None or error:
                raise MetaSimError(f"{path}: pixels unreadable, the file is truncated or damaged "
                                   f"({_first_line(error) or 'no detail'})")
            band = _pick_rgb(np.asarray(pixels).reshape(y1 - y0, width, -1), names)[:, left: left + side]
            band = band.astype(np.float32)
            rows = np.zeros((r1 - r0, side, 3), np.float32)
            for tap in range(row_index.shape[1]):
                rows += band[row_index[r0:r1, tap] - y0] * row_weight[r0:r1, tap, None, None]
            rows = _resample_axis(rows, scale, size, axis=1)
            out[r0:r1] = np.floor(np.clip(rows, 0.0, 255.0) + 0.5).astype(np.uint8)
    finally:
        image.close()
    return out


def image_size(path: str | Path) -> tuple[int, int]:
    """(width, height) of the image at ``path`` from its header alone; MetaSimError when the file is
    missing, empty or not an image OpenImageIO can open."""
    image = _open(Path(path))
    try:
        spec = image.spec()
        return spec.width, spec.height
    finally:
        image.close()


def image_tiles(path: str | Path, tile_px: int, gsd: float | None = None,
                render_gsd: float = RENDER_PIXEL_SIZE_M, dropped: list | None = None) -> Iterator[np.ndarray]:
    """The tiles of the image at ``path`` as ``load_targets`` cuts them, row of tiles by row of tiles.

    ``gsd`` is the image's pixel size (as ``pixelsize.resolve_pixel_size`` finds it); None takes it as
    ``render_gsd``. An image of up to ``MAX_WHOLE_PIXELS`` is read whole; a larger one in windows of the
    source rows that one row of tiles needs, so memory stays bounded whatever its size (the tiles are
    the same).

    No-data pixels (alpha 0, a TIFF's ``GDAL_NODATA`` value or its internal mask) are not imagery: a tile
    more than ``NODATA_MAX_SHARE`` no-data is left out (``dropped``, when given, gets one entry for it);
    in the others each no-data pixel takes the mean colour of the tile's imagery, so the file's fill
    colour (black, white) never reaches the features. Real orthomosaics have specks of no-data in
    most tiles (a few per cent of a drone mosaic's pixels), so leaving out every such tile would
    leave little.
    """
    path = Path(path)
    width, height = image_size(path)
    scale = 1.0 if gsd is None else gsd / render_gsd
    if abs(scale - 1.0) < 1e-6:
        out_h, out_w = height, width
    else:
        out_h, out_w = round(height * scale), round(width * scale)
        if min(out_h, out_w) < 1 or max(out_h, out_w) > _MAX_SIDE_PX:
            raise MetaSimError(f"resampling a {width}x{height} image from {gsd} m to {render_gsd} m pixels "
                               f"would make it {out_w}x{out_h}; check the pixel size stated for it")
    if min(out_h, out_w) < MIN_TILE_PX:
        raise MetaSimError(f"{path}: {out_w}x{out_h} px at {render_gsd} m/px is smaller than "
                           f"the {MIN_TILE_PX} px minimum; remove it or use larger images")
    nodata, mask = _nodata_value(path), _mask_subimage(path, width, height)
    if width * height <= MAX_WHOLE_PIXELS:
        pixels, names, fmt = _read_pixels(path, "float")
        masked = _read_mask(path, mask, 0, height, width) if mask is not None else None
        img = _with_validity(_display(pixels, names, fmt), pixels, names, nodata, masked)
        if gsd is not None:
            img = resample(img, gsd, render_gsd)
        yield from _imagery(cut_tiles(img, tile_px), dropped)
        return
    yield from _imagery(_windowed_tiles(path, tile_px, scale, (height, width), (out_h, out_w), nodata, mask),
                        dropped)


def _windowed_tiles(path: Path, tile_px: int, scale: float, shape: tuple, out_shape: tuple,
                    nodata: float | None, mask: int | None) -> Iterator[np.ndarray]:
    (height, width), (out_h, out_w) = shape, out_shape
    resampled = abs(scale - 1.0) >= 1e-6
    if resampled:
        row_index, row_weight = _resample_weights(height, scale, out_h)
    image = _open(path)
    try:
        spec, fmt = image.spec(), image.format_name()
        names = tuple(spec.channelnames)
        for r0, r1 in _spans(out_h, tile_px):
            y0, y1 = (int(row_index[r0:r1].min()), int(row_index[r0:r1].max()) + 1) if resampled else (r0, r1)
            pixels = image.read_scanlines(0, 0, y0, y1, 0, 0, spec.nchannels, "float")
            error = image.geterror()
            if pixels is None or error:
                raise MetaSimError(f"{path}: pixels unreadable from row {y0}, the file is truncated or damaged "
                                   f"({_first_line(error) or 'no detail'})")
            pixels = np.asarray(pixels).reshape(y1 - y0, width, -1)
            masked = _read_mask(path, mask, y0, y1, width) if mask is not None else None
            strip = _with_validity(_display(pixels, names, fmt), pixels, names, nodata, masked)
            if resampled:
                rows = np.zeros((r1 - r0, width, strip.shape[2]), np.float32)
                for tap in range(row_index.shape[1]):
                    rows += strip[row_index[r0:r1, tap] - y0] * row_weight[r0:r1, tap, None, None]
                strip = _resample_axis(rows, scale, out_w, axis=1)
            yield from cut_tiles(strip, tile_px)
    finally:
        image.close()


_GDAL_NODATA = 42113  # TIFF tag (ASCII) GDAL writes the no-data value into


def _nodata_value(path: Path) -> float | None:
    """A TIFF's GDAL_NODATA value on OpenImageIO's float scale (0..1 for integer pixels), or None."""
    image = _open(path)
    try:
        fmt, base = image.format_name(), str(image.spec().format)
    finally:
        image.close()
    if fmt != "tiff":
        return None
    try:
        raw = _tiff_tags(path, {_GDAL_NODATA}).get(_GDAL_NODATA)
        value = float(raw[0].decode("ascii", "replace").strip("\x00 ")) if raw else None
    except (OSError, struct.error, ValueError):
        return None
    if value is None or not math.isfinite(value):
        return None
    scale = {"uint8": 255.0, "uint16": 65535.0, "int16": 32767.0, "int8": 127.0}.get(base, 1.0)
    return value / scale


def _mask_subimage(path: Path, width: int, height: int) -> int | None:
    """The subimage of a TIFF's internal no-data mask (GDAL's, NewSubfileType 4, the image's size), or None."""
    image = _open(path)
    try:
        if image.format_name() != "tiff":
            return None
        index = 1
        while image.seek_subimage(index, 0):
            spec = image.spec()
            if (spec.getattribute("tiff:SubfileType") == 4 and spec.nchannels == 1
                    and (spec.width, spec.height) == (width, height)):
                return index
            index += 1
        return None
    finally:
        image.close()


def _read_mask(path: Path, subimage: int, y0: int, y1: int, width: int) -> np.ndarray:
    """Rows ``y0``..``y1`` of a TIFF's internal mask: True where the pixel is imagery."""
    image = _open(path)
    try:
        rows = image.read_scanlines(subimage, 0, y0, y1, 0, 0, 1, "uint8")
    finally:
        image.close()
    if rows is None:
        raise MetaSimError(f"{path}: its no-data mask is unreadable, the file is truncated or damaged")
    return np.asarray(rows).reshape(y1 - y0, width) > 0


def _with_validity(rgb: np.ndarray, pixels: np.ndarray, names: tuple, nodata: float | None,
                   mask: np.ndarray | None = None) -> np.ndarray:
    """``rgb`` with a fourth channel, 1 where a pixel is imagery and 0 where it is no-data, when the file
    says which pixels are no-data (an alpha channel, a GDAL_NODATA value, an internal mask); ``rgb`` as
    it is otherwise."""
    masks = [] if mask is None else [mask]
    alpha = _alpha_channel(names)
    if alpha is not None:
        masks.append(pixels[:, :, alpha] > 0)
    if nodata is not None:
        colour = pixels[:, :, :min(3, pixels.shape[2])]
        masks.append(~np.all(np.abs(colour - nodata) <= 1e-6 + 1e-6 * abs(nodata), axis=2))
    if not masks:
        return rgb
    valid = np.logical_and.reduce(masks).astype(np.float32)
    return np.concatenate([rgb, valid[:, :, None]], axis=2)


def _alpha_channel(names: tuple) -> int | None:
    for index, name in enumerate(names):
        if name.rpartition(".")[2] in ("A", "a", "alpha"):
            return index
    return None


# A tile with more than this share of no-data pixels is not imagery enough to describe a place.
NODATA_MAX_SHARE = 0.05


def _imagery(tiles, dropped: list | None) -> Iterator[np.ndarray]:
    """The RGB of tiles that are imagery, no-data pixels filled with the tile's mean imagery colour;
    tiles more than ``NODATA_MAX_SHARE`` no-data are counted in ``dropped``."""
    for tile in tiles:
        if tile.shape[2] == 4:
            nodata = tile[:, :, 3] < 0.5  # after resampling: a pixel more than half no-data
            if nodata.mean() > NODATA_MAX_SHARE:
                if dropped is not None:
                    dropped.append(1)
                continue
            rgb = np.ascontiguousarray(tile[:, :, :3])
            if nodata.any():
                rgb[nodata] = rgb[~nodata].mean(axis=0)
            tile = rgb
        yield tile


def _open(path: Path):
    """An open ImageInput for ``path``, or MetaSimError saying why not."""
    if not path.is_file():
        raise MetaSimError(f"{path}: no such file")
    if path.stat().st_size == 0:
        raise MetaSimError(f"{path}: empty file (0 bytes)")
    config = oiio.ImageSpec()
    config.attribute("oiio:UnassociatedAlpha", 1)
    image = oiio.ImageInput.open(str(path), config)
    if image is None:
        detail = _first_line(oiio.geterror())
        recognised = oiio.ImageInput.create(str(path)) is not None  # a reader knows the format from the content
        oiio.geterror()
        if recognised:
            raise MetaSimError(f"{path}: damaged or truncated image, OpenImageIO cannot open it")
        # The message for an unknown format only repeats the path.
        known = "could not find a format reader" not in detail
        raise MetaSimError(f"{path}: not an image OpenImageIO can read" + (f" ({detail})" if known and detail else ""))
    return image


def _read_pixels(path: Path, fmt) -> tuple[np.ndarray, tuple, str]:
    """All channels of the first subimage, or MetaSimError saying why not (``MAX_WHOLE_PIXELS``)."""
    image = _open(path)
    try:
        spec = image.spec()
        if spec.width * spec.height > MAX_WHOLE_PIXELS:
            raise MetaSimError(f"{path}: {spec.width}x{spec.height} pixels is more than this reader takes whole "
                               f"({MAX_WHOLE_PIXELS // 1_000_000} megapixels); crop or shrink the image")
        pixels = image.read_image(0, 0, 0, spec.nchannels, fmt)
        # A truncated file may still yield pixels (JPEG, TIFF fill the rest); the error says so.
        error = image.geterror()
        format_name = image.format_name()
    finally:
        image.close()
    if pixels is None or error:
        raise MetaSimError(f"{path}: pixels unreadable, the file is truncated or damaged "
                           f"({_first_line(error) or 'no detail'})")
    pixels = np.asarray(pixels)
    if pixels.ndim == 2:
        pixels = pixels[:, :, None]
    if pixels.ndim != 3 or pixels.shape[0] == 0 or pixels.shape[1] == 0:
        raise MetaSimError(f"{path}: not a 2-D image (pixel array of shape {pixels.shape})")
    return pixels, tuple(spec.channelnames), format_name


def _first_line(text: str) -> str:
    return text.strip().splitlines()[0] if text.strip() else ""


def _pick_rgb(pixels: np.ndarray, names: tuple) -> np.ndarray:
    layers: dict[str, dict[str, int]] = {}
    for index, name in enumerate(names):
        layer, _, short = name.rpartition(".")
        layers.setdefault(layer, {})[short] = index
    for wanted in (("R", "G", "B"), ("Y",)):
        for channels in layers.values():
            if all(c in channels for c in wanted):
                picked = pixels[:, :, [channels[c] for c in wanted]]
                return np.repeat(picked, 3, axis=2) if len(wanted) == 1 else picked
    if pixels.shape[2] < 3:
        return np.repeat(pixels[:, :, :1], 3, axis=2)
    return pixels[:, :, :3]


def image_pixel_size_m(path: str | Path) -> float | None:
    """Ground size of one pixel in metres, from the file's own metadata, or None when it does not say.

    Read from our EXR tiles' ``metasim:pixel_size_m`` header, else from GeoTIFF tags (see
    ``_geotiff_pixel_size_m``). Files beside the image (world files, ``pixel_size.txt``) are
    ``pixelsize.resolve_pixel_size``'s to read.
    """
    path = Path(path)
    image = oiio.ImageInput.open(str(path))
    if image is None:
        oiio.geterror()  # clear it: an unreadable file simply has no pixel size
        return None
    try:
        value = image.spec().getattribute("metasim:pixel_size_m")
        format_name = image.format_name()
    finally:
        image.close()
    if value is not None:
        try:
            return _valid_size(float(json.loads(value) if isinstance(value, str) else value))
        except (TypeError, ValueError):
            return None
    return _geotiff_pixel_size_m(path) if format_name == "tiff" else None


# Files GIS tools put beside an image: its world file, projection, statistics and overviews. They are
# read with the image they belong to, never listed as targets.
SIDECAR_SUFFIXES = (".tfw", ".tifw", ".tiffw", ".pgw", ".pngw", ".jgw", ".jpgw", ".jpegw", ".wld", ".prj", ".xml",
                    ".ovr", ".aux")
PIXEL_SIZE_FILE = "pixel_size.txt"  # a folder's stated pixel size (``pixelsize``), never a target image
def _valid_size(size: float) -> float | None:
    return size if math.isfinite(size) and 0.0 < size < 1e5 else None


# GeoTIFF: OpenImageIO does not expose these tags, so they are read from the first IFD directly.
_TAG_HEIGHT, _TAG_WIDTH = 257, 256
_TAG_PIXEL_SCALE, _TAG_TIEPOINT, _TAG_TRANSFORM, _TAG_GEOKEYS = 33550, 33922, 34264, 34735
_TIFF_TYPES = {2: "s", 3: "H", 4: "I", 12: "d", 16: "Q"}  # ASCII, SHORT, LONG, DOUBLE, LONG8: what the tags use
# EPSG unit codes (GeoTIFF ProjLinearUnitsGeoKey): metre, foot, US survey foot.
_LINEAR_UNITS_M = {9001: 1.0, 9002: 0.3048, 9003: 1200.0 / 3937.0}
_WEB_MERCATOR = (3857, 3785, 900913)
_EARTH_RADIUS_M = 6378137.0
METRES_PER_DEGREE = math.pi * _EARTH_RADIUS_M / 180.0


def _geotiff_pixel_size_m(path: Path) -> float | None:
    """Mean of the x and y pixel sizes in metres, from ModelPixelScale or ModelTransformation.

    The GeoKeys give the units: projected CRSs in metres or feet (web
    mercator is corrected to ground size with the cosine of the image
    centre's latitude); geographic CRSs in degrees are converted at the
    image centre's latitude on a sphere (within 0.5 % of the ellipsoid,
    enough to choose a resampling factor). No GeoKeys, or units we do not
    know: None.
    """
    try:
        tags = _tiff_tags(path, {_TAG_WIDTH, _TAG_HEIGHT, _TAG_PIXEL_SCALE, _TAG_TIEPOINT,
                                 _TAG_TRANSFORM, _TAG_GEOKEYS})
    except (OSError, struct.error, ValueError):
        return None
    keys = _geokeys(tags.get(_TAG_GEOKEYS, ()))
    width, height = tags.get(_TAG_WIDTH, (0,))[0], tags.get(_TAG_HEIGHT, (0,))[0]
    if len(tags.get(_TAG_TRANSFORM, ())) == 16:
        m = tags[_TAG_TRANSFORM]
        sx, sy = math.hypot(m[0], m[4]), math.hypot(m[1], m[5])
        centre_y = m[4] * width / 2 + m[5] * height / 2 + m[7]
    elif len(tags.get(_TAG_PIXEL_SCALE, ())) >= 2:
        sx, sy = abs(tags[_TAG_PIXEL_SCALE][0]), abs(tags[_TAG_PIXEL_SCALE][1])
        tie = tags.get(_TAG_TIEPOINT, (0.0,) * 6)
        centre_y = tie[4] - (height / 2 - tie[1]) * sy if len(tie) >= 6 else 0.0
    else:
        return None
    model = keys.get(1024)  # GTModelTypeGeoKey: 1 projected, 2 geographic
    if model == 2:
        if keys.get(2054, 9102) != 9102:  # GeogAngularUnitsGeoKey: only degrees
            return None
        lat = math.radians(max(-89.0, min(89.0, centre_y)))
        return _valid_size(0.5 * (sx * math.cos(lat) + sy) * METRES_PER_DEGREE)
    if model != 1:
        return None
    if 3076 in keys:  # ProjLinearUnitsGeoKey
        unit = _LINEAR_UNITS_M.get(keys[3076])
    else:  # the projected CRS's own unit, when pyproj (the `geo` extra) knows its code; else metres
        unit = _crs_unit_m(keys.get(3072))
    if unit is None:
        return None
    size = 0.5 * (sx + sy) * unit
    if keys.get(3072) in _WEB_MERCATOR:  # ProjectedCSTypeGeoKey: mercator metres grow as 1 / cos(lat)
        size *= math.cos(2.0 * math.atan(math.exp(centre_y * unit / _EARTH_RADIUS_M)) - math.pi / 2.0)
    return _valid_size(size)


def _crs_unit_m(code: int | None) -> float | None:
    """Metres per unit of the projected CRS with EPSG ``code``: from pyproj when it is installed (the
    `geo` extra; Blender's Python has none), else metres, the unit of most projected CRSs."""
    if code is None or code in _WEB_MERCATOR or not 1024 <= code < 32767:
        return 1.0
    try:
        import pyproj
    except ImportError:
        return 1.0
    try:
        axes = pyproj.CRS.from_epsg(code).axis_info
    except pyproj.exceptions.CRSError:
        return None
    return float(axes[0].unit_conversion_factor) if axes else None


def _geokeys(directory) -> dict[int, int]:
    """Inline SHORT-valued GeoKeys (the only kind the unit and model keys use)."""
    keys = {}
    if len(directory) >= 4:
        for k in range(min(directory[3], (len(directory) - 4) // 4)):
            key, location, count, value = directory[4 + 4 * k: 8 + 4 * k]
            if location == 0 and count == 1:
                keys[key] = value
    return keys


def _tiff_tags(path: Path, wanted: set[int]) -> dict[int, tuple]:
    """Values of ``wanted`` numeric tags in the first IFD of a TIFF or BigTIFF."""
    with open(path, "rb") as f:
        head = f.read(16)
        order = {b"II": "<", b"MM": ">"}.get(head[:2])
        if order is None:
            return {}
        magic = struct.unpack(order + "H", head[2:4])[0]
        if magic == 42:
            offset, count_fmt, entry_fmt = struct.unpack(order + "I", head[4:8])[0], "H", "HHI4s"
        elif magic == 43:
            offset, count_fmt, entry_fmt = struct.unpack(order + "Q", head[8:16])[0], "Q", "HHQ8s"
        else:
            return {}
        f.seek(offset)
        (n_entries,) = struct.unpack(order + count_fmt, f.read(struct.calcsize(count_fmt)))
        entry_size = struct.calcsize(order + entry_fmt)
        entries = f.read(entry_size * min(n_entries, 4096))
        tags = {}
        for start in range(0, len(entries) - entry_size + 1, entry_size):
            tag, kind, count, inline = struct.unpack(order + entry_fmt, entries[start:start + entry_size])
            if tag not in wanted or kind not in _TIFF_TYPES or count > 4096:
                continue
            item = _TIFF_TYPES[kind]
            size = struct.calcsize(item) * count
            if size <= len(inline):
                data = inline[:size]
            else:
                f.seek(struct.unpack(order + ("I" if magic == 42 else "Q"), inline)[0])
                data = f.read(size)
            tags[tag] = (data,) if item == "s" else struct.unpack(f"{order}{count}{item}", data)
        return tags


def resize(img: np.ndarray, out_h: int, out_w: int) -> np.ndarray:
    """``img`` (H, W, C) resized to ``out_h`` x ``out_w`` pixels.

    Shrinking averages each output pixel's exact footprint (area resampling, no aliasing);
    enlarging interpolates bilinearly between pixel centres, holding the edge pixels.
    Deterministic. A uint8 image comes back uint8 (rounded), anything else float32.
    """
    src = np.asarray(img)
    h, w = src.shape[:2]
    if min(out_h, out_w) < 1:
        raise MetaSimError(f"cannot resize a {w}x{h} image to {out_w}x{out_h} pixels")
    out = _resize(src.astype(np.float32, copy=False), out_h / h, out_h, out_w / w, out_w)
    return np.floor(np.clip(out, 0.0, 255.0) + 0.5).astype(np.uint8) if src.dtype == np.uint8 else out


def resample(img: np.ndarray, src_m: float, dst_m: float) -> np.ndarray:
    """``img`` (H, W, C) with pixels of ``src_m`` metres resampled to ``dst_m`` metres, as ``resize``
    does (float32 out); the image itself when the sizes agree."""
    if not (_positive(src_m) and _positive(dst_m)):
        raise MetaSimError(f"pixel sizes must be positive numbers of metres, got {src_m!r} and {dst_m!r}")
    img = np.asarray(img, dtype=np.float32)
    scale = src_m / dst_m
    if abs(scale - 1.0) < 1e-6:
        return img
    out_h, out_w = (round(n * scale) for n in img.shape[:2])
    if min(out_h, out_w) < 1 or max(out_h, out_w) > _MAX_SIDE_PX:
        raise MetaSimError(f"resampling a {img.shape[1]}x{img.shape[0]} image from {src_m} m to {dst_m} m pixels "
                           f"would make it {out_w}x{out_h}; check the pixel size (pass --gsd)")
    return _resize(img, scale, out_h, scale, out_w)


def _resize(img: np.ndarray, scale_h: float, out_h: int, scale_w: float, out_w: int) -> np.ndarray:
    return _resample_axis(_resample_axis(img, scale_h, out_h, axis=0), scale_w, out_w, axis=1)


def _positive(x) -> bool:
    return isinstance(x, (int, float)) and math.isfinite(x) and x > 0


def _resample_axis(img: np.ndarray, scale: float, n_out: int, axis: int) -> np.ndarray:
    index, weight = _resample_weights(img.shape[axis], scale, n_out)
    shape = [1] * img.ndim
    shape[axis] = n_out
    out = np.zeros(img.shape[:axis] + (n_out,) + img.shape[axis + 1:], dtype=np.float32)
    for tap in range(index.shape[1]):  # one tap at a time keeps memory at one output image
        out += np.take(img, index[:, tap], axis=axis) * weight[:, tap].reshape(shape)
    return out


def _resample_weights(n_in: int, scale: float, n_out: int) -> tuple[np.ndarray, np.ndarray]:
    """Per output pixel, the input indices and weights (rows sum to 1)."""
    if scale < 1.0:
        step = 1.0 / scale  # input pixels under one output pixel
        lo = np.arange(n_out) * step
        hi = np.minimum(lo + step, n_in)
        index = np.floor(lo)[:, None].astype(np.int64) + np.arange(int(math.ceil(step)) + 1)
        weight = np.clip(np.minimum(hi[:, None], index + 1) - np.maximum(lo[:, None], index), 0.0, None)
    else:
        x = (np.arange(n_out) + 0.5) / scale - 0.5
        base = np.floor(x)
        index = base[:, None].astype(np.int64) + np.arange(2)
        frac = (x - base)[:, None]
        weight = np.concatenate([1.0 - frac, frac], axis=1)
    weight = weight / weight.sum(axis=1, keepdims=True)
    return np.clip(index, 0, n_in - 1), weight.astype(np.float32)


def cut_tiles(img: np.ndarray, tile_px: int) -> list[np.ndarray]:
    """Non-overlapping ``tile_px`` crops of ``img``, row by row from the top left.

    Along each side, a remainder of at least half a tile is kept as a
    narrower crop and a smaller one is dropped; a side shorter than a tile
    is kept whole (an image smaller than a tile is one crop, itself).
    """
    rows, cols = _spans(img.shape[0], tile_px), _spans(img.shape[1], tile_px)
    return [np.ascontiguousarray(img[r0:r1, c0:c1]) for r0, r1 in rows for c0, c1 in cols]


def _spans(n: int, tile: int) -> list[tuple[int, int]]:
    if n <= tile:
        return [(0, n)]
    spans = [(start, min(start + tile, n)) for start in range(0, n, tile)]
    return [(a, b) for a, b in spans if 2 * (b - a) >= tile]


def list_images(folder: str | Path) -> tuple[list[Path], list[tuple[Path, str]]]:
    """The images directly in ``folder`` (sorted by name) and the files skipped, with why.

    Only headers are read here, so listing a large folder costs little; a file whose pixels turn
    out damaged is skipped when it is read (``image_tiles``). Hidden files and sub-folders are
    ignored. Raises MetaSimError when no file is an image.
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise MetaSimError(f"{folder} is not a folder; pass a folder of images")
    paths, skipped = [], []
    for path in sorted(folder.iterdir(), key=lambda p: p.name):
        if (path.name.startswith(".") or not path.is_file() or path.suffix.lower() in SIDECAR_SUFFIXES
                or path.name == PIXEL_SIZE_FILE):
            continue
        try:
            image_size(path)
            paths.append(path)
        except MetaSimError as exc:
            skipped.append((path, str(exc).removeprefix(f"{path}: ")))
    if not paths:
        listing = "; ".join(f"{p.name} ({why})" for p, why in skipped[:5])
        more = f"; and {len(skipped) - 5} more" if len(skipped) > 5 else ""
        raise MetaSimError(f"no readable images in {folder}; {len(skipped)} files skipped"
                           + (f": {listing}{more}" if skipped else ""))
    return paths, skipped


def load_targets(paths, tile_px: int, gsd: float | None = None, render_gsd: float = RENDER_PIXEL_SIZE_M,
                 progress: Callable[[int], None] | None = None) -> list[tuple[Path, np.ndarray]]:
    """Every image read, brought to the render pixel size and cut into tiles: ``(path, tile)`` pairs.

    ``gsd`` is every image's pixel size; None takes them as ``render_gsd``. ``progress(1)`` after
    each image.
    """
    targets = []
    for path in map(Path, paths):
        targets.extend((path, tile) for tile in image_tiles(path, tile_px, gsd, render_gsd))
        if progress:
            progress(1)
    return targets

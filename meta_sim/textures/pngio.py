"""Image files for the texture bank: a deterministic PNG writer and a reader
for users' photos.

The writer uses only the standard library (zlib + struct): 8-bit grey, RGB or
RGBA, Paeth filter on every row, zlib level 6, no timestamp or text chunks, so
the same pixels give the same file on a given machine. (zlib builds may
differ between machines; the pixel sha256 in the manifest is the contract.)
Files are written atomically: a temporary file in the target directory,
then ``os.replace``.

The reader goes through OpenImageIO, so any format it knows works (PNG, JPEG,
TIFF 8/16 bit, ...); grey becomes RGB and alpha is dropped.
"""

from __future__ import annotations

import os
import struct
import zlib
from pathlib import Path

import numpy as np

from ..errors import MetaSimError
from ..fileio import write_bytes_atomic

_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
_COLOUR_TYPES = {1: 0, 2: 4, 3: 2, 4: 6}  # channels -> PNG colour type
_ZLIB_LEVEL = 6


def _chunk(kind: bytes, data: bytes) -> bytes:
    crc = zlib.crc32(kind + data) & 0xFFFFFFFF
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", crc)


def _paeth_filter(img: np.ndarray) -> bytes:
    """Rows prefixed with filter type 4 (Paeth), computed for all rows at once."""
    h, w, c = img.shape
    raw = img.reshape(h, w * c).astype(np.int16)
    left = np.zeros_like(raw)
    left[:, c:] = raw[:, :-c]
    up = np.zeros_like(raw)
    up[1:] = raw[:-1]
    upleft = np.zeros_like(raw)
    upleft[1:, c:] = raw[:-1, :-c]
    p = left + up - upleft
    pa = np.abs(p - left)
    pb = np.abs(p - up)
    pc = np.abs(p - upleft)
    pred = np.where((pa <= pb) & (pa <= pc), left, np.where(pb <= pc, up, upleft))
    out = np.empty((h, w * c + 1), dtype=np.uint8)
    out[:, 0] = 4
    out[:, 1:] = ((raw - pred) & 0xFF).astype(np.uint8)
    return out.tobytes()


def encode_png(img: np.ndarray) -> bytes:
    """PNG bytes for a uint8 image of shape HxW (grey) or HxWxC, C in 1..4."""
    arr = np.asarray(img)
    if arr.dtype != np.uint8:
        raise ValueError(f"encode_png needs uint8 pixels, got {arr.dtype}")
    if arr.ndim == 2:
        arr = arr[:, :, None]
    if arr.ndim != 3 or arr.shape[2] not in _COLOUR_TYPES or 0 in arr.shape:
        raise ValueError(f"encode_png needs HxW or HxWx1..4 pixels, got shape {arr.shape}")
    h, w, c = arr.shape
    header = struct.pack(">IIBBBBB", w, h, 8, _COLOUR_TYPES[c], 0, 0, 0)
    data = zlib.compress(_paeth_filter(np.ascontiguousarray(arr)), _ZLIB_LEVEL)
    return _PNG_SIGNATURE + _chunk(b"IHDR", header) + _chunk(b"IDAT", data) + _chunk(b"IEND", b"")


def write_png(path: str | os.PathLike, img: np.ndarray) -> Path:
    """Write a uint8 grey/RGB/RGBA image as PNG, atomically. Returns the path."""
    return write_bytes_atomic(path, encode_png(img))


def read_rgb8(path: str | os.PathLike) -> np.ndarray:
    """Read any image OpenImageIO understands as a uint8 HxWx3 RGB array.

    16-bit and float images are converted by OpenImageIO (scaled and rounded to
    8 bit); grey is repeated to three channels; alpha and extra channels are
    dropped. Raises MetaSimError when the file is missing or unreadable.
    """
    import OpenImageIO as oiio  # imported here: the writer and the generator need no OIIO

    path = Path(path)
    if not path.is_file():
        raise MetaSimError(f"image file not found: {path}")
    config = oiio.ImageSpec()
    config.attribute("oiio:UnassociatedAlpha", 1)  # keep colours as stored, not premultiplied
    inp = oiio.ImageInput.open(str(path), config)
    if inp is None:
        raise MetaSimError(
            f"cannot read image {path}: {oiio.geterror() or 'unknown format'}; "
            "use a PNG, JPEG or TIFF file"
        )
    try:
        spec = inp.spec()
        pixels = inp.read_image(0, 0, 0, spec.nchannels, oiio.UINT8)
    finally:
        inp.close()
    if pixels is None or not isinstance(pixels, np.ndarray) or pixels.size == 0:
        raise MetaSimError(f"cannot decode image {path}: {oiio.geterror() or 'no pixels'}")
    pixels = pixels.reshape(spec.height, spec.width, spec.nchannels)
    if spec.nchannels >= 3:
        rgb = pixels[:, :, :3]
    else:  # grey or grey + alpha
        rgb = np.repeat(pixels[:, :, :1], 3, axis=2)
    return np.ascontiguousarray(rgb, dtype=np.uint8)


def resize_area(img: np.ndarray, out_h: int, out_w: int) -> np.ndarray:
    """Resize a uint8 HxWxC image by exact area averaging (box filter).

    Each output pixel is the mean of the input area it covers, with partial
    pixels weighted by overlap; good for thumbnails and downsizing photos.
    """
    src = np.asarray(img, dtype=np.float64)
    h, w = src.shape[:2]
    rows = _area_weights(h, out_h)
    cols = _area_weights(w, out_w)
    out = np.einsum("ih,hwc,jw->ijc", rows, src, cols, optimize=True)
    return np.floor(np.clip(out, 0.0, 255.0) + 0.5).astype(np.uint8)


def _area_weights(n_in: int, n_out: int) -> np.ndarray:
    """(n_out, n_in) matrix: overlap of each output cell with each input pixel."""
    edges_out = np.arange(n_out + 1, dtype=np.float64) * (n_in / n_out)
    lo = np.maximum(edges_out[:-1, None], np.arange(n_in)[None, :])
    hi = np.minimum(edges_out[1:, None], np.arange(n_in)[None, :] + 1.0)
    weights = np.clip(hi - lo, 0.0, None)
    return weights / weights.sum(axis=1, keepdims=True)

"""A deterministic PNG writer for texture banks, previews and sheets.

The writer uses only the standard library (zlib + struct): 8-bit grey, RGB or
RGBA, Paeth filter on every row, zlib level 6, no timestamp or text chunks, so
the same pixels give the same file on a given machine. (zlib builds may
differ between machines; the pixel sha256 in the manifest is the contract.)
Files are written atomically (``core.fileio``). Images are read with ``sim.imageio``.
"""

from __future__ import annotations

import os
import struct
import zlib
from pathlib import Path

import numpy as np

from ...core.fileio import write_bytes_atomic

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

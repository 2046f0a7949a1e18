"""Texture-to-texture colour similarity: the paper's HSV similarity (section
5.4, after Belongie et al. 1998), used to rank textures for top-1/top-10
scoring.

Definition (version 1), for an 8-bit sRGB image as stored (no linearisation):

1. ``r, g, b = pixel / 255``; ``v = max(r, g, b)``; chroma
   ``c = v - min(r, g, b)``; ``s = c / v`` (0 when v = 0); hue ``h`` in
   [0, 1) by the standard hexcone formula (``h = 0`` when ``c = 0``).
2. Map to the cone ``(x, y, z) = (s v cos 2 pi h, s v sin 2 pi h, v)``
   (note ``s v = c``), so dark colours are close whatever their hue.
3. Histogram the pixels in 8 x 8 x 8 equal bins over
   ``[-1, 1] x [-1, 1] x [0, 1]``: ``i = clip(floor((x + 1) / 2 * 8), 0, 7)``,
   likewise ``j`` from y, ``k = clip(floor(z * 8), 0, 7)``; flat index
   ``64 i + 8 j + k``; divide by the pixel count so it sums to 1.
4. ``similarity(p, q) = sum(min(p, q))``, the histogram intersection, in
   [0, 1]: 1 for identical colour distributions, 0 for disjoint ones.

It is symmetric and ``similarity(p, p) = 1``. It sees colour only, not
structure, and is computed in float64 with numpy's cos/sin, so a colour
exactly on a bin edge lands where rounding puts it (pure blue has
``x = -0.5000000000000004``, bin i = 1; exact greys have x = y = 0, bin 4).
Values are not required to be byte-identical across machines.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ...core.errors import MetaSimError
from ...core.fileio import write_bytes_atomic
from ..imageio import read_rgb8

SIMILARITY_FORMAT = "meta-sim-similarity"
SIMILARITY_VERSION = 1
BINS = 8
DEFINITION = (
    "HSV cone histogram intersection (Belongie et al. 1998; paper section 5.4): sRGB/255 -> HSV; "
    "cone (s*v*cos(2*pi*h), s*v*sin(2*pi*h), v); normalised 8x8x8 histogram over "
    "[-1,1]x[-1,1]x[0,1], bin = clip(floor((x+1)/2*8),0,7), clip(floor((y+1)/2*8),0,7), "
    "clip(floor(v*8),0,7), flat index 64*i+8*j+k; similarity = sum(min(p, q))"
)


def hsv_cone_bins(rgb: np.ndarray) -> np.ndarray:
    """(H*W,) int64: the flat HSV-cone bin (see the module docstring) of each pixel of a uint8 HxWx3
    image, row by row."""
    arr = np.asarray(rgb)
    if arr.dtype != np.uint8 or arr.ndim != 3 or arr.shape[2] != 3 or arr.shape[0] * arr.shape[1] == 0:
        raise ValueError(f"need a non-empty uint8 HxWx3 image, got {arr.dtype} {arr.shape}")
    pix = arr.reshape(-1, 3).astype(np.float64) / 255.0
    r, g, b = pix[:, 0], pix[:, 1], pix[:, 2]
    v = pix.max(axis=1)
    chroma = v - pix.min(axis=1)
    safe = np.where(chroma > 0.0, chroma, 1.0)
    hue = np.where(
        v == r,
        np.mod((g - b) / safe, 6.0),
        np.where(v == g, (b - r) / safe + 2.0, (r - g) / safe + 4.0),
    )
    hue = np.where(chroma > 0.0, hue / 6.0, 0.0)
    angle = 2.0 * np.pi * hue
    x = chroma * np.cos(angle)
    y = chroma * np.sin(angle)
    i = np.clip(np.floor((x + 1.0) * 0.5 * BINS), 0, BINS - 1).astype(np.int64)
    j = np.clip(np.floor((y + 1.0) * 0.5 * BINS), 0, BINS - 1).astype(np.int64)
    k = np.clip(np.floor(v * BINS), 0, BINS - 1).astype(np.int64)
    return i * BINS * BINS + j * BINS + k


def hsv_cone_histogram(rgb: np.ndarray) -> np.ndarray:
    """Normalised (512,) float64 histogram of a uint8 HxWx3 image's colours
    in the HSV cone (see the module docstring)."""
    bins = hsv_cone_bins(rgb)
    return np.bincount(bins, minlength=BINS**3).astype(np.float64) / float(len(bins))


def similarity(h1: np.ndarray, h2: np.ndarray) -> float:
    """Histogram intersection of two normalised histograms, in [0, 1]."""
    return float(np.minimum(np.asarray(h1, np.float64), np.asarray(h2, np.float64)).sum())


def similarity_matrix(hists_a: np.ndarray, hists_b: np.ndarray) -> np.ndarray:
    """(len(a), len(b)) matrix of histogram intersections."""
    a = np.asarray(hists_a, dtype=np.float64)
    b = np.asarray(hists_b, dtype=np.float64)
    return np.minimum(a[:, None, :], b[None, :, :]).sum(axis=2)


@dataclass(frozen=True)
class Similarity:
    """A similarity matrix with its row and column texture ids."""

    rows: tuple[str, ...]
    cols: tuple[str, ...]
    matrix: np.ndarray

    def value(self, row_id: str, col_id: str) -> float:
        return float(self.matrix[self._row(row_id), self._col(col_id)])

    def _row(self, texture_id: str) -> int:
        try:
            return self.rows.index(texture_id)
        except ValueError:
            raise MetaSimError(
                f"texture {texture_id!r} is not a row of this similarity matrix; "
                "use an id from the bank it was computed for"
            ) from None

    def _col(self, texture_id: str) -> int:
        try:
            return self.cols.index(texture_id)
        except ValueError:
            raise MetaSimError(
                f"texture {texture_id!r} is not a column of this similarity matrix; "
                "use an id from the bank it was computed against"
            ) from None

    def to_dict(self) -> dict:
        return {
            "format": SIMILARITY_FORMAT,
            "version": SIMILARITY_VERSION,
            "definition": DEFINITION,
            "rows": list(self.rows),
            "cols": list(self.cols),
            "matrix": [[round(float(x), 6) for x in row] for row in self.matrix],
        }

    @classmethod
    def from_dict(cls, data: dict, where: str = "similarity data") -> "Similarity":
        if not isinstance(data, dict) or data.get("format") != SIMILARITY_FORMAT:
            raise MetaSimError(f"{where} is not a meta-sim similarity file (format {SIMILARITY_FORMAT!r})")
        if data.get("version") != SIMILARITY_VERSION:
            raise MetaSimError(
                f"{where} has similarity version {data.get('version')!r}; this meta-sim reads "
                f"version {SIMILARITY_VERSION}: recompute it"
            )
        try:
            rows = tuple(str(r) for r in data["rows"])
            cols = tuple(str(c) for c in data["cols"])
            matrix = np.array(data["matrix"], dtype=np.float64).reshape(len(rows), len(cols))
        except (KeyError, TypeError, ValueError) as exc:
            raise MetaSimError(f"{where} is malformed ({exc}); recompute it") from None
        return cls(rows, cols, matrix)


def bank_histograms(bank) -> np.ndarray:
    """(n, 512) histograms of a bank's textures, in bank order."""
    return np.stack([hsv_cone_histogram(read_rgb8(bank.image_path(e.id))) for e in bank.entries])


def bank_similarity(bank, other=None) -> Similarity:
    """Similarity of every texture of ``bank`` (rows) to every texture of
    ``other`` (columns; the bank itself when None)."""
    hists = bank_histograms(bank)
    other_hists = hists if other is None else bank_histograms(other)
    cols = bank.ids() if other is None else other.ids()
    return Similarity(tuple(bank.ids()), tuple(cols), similarity_matrix(hists, other_hists))


def save_similarity(sim: Similarity, out_path: str | os.PathLike) -> Path:
    text = json.dumps(sim.to_dict(), indent=None, separators=(",", ":"))
    return write_bytes_atomic(out_path, (text + "\n").encode("utf-8"))


def write_similarity(bank, out_path: str | os.PathLike, other_bank=None) -> Path:
    """Compute ``bank_similarity`` and write it as JSON (see ``Similarity.to_dict``)."""
    return save_similarity(bank_similarity(bank, other_bank), out_path)


def load_similarity(path: str | os.PathLike) -> Similarity:
    path = Path(path)
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise MetaSimError(f"similarity file not found: {path}") from None
    except (OSError, ValueError) as exc:
        raise MetaSimError(f"cannot read similarity file {path}: {exc}") from None
    return Similarity.from_dict(data, where=str(path))


def rank_by_similarity(true_id: str, candidate_ids, sim: Similarity) -> list[str]:
    """Candidate ids, most similar to ``true_id`` first (ties keep the
    candidates' order). ``true_id`` is a row, candidates are columns."""
    row = sim.matrix[sim._row(true_id)]
    candidates = list(candidate_ids)
    scores = np.array([row[sim._col(c)] for c in candidates], dtype=np.float64)
    order = np.argsort(-scores, kind="stable")
    return [candidates[i] for i in order]

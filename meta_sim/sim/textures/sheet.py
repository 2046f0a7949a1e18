"""Contact sheets: every texture of a bank as a labelled thumbnail grid.

Flat textures come first, then sloped ones, each kind starting a new row.
Labels are short indices within the kind (F00.., S00..) drawn with a tiny
built-in 5x7 bitmap font; ``contact_sheet`` returns the label -> id legend.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from ..imageio import read_rgb8, resize
from .pngio import write_png

# 5x7 glyphs, one string of five '#'/'.' per row.
_GLYPHS = {
    "0": (".###.", "#...#", "#..##", "#.#.#", "##..#", "#...#", ".###."),
    "1": ("..#..", ".##..", "..#..", "..#..", "..#..", "..#..", ".###."),
    "2": (".###.", "#...#", "....#", "...#.", "..#..", ".#...", "#####"),
    "3": ("####.", "....#", "....#", ".###.", "....#", "....#", "####."),
    "4": ("...#.", "..##.", ".#.#.", "#..#.", "#####", "...#.", "...#."),
    "5": ("#####", "#....", "####.", "....#", "....#", "#...#", ".###."),
    "6": ("..##.", ".#...", "#....", "####.", "#...#", "#...#", ".###."),
    "7": ("#####", "....#", "...#.", "..#..", ".#...", ".#...", ".#..."),
    "8": (".###.", "#...#", "#...#", ".###.", "#...#", "#...#", ".###."),
    "9": (".###.", "#...#", "#...#", ".####", "....#", "...#.", ".##.."),
    "F": ("#####", "#....", "#....", "####.", "#....", "#....", "#...."),
    "S": (".####", "#....", "#....", ".###.", "....#", "....#", "####."),
    "H": ("#...#", "#...#", "#...#", "#####", "#...#", "#...#", "#...#"),
    "-": (".....", ".....", ".....", "#####", ".....", ".....", "....."),
    " ": (".....",) * 7,
    "A": (".###.", "#...#", "#...#", "#####", "#...#", "#...#", "#...#"),
    "B": ("####.", "#...#", "#...#", "####.", "#...#", "#...#", "####."),
    "C": (".###.", "#...#", "#....", "#....", "#....", "#...#", ".###."),
    "D": ("####.", "#...#", "#...#", "#...#", "#...#", "#...#", "####."),
    "E": ("#####", "#....", "#....", "####.", "#....", "#....", "#####"),
    "G": (".###.", "#...#", "#....", "#.###", "#...#", "#...#", ".###."),
    "I": (".###.", "..#..", "..#..", "..#..", "..#..", "..#..", ".###."),
    "J": ("..###", "...#.", "...#.", "...#.", "...#.", "#..#.", ".##.."),
    "K": ("#...#", "#..#.", "#.#..", "##...", "#.#..", "#..#.", "#...#"),
    "L": ("#....", "#....", "#....", "#....", "#....", "#....", "#####"),
    "M": ("#...#", "##.##", "#.#.#", "#.#.#", "#...#", "#...#", "#...#"),
    "N": ("#...#", "#...#", "##..#", "#.#.#", "#..##", "#...#", "#...#"),
    "O": (".###.", "#...#", "#...#", "#...#", "#...#", "#...#", ".###."),
    "P": ("####.", "#...#", "#...#", "####.", "#....", "#....", "#...."),
    "Q": (".###.", "#...#", "#...#", "#...#", "#.#.#", "#..#.", ".##.#"),
    "R": ("####.", "#...#", "#...#", "####.", "#.#..", "#..#.", "#...#"),
    "T": ("#####", "..#..", "..#..", "..#..", "..#..", "..#..", "..#.."),
    "U": ("#...#", "#...#", "#...#", "#...#", "#...#", "#...#", ".###."),
    "V": ("#...#", "#...#", "#...#", "#...#", "#...#", ".#.#.", "..#.."),
    "W": ("#...#", "#...#", "#...#", "#.#.#", "#.#.#", "#.#.#", ".#.#."),
    "X": ("#...#", "#...#", ".#.#.", "..#..", ".#.#.", "#...#", "#...#"),
    "Y": ("#...#", "#...#", ".#.#.", "..#..", "..#..", "..#..", "..#.."),
    "Z": ("#####", "....#", "...#.", "..#..", ".#...", "#....", "#####"),
    ".": (".....", ".....", ".....", ".....", ".....", ".##..", ".##.."),
    ":": (".....", ".##..", ".##..", ".....", ".##..", ".##..", "....."),
    "/": ("....#", "....#", "...#.", "..#..", ".#...", "#....", "#...."),
    "+": (".....", "..#..", "..#..", "#####", "..#..", "..#..", "....."),
    "%": ("##..#", "##..#", "...#.", "..#..", ".#...", "#..##", "#..##"),
    "_": (".....", ".....", ".....", ".....", ".....", ".....", "#####"),
}
_GLYPH_W, _GLYPH_H = 5, 7
_BACKGROUND = np.array([32, 32, 32], dtype=np.uint8)
_INK = np.array([235, 235, 235], dtype=np.uint8)
_PAD = 4


def text_mask(text: str, scale: int = 1) -> np.ndarray:
    """Boolean mask of ``text`` in the built-in font (1 px between glyphs)."""
    width = max(1, len(text) * (_GLYPH_W + 1) - 1)
    mask = np.zeros((_GLYPH_H, width), dtype=bool)
    for i, ch in enumerate(text.upper()):
        glyph = _GLYPHS.get(ch, _GLYPHS[" "])
        rows = np.array([[c == "#" for c in row] for row in glyph], dtype=bool)
        mask[:, i * (_GLYPH_W + 1): i * (_GLYPH_W + 1) + _GLYPH_W] = rows
    return np.kron(mask, np.ones((scale, scale), dtype=bool))


def _label_strip(text: str, width: int) -> np.ndarray:
    strip = np.broadcast_to(_BACKGROUND, (_GLYPH_H + 4, width, 3)).copy()
    mask = text_mask(text)[:, : max(0, width - 2)]
    strip[2: 2 + mask.shape[0], 2: 2 + mask.shape[1]][mask] = _INK
    return strip


def render_sheet(rows_of_items: list[list[tuple[str, np.ndarray]]], thumb: int, cols: int) -> np.ndarray:
    """Grid image from groups of (label, uint8 RGB) items; each group starts
    a new row and wraps after ``cols`` items."""
    layout: list[list[tuple[str, np.ndarray]]] = []
    for group in rows_of_items:
        for start in range(0, len(group), cols):
            layout.append(group[start: start + cols])
    cell_h = thumb + _GLYPH_H + 4
    height = _PAD + len(layout) * (cell_h + _PAD)
    width = _PAD + cols * (thumb + _PAD)
    sheet = np.broadcast_to(_BACKGROUND, (max(height, 1), width, 3)).copy()
    for r, line in enumerate(layout):
        y = _PAD + r * (cell_h + _PAD)
        for c, (label, img) in enumerate(line):
            x = _PAD + c * (thumb + _PAD)
            sheet[y: y + thumb, x: x + thumb] = resize(img, thumb, thumb)
            sheet[y + thumb: y + cell_h, x: x + thumb] = _label_strip(label, thumb)
    return sheet


def sheet_labels(bank) -> dict[str, str]:
    """Label (F00.., S00..) -> texture id, in sheet order."""
    legend = {}
    for kind, prefix in (("flat", "F"), ("sloped", "S")):
        for i, texture_id in enumerate(bank.ids(kind)):
            legend[f"{prefix}{i:02d}"] = texture_id
    return legend


def contact_sheet(bank, out_png: str | os.PathLike, thumb: int = 96, cols: int = 12) -> dict[str, str]:
    """Write a labelled thumbnail grid of ``bank`` to ``out_png``.

    Returns the legend: label -> texture id.
    """
    if thumb < 8 or cols < 1:
        raise ValueError(f"thumb must be >= 8 and cols >= 1, got {thumb}, {cols}")
    legend = sheet_labels(bank)
    groups: dict[str, list[tuple[str, np.ndarray]]] = {"F": [], "S": []}
    for label, texture_id in legend.items():
        groups[label[0]].append((label, read_rgb8(bank.image_path(texture_id))))
    write_png(Path(out_png), render_sheet([g for g in groups.values() if g], thumb, cols))
    return legend

"""How much ground one pixel of a real image covers, and who said so: the one resolver that every reader of real
imagery asks (`task train --real`, `task eval`, `infer`, ``RealDataset``).

An image's pixel size is the first of these that says it:

1. ``flag``: the folder as the command line names it, ``DIR:METRES`` (``--real banepa:0.13``);
2. ``metadata``: the image file's own (GeoTIFF tags, a rendered tile's EXR header: ``imageio.image_pixel_size_m``);
3. ``world file``: the world file beside the image (``.pgw``, ``.tfw``, ``.jgw``, ``.wld``, ...), or
   ``pixel_size.txt``: a file of that name in the folder, holding one number, metres per pixel;
4. ``global option``: the command's option for every folder (``--real-gsd``, infer's ``--gsd``);
5. ``assumed``: the model's own pixel size, where the command may assume one; elsewhere an unknown size is an error.

Two of 1-3 that disagree are an error naming both and the fix, so a size the files state is never overridden
without a word. Files beside the images are untrusted: each is read strictly and a malformed one is an error,
never skipped.
"""

from __future__ import annotations

import math
import re
from collections import Counter
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path

from ..core.errors import MetaSimError
from .imageio import METRES_PER_DEGREE, PIXEL_SIZE_FILE, image_pixel_size_m

LIMITS_M = (0.01, 10.0)  # metres per pixel a stated size may have: drone to coarse satellite imagery
# Sizes within this share of each other agree: stated sizes are rounded (0.13 for 0.134 m), and a few per cent
# changes no building's look after resampling.
AGREE = 0.05
SQUARE = 0.01  # a world file's x and y pixel sizes may differ by this share (rounding) and still be square
SOURCES = ("flag", "metadata", "world file", PIXEL_SIZE_FILE, "global option", "assumed")
_NUMBER = re.compile(r"[+-]?(\d+\.?\d*|\.\d+)([eE][+-]?\d+)?")
_MAX_BYTES = 4096  # a pixel_size.txt or world file is a few numbers; anything larger is not one
_OWN = "its own metadata"
_FEET = {"foot_us": 1200.0 / 3937.0, "us survey foot": 1200.0 / 3937.0, "foot": 0.3048, "international foot": 0.3048}


@dataclass(frozen=True)
class PixelSize:
    """One image's ground size of a pixel and where it came from (one of ``SOURCES``)."""

    metres: float
    source: str

    @property
    def stated(self) -> bool:
        return self.source != "assumed"


@dataclass(frozen=True)
class ImageFolder:
    """A folder of real images and how the command that reads it states their pixel size.

    ``stated_m`` is the folder's own size (``DIR:METRES``), ``flag`` how a user states it (``METRES`` standing
    for the number, for messages), ``fallback_m`` the command's size for every folder and ``fallback_flag`` its
    option, ``assumed_m`` the size taken for images nothing states (None: such an image is an error).
    """

    path: Path
    stated_m: float | None = None
    flag: str = "pixel_size_m=METRES"
    fallback_m: float | None = None
    fallback_flag: str | None = None
    assumed_m: float | None = None

    def __post_init__(self):
        object.__setattr__(self, "path", Path(self.path))
        if self.stated_m is not None:
            _check_range(self.stated_m, self.flag.replace("METRES", str(self.stated_m)))
        if self.fallback_m is not None:
            _check_range(self.fallback_m, self.fallback_flag or "the pixel size for every folder")

    @classmethod
    def parse(cls, text: str | Path, option: str = "", **fields) -> ImageFolder:
        """The folder a command line names as ``DIR`` or ``DIR:METRES`` (after ``option``, e.g. "--real";
        "" for an argument); ``fields``: the fallback and assumed sizes. A name that exists as it is given
        is a folder even when it ends in ``:NUMBER``."""
        text = str(text)
        head, colon, tail = text.rpartition(":")
        if not colon or not head or not tail or "/" in tail or "\\" in tail or Path(text).exists():
            head, stated = text, None
        elif _NUMBER.fullmatch(tail) and _in_range(float(tail)):
            stated = float(tail)
        else:
            raise MetaSimError(f"{text}: the pixel size after ':' must be a number of metres per pixel from "
                               f"{LIMITS_M[0]:g} to {LIMITS_M[1]:g}, for example {head}:0.5")
        return cls(Path(head), stated, f"{option} {head}:METRES".strip(), **fields)

    @classmethod
    def of(cls, folder: str | Path | ImageFolder, **fields) -> ImageFolder:
        """``folder`` as it is, or a path with ``fields`` (no ``:METRES`` suffix: a path from code is a path)."""
        return folder if isinstance(folder, ImageFolder) else cls(Path(folder), **fields)

    def ways(self) -> str:
        """The ways a user can state the folder's pixel size, for messages."""
        ways = [self.flag, f"a {PIXEL_SIZE_FILE} in {self.path}", *([self.fallback_flag] if self.fallback_flag else [])]
        return ", ".join(ways[:-1]) + " or " + ways[-1]

    @cached_property
    def file_m(self) -> float | None:
        """The size in the folder's ``pixel_size.txt``, None without one; MetaSimError for a malformed one."""
        return read_pixel_size_file(self.path / PIXEL_SIZE_FILE)


def resolve_pixel_size(image: str | Path, folder: ImageFolder) -> PixelSize:
    """The pixel size of ``image`` in ``folder``, by the precedence of the module's docstring.

    MetaSimError, naming the fix, when two stated sizes disagree by more than ``AGREE``, when a world file or
    ``pixel_size.txt`` is malformed, and when nothing states the size and ``folder`` assumes none.
    """
    image = Path(image)
    said = [(source, metres, who) for source, metres, who in (
        ("flag", folder.stated_m, folder.flag.replace("METRES", f"{folder.stated_m}")),
        ("metadata", image_pixel_size_m(image), _OWN),
        ("world file", world_file_pixel_size_m(image), str(world_file(image))),
        (PIXEL_SIZE_FILE, folder.file_m, str(folder.path / PIXEL_SIZE_FILE)),
    ) if metres is not None]
    if said:
        source, metres, who = said[0]
        for _, other, other_who in said[1:]:
            if abs(other / metres - 1.0) > AGREE:
                fix = " or ".join(w for w in (who, other_who) if w != _OWN)
                raise MetaSimError(f"{image}: {who} says {metres:g} m per pixel but {other_who} says {other:g}; "
                                   f"correct or remove {fix}")
        return PixelSize(float(metres), source)
    if folder.fallback_m is not None:
        return PixelSize(float(folder.fallback_m), "global option")
    if folder.assumed_m is not None:
        return PixelSize(float(folder.assumed_m), "assumed")
    raise MetaSimError(f"{image}: its pixel size is unknown; give its pixel size: {folder.ways()}")


def read_pixel_size_file(path: str | Path) -> float | None:
    """The metres per pixel in a ``pixel_size.txt`` at ``path`` (None when there is none): one number from
    ``LIMITS_M``, alone on its line; blank lines and lines starting with ``#`` may surround it."""
    path = Path(path)
    if not path.exists():
        return None
    lines = [line.strip() for line in _small_text(path).splitlines()]
    numbers = [line for line in lines if line and not line.startswith("#")]
    if len(numbers) != 1 or not _NUMBER.fullmatch(numbers[0]) or not _in_range(float(numbers[0])):
        raise MetaSimError(f"{path} must hold one number, the metres per pixel of the folder's images from "
                           f"{LIMITS_M[0]:g} to {LIMITS_M[1]:g} (e.g. 0.5), and nothing else but # comments; "
                           "correct or remove it")
    return float(numbers[0])


def world_file(image: str | Path) -> Path | None:
    """The world file beside ``image`` (``.pgw`` or ``.pngw`` for ``.png``, ``.tfw`` for ``.tif``, ...,
    else ``.wld``), or None."""
    path = Path(image)
    suffix = path.suffix.lower()
    names = [suffix[:2] + suffix[-1:] + "w", suffix + "w", ".wld"] if len(suffix) > 1 else [".wld"]
    return next((w for w in (path.with_suffix(s) for s in names) if w.is_file()), None)


def world_file_pixel_size_m(image: str | Path) -> float | None:
    """The pixel size in metres that the world file beside ``image`` states, or None without one.

    A world file holds six numbers: the pixel's x size, two rotation terms, its y size (negative), and the top
    left pixel's centre. Their unit comes from the ``.prj`` beside it when there is one (a geographic CRS in
    degrees is converted at the image's latitude; a projected one in metres or feet); without a ``.prj`` they are
    metres. MetaSimError, naming the file, unless it holds exactly six numbers of square, north-up pixels whose
    size is within ``LIMITS_M``.
    """
    path = Path(image)
    world = world_file(path)
    if world is None:
        return None
    words = _small_text(world).split()
    if len(words) != 6 or not all(_NUMBER.fullmatch(w) for w in words):
        raise MetaSimError(f"{world}: a world file holds six numbers (pixel x size, two rotation terms, pixel y "
                           "size, x and y of the first pixel); correct or remove it")
    a, d, b, e, _, f = (float(w) for w in words)
    if not (math.isfinite(a) and math.isfinite(e) and a != 0 and e != 0):
        raise MetaSimError(f"{world}: its pixel sizes ({a:g}, {e:g}) must be numbers other than 0; correct or "
                           "remove it")
    if abs(d) + abs(b) > 1e-9 * abs(a):
        raise MetaSimError(f"{world}: the image is rotated (terms {d:g}, {b:g}); meta-sim reads north-up images "
                           "only: remove the world file and state the pixel size another way")
    if abs(abs(e) / abs(a) - 1.0) > SQUARE:
        raise MetaSimError(f"{world}: its pixels are not square ({abs(a):g} by {abs(e):g}); correct or remove it")
    prj = path.with_suffix(".prj")
    wkt = prj.read_text(errors="replace")[:20000].lower() if prj.is_file() else ""
    if wkt.startswith(("geogcs", "geogcrs")):
        lat = math.radians(max(-89.0, min(89.0, f)))
        size = 0.5 * (abs(a) * math.cos(lat) + abs(e)) * METRES_PER_DEGREE
    else:
        unit = next((m for name, m in _FEET.items() if f'unit["{name}"' in wkt or f'lengthunit["{name}"' in wkt), 1.0)
        size = 0.5 * (abs(a) + abs(e)) * unit
    if not _in_range(size):
        raise MetaSimError(f"{world}: it says {size:g} m per pixel, outside {LIMITS_M[0]:g}-{LIMITS_M[1]:g} m; "
                           "correct or remove it")
    return size


def summary(sizes: list[PixelSize]) -> list[dict]:
    """What a report records of a folder's pixel sizes: each distinct size and source with its image count."""
    counts = Counter((s.source, s.metres) for s in sizes)
    return [{"pixel_size_m": metres, "source": source, "stated": source != "assumed", "images": n}
            for (source, metres), n in sorted(counts.items(), key=lambda kv: (SOURCES.index(kv[0][0]), kv[0][1]))]


def summary_line(entries: list[dict]) -> str:
    """``summary`` in words, for Markdown reports and the terminal."""
    return "; ".join(f"{e['pixel_size_m']:g} m per pixel ({'stated by ' + e['source'] if e['stated'] else 'assumed'})"
                     f" for {e['images']} image{'s' if e['images'] != 1 else ''}" for e in entries)


def assumed_warning(folder: ImageFolder, sizes: list[PixelSize]) -> str | None:
    """One line saying how many of ``folder``'s images were taken at the assumed size, or None for none."""
    assumed = sum(not s.stated for s in sizes)
    if not assumed:
        return None
    return (f"warning: {assumed} of {len(sizes)} images in {folder.path} do not state their pixel size; taken as "
            f"the model's {folder.assumed_m:g} m. State it: {folder.ways()}")


def _small_text(path: Path) -> str:
    try:
        if not path.is_file() or path.stat().st_size > _MAX_BYTES:
            raise MetaSimError(f"{path} is not a small text file of numbers; correct or remove it")
        return path.read_bytes().decode("utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise MetaSimError(f"{path} cannot be read as text ({exc.__class__.__name__}); correct or remove it") from None


def _in_range(metres: float) -> bool:
    return math.isfinite(metres) and LIMITS_M[0] <= metres <= LIMITS_M[1]


def _check_range(metres, who: str) -> None:
    if isinstance(metres, bool) or not isinstance(metres, (int, float)) or not _in_range(float(metres)):
        raise MetaSimError(f"{who}: a pixel size must be from {LIMITS_M[0]:g} to {LIMITS_M[1]:g} metres per pixel, "
                           f"not {metres!r}")


"""Texture banks: a folder of RGB PNGs plus ``manifest.json``.

Manifest (the one contract between bank writers and readers)::

    {"format": "meta-sim-texture-bank", "version": 1, "name": "default-v1",
     "textures": [{"id": "flat-gravel-light", "name": "Light grey gravel ballast",
                   "kind": "flat", "path": "flat/flat-gravel-light.png",
                   "repeat_m": 3.0, "source": "procedural:flat-gravel-light@v1",
                   "sha256": "<sha256 of the image's RGB pixel bytes, row-major>"}, ...]}

``path`` is relative to the bank folder; ``repeat_m`` is the physical width
of one repeat of the image in metres (its height scales with the aspect
ratio). Banks also hold ``similarity.json`` (see ``similarity.py``).

Banks come from three places: the default procedural bank and the held-out
sets ``heldout-v1`` to ``heldout-v5`` (cached under ``$META_SIM_CACHE`` or ``~/.cache/meta-sim`` and built on
first use), or a user's folder of photos (``build_bank_from_folder``).
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Iterable

import numpy as np

from ...core.cache import cache_root
from ...core.errors import MetaSimError
from ...core.fileio import atomic_dir, write_bytes_atomic
from ...core.names import inside, safe_name
from ...core.progress import Bars, Progress
from ..imageio import read_rgb8, read_rgb8_square
from . import procedural
from .pngio import write_png
from .similarity import Similarity, hsv_cone_histogram, save_similarity, similarity_matrix

BANK_FORMAT = "meta-sim-texture-bank"
BANK_VERSION = 1
MANIFEST = "manifest.json"
SIMILARITY_FILE = "similarity.json"
SIMILARITY_TO_DEFAULT_FILE = "similarity_to_default.json"
KINDS = procedural.KINDS
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".tif", ".tiff", ".bmp", ".tga", ".webp", ".exr", ".hdr")
_ENTRY_KEYS = ("id", "name", "kind", "path", "repeat_m", "source", "sha256")


def pixel_sha256(rgb: np.ndarray) -> str:
    """sha256 of a uint8 RGB image's pixel bytes (row-major, no header)."""
    return hashlib.sha256(np.ascontiguousarray(rgb, dtype=np.uint8).tobytes()).hexdigest()


def slugify(text: str) -> str:
    """Lowercase ASCII slug: runs of anything but a-z0-9 become one '-'."""
    return re.sub(r"[^a-z0-9]+", "-", text.lower()).strip("-")


def _positive_metres(value, what: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or value <= 0:
        raise MetaSimError(f"{what} must be a positive number of metres, got {value!r}")
    return float(value)


@dataclass(frozen=True)
class TextureEntry:
    """One texture of a bank."""

    id: str
    name: str
    kind: str
    path: str
    repeat_m: float
    source: str
    sha256: str

    def to_dict(self) -> dict:
        return {key: getattr(self, key) for key in _ENTRY_KEYS}

    @classmethod
    def from_dict(cls, data, where: str = "texture entry") -> "TextureEntry":
        if not isinstance(data, dict):
            raise MetaSimError(f"{where} must be a JSON object, got {type(data).__name__}")
        missing = [key for key in _ENTRY_KEYS if key not in data]
        if missing:
            raise MetaSimError(f"{where} lacks {', '.join(missing)}; rebuild the bank")
        for key in ("id", "name", "kind", "path", "source", "sha256"):
            if not isinstance(data[key], str) or not data[key]:
                raise MetaSimError(f"{where}: {key} must be a non-empty string, got {data[key]!r}")
        safe_name(data["id"], f"{where}: texture id")
        if data["kind"] not in KINDS:
            raise MetaSimError(f"{where}: kind must be one of {', '.join(KINDS)}, got {data['kind']!r}")
        rel = Path(data["path"])
        if rel.is_absolute() or ".." in rel.parts:
            raise MetaSimError(f"{where}: path must be relative to the bank folder, got {data['path']!r}")
        if not re.fullmatch(r"[0-9a-f]{64}", data["sha256"]):
            raise MetaSimError(f"{where}: sha256 must be 64 lowercase hex digits")
        return cls(
            id=data["id"],
            name=data["name"],
            kind=data["kind"],
            path=rel.as_posix(),
            repeat_m=_positive_metres(data["repeat_m"], f"{where}: repeat_m"),
            source=data["source"],
            sha256=data["sha256"],
        )


@dataclass(frozen=True)
class TextureBank:
    """A loaded bank: its folder, name and entries (flat ones first)."""

    root: Path
    name: str
    entries: tuple[TextureEntry, ...]
    version: int = BANK_VERSION

    def __len__(self) -> int:
        return len(self.entries)

    def to_dict(self) -> dict:
        return {
            "format": BANK_FORMAT,
            "version": self.version,
            "name": self.name,
            "textures": [e.to_dict() for e in self.entries],
        }

    @classmethod
    def from_dict(cls, data, root: str | os.PathLike, where: str = "texture manifest") -> "TextureBank":
        if not isinstance(data, dict) or data.get("format") != BANK_FORMAT:
            raise MetaSimError(f"{where} is not a meta-sim texture bank manifest (format {BANK_FORMAT!r})")
        version = data.get("version")
        if version != BANK_VERSION:
            raise MetaSimError(
                f"{where} has bank version {version!r}; this meta-sim reads version {BANK_VERSION}: "
                "rebuild the bank or use a matching meta-sim"
            )
        name = data.get("name")
        if not isinstance(name, str) or not name:
            raise MetaSimError(f"{where}: name must be a non-empty string")
        textures = data.get("textures")
        if not isinstance(textures, list) or not textures:
            raise MetaSimError(f"{where}: textures must be a non-empty list")
        entries = tuple(TextureEntry.from_dict(item, f"{where}, texture {i}") for i, item in enumerate(textures))
        seen: set[str] = set()
        for entry in entries:
            if entry.id in seen:
                raise MetaSimError(f"{where}: texture id {entry.id!r} appears twice; ids must be unique")
            seen.add(entry.id)
        return cls(root=Path(root), name=name, entries=entries, version=version)

    def contains(self, texture_id: str) -> bool:
        return any(e.id == texture_id for e in self.entries)

    def by_id(self, texture_id: str) -> TextureEntry:
        for entry in self.entries:
            if entry.id == texture_id:
                return entry
        raise MetaSimError(
            f"texture {texture_id!r} is not in bank {self.name!r} ({self.root}); "
            f"its ids start with {', '.join(self.ids()[:3])}, ... ({len(self)} in all)"
        )

    def ids(self, kind: str | None = None) -> list[str]:
        if kind is not None and kind not in KINDS:
            raise MetaSimError(f"kind must be one of {', '.join(KINDS)}, got {kind!r}")
        return [e.id for e in self.entries if kind is None or e.kind == kind]

    def image_path(self, texture_id: str) -> Path:
        """The texture's image file, checked to lie inside the bank folder (links followed)."""
        return inside(self.root, self.by_id(texture_id).path, f"texture {texture_id!r}: image")

    def load_image(self, texture_id: str) -> np.ndarray:
        return read_rgb8(self.image_path(texture_id))


def save_manifest(bank: TextureBank) -> Path:
    text = json.dumps(bank.to_dict(), indent=2)
    return write_bytes_atomic(bank.root / MANIFEST, (text + "\n").encode("utf-8"))


def load_bank(bank_dir: str | os.PathLike, verify: bool = False) -> TextureBank:
    """Read and check ``bank_dir/manifest.json``; every image must exist.

    With ``verify`` the images are read and their pixel sha256 compared with
    the manifest (slower; catches edited or corrupted files).
    """
    root = Path(bank_dir)
    if not root.is_dir():
        raise MetaSimError(f"texture bank folder not found: {root}")
    manifest = root / MANIFEST
    if not manifest.is_file():
        raise MetaSimError(
            f"no {MANIFEST} in {root}: not a texture bank. Build one from a folder of photos "
            "(with flat/ and sloped/ subfolders) or use the default bank"
        )
    try:
        data = json.loads(manifest.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, ValueError) as exc:
        raise MetaSimError(f"cannot read texture manifest {manifest}: {exc}") from None
    bank = TextureBank.from_dict(data, root, where=str(manifest))
    for entry in bank.entries:
        path = root / entry.path
        if not path.is_file():
            raise MetaSimError(f"texture {entry.id!r} in {manifest} points at a missing file: {path}")
        if verify and pixel_sha256(read_rgb8(path)) != entry.sha256:
            raise MetaSimError(
                f"texture {entry.id!r} ({path}) does not match the sha256 in {manifest}; "
                "the file was changed: rebuild the bank"
            )
    return bank


def _write_bank(out_dir: Path, name: str, textures, repeat_source) -> TextureBank:
    """Write images and manifest. ``textures``: (id, name, kind, rgb) in
    order; ``repeat_source(id) -> (repeat_m, source)``."""
    entries = []
    for texture_id, texture_name, kind, rgb in textures:
        rel = f"{kind}/{texture_id}.png"
        write_png(out_dir / rel, rgb)
        repeat_m, source = repeat_source(texture_id)
        entries.append(TextureEntry(texture_id, texture_name, kind, rel, repeat_m, source, pixel_sha256(rgb)))
    bank = TextureBank(root=out_dir, name=name, entries=tuple(entries))
    save_manifest(bank)
    return bank


def _histograms(images) -> np.ndarray:
    return np.stack([hsv_cone_histogram(img) for img in images])


def drawn_heldout(kind: str, count: int, before: list[np.ndarray], bank_kind: np.ndarray,
                  seed: int = procedural.DRAWN_SEED, size: int = 256, limit: int = 1000) -> tuple[int, ...]:
    """The first ``count`` candidates of ``procedural.drawn_recipe(kind, i, seed)`` that meet the held-out
    conditions (tests/sim/textures_test.py), kept in turn: further from every texture known (the HSV-cone
    histograms ``before``, of every set before and of the candidates kept so far) than a typical bank texture
    of the kind is from its nearest bank neighbour, yet sharing some colour (similarity above 0.01) with at
    least 10 bank textures of the kind (``bank_kind``, their histograms). MetaSimError if ``limit``
    candidates do not give ``count``."""
    within = similarity_matrix(bank_kind, bank_kind)
    np.fill_diagonal(within, -1.0)
    typical = float(np.median(within.max(axis=1)))
    known, kept = np.concatenate(before), []
    for index in range(limit):
        hist = _histograms([procedural.generate(procedural.drawn_recipe(kind, index, seed), size)])
        if similarity_matrix(hist, known).max() < typical and (similarity_matrix(hist, bank_kind) > 0.01).sum() >= 10:
            kept.append(index)
            known = np.concatenate([known, hist])
            if len(kept) == count:
                return tuple(kept)
    raise MetaSimError(f"only {len(kept)} of {limit} drawn {kind} candidates meet the held-out conditions, not {count}")


MIN_SIZE, MAX_SIZE = 8, 4096


def check_size(size) -> int:
    """A texture side in pixels, or MetaSimError (a bank of 4096 x 4096 textures is already 84 x 48 MB)."""
    if isinstance(size, bool) or not isinstance(size, int) or not MIN_SIZE <= size <= MAX_SIZE:
        raise MetaSimError(f"--size must be a whole number of pixels from {MIN_SIZE} to {MAX_SIZE}, not {size!r}")
    return size


def build_default_bank(out_dir: str | os.PathLike, size: int = 256, heldout: bool | str = False,
                       progress: Progress | None = None) -> TextureBank:
    """Generate the default procedural bank, or a held-out set (``heldout``: True for the first, or a
    name of ``procedural.HELDOUT_SETS``), into ``out_dir``.

    Writes ``<kind>/<id>.png``, ``manifest.json`` and ``similarity.json``
    (bank against itself); a held-out set also gets
    ``similarity_to_default.json`` (held-out rows, default-bank columns).
    ``progress`` is told of each texture generated (``build_steps(heldout)`` in all, the default
    textures a held-out set is compared with among them); an exception it raises (a cancel) stops the build.
    """
    check_size(size)
    if isinstance(heldout, str):
        _heldout_name(heldout)
    out = Path(out_dir)
    recipes = procedural.recipes(heldout=heldout)
    images = list(_generated(recipes, size, progress))
    by_id = {r.id: r for r in recipes}
    bank = _write_bank(
        out,
        procedural.set_name(heldout),
        [(r.id, r.name, r.kind, img) for r, img in zip(recipes, images)],
        lambda texture_id: (by_id[texture_id].repeat_m, by_id[texture_id].source),
    )
    hists = _histograms(images)
    ids = tuple(r.id for r in recipes)
    save_similarity(Similarity(ids, ids, similarity_matrix(hists, hists)), out / SIMILARITY_FILE)
    if procedural.heldout_set(heldout) is not None:
        default = procedural.recipes()
        default_hists = _histograms(_generated(default, size, progress))
        save_similarity(
            Similarity(ids, tuple(r.id for r in default), similarity_matrix(hists, default_hists)),
            out / SIMILARITY_TO_DEFAULT_FILE,
        )
    return bank


def build_steps(heldout: bool | str = False) -> int:
    """The steps ``build_default_bank`` reports to its ``progress`` for the default bank or a held-out set."""
    steps = len(procedural.recipes(heldout=heldout))
    return steps + len(procedural.recipes()) if procedural.heldout_set(heldout) is not None else steps


def _generated(recipes, size: int, progress: Progress | None):
    """Each recipe's texture in turn, ``progress`` told of each."""
    for recipe in recipes:
        yield procedural.generate(recipe, size)
        if progress is not None:
            progress(1)


def _read_folder_options(src: Path, images: dict[str, Path]) -> dict[str, dict]:
    """Per-file options from an optional ``textures.json``:
    ``{"flat/red tiles.jpg": {"name": "...", "repeat_m": 6.0}, ...}``."""
    path = src / "textures.json"
    if not path.is_file():
        return {}
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, ValueError) as exc:
        raise MetaSimError(f"cannot read {path}: {exc}") from None
    if not isinstance(data, dict):
        raise MetaSimError(f"{path} must map image paths (like \"flat/red.jpg\") to options")
    for key, options in data.items():
        if key not in images:
            raise MetaSimError(
                f"{path} mentions {key!r}, which is not an image in flat/ or sloped/ "
                "(keys are paths relative to the folder, like \"flat/red.jpg\")"
            )
        if not isinstance(options, dict) or set(options) - {"name", "repeat_m"}:
            raise MetaSimError(f"{path}: options for {key!r} must be an object with only name and repeat_m")
        if "name" in options and (not isinstance(options["name"], str) or not options["name"]):
            raise MetaSimError(f"{path}: name for {key!r} must be a non-empty string")
        if "repeat_m" in options:
            _positive_metres(options["repeat_m"], f"{path}: repeat_m for {key!r}")
    return data


def build_bank_from_folder(
    src_dir: str | os.PathLike,
    out_dir: str | os.PathLike,
    repeat_m: float = 8.0,
    size: int | None = None,
    name: str | None = None,
) -> TextureBank:
    """Build a bank from a folder of photos with ``flat/`` and ``sloped/``
    subfolders (PNG, JPEG, TIFF 8/16 bit, ...; grey becomes RGB, alpha is
    dropped). Ids are ``<kind>-<slug of the file name>``; ``source`` is the
    original file. With ``size`` each image is centre-cropped to a square and
    resized to size x size; otherwise pixels are kept. ``repeat_m`` (the
    physical width of one image) and names can be set per file in an
    optional ``textures.json`` in ``src_dir``.
    """
    src = Path(src_dir).resolve()
    out = Path(out_dir).resolve()
    repeat_m = _positive_metres(repeat_m, "repeat_m")
    if size is not None:
        check_size(size)
    if not src.is_dir():
        raise MetaSimError(f"texture folder not found: {src}; it should hold flat/ and sloped/ subfolders of images")
    if out == src or src in out.parents:
        raise MetaSimError(f"write the bank outside the photo folder {src} (got {out})")
    images: dict[str, Path] = {}
    kinds: dict[str, str] = {}
    for kind in KINDS:
        folder = src / kind
        if folder.is_dir():
            for path in sorted(folder.iterdir()):
                if path.is_file() and not path.name.startswith(".") and path.suffix.lower() in IMAGE_SUFFIXES:
                    images[f"{kind}/{path.name}"] = path
                    kinds[f"{kind}/{path.name}"] = kind
    if not images:
        raise MetaSimError(
            f"no images in {src / 'flat'} or {src / 'sloped'}; put roof photos "
            f"({', '.join(IMAGE_SUFFIXES)}) in those subfolders"
        )
    options = _read_folder_options(src, images)
    textures = []
    meta: dict[str, tuple[float, str]] = {}
    origin: dict[str, Path] = {}
    for key, path in images.items():
        kind = kinds[key]
        slug = slugify(path.stem)
        if not slug:
            raise MetaSimError(f"cannot make a texture id from the file name {path}; rename it with letters or digits")
        texture_id = f"{kind}-{slug}"
        if texture_id in origin:
            raise MetaSimError(
                f"{origin[texture_id]} and {path} both give texture id {texture_id!r}; rename one of them"
            )
        origin[texture_id] = path
        rgb = read_rgb8(path) if size is None else read_rgb8_square(path, size)
        opts = options.get(key, {})
        textures.append((texture_id, opts.get("name", path.stem), kind, rgb))
        meta[texture_id] = (float(opts.get("repeat_m", repeat_m)), str(path))
    bank = _write_bank(out, name or src.name or "user-bank", textures, lambda i: meta[i])
    hists = _histograms(t[3] for t in textures)
    ids = tuple(t[0] for t in textures)
    save_similarity(Similarity(ids, ids, similarity_matrix(hists, hists)), out / SIMILARITY_FILE)
    return bank


def build_into(out: str | os.PathLike, build: Callable[[Path], TextureBank]) -> TextureBank:
    """The bank ``build`` writes into a folder, put at ``out`` as a whole (``core.fileio.atomic_dir``): a bank
    there before is replaced, and on any error ``out`` is left as it was. MetaSimError when ``out`` is a file,
    a folder holding files that are not a bank (they would be lost), or cannot be written."""
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise MetaSimError(f"{out} is a file; give --out a folder for the bank")
    if out.is_dir() and any(out.iterdir()) and not (out / MANIFEST).is_file():
        raise MetaSimError(f"{out} holds files that are not a texture bank; give --out a new or empty folder")
    try:
        with atomic_dir(out, replace=True) as tmp:
            build(tmp)
    except OSError as exc:
        raise MetaSimError(f"cannot write the bank {out}: {exc.strerror or exc}; choose another --out") from None
    return load_bank(out)


# --- cached default banks -------------------------------------------------


def default_bank_dir(size: int = 256, cache_dir: str | os.PathLike | None = None) -> Path:
    return cache_root(cache_dir) / "banks" / f"default-v{procedural.RECIPE_VERSION}-{size}"


def heldout_bank_dir(size: int = 256, cache_dir: str | os.PathLike | None = None,
                     name: str = procedural.FIRST_HELDOUT) -> Path:
    """The cache folder of the held-out set ``name`` (a name of ``procedural.HELDOUT_SETS``)."""
    return cache_root(cache_dir) / "banks" / f"{procedural.set_name(_heldout_name(name))}-{size}"


def _heldout_name(name: str) -> str:
    """``name`` if it is a held-out set, else MetaSimError listing them."""
    if name not in procedural.HELDOUT_SETS:
        raise MetaSimError(f"unknown held-out set {name!r}; choose one of {', '.join(procedural.HELDOUT_SETS)}")
    return name


def _ensure(final: Path, build: Callable[[Path], TextureBank]) -> TextureBank:
    """Load the bank at ``final``, building it first if absent. The build goes
    to a temporary sibling folder renamed into place, so readers never see a
    half-built bank and racing processes are safe: the first rename wins."""
    if (final / MANIFEST).is_file():
        return load_bank(final)
    if final.exists():
        raise MetaSimError(f"{final} exists but holds no {MANIFEST}; delete that folder and try again")
    with atomic_dir(final) as tmp:
        build(tmp)
    return load_bank(final)


def ensure_default_bank(size: int = 256, cache_dir: str | os.PathLike | None = None,
                        progress: Progress | None = None) -> TextureBank:
    """The cached default bank, built on first use (``progress`` as in `build_default_bank`)."""
    return _ensure(default_bank_dir(size, cache_dir), lambda d: build_default_bank(d, size, progress=progress))


def ensure_heldout_bank(size: int = 256, cache_dir: str | os.PathLike | None = None,
                        name: str = procedural.FIRST_HELDOUT, progress: Progress | None = None) -> TextureBank:
    """The cached held-out set ``name`` (textures not in the default bank), built on first use:
    ``heldout-v5`` (E2's validation textures; ``heldout-v4``, those of a day, are among them), ``heldout-v2``
    (E2's test textures), ``heldout-v3`` (its check textures) or ``heldout-v1`` (E2's earlier validation
    textures, and a single seed's); ``progress`` as in `build_default_bank`."""
    return _ensure(heldout_bank_dir(size, cache_dir, name),
                   lambda d: build_default_bank(d, size, heldout=name, progress=progress))


def ensure_heldout_banks(size: int = 256, cache_dir: str | os.PathLike | None = None,
                         ids: Iterable[str] | None = None, bars: Bars | None = None) -> list[TextureBank]:
    """The held-out sets, cached: what a render looks texture ids up in besides its bank. Every set, or with
    ``ids`` only the first set holding each held-out one among them (none for a render of bank textures
    alone), so a fresh cache builds only what is named. ``bars`` shows the build of each set missing."""
    names = list(procedural.HELDOUT_SETS)
    if ids is not None:
        holder = {recipe.id: name for name in reversed(names) for recipe in procedural.recipes(heldout=name)}
        wanted = {holder[i] for i in ids if i in holder}
        names = [name for name in names if name in wanted]
    return [ensure_heldout_bank(size, cache_dir, name,
                                bars(f"texture bank {name}", build_steps(name)) if bars else None) for name in names]


def heldout_ids(kind: str) -> list[str]:
    """The ids of every held-out texture of ``kind``, each once, in set order: what a design may name besides its
    bank's textures. Read from the recipes, so no bank is built."""
    return list(dict.fromkeys(recipe.id for name in procedural.HELDOUT_SETS
                              for recipe in procedural.recipes(kind, heldout=name)))

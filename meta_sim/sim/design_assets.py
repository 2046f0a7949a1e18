"""What the Blender asset library of a folder of design presets holds, worked out without Blender.

The add-on turns a folder of presets (the ``--out`` folder of `meta-sim infer`, or any folder of
preset files) into a Blender asset library in its subfolder ``meta-sim-assets/``: one asset per
preset, a catalog per target folder (``blender_assets.cats.txt``), and on each asset a preview, a
description and custom properties. This module decides all of that from the presets alone; the
add-on's ``assets`` module writes it with ``bpy``.

The JSON presets stay the source of truth. An asset records where its preset file lies,
relative to the presets folder, and applying an asset reads and validates that file again; the
library is rebuilt from the presets, never the other way round, and nothing in it is code.
"""

from __future__ import annotations

import hashlib
import json
import os
import uuid
from dataclasses import dataclass
from pathlib import Path, PurePosixPath
from typing import Mapping

import numpy as np

from ..core.errors import MetaSimError
from ..core.names import inside
from .design import DesignSpace, builtin_spaces
from .presets import DesignPreset, load_preset

LIBRARY_DIR = "meta-sim-assets"  # inside the presets folder
BLEND_FILE = "meta-sim-designs.blend"
CATALOG_FILE = "blender_assets.cats.txt"  # the name Blender reads catalogs from
PREVIEWS_DIR = "previews"  # rendered tiles, kept by what went into them, so a rebuild renders only new designs
PREVIEW_PX = 256  # Blender's preview size
ASSET_FORMAT = "meta-sim-design-asset"
ASSET_VERSION = 1
CATALOG_ROOT = "Meta-Sim"
TAG = "Meta-Sim"
FAR_TAG = "unlike-the-bank"  # a group searched as far from every design (nams ColourComparison.far)
INFER_REPORT = "report.json"  # `meta-sim infer` writes it beside population.json: a report, not a preset
PRESETS_SUBDIR = "presets"  # where `meta-sim infer` puts the groups' presets
POPULATION_TILES = 4  # a population's preview: its most common designs, 2 x 2
_NAMESPACE = uuid.UUID("5d1c9a62-3f0e-4d84-9a27-8f1d6c0b7e41")  # catalog ids: stable across rebuilds


@dataclass(frozen=True)
class Found:
    """A preset file that loaded and fits its design space."""

    path: Path
    rel: str  # relative to the presets folder, with '/'
    preset: DesignPreset
    space: DesignSpace


def preset_space(name: str, current: DesignSpace) -> DesignSpace:
    """The design space a preset names: ``current`` when it has that name (or the preset names none), else
    the shipped space of that name; MetaSimError for a space meta-sim does not ship."""
    if not name or name == current.name:
        return current
    if name in builtin_spaces():
        return DesignSpace.load(name)
    raise MetaSimError(f"design space {name!r} is not one meta-sim ships; choose its JSON file as the design "
                       "space (City > Design Space > File) and load the presets again")


def load_in_own_space(path: str | os.PathLike, current: DesignSpace) -> tuple[DesignPreset, DesignSpace]:
    """A preset file and the space it was inferred in (``preset_space``), its design and a population's
    designs checked against that space; MetaSimError (one line, naming the file) otherwise."""
    preset = load_preset(path)
    try:
        space = preset_space(preset.design_space, current)
        try:
            preset.design = space.validate(preset.design)
            preset.designs = [{**entry, "design": space.validate(entry["design"])} for entry in preset.designs]
        except MetaSimError as exc:
            raise MetaSimError(f"does not fit design space {space.name!r}: {exc}") from None
    except MetaSimError as exc:
        raise MetaSimError(f"{path}: preset {preset.name!r} {exc}") from None
    return preset, space


def preset_files(folder: str | os.PathLike) -> list[Path]:
    """The preset files of a folder: its ``*.json`` and those of its ``presets/`` subfolder (the layout of
    `meta-sim infer`'s output), sorted; infer's ``report.json`` is no preset and left out."""
    folder = Path(folder)
    if not folder.is_dir():
        raise MetaSimError(f"preset folder {folder} does not exist; choose the --out folder of `meta-sim infer`")
    files = sorted(p for p in folder.glob("*.json") if p.name != INFER_REPORT)
    files += sorted((folder / PRESETS_SUBDIR).glob("*.json"))
    if not files:
        raise MetaSimError(f"no presets (*.json) in {folder} or {folder / PRESETS_SUBDIR}")
    return files


def scan(folder: str | os.PathLike, current: DesignSpace) -> tuple[list[Found], list[tuple[Path, str]]]:
    """Every preset of ``folder`` that loads and fits its own space (``load_in_own_space``; ``current`` for one
    of the scene's space), and every file that does not, with why."""
    folder = Path(folder)
    good, bad = [], []
    for path in preset_files(folder):
        try:
            good.append(Found(path, path.relative_to(folder).as_posix(), *load_in_own_space(path, current)))
        except MetaSimError as exc:
            bad.append((path, str(exc).replace(f"{path}: ", "")))
    return good, bad


def asset_names(found: list[Found]) -> list[str]:
    """One unique name per preset (its name, else its file's; the file's path where two share a name)."""
    names = [f.preset.name or Path(f.rel).stem for f in found]
    return [f.rel.removesuffix(".json") if names.count(name) > 1 else name for f, name in zip(found, names)]


def target_folder(preset: DesignPreset) -> str:
    """The folder the preset's target images lie in (their common folder's name), or '' when unknown."""
    common = preset.common_folder()
    return "" if common is None else PurePosixPath(common.replace("\\", "/")).name


def catalog_path(preset: DesignPreset) -> str:
    """``Meta-Sim/<target folder>``: the catalog of the designs inferred from one folder of images."""
    folder = target_folder(preset)
    # ':' ends a field and '/' nests catalogs in Blender's catalog file
    return f"{CATALOG_ROOT}/{folder.replace(':', '_') if folder else 'Unknown target'}"


def catalog_id(path: str) -> str:
    return str(uuid.uuid5(_NAMESPACE, path))


def catalogs_text(paths) -> str:
    """The ``blender_assets.cats.txt`` of the catalogs ``paths`` (and the common root catalog)."""
    lines = ["# Asset catalogs of a Meta-Sim design library, written by the Meta-Sim add-on from the presets;",
             "# rebuilding the library rewrites this file.", "", "VERSION 1", ""]
    for path in sorted({CATALOG_ROOT, *paths}):
        lines.append(f"{catalog_id(path)}:{path}:{path.replace('/', '-')}")
    return "\n".join(lines) + "\n"


def _percent(share: float) -> str:
    return f"{share:.0%}"


def description(preset: DesignPreset, space: DesignSpace) -> str:
    """What the Asset Browser shows about a design: its choices with their vote shares, the search's loss,
    the target images and the model."""
    what = "Population of inferred designs" if preset.kind == "population" else "Inferred design"
    parts = [f"{what} ({space.name})."]
    choices = []
    for name in space.names:
        if name in preset.design:
            shares = preset.vote_shares.get(name)
            share = f" ({_percent(preset.confidence(name))} of votes)" if shares else ""
            choices.append(f"{name} {preset.design[name]}{share}")
    parts.append("; ".join(choices) + ".")
    loss = preset.search.get("loss")
    if isinstance(loss, (int, float)) and not isinstance(loss, bool):
        parts.append(f"Search loss {loss:.4g}.")
    if preset.search.get("far") is True:
        parts.append("Unlike every design the model knows: the roofs were chosen by their colours alone.")
    if preset.kind == "population" and preset.designs:
        parts.append(f"{len(preset.designs)} distinct designs over {sum(d['count'] for d in preset.designs)} groups.")
    parts.append(f"Target: {preset.target()}.")
    if preset.model_id:
        parts.append(f"Model {preset.model_id}.")
    return " ".join(parts)


def properties(found: Found) -> dict:
    """The asset's custom properties (strings and numbers): its preset file and what the preset says."""
    preset = found.preset
    props = {"meta_sim_format": ASSET_FORMAT, "meta_sim_version": ASSET_VERSION, "preset": found.rel,
             "kind": preset.kind, "design_space": preset.design_space, "design": json.dumps(preset.design),
             "vote_shares": json.dumps(preset.vote_shares), "source_images": len(preset.source_images),
             "target": preset.target(), "model_id": preset.model_id}
    loss = preset.search.get("loss")
    if isinstance(loss, (int, float)) and not isinstance(loss, bool):
        props["search_loss"] = float(loss)
    props["far_from_every_design"] = int(preset.search.get("far") is True)
    return props


def tags(preset: DesignPreset, space: DesignSpace) -> list[str]:
    """Tags to filter by: Meta-Sim, the kind, the design space, each texture chosen, and FAR_TAG for a group
    unlike every design the model knows (searched by its roof colours alone)."""
    textures = [str(preset.design[p.name]) for p in (space.texture_parameter(k) for k in ("flat", "sloped"))
                if p is not None and p.name in preset.design]
    far = [FAR_TAG] if preset.search.get("far") is True else []
    return list(dict.fromkeys([TAG, preset.kind, preset.design_space, *textures, *far]))


def is_design_asset(metadata) -> bool:
    """Whether an asset's metadata (``AssetMetaData`` or a mapping) is a Meta-Sim design's."""
    try:
        return metadata.get("meta_sim_format") == ASSET_FORMAT
    except (AttributeError, TypeError):
        return False


def preset_of_asset(library_file: str | os.PathLike, metadata: Mapping) -> Path:
    """The preset file behind an asset of the library file ``library_file``: its recorded path, which must
    stay inside the presets folder (the library's parent); MetaSimError otherwise or when it is gone."""
    if not is_design_asset(metadata):
        raise MetaSimError("this asset is not a Meta-Sim design; choose one from a Meta-Sim design library")
    version = metadata.get("meta_sim_version")
    if not isinstance(version, int) or version > ASSET_VERSION:
        raise MetaSimError(f"this design asset has version {version!r}, newer than this add-on reads; update it")
    rel = metadata.get("preset")
    if not library_file or not isinstance(rel, str) or not rel.endswith(".json") or os.path.isabs(rel):
        raise MetaSimError("this design asset does not name its preset file; rebuild the asset library from "
                           "the presets (Design Presets > Build Asset Library)")
    presets_folder = Path(library_file).parent.parent
    path = inside(presets_folder, rel, "preset file of the asset")
    if not path.is_file():
        raise MetaSimError(f"the preset file {path} behind this asset is gone; rebuild the asset library")
    return path


def preview_key(design: Mapping, space: DesignSpace, params: Mapping, quality: str, bank: str) -> str:
    """The name of a design's cached preview: what the rendered tile depends on."""
    text = json.dumps({"design": design, "space": space.to_dict(), "city": params, "quality": quality,
                       "bank": bank, "px": PREVIEW_PX}, sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()[:20]


def population_designs(preset: DesignPreset) -> list[dict]:
    """The designs a population's preview shows: its most common ones (its own design when it lists none)."""
    designs = [entry["design"] for entry in sorted(preset.designs, key=lambda e: -e["count"])]
    return designs[:POPULATION_TILES] or [preset.design]


def mosaic(tiles: list[np.ndarray]) -> np.ndarray:
    """One tile as it is; several as a 2 x 2 grid of half-size tiles (the first repeated to fill it)."""
    if len(tiles) == 1:
        return tiles[0]
    tiles = (tiles + tiles[:1] * POPULATION_TILES)[:POPULATION_TILES]
    h, w = tiles[0].shape[:2]
    half = [t[: h // 2 * 2, : w // 2 * 2].reshape(h // 2, 2, w // 2, 2, -1).mean(axis=(1, 3)) for t in tiles]
    return np.concatenate([np.concatenate(half[:2], axis=1), np.concatenate(half[2:], axis=1)], axis=0)

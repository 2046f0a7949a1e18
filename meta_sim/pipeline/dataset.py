"""Training sets: random designs rendered through the simulator, and their cached features.

A training set lives in one folder: ``tiles/`` (the EXR tiles and their
``designs.json``, resumable like any render) and one feature cache per
extractor and view count, ``features-<key>.pt``, holding the design names,
the design-space spec, the extractor id, the view count and one averaged
feature vector per design. ``tile-features-<key>.pt`` beside it holds, in
the same format, one feature vector per tile (the pool MS2 samples from);
the design's vector is the mean of its tiles'.
Rendering needs ``bpy``; everything after the caches (training, search)
needs only torch.
"""

from __future__ import annotations

import hashlib
import json
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Callable, NamedTuple

import torch

from ..core.errors import MetaSimError
from ..core.fileio import atomic_path
from ..sim.design import DesignSpace

CACHE_VERSION = 1
# The tile-feature cache is saved at least this often while it grows, so a killed run resumes there.
SAVE_SECONDS = 60.0


@dataclass(frozen=True)
class DatasetConfig:
    """What a training set is made of: how many random designs (drawn with ``seed``) and tiles per
    design, rendered in how many cities, with which render quality preset, design space, tile size
    and metres per pixel. The default fits a 2-core machine in a few minutes; ``paper()`` is the
    paper's scale (1,700 designs x 9 tiles).

    600 designs x 2 tiles rather than 300 x 4: the same rendering, and more
    designs is what NAMS needs to infer designs it was not trained on (rows
    "training set" of `make bench-tradeoff` in docs/benchmarks.md, on E1's
    validation split).
    """

    designs: int = 600
    tiles: int = 2
    seed: int = 1
    cities: int = 8
    preset: str = "fast"
    space: str = "rooftops-v1"
    tile_px: int = 384
    pixel_size_m: float = 0.3

    @classmethod
    def paper(cls, **overrides) -> "DatasetConfig":
        """The paper's scale, 1,700 designs x 9 tiles, with any other field overridden."""
        return cls(**{"designs": 1700, "tiles": 9, **overrides})

    def check(self) -> "DatasetConfig":
        """This config, or MetaSimError for a field no render would accept (checked before any work)."""
        from ..render.plan import LIMITS, MAX_DESIGNS
        from ..sim.design import DesignSpace
        from ..sim.quality import get_preset

        for name, low, high in (("designs", 1, MAX_DESIGNS), *LIMITS):  # the render's own bounds
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or not low <= value <= high:
                option = {"seed": "dataset-seed", "tile_px": "tile-px"}.get(name, name)
                raise MetaSimError(f"--{option} must be a whole number from {low} to {high}, not {value!r}")
        if not (isinstance(self.pixel_size_m, (int, float)) and 0.01 <= self.pixel_size_m <= 10.0):
            raise MetaSimError(f"--gsd must be between 0.01 and 10 metres per pixel, not {self.pixel_size_m!r}")
        get_preset(self.preset)
        DesignSpace.load(self.space)
        return self

    def identity(self) -> dict:
        """Every input of the training set: the fields, what of the render preset's settings sets its
        tiles apart (``RenderPreset.cache_fields``) and, for a space of the richer scene, the scene's
        version (``DesignSpace.scene_version``)."""
        from ..sim.design import DesignSpace
        from ..sim.quality import get_preset

        identity = {**asdict(self), **get_preset(self.preset).cache_fields()}
        space = DesignSpace.load(self.space)
        if Path(self.space).suffix:  # a space from a file: what it declares, not where it lies
            identity["space"] = space.to_dict()
        return {**identity, **space.scene_version()}

    def key(self) -> str:
        """A short hash of ``identity()``: the training set's folder name in the cache."""
        return hashlib.sha256(json.dumps(self.identity(), sort_keys=True).encode()).hexdigest()[:12]


@dataclass
class FeatureSet:
    """A training set's features, one row per design (the mean over its tiles and views), with the
    designs' names, the designs as dicts and encoded, the design space, and the extractor id and
    view count that made them (``build_features``)."""

    names: list[str]
    designs: list[dict]
    encoded: torch.Tensor  # (N, design_dim) float32
    features: torch.Tensor  # (N, feature_dim) float32
    space: DesignSpace
    extractor_id: str
    views: int
    # With roof colour (pipeline.roofcolour.RoofColourExtractor): the widths of the features' trailing
    # histograms, and the roof finder and power they were weighted by (its to_dict()), for the checkpoint.
    hist_blocks: tuple[int, ...] = ()
    roof_likelihood: dict | None = None


class TileFeatures(NamedTuple):
    """Per-tile features of a training set, every tile one simulation of its design: the designs,
    encoded (N, design_dim) and the features (N, tiles, feature_dim) (``build_tile_features``)."""

    designs: list[dict]
    encoded: torch.Tensor  # (N, design_dim) float32
    features: torch.Tensor  # (N, tiles, feature_dim) float32


def render_training_set(root: Path, config: DatasetConfig, progress: Callable[[int], None] | None = None):
    """Render (or finish rendering) the training set's tiles into ``root/tiles`` with the default
    texture bank; returns the render jobs (one per design) and the ``RenderSummary`` (tiles written,
    tiles already there).

    Tiles already rendered with the same settings are kept, so a rerun resumes. ``progress(n)`` is
    called as tiles are done. Needs ``bpy``; raises MetaSimError for an unknown design space or
    render preset, a missing ``bpy`` or an unwritable folder.
    """
    from ..render.jobs import RenderSettings, design_jobs, sample_designs
    from ..render.loop import render_jobs
    from ..sim.quality import get_preset
    from ..sim.textures import ensure_default_bank

    space = DesignSpace.load(config.space)
    jobs = design_jobs(space, sample_designs(space, config.designs, config.seed), config.seed, config.cities)
    settings = RenderSettings(space=space, banks=[ensure_default_bank()], preset=get_preset(config.preset),
                              out_dir=Path(root) / "tiles", n_tiles=config.tiles, tile_px=config.tile_px,
                              pixel_size_m=config.pixel_size_m)
    return jobs, render_jobs(jobs, settings, progress)


def job_tiles(tile_dir: Path, name: str, n_tiles: int) -> list[Path]:
    """The paths of the first ``n_tiles`` tiles of the design named ``name`` in ``tile_dir``
    (whether or not they exist)."""
    return [Path(tile_dir) / f"{name}_t{j:02d}.exr" for j in range(n_tiles)]


def training_tiles(root: Path, config: DatasetConfig) -> list[Path]:
    """Every tile of a rendered training set, in design order; MetaSimError naming the first tile
    that is missing (render the set with ``render_training_set`` / `meta-sim dataset` first)."""
    _, _, names = _training_designs(config)
    return [p for name in names for p in _existing_tiles(Path(root), name, config.tiles)]


def build_features(root: Path, config: DatasetConfig, extractor, views: int = 8,
                   progress: Callable[[int], None] | None = None) -> FeatureSet:
    """Features of every design of the training set, computing only what the cache lacks.

    A design's feature is the mean of its tiles' features (every tile x view
    weighs the same in it), so the tiles' features are computed once, cached
    (``build_tile_features``, the pool MS2 samples from) and averaged here.
    ``extractor`` is a feature extractor (``features.Extractor`` or
    ``roofcolour.RoofColourExtractor``), ``views`` how many rotations and flips
    of each tile it averages, ``progress(1)`` is called after each design
    computed. Both caches live in ``root``. Raises MetaSimError when a tile is
    missing or unreadable.
    """
    root = Path(root)
    space, designs, names = _training_designs(config)
    cache_path = _cache_path(root, "features", extractor, views)
    cached = _load_cache(cache_path, extractor.id, views)
    if any(name not in cached for name in names):
        tiles = _tile_features(root, config, space, names, extractor, views, progress)
        cached.update({name: tiles[name].mean(dim=0) for name in names if name not in cached})
        _save_cache(cache_path, cached, extractor.id, views, space)
    return FeatureSet(names=names, designs=designs, encoded=_encode(space, designs),
                      features=torch.stack([cached[name] for name in names]).float(), space=space,
                      extractor_id=extractor.id, views=views,
                      hist_blocks=tuple(getattr(extractor, "hist_blocks", ())),
                      roof_likelihood=extractor.to_dict() if hasattr(extractor, "finder") else None)


def build_tile_features(root: Path, config: DatasetConfig, extractor, views: int = 8,
                        progress: Callable[[int], None] | None = None) -> TileFeatures:
    """Features of every tile of the training set, each tile alone (averaged over its ``views``).

    Cached per design beside ``build_features``'s cache, computing only what
    the cache lacks; ``progress(1)`` after each design computed. Raises
    MetaSimError when a tile is missing or unreadable.
    """
    space, designs, names = _training_designs(config)
    cached = _tile_features(Path(root), config, space, names, extractor, views, progress)
    return TileFeatures(designs=designs, encoded=_encode(space, designs),
                        features=torch.stack([cached[name] for name in names]).float())


def _tile_features(root: Path, config: DatasetConfig, space: DesignSpace, names: list[str], extractor, views: int,
                   progress: Callable[[int], None] | None) -> dict[str, torch.Tensor]:
    """Design name -> (tiles, F) features of its tiles (``names``: the training set's designs, in
    ``space``), from the cache or computed (and cached)."""
    from ..sim.imageio import read_image
    from .features import features_for_groups

    cache_path = _cache_path(root, "tile-features", extractor, views)
    cached = {name: tiles for name, tiles in _load_cache(cache_path, extractor.id, views).items()
              if len(tiles) == config.tiles}
    missing = [name for name in names if name not in cached]
    saved = time.monotonic()
    for count, name in enumerate(missing, 1):
        paths = _existing_tiles(root, name, config.tiles)
        cached[name] = features_for_groups([[read_image(p)] for p in paths], extractor, views)
        if count == len(missing) or time.monotonic() - saved >= SAVE_SECONDS:
            _save_cache(cache_path, cached, extractor.id, views, space)
            saved = time.monotonic()
        if progress:
            progress(1)
    return cached


def _training_designs(config: DatasetConfig) -> tuple[DesignSpace, list[dict], list[str]]:
    """The space, the designs and their names (``d00000``, ...) of a training set."""
    from ..render.jobs import sample_designs

    space = DesignSpace.load(config.space)
    designs = sample_designs(space, config.designs, config.seed)
    return space, designs, [f"d{k:05d}" for k in range(len(designs))]


def _encode(space: DesignSpace, designs: list[dict]) -> torch.Tensor:
    return torch.stack([torch.from_numpy(space.encode(d)) for d in designs])


def _existing_tiles(root: Path, name: str, n_tiles: int) -> list[Path]:
    paths = job_tiles(root / "tiles", name, n_tiles)
    missing = [p for p in paths if not p.is_file()]
    if missing:
        raise MetaSimError(f"training tile {missing[0]} is missing; run `meta-sim dataset` to render it")
    return paths


def _cache_path(root: Path, kind: str, extractor, views: int) -> Path:
    key = hashlib.sha256(f"{extractor.id}|{views}".encode()).hexdigest()[:10]
    return root / f"{kind}-{key}.pt"


def _load_cache(path: Path, extractor_id: str, views: int) -> dict:
    if not path.is_file():
        return {}
    try:
        data = torch.load(path, weights_only=True)
    except Exception:  # a damaged cache is recomputed, never trusted
        return {}
    if data.get("version") != CACHE_VERSION or data.get("extractor_id") != extractor_id or data.get("views") != views:
        return {}
    return dict(zip(data["names"], data["features"]))


def _save_cache(path: Path, cached: dict, extractor_id: str, views: int, space: DesignSpace) -> None:
    names = sorted(cached)
    data = {"version": CACHE_VERSION, "extractor_id": extractor_id, "views": views,
            "space": json.dumps(space.to_dict()), "names": names,
            "features": torch.stack([cached[n] for n in names]) if names else torch.zeros(0)}
    with atomic_path(path) as tmp:
        torch.save(data, tmp)

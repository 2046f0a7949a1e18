"""Labelled tiles for a trainer (a building segmenter): PyTorch datasets over rendered tiles and over
real image/mask folders, with the same keys, so one training loop takes either or both.

Each item is a dict: ``image`` float32 (3, H, W) in display sRGB (or linear light for rendered tiles),
``mask`` uint8 (H, W), 1 on buildings; ``roof_class`` int64 (H, W), 0 background (or a wall), 1 flat, 2 sloped;
``instance`` int64 (H, W), the building id (0: none); ``meta``: the tile's path, pixel size, its own pixel
size before resampling and what stated it (``pixelsize.SOURCES``) and, for rendered tiles, design (JSON), city
seed and tile index. Real masks tell buildings only: their
``roof_class`` and ``instance`` are 0 and ``meta["labels"]`` says "mask". Items are read when asked for,
so the datasets work with DataLoader worker processes started by spawning (``loader`` does that):
forked workers, Linux's default, hang at exit once OpenImageIO has run in the parent.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import torch
from torch.utils.data import DataLoader, Dataset

from ..core.errors import MetaSimError
from ..sim.imageio import RENDER_PIXEL_SIZE_M, linear_to_srgb, read_image, read_rgb8, resample
from ..sim.pixelsize import ImageFolder, PixelSize, resolve_pixel_size
from ..sim.tiles import read_tile

COLOURS = ("srgb", "linear")


class TileDataset(Dataset):
    """The rendered tiles (``*.exr``) of ``folder``, in name order; ``colour`` "srgb" (as previews show
    them, and as real imagery is stored) or "linear" (as rendered); brought to ``working_pixel_size_m``
    when given (images area-averaged, the building mask by majority, ids by nearest pixel)."""

    def __init__(self, folder: str | Path, colour: str = "srgb", working_pixel_size_m: float | None = None):
        if colour not in COLOURS:
            raise MetaSimError(f"colour must be one of {', '.join(COLOURS)}, not {colour!r}")
        folder = Path(folder)
        if not folder.is_dir():
            raise MetaSimError(f"{folder} is not a folder of rendered tiles")
        self.paths = sorted(p for p in folder.glob("*.exr") if not p.name.startswith("."))
        if not self.paths:
            raise MetaSimError(f"no rendered tiles (*.exr) in {folder}; render some with `meta-sim render`")
        self.colour, self.working = colour, _pixel_size(working_pixel_size_m)

    @classmethod
    def from_paths(cls, paths, colour: str = "srgb", working_pixel_size_m: float | None = None) -> TileDataset:
        """Over the given tile files, in the order given (for example some tiles of each target city)."""
        if colour not in COLOURS:
            raise MetaSimError(f"colour must be one of {', '.join(COLOURS)}, not {colour!r}")
        data = cls.__new__(cls)
        data.paths = [Path(p) for p in paths]
        if not data.paths:
            raise MetaSimError("no rendered tiles given")
        data.colour, data.working = colour, _pixel_size(working_pixel_size_m)
        return data

    def __len__(self) -> int:
        return len(self.paths)

    def __getitem__(self, index: int) -> dict:
        path = self.paths[index]
        tile = read_tile(path)
        rgb = linear_to_srgb(tile.rgb) if self.colour == "srgb" else np.clip(np.nan_to_num(tile.rgb), 0.0, None)
        size = float(tile.meta.get("pixel_size_m", RENDER_PIXEL_SIZE_M))
        own = PixelSize(size, "metadata" if "pixel_size_m" in tile.meta else "assumed")
        building, roof_class, instance = tile.building > 0, tile.roof_class, tile.instance
        if self.working and self.working != size:
            rgb = resample(rgb, size, self.working)
            building = resample(building[:, :, None].astype(np.float32), size, self.working)[:, :, 0] > 0.5
            roof_class, instance = (_nearest(x, building.shape) for x in (roof_class, instance))
            size = self.working
        meta = {"path": str(path), "pixel_size_m": size,
                "design": json.dumps(tile.meta.get("design", {}), sort_keys=True),
                "city_seed": int(tile.meta.get("city_seed", -1)), "tile_index": int(tile.meta.get("tile_index", -1)),
                "labels": "render", **_origin(own)}
        return _item(rgb, building, roof_class, instance, meta)


class RealDataset(Dataset):
    """Real images with building masks: ``images/NAME`` beside ``masks/NAME`` (any image file; a mask
    pixel above half its range is a building), brought from their pixel size to ``working_pixel_size_m``.

    Each image's size is resolved once, here, by ``pixelsize.resolve_pixel_size``: from ``folder`` (an
    ``ImageFolder`` saying how the command states sizes) when given, else from ``pixel_size_m`` (the
    images' stated size), the files' metadata, their world files or a ``pixel_size.txt`` in the folder
    holding ``images/`` and ``masks/``. MetaSimError when a size is unknown or two stated sizes disagree.
    """

    def __init__(self, images: str | Path, masks: str | Path, pixel_size_m: float | None = None,
                 working_pixel_size_m: float = RENDER_PIXEL_SIZE_M, folder: ImageFolder | None = None):
        images, masks = Path(images), Path(masks)
        for path in (images, masks):
            if not path.is_dir():
                raise MetaSimError(f"{path} is not a folder")
        folder = folder or ImageFolder(images.parent, pixel_size_m)
        by_name = {p.name: p for p in masks.iterdir() if p.is_file() and not p.name.startswith(".")}
        self.pairs = [(p, by_name[p.name], resolve_pixel_size(p, folder)) for p in sorted(images.iterdir())
                      if p.is_file() and not p.name.startswith(".") and p.name in by_name]
        if not self.pairs:
            raise MetaSimError(f"no image in {images} has a mask of the same name in {masks}")
        self.working = _pixel_size(working_pixel_size_m)

    @classmethod
    def from_pairs(cls, pairs, working_pixel_size_m: float = RENDER_PIXEL_SIZE_M) -> RealDataset:
        """Over explicit ``(image, mask, pixel size or None)`` triples, for images whose masks are not
        named alike or whose pixel sizes differ; a size None is resolved as in a folder of its own."""
        data = cls.__new__(cls)
        data.pairs = [(Path(i), Path(m), resolve_pixel_size(i, ImageFolder(Path(i).parent, s)))
                      for i, m, s in pairs]
        if not data.pairs:
            raise MetaSimError("no image/mask pairs given")
        data.working = _pixel_size(working_pixel_size_m)
        return data

    def __len__(self) -> int:
        return len(self.pairs)

    def __getitem__(self, index: int) -> dict:
        image_path, mask_path, own = self.pairs[index]
        rgb = resample(read_image(image_path), own.metres, self.working)
        building = resample(read_rgb8(mask_path)[:, :, :1].astype(np.float32) / 255.0, own.metres,
                            self.working)[:, :, 0]
        if building.shape != rgb.shape[:2]:
            raise MetaSimError(f"{mask_path}: the mask is not the size of {image_path}")
        zeros = np.zeros(building.shape, np.int64)
        meta = {"path": str(image_path), "pixel_size_m": self.working, "design": "", "city_seed": -1,
                "tile_index": -1, "labels": "mask", **_origin(own)}
        return _item(rgb, building > 0.5, zeros, zeros, meta)


def _origin(own: PixelSize) -> dict:
    """An item's own pixel size and what stated it (``pixelsize.SOURCES``), before it was brought to the
    working size."""
    return {"own_pixel_size_m": own.metres, "own_pixel_size_source": own.source}


def _nearest(labels: np.ndarray, shape: tuple) -> np.ndarray:
    """Labels (ids: never averaged) at the pixel nearest each output pixel's centre."""
    rows = np.minimum(((np.arange(shape[0]) + 0.5) * labels.shape[0] / shape[0]).astype(int), labels.shape[0] - 1)
    cols = np.minimum(((np.arange(shape[1]) + 0.5) * labels.shape[1] / shape[1]).astype(int), labels.shape[1] - 1)
    return labels[np.ix_(rows, cols)]


def _pixel_size(size):
    if size is not None and (isinstance(size, bool) or not isinstance(size, (int, float))
                             or not 0.01 <= size <= 100):
        raise MetaSimError(f"pixel sizes must be between 0.01 and 100 metres, not {size!r}")
    return None if size is None else float(size)


def _item(rgb: np.ndarray, building: np.ndarray, roof_class: np.ndarray, instance: np.ndarray, meta: dict) -> dict:
    return {"image": torch.from_numpy(np.ascontiguousarray(rgb.transpose(2, 0, 1), dtype=np.float32)),
            "mask": torch.from_numpy(building.astype(np.uint8)),
            "roof_class": torch.from_numpy(np.asarray(roof_class, dtype=np.int64)),
            "instance": torch.from_numpy(np.asarray(instance, dtype=np.int64)), "meta": meta}


def loader(dataset: Dataset, **options) -> DataLoader:
    """A DataLoader over ``dataset`` whose worker processes (``num_workers``) are spawned, not forked."""
    if options.get("num_workers", 0) > 0:
        options.setdefault("multiprocessing_context", "spawn")
    return DataLoader(dataset, **options)

"""Training images for the segmenter, held in memory at the working pixel size, and the crops a
training step draws from them.

A ``Pool`` is one source of labelled images (a real domain, or a folder of rendered tiles), read
once through the datasets of ``pipeline.trainsets``. ``Pool.crops`` draws random crops: an image with
probability proportional to its area (so every ground pixel is equally likely), a position in it,
then (with ``augment``) one of the 8 rotations and flips of the square and a colour augmentation
(``COLOUR_AUGMENTS``): "light", a small per-channel gain and offset (a sensor's colour balance and exposure);
"ground", that, then for most crops the ground (non-building) pixels recoloured on their own, so that a segmenter
learns buildings by shape more than by the renders' ground colours; "camera", "light" then most crops seen as
another camera might (``pipeline.roofsegment.camera_jitter``: exposure, contrast, gamma, blur, noise), roofs and
ground keeping their colours against each other; "scene", both: the ground recoloured, then the other camera.
Images smaller than a crop are padded, and the
padding is marked invalid so the loss ignores it. Every draw comes from the ``torch.Generator``
passed in, so a seed fixes the crops.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass

import numpy as np
import torch

from ..core.errors import MetaSimError
from ..core.progress import Bars

GAIN = 0.1  # per-channel gain within 1 +- GAIN
OFFSET = 0.04  # brightness offset within +- OFFSET
# The augmentations beyond "light", by what they change (``pipeline.roofsegment.jitter_scene``): the ground's
# colour apart from the buildings', and the camera.
SCENE_PARTS = {"ground": (True, False), "camera": (False, True), "scene": (True, True)}
COLOUR_AUGMENTS = ("light", *SCENE_PARTS)


@dataclass
class Batch:
    image: torch.Tensor  # (N, 3, C, C) display sRGB in [0, 1]
    mask: torch.Tensor  # (N, 1, C, C) 1 on buildings
    valid: torch.Tensor  # (N, 1, C, C) 0 on padding


class Pool:
    """Labelled images (``image`` float32 (H, W, 3), ``mask`` bool (H, W)), all at one pixel size;
    ``own_sizes``, when known, each image's ``pixelsize.PixelSize`` before it was brought to it."""

    def __init__(self, name: str, images: list[np.ndarray], masks: list[np.ndarray], pixel_size_m: float,
                 sources: list[str], own_sizes: list | None = None):
        if not images:
            raise MetaSimError(f"{name}: no labelled images")
        self.name, self.images, self.masks, self.pixel_size_m = name, images, masks, float(pixel_size_m)
        self.sources, self.own_sizes = sources, own_sizes
        areas = np.array([m.size for m in masks], dtype=np.float64)
        self.weights = torch.from_numpy(areas / areas.sum())

    @classmethod
    def from_dataset(cls, name: str, dataset, bars: Bars | None = None) -> Pool:
        """Every item of a ``TileDataset`` or ``RealDataset`` (made with a working pixel size)."""
        from ..sim.pixelsize import PixelSize

        images, masks, sources, sizes, own = [], [], [], set(), []
        progress = bars(f"read {name}", len(dataset)) if bars else None
        for k in range(len(dataset)):
            item = dataset[k]
            images.append(np.ascontiguousarray(item["image"].numpy().transpose(1, 2, 0)))
            masks.append(item["mask"].numpy() > 0)
            sources.append(item["meta"]["path"])
            sizes.add(round(item["meta"]["pixel_size_m"], 6))
            own.append(PixelSize(item["meta"]["own_pixel_size_m"], item["meta"]["own_pixel_size_source"]))
            if progress:
                progress(1)
        if len(sizes) != 1:
            raise MetaSimError(f"{name}: images at several pixel sizes ({sorted(sizes)}); give a working size")
        return cls(name, images, masks, sizes.pop(), sources, own)

    def __len__(self) -> int:
        return len(self.images)

    def fingerprint(self) -> str:
        """Names the pool's content (pixels and labels), for caches of models trained on it."""
        digest = hashlib.sha256(f"{self.pixel_size_m}".encode())
        for image, mask in zip(self.images, self.masks):
            digest.update(np.ascontiguousarray(image).tobytes())
            digest.update(np.packbits(mask).tobytes())
        return digest.hexdigest()[:16]

    def building_share(self) -> float:
        return float(sum(m.sum() for m in self.masks) / sum(m.size for m in self.masks))

    def crops(self, n: int, size: int, generator: torch.Generator, augment: bool = True,
              colour: str | None = "light") -> Batch:
        """``n`` random crops of ``size`` pixels (see the module's docstring); ``colour`` one of
        ``COLOUR_AUGMENTS``, or None to keep the augmentation to rotations and flips."""
        if colour is not None and colour not in COLOUR_AUGMENTS:
            raise MetaSimError(f"unknown colour augmentation {colour!r}; choose one of {', '.join(COLOUR_AUGMENTS)}")
        picks = torch.multinomial(self.weights, n, replacement=True, generator=generator).tolist()
        images = torch.zeros(n, 3, size, size)
        masks = torch.zeros(n, 1, size, size)
        valid = torch.zeros(n, 1, size, size)
        for row, k in enumerate(picks):
            image, mask = self.images[k], self.masks[k]
            h, w = mask.shape
            y = int(torch.randint(max(1, h - size + 1), (1,), generator=generator))
            x = int(torch.randint(max(1, w - size + 1), (1,), generator=generator))
            ch, cw = min(size, h), min(size, w)
            images[row, :, :ch, :cw] = torch.from_numpy(image[y:y + ch, x:x + cw].transpose(2, 0, 1))
            masks[row, 0, :ch, :cw] = torch.from_numpy(mask[y:y + ch, x:x + cw].astype(np.float32))
            valid[row, 0, :ch, :cw] = 1.0
        if augment:
            images, masks, valid = _dihedral(images, masks, valid, generator)
        if augment and colour:
            gain = 1.0 + GAIN * (2 * torch.rand(n, 3, 1, 1, generator=generator) - 1)
            offset = OFFSET * (2 * torch.rand(n, 1, 1, 1, generator=generator) - 1)
            images = (images * gain + offset).clamp(0.0, 1.0) * valid
        if augment and colour in SCENE_PARTS:
            from ..pipeline.roofsegment import jitter_scene

            ground, camera = SCENE_PARTS[colour]
            images = jitter_scene(images, masks if ground else None, generator, camera=camera) * valid
        return Batch(images, masks, valid)


def _dihedral(images, masks, valid, generator):
    views = torch.randint(8, (images.shape[0],), generator=generator).tolist()
    out = []
    for tensor in (images, masks, valid):
        turned = [torch.rot90(t, v % 4, dims=(-2, -1)) for t, v in zip(tensor, views)]
        out.append(torch.stack([torch.flip(t, dims=(-1,)) if v >= 4 else t for t, v in zip(turned, views)]))
    return out


def join(batches: list[Batch]) -> Batch:
    return Batch(*(torch.cat([getattr(b, f) for b in batches]) for f in ("image", "mask", "valid")))


def real_pool(folder, working_pixel_size_m: float, bars: Bars | None = None) -> Pool:
    """The labelled real images of ``folder`` (``images/NAME`` beside ``masks/NAME``), at the working
    pixel size; ``folder`` a path or a ``pixelsize.ImageFolder`` that says how their own sizes are
    stated (``RealDataset`` resolves them)."""
    return real_pools([folder], working_pixel_size_m, bars)[0]


def real_pools(folders: list, working_pixel_size_m: float, bars: Bars | None = None) -> list[Pool]:
    """``real_pool`` of each of ``folders``; every image's pixel size is resolved before any image is
    read, so a size missing in the last folder stops a command before it reads the first."""
    from ..pipeline.trainsets import RealDataset
    from ..sim.pixelsize import ImageFolder

    datasets = []
    for folder in map(ImageFolder.of, folders):
        if not (folder.path / "images").is_dir() or not (folder.path / "masks").is_dir():
            raise MetaSimError(f"{folder.path} must hold images/ and masks/ folders (a mask per image, same name)")
        datasets.append((folder.path.name, RealDataset(folder.path / "images", folder.path / "masks",
                                                        working_pixel_size_m=working_pixel_size_m, folder=folder)))
    return [Pool.from_dataset(name, dataset, bars) for name, dataset in datasets]


def tile_pool(folder, working_pixel_size_m: float, bars: Bars | None = None) -> Pool:
    """The rendered tiles (``*.exr``) of ``folder``, in display sRGB at the working pixel size."""
    from pathlib import Path

    from ..pipeline.trainsets import TileDataset

    return Pool.from_dataset(Path(folder).name, TileDataset(folder, "srgb", working_pixel_size_m), bars)


def labelled_pool(folder, working_pixel_size_m: float, bars: Bars | None = None) -> Pool:
    """A folder of rendered tiles, or of real images and masks: whichever it holds (``folder`` as for
    ``real_pool``). Rendered tiles carry their own pixel size: one stated for their folder is an error."""
    from ..sim.pixelsize import ImageFolder

    folder = ImageFolder.of(folder)
    if not folder.path.is_dir():
        raise MetaSimError(f"{folder.path} is not a folder")
    if any(p.suffix == ".exr" and not p.name.startswith(".") for p in folder.path.iterdir()):
        if folder.stated_m is not None:
            raise MetaSimError(f"{folder.path} holds rendered tiles, whose files carry their pixel size; drop the "
                               f":{folder.stated_m:g}")
        return tile_pool(folder.path, working_pixel_size_m, bars)
    return real_pool(folder, working_pixel_size_m, bars)


def merge(pools: list[Pool]) -> Pool | None:
    """One pool of several (None for none); all at one pixel size."""
    if not pools:
        return None
    if len({p.pixel_size_m for p in pools}) > 1:
        raise MetaSimError("pools at different pixel sizes cannot be merged")
    if len(pools) == 1:
        return pools[0]
    return Pool("+".join(p.name for p in pools), [i for p in pools for i in p.images],
                [m for p in pools for m in p.masks], pools[0].pixel_size_m, [s for p in pools for s in p.sources])

"""The shared real domains (``../shared/realdata``) as labelled scenes, split for the task experiments.

* ``rio``: 15 SpaceNet-1 WorldView-2 chips of Rio de Janeiro at 0.5 m. Satellite imagery from the
  same programme as DeepGlobe's building data, so it plays the paper's DeepGlobe role: the labelled
  real source every task model trains on.
* ``banepa``: 48 drone chips of central Banepa, Nepal, at about 0.13 m.
* ``kampala``: the two stitched drone mosaics of Ggaba, Kampala, Uganda, at about 0.3 m (the
  z21 ones, downsampled from 0.075 m; the z19 ones show the same ground and are left out so no ground
  is counted twice), cut into 256-pixel scenes.

Banepa and Kampala are the real targets (E3): drone imagery of dense towns on other continents,
unlike the source in sensor, roofs and layout, as the paper's Inria cities are unlike DeepGlobe.
Each domain's scenes are split alternately in name order into ``adapt`` (unlabelled images a method
infers designs from; with labels, the "GT" augmentation) and ``test`` (scored only).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..core.errors import MetaSimError

REALDATA = Path(__file__).resolve().parents[3] / "shared" / "realdata"
DOMAINS = ("rio", "banepa", "kampala")
SOURCE = "rio"
TARGETS = ("banepa", "kampala")
KAMPALA_SCENE_PX = 256
# The named sensor (``sim.sensor``) of each domain's kind of imagery, from its README: satellite or drone.
SENSOR_OF = {"rio": "satellite", "banepa": "drone", "kampala": "drone"}


@dataclass
class Scene:
    name: str
    image: np.ndarray  # float32 (H, W, 3) display sRGB
    mask: np.ndarray  # bool (H, W)
    pixel_size_m: float


def _pairs(realdata: Path, domain: str) -> list[tuple[Path, Path, float]]:
    if domain == "rio":
        return [(p, realdata / "rio" / "masks" / p.name, 0.5)
                for p in sorted((realdata / "rio" / "images").glob("*.png"))]
    if domain == "banepa":
        return [(p, realdata / "banepa" / "masks" / p.name, 0.13)
                for p in sorted((realdata / "banepa" / "images").glob("*.png"))]
    if domain == "kampala":
        folder = realdata / "kampala" / "mosaics_0p3m"
        return [(folder / f"z21_cluster{c}_image.png", folder / f"z21_cluster{c}_mask.png", 0.3) for c in (0, 1)]
    raise MetaSimError(f"unknown real domain {domain!r}; choose from {', '.join(DOMAINS)}")


def require(realdata: Path = REALDATA, domains=DOMAINS) -> Path:
    """``realdata`` when every file of ``domains`` is there; MetaSimError naming the first one missing."""
    realdata = Path(realdata)
    for domain in domains:
        pairs = _pairs(realdata, domain)
        missing = [str(p) for pair in pairs for p in pair[:2] if not p.is_file()]
        if not pairs or missing:
            raise MetaSimError(f"the shared real domain {domain!r} is not in {realdata} "
                               f"({missing[0] if missing else 'no images'}); pass --realdata")
    return realdata


def scenes(domain: str, realdata: Path = REALDATA) -> list[Scene]:
    """A domain's labelled scenes at their own pixel size; MetaSimError when the files are missing."""
    from ..sim.imageio import cut_tiles, read_image, read_rgb8

    realdata = require(realdata, (domain,))
    pairs = _pairs(realdata, domain)
    out = []
    for image_path, mask_path, size in pairs:
        image = read_image(image_path)
        mask = read_rgb8(mask_path)[:, :, 0] > 127
        if mask.shape != image.shape[:2]:
            raise MetaSimError(f"{mask_path} is not the size of {image_path}")
        if domain == "kampala":
            pieces = zip(cut_tiles(image, KAMPALA_SCENE_PX), cut_tiles(mask, KAMPALA_SCENE_PX))
            out += [Scene(f"{image_path.stem}-{k}", i, m, size) for k, (i, m) in enumerate(pieces)]
        else:
            out.append(Scene(image_path.stem, image, mask, size))
    return out


def split(domain_scenes: list[Scene]) -> tuple[list[Scene], list[Scene]]:
    """``(adapt, test)``: alternate scenes in name order (neighbouring chips go to different sides)."""
    ordered = sorted(domain_scenes, key=lambda s: s.name)
    return ordered[0::2], ordered[1::2]


def at_pixel_size(scene: Scene, pixel_size_m: float) -> tuple[np.ndarray, np.ndarray]:
    """The scene's image and mask brought to ``pixel_size_m`` (area averaging; mask by majority)."""
    from ..sim.imageio import resample

    image = resample(scene.image, scene.pixel_size_m, pixel_size_m)
    mask = resample(scene.mask[:, :, None].astype(np.float32), scene.pixel_size_m, pixel_size_m)[:, :, 0] > 0.5
    return image.astype(np.float32), mask

"""Can a small net tell our renders from real imagery? A real-versus-rendered classifier.

A measure of the appearance gap: a small CNN is trained on crops of real images (one class) and of
rendered tiles (the other), then scored on crops of held-out real images and held-out renders. An
accuracy of 0.5 means the two are indistinguishable to it; 1.0 means every render gives itself away.
Crops are balanced between the classes in training and scoring, and get random rotations and flips
but no colour changes: colour balance is part of what it should notice. Deterministic for a seed.

Where the gap lies, the same classifier says when its crops (real and rendered alike, in training and in
scoring) are shown in a reduced ``view`` (``VIEWS``): "grey" keeps brightness only (what colour told it is
gone), "blur" a Gaussian blur of ``BLUR_PX`` pixels (what fine detail, sharpness and noise told it is gone),
"grey+blur" both. An accuracy that falls towards 0.5 in a view says the renders differ from the real imagery
mostly in what that view removes.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from torch import nn

from ..core.errors import MetaSimError
from ..core.progress import Progress
from .data import Pool


@dataclass(frozen=True)
class RealnessSettings:
    steps: int = 300
    batch: int = 16  # crops per step, half of each class
    crop: int = 64
    lr: float = 2e-3
    width: int = 16
    test_crops: int = 256  # per class
    seed: int = 0
    view: str = "full"  # one of VIEWS


VIEWS = ("full", "grey", "blur", "grey+blur")
BLUR_PX = 2.0  # the "blur" view's standard deviation, in pixels at the working pixel size


def _check_view(name: str) -> None:
    if name not in VIEWS:
        raise MetaSimError(f"unknown classifier view {name!r}; choose one of {', '.join(VIEWS)}")


def view(images: torch.Tensor, name: str) -> torch.Tensor:
    """(N, 3, H, W) display-sRGB crops as the view ``name`` of ``VIEWS`` shows them."""
    _check_view(name)
    if "grey" in name:
        images = images.mean(dim=1, keepdim=True).expand(-1, 3, -1, -1)
    if "blur" in name:
        radius = int(3 * BLUR_PX)
        taps = torch.arange(-radius, radius + 1, dtype=images.dtype)
        kernel = torch.exp(-taps ** 2 / (2 * BLUR_PX ** 2))
        kernel = (kernel / kernel.sum()).repeat(3, 1)[:, None]  # (3, 1, K): one per channel
        images = nn.functional.conv2d(nn.functional.pad(images, (radius, radius, 0, 0), mode="replicate"),
                                      kernel[:, :, None, :], groups=3)
        images = nn.functional.conv2d(nn.functional.pad(images, (0, 0, radius, radius), mode="replicate"),
                                      kernel[:, :, :, None], groups=3)
    return images.contiguous()


class _Net(nn.Module):
    def __init__(self, width: int):
        super().__init__()
        layers, previous = [], 3
        for c in (width, 2 * width, 4 * width, 4 * width):
            layers += [nn.Conv2d(previous, c, 3, stride=2, padding=1, bias=False), nn.BatchNorm2d(c), nn.ReLU()]
            previous = c
        self.features = nn.Sequential(*layers)
        self.head = nn.Linear(previous, 1)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.head(self.features(x).mean(dim=(-2, -1)))[:, 0]


def train_critic(real: Pool, rendered: Pool, settings: RealnessSettings = RealnessSettings(),
                 progress: Progress | None = None) -> nn.Module:
    """The classifier trained to tell ``real`` (label 1) from ``rendered`` (label 0) crops seen in
    ``settings.view``, in inference mode: a crop's logit says how real it looks to it."""
    _check_view(settings.view)  # before any training
    if real.pixel_size_m != rendered.pixel_size_m:
        raise MetaSimError("real and rendered images must be at one pixel size")
    real, rendered = (_whole_crops_only(p, settings.crop) for p in (real, rendered))
    torch.manual_seed(settings.seed)
    net = _Net(settings.width)
    crops = torch.Generator().manual_seed(settings.seed)
    optimiser = torch.optim.Adam(net.parameters(), lr=settings.lr)
    half = settings.batch // 2
    labels = torch.cat([torch.ones(half), torch.zeros(half)])
    net.train()
    for _ in range(settings.steps):
        images = view(torch.cat([real.crops(half, settings.crop, crops, colour=None).image,
                                 rendered.crops(half, settings.crop, crops, colour=None).image]), settings.view)
        loss = nn.functional.binary_cross_entropy_with_logits(net(images), labels)
        optimiser.zero_grad(set_to_none=True)
        loss.backward()
        optimiser.step()
        if progress:
            progress(1)
    return net.eval()


def realness_accuracy(real_train: Pool, rendered_train: Pool, real_test: Pool, rendered_test: Pool,
                      settings: RealnessSettings = RealnessSettings(), progress: Progress | None = None) -> float:
    """Held-out accuracy of telling real (label 1) from rendered (label 0) crops, seen in ``settings.view``."""
    _check_view(settings.view)  # before any training
    pools = (real_train, rendered_train, real_test, rendered_test)
    if len({p.pixel_size_m for p in pools}) != 1:
        raise MetaSimError("real and rendered images must be at one pixel size")
    real_test, rendered_test = (_whole_crops_only(p, settings.crop) for p in (real_test, rendered_test))
    net = train_critic(real_train, rendered_train, settings, progress)
    scoring = torch.Generator().manual_seed(settings.seed + 1)
    with torch.no_grad():
        real = net(view(real_test.crops(settings.test_crops, settings.crop, scoring, augment=False).image,
                        settings.view)) > 0
        rendered = net(view(rendered_test.crops(settings.test_crops, settings.crop, scoring, augment=False).image,
                            settings.view)) <= 0
    return float(torch.cat([real, rendered]).float().mean())


def realness_scores(net: nn.Module, images, crop: int, view_name: str = "full") -> list[float]:
    """How real each image (float32 (H, W, 3) display sRGB) looks to a ``train_critic`` net: the mean logit over
    the whole ``crop``-pixel crops tiling it (at least one, from its top-left corner)."""
    scores = []
    with torch.no_grad():
        for image in images:
            h, w = image.shape[:2]
            if min(h, w) < crop:
                raise MetaSimError(f"an image of {w} x {h} pixels holds no {crop}-pixel crop")
            tiles = [image[y:y + crop, x:x + crop] for y in range(0, h - crop + 1, crop)
                     for x in range(0, w - crop + 1, crop)]
            batch = torch.from_numpy(np.stack(tiles).transpose(0, 3, 1, 2).copy())
            scores.append(float(net(view(batch, view_name)).mean()))
    return scores


def _whole_crops_only(pool: Pool, size: int) -> Pool:
    """The images of ``pool`` at least ``size`` pixels on a side, so every crop lies wholly inside one."""
    usable = [k for k, m in enumerate(pool.masks) if min(m.shape) >= size]
    if not usable:
        raise MetaSimError(f"{pool.name}: no image is {size} pixels on a side")
    return Pool(pool.name, [pool.images[k] for k in usable], [pool.masks[k] for k in usable], pool.pixel_size_m,
                [pool.sources[k] for k in usable])

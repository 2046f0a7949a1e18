"""Can a small net tell our renders from real imagery? A real-versus-rendered classifier.

A measure of the appearance gap: a small CNN is trained on crops of real images (one class) and of
rendered tiles (the other), then scored on crops of held-out real images and held-out renders. An
accuracy of 0.5 means the two are indistinguishable to it; 1.0 means every render gives itself away.
Crops are balanced between the classes in training and scoring, and get random rotations and flips
but no colour changes: colour balance is part of what it should notice. Deterministic for a seed.
"""

from __future__ import annotations

from dataclasses import dataclass

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


def realness_accuracy(real_train: Pool, rendered_train: Pool, real_test: Pool, rendered_test: Pool,
                      settings: RealnessSettings = RealnessSettings(), progress: Progress | None = None) -> float:
    """Held-out accuracy of telling real (label 1) from rendered (label 0) crops."""
    pools = (real_train, rendered_train, real_test, rendered_test)
    if len({p.pixel_size_m for p in pools}) != 1:
        raise MetaSimError("real and rendered images must be at one pixel size")
    real_train, rendered_train, real_test, rendered_test = (_whole_crops_only(p, settings.crop) for p in pools)
    torch.manual_seed(settings.seed)
    net = _Net(settings.width)
    crops = torch.Generator().manual_seed(settings.seed)
    optimiser = torch.optim.Adam(net.parameters(), lr=settings.lr)
    half = settings.batch // 2
    labels = torch.cat([torch.ones(half), torch.zeros(half)])
    net.train()
    for _ in range(settings.steps):
        images = torch.cat([real_train.crops(half, settings.crop, crops, colour=None).image,
                            rendered_train.crops(half, settings.crop, crops, colour=None).image])
        loss = nn.functional.binary_cross_entropy_with_logits(net(images), labels)
        optimiser.zero_grad(set_to_none=True)
        loss.backward()
        optimiser.step()
        if progress:
            progress(1)
    net.eval()
    scoring = torch.Generator().manual_seed(settings.seed + 1)
    with torch.no_grad():
        real = net(real_test.crops(settings.test_crops, settings.crop, scoring, augment=False).image) > 0
        rendered = net(rendered_test.crops(settings.test_crops, settings.crop, scoring, augment=False).image) <= 0
    return float(torch.cat([real, rendered]).float().mean())


def _whole_crops_only(pool: Pool, size: int) -> Pool:
    """The images of ``pool`` at least ``size`` pixels on a side, so every crop lies wholly inside one."""
    usable = [k for k, m in enumerate(pool.masks) if min(m.shape) >= size]
    if not usable:
        raise MetaSimError(f"{pool.name}: no image is {size} pixels on a side")
    return Pool(pool.name, [pool.images[k] for k in usable], [pool.masks[k] for k in usable], pool.pixel_size_m,
                [pool.sources[k] for k in usable])

"""Training the building segmenter on real and/or rendered images, mixed as the paper mixes them.

Each step draws one batch: with both a real and a synthetic pool, ``mix`` says how many crops of each
(6:1 in the paper, after Synthinel-1, whose batch of 7 is 6 real and 1 synthetic crops); with one
pool, every crop comes from it. The loss is binary cross-entropy plus soft Dice (buildings cover a
small share of most tiles), over the valid (unpadded) pixels. Adam, with the learning rate dropped
tenfold after 5/8 of the steps as the paper does (at 50,000 of 80,000). Deterministic for a seed:
the weights are initialised and every crop drawn from generators seeded by it.
"""

from __future__ import annotations

import hashlib
import json
import math
from dataclasses import asdict, dataclass

import torch
from torch import nn

from ..core.errors import MetaSimError
from ..core.progress import Progress
from .data import COLOUR_AUGMENTS, Pool, join
from .unet import Segmenter, UNet, UNetConfig, load_encoder

VERSION = 1  # of the training procedure: part of ``TrainSettings.id``
LR_DROP_AT = 5 / 8


@dataclass(frozen=True)
class TrainSettings:
    steps: int = 500
    batch: int = 7  # crops per step
    crop: int = 96  # pixels at the working pixel size
    lr: float = 2e-3
    mix: tuple[int, int] = (6, 1)  # real : synthetic crops per batch when both are given
    pixel_size_m: float = 0.6  # working pixel size
    augment: bool = True
    colour: str = "light"  # the rendered crops' colour augmentation (``data.COLOUR_AUGMENTS``); real ones: light
    seed: int = 0
    width: int = 16
    depth: int = 4
    encoder: str | None = None  # a segmenter checkpoint whose encoder starts training

    def check(self) -> TrainSettings:
        """MetaSimError for a setting training would refuse, before any image is read."""
        UNetConfig(self.width, self.depth).check()
        for name, value, low, high in (("--steps", self.steps, 1, 10_000_000), ("--batch", self.batch, 1, 4096),
                                       ("--crop", self.crop, 8, 4096), ("--seed", self.seed, 0, 2 ** 63 - 1)):
            if isinstance(value, bool) or not isinstance(value, int) or not low <= value <= high:
                raise MetaSimError(f"{name} must be a whole number from {low} to {high}, not {value!r}")
        if self.crop % 2 ** (self.depth - 1):
            raise MetaSimError(f"--crop must be a multiple of {2 ** (self.depth - 1)} for a U-Net of depth "
                               f"{self.depth}, not {self.crop}")
        if not (isinstance(self.lr, (int, float)) and 0 < self.lr <= 1):
            raise MetaSimError(f"--lr must be in (0, 1], not {self.lr!r}")
        if not (isinstance(self.pixel_size_m, (int, float)) and 0.01 <= self.pixel_size_m <= 100):
            raise MetaSimError(f"--gsd must be between 0.01 and 100 metres, not {self.pixel_size_m!r}")
        if self.colour not in COLOUR_AUGMENTS:
            raise MetaSimError(f"--colour-augment must be one of {', '.join(COLOUR_AUGMENTS)}, not {self.colour!r}")
        real, synthetic = self.mix
        if min(real, synthetic) < 0 or real + synthetic != self.batch or real == 0 == synthetic:
            raise MetaSimError(f"the mix {real}:{synthetic} must add up to the batch of {self.batch} crops")
        return self

    def id(self, *fingerprints: str) -> str:
        """Names a model trained with these settings on pools with these fingerprints (for caches)."""
        fields = asdict(self)
        if fields["colour"] == "light":  # the augmentation before there was a choice keeps its models' names
            del fields["colour"]
        text = json.dumps({"v": VERSION, **fields, "pools": fingerprints}, sort_keys=True)
        return hashlib.sha256(text.encode()).hexdigest()[:16]


def parse_mix(text: str, batch: int) -> tuple[int, int]:
    """``"6:1"`` to the crops of each kind in a batch of ``batch`` (6:1 and 7 give 6 and 1). A mix is read when
    both real and synthetic images are given, so a kind without a share is an error: its images would be read
    and never trained on."""
    try:
        real, synthetic = (float(x) for x in text.split(":"))
    except ValueError:
        raise MetaSimError(f"--mix takes REAL:SYNTHETIC, e.g. 6:1, not {text!r}") from None
    if not (math.isfinite(real) and math.isfinite(synthetic)) or real < 0 or synthetic < 0 or real + synthetic == 0:
        raise MetaSimError(f"--mix needs non-negative parts, not both zero: {text!r}")
    if real == 0 or synthetic == 0:
        unused = "--real" if real == 0 else "--synthetic"
        raise MetaSimError(f"--mix {text} gives {unused} no crops; drop {unused}, or give it a share such as 6:1")
    n_real = round(batch * real / (real + synthetic))
    if synthetic > 0 and n_real == batch and batch > 1:
        n_real = batch - 1  # a synthetic share, however small, gets a crop
    if real > 0 and n_real == 0 and batch > 1:
        n_real = 1
    return n_real, batch - n_real


def train_segmenter(real: Pool | None, synthetic: Pool | None, settings: TrainSettings,
                    progress: Progress | None = None) -> Segmenter:
    """A U-Net trained on ``real`` and/or ``synthetic`` (see the module's docstring).

    Pools must be at ``settings.pixel_size_m``. Raises MetaSimError with neither pool, or when the
    settings are invalid.
    """
    settings.check()
    if real is None and synthetic is None:
        raise MetaSimError("give real and/or synthetic training images")
    for pool in (real, synthetic):
        if pool is not None and abs(pool.pixel_size_m - settings.pixel_size_m) > 1e-6:
            raise MetaSimError(f"{pool.name} is at {pool.pixel_size_m} m per pixel, training at "
                               f"{settings.pixel_size_m}")
    n_real, n_synthetic = settings.mix if real is not None and synthetic is not None else (
        (settings.batch, 0) if real is not None else (0, settings.batch))
    torch.manual_seed(settings.seed)  # the weights' initialisation
    model = UNet(UNetConfig(settings.width, settings.depth)).to(memory_format=torch.channels_last)
    if settings.encoder:
        load_encoder(model, settings.encoder)
    crops = torch.Generator().manual_seed(settings.seed)
    optimiser = torch.optim.Adam(model.parameters(), lr=settings.lr)
    drop = int(settings.steps * LR_DROP_AT)
    model.train()
    for step in range(settings.steps):
        if step == drop:
            for group in optimiser.param_groups:
                group["lr"] = settings.lr / 10
        parts = []
        if n_real:
            parts.append(real.crops(n_real, settings.crop, crops, settings.augment))
        if n_synthetic:
            parts.append(synthetic.crops(n_synthetic, settings.crop, crops, settings.augment, settings.colour))
        batch = join(parts)
        logits = model(batch.image.contiguous(memory_format=torch.channels_last))
        loss = segmentation_loss(logits, batch.mask, batch.valid)
        optimiser.zero_grad(set_to_none=True)
        loss.backward()
        optimiser.step()
        if progress:
            progress(1)
    model.eval()
    training = {**asdict(settings), "mix": list(settings.mix), "crops": [n_real, n_synthetic],
                "real": _describe(real), "synthetic": _describe(synthetic)}
    return Segmenter(model.to(memory_format=torch.contiguous_format), settings.pixel_size_m, training)


def segmentation_loss(logits: torch.Tensor, mask: torch.Tensor, valid: torch.Tensor) -> torch.Tensor:
    """Binary cross-entropy plus soft Dice over the valid pixels."""
    bce = nn.functional.binary_cross_entropy_with_logits(logits, mask, weight=valid, reduction="sum")
    bce = bce / valid.sum().clamp(min=1.0)
    p = torch.sigmoid(logits) * valid
    dice = 1.0 - (2 * (p * mask).sum() + 1.0) / (p.sum() + (mask * valid).sum() + 1.0)
    return bce + dice


def _describe(pool: Pool | None) -> dict | None:
    if pool is None:
        return None
    return {"name": pool.name, "images": len(pool), "fingerprint": pool.fingerprint(),
            "building_share": round(pool.building_share(), 4)}

"""Roof segmenter: a small convolutional net that finds flat and sloped roofs in a tile, learnt from
the training tiles' label passes, so that inference needs no labels.

Why. ``roofcolour`` histograms the colours of the pixels likely to be roofs
of each kind. A likelihood from a pixel's colour alone (``RoofLikelihood``)
cannot tell a green roof from the grass around it, nor a roof texture the
bank lacks from the ground; the layout can: roofs are rectangles with
edges, shadows beside them, and sloped ones show their facets. The net sees
a neighbourhood of about 80 m at 0.3 m per pixel (dilated 3x3 convolutions on
the 2x2-pixel means, see ``_Net``) and gives, per pixel, p(other), p(flat
roof), p(sloped roof). Its settings are the constants below; the reasoning is
in docs/design.md ("Roof colour").

Learnt to generalise to roofs it has not seen: while training, the roof
pixels of half the crops get a random per-channel gain, offset and channel
order (weighted by their label share), so the net cannot rely on the bank's
roof colours alone and looks at shape and shading; the ground, roads and trees keep
their colours, which the city draws from a fixed palette. Crops also get a
random dihedral view. Deterministic for a seed: the crops and augmentations
come from one ``torch.Generator``.

That palette is also a shortcut: a net that knows every ground colour of the
renders may call any colour it has not seen a roof, and real ground has colours
no render has. With ``augment="scene"`` (the finder ``segmenter-jitter``) most
crops also get the ground's colours jittered on their own (per-channel gain and
offset) and then the whole crop's exposure, contrast, gamma, blur and noise, so
that only shape and shading are left to tell roofs by. `make bench-roof-finder`
measures both finders on real imagery.
"""

from __future__ import annotations

import hashlib
from typing import Callable, Mapping

import numpy as np
import torch
from torch import nn

from ..core.errors import MetaSimError

VERSION = 1
WIDTH = 24
DILATIONS = (1, 2, 4, 8, 16, 1)
STEPS = 3000
BATCH = 8
CROP = 96  # 2x2-pixel means (192 pixels of the tile)
LR = 3e-3
MAX_TILES = 1200  # tiles kept in memory for training (evenly spaced over the training set)
CLASSES = 3  # other, flat roof, sloped roof
RECOLOUR = 0.5  # share of the training crops whose roofs are recoloured
AUGMENTS = ("roofs", "scene")  # what is recoloured while training: the roofs only, or the whole scene too
SCENE_JITTER = 0.8  # with "scene": share of the training crops whose ground and whole image are jittered
# Convolutions in channels-last layout: the same net, learnt and run faster on CPUs (oneDNN's fastest
# layout); a layout gives slightly different rounding, so it is part of ``config_id``.
MEMORY_FORMAT = torch.channels_last


def config_id(augment: str = "roofs", steps: int | None = None) -> str:
    """Names what a fit depends on besides the tiles and the seed (for caches): the augmentation and the
    training steps (None: ``STEPS``); the default augmentation keeps the names it had before the choice
    existed."""
    steps = STEPS if steps is None else steps
    settings = (VERSION, WIDTH, DILATIONS, steps, BATCH, CROP, LR, MAX_TILES, RECOLOUR, str(MEMORY_FORMAT))
    if augment != "roofs":
        settings += (augment, SCENE_JITTER)
    return hashlib.sha256(repr(settings).encode()).hexdigest()[:8]


class _Net(nn.Module):
    """Per pixel of the 2x2-pixel means: fine features there, and features of a context of about
    80 m at 0.3 m per pixel (dilated convolutions at half that resolution, enough to see a whole roof
    and its facets)."""

    def __init__(self):
        super().__init__()
        self.fine = nn.Sequential(nn.Conv2d(3, WIDTH, 3, padding=1), nn.ReLU())
        layers = [nn.Conv2d(WIDTH, WIDTH, 3, stride=2, padding=1), nn.ReLU()]
        for d in DILATIONS:
            layers += [nn.Conv2d(WIDTH, WIDTH, 3, padding=d, dilation=d), nn.ReLU()]
        self.context = nn.Sequential(*layers)
        self.head = nn.Conv2d(2 * WIDTH, CLASSES, 1)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        fine = self.fine(x)
        context = nn.functional.interpolate(self.context(fine), size=x.shape[-2:], mode="bilinear",
                                            align_corners=False)
        return self.head(torch.cat([fine, context], dim=1))


def _dihedral(x: torch.Tensor, k: int, flip: bool) -> torch.Tensor:
    x = torch.rot90(x, k, dims=(-2, -1))
    return torch.flip(x, dims=(-1,)) if flip else x


def _recolour_roofs(rgb: torch.Tensor, shares: torch.Tensor, generator: torch.Generator) -> torch.Tensor:
    """(B, 3, H, W) crops whose roof pixels of each kind (``shares`` (B, 2, H, W)) get a random colour
    transform: channel order, gain in [0.5, 1.5] and offset in [-0.25, 0.25] per channel."""
    out = rgb
    b = rgb.shape[0]
    for k in range(shares.shape[1]):
        order = torch.argsort(torch.rand(b, 3, generator=generator), dim=1)
        gain = 0.5 + torch.rand(b, 3, 1, 1, generator=generator)
        offset = (torch.rand(b, 3, 1, 1, generator=generator) - 0.5) * 0.5
        shuffled = torch.gather(rgb, 1, order[:, :, None, None].expand_as(rgb))
        recoloured = (shuffled * gain + offset).clamp(0.0, 1.0)
        w = shares[:, k:k + 1] * (torch.rand(b, 1, 1, 1, generator=generator) < RECOLOUR)
        out = out * (1 - w) + recoloured * w
    return out


def jitter_scene(rgb: torch.Tensor, shares: torch.Tensor | None, generator: torch.Generator,
                 camera: bool = True) -> torch.Tensor:
    """(B, 3, H, W) crops, ``SCENE_JITTER`` of them changed: the non-roof pixels (1 - ``shares`` (B, K, H, W)
    summed over its K kinds, e.g. the roof kinds, or one building mask) get
    their own per-channel gain in [0.6, 1.4] and offset in [-0.15, 0.15]; then (with ``camera``) the whole
    crop ``camera_jitter``. ``shares`` None keeps the ground's colour: the camera alone changes."""
    b = rgb.shape[0]
    chosen = (torch.rand(b, 1, 1, 1, generator=generator) < SCENE_JITTER).float()
    x = rgb
    if shares is not None:
        ground = (1.0 - shares.sum(1, keepdim=True)).clamp(0.0, 1.0)
        x = rgb * (1 - ground) + _recolour_ground(rgb, generator) * ground
    if camera:
        x = camera_jitter(x, generator)
    return rgb * (1 - chosen) + x * chosen


def _uniform(generator: torch.Generator, low: float, high: float, b: int, *shape: int) -> torch.Tensor:
    return low + (high - low) * torch.rand(b, *shape, generator=generator)


def _recolour_ground(rgb: torch.Tensor, generator: torch.Generator) -> torch.Tensor:
    """(B, 3, H, W) crops with a per-channel gain in [0.6, 1.4] and offset in [-0.15, 0.15] each."""
    b = rgb.shape[0]
    return (rgb * _uniform(generator, 0.6, 1.4, b, 3, 1, 1)
            + _uniform(generator, -0.15, 0.15, b, 3, 1, 1)).clamp(0.0, 1.0)


def camera_jitter(x: torch.Tensor, generator: torch.Generator) -> torch.Tensor:
    """(B, 3, H, W) display-sRGB crops as another camera might have taken them: each an exposure gain in
    [0.6, 1.5], a contrast in [0.6, 1.4] about its mean, a gamma in [0.7, 1.4], a Gaussian blur of up to 1.2
    pixels (half of them) and noise of up to 0.04. Every draw comes from ``generator``."""
    b = x.shape[0]

    def uniform(low, high, *shape):
        return _uniform(generator, low, high, b, *shape)

    x = (x * uniform(0.6, 1.5, 1, 1, 1)).clamp(0.0, 1.0)
    mean = x.mean(dim=(1, 2, 3), keepdim=True)
    x = ((x - mean) * uniform(0.6, 1.4, 1, 1, 1) + mean).clamp(0.0, 1.0)
    x = x ** uniform(0.7, 1.4, 1, 1, 1)
    sigma = uniform(0.0, 1.2, 1, 1, 1) * (torch.rand(b, 1, 1, 1, generator=generator) < 0.5)
    taps = torch.arange(-3, 4, dtype=x.dtype)
    kernel = torch.exp(-taps[None] ** 2 / (2 * sigma.view(b, 1).clamp_min(1e-3) ** 2))
    kernel = kernel / kernel.sum(1, keepdim=True)  # (B, 7); sigma near 0: a delta
    channels = x.reshape(1, b * 3, *x.shape[-2:])
    weights = kernel.repeat_interleave(3, dim=0)[:, None]
    channels = nn.functional.conv2d(nn.functional.pad(channels, (3, 3, 0, 0), mode="replicate"),
                                    weights[:, :, None, :], groups=b * 3)
    channels = nn.functional.conv2d(nn.functional.pad(channels, (0, 0, 3, 3), mode="replicate"),
                                    weights[:, :, :, None], groups=b * 3)
    x = channels.reshape(x.shape)
    return (x + uniform(0.0, 0.04, 1, 1, 1) * torch.randn(x.shape, generator=generator)).clamp(0.0, 1.0)


class RoofSegmenter:
    """p(flat roof) and p(sloped roof) per 2x2-pixel mean of a tile, from a trained ``_net``."""

    def __init__(self, state: Mapping[str, torch.Tensor]):
        self.net = _Net()
        try:
            self.net.load_state_dict({k: torch.as_tensor(v, dtype=torch.float32) for k, v in state.items()})
        except (RuntimeError, KeyError) as error:
            raise MetaSimError(f"a roof segmenter's weights do not fit its network ({error}); "
                               "train the model again") from error
        self.net.eval()
        self.net.to(memory_format=MEMORY_FORMAT)
        digest = hashlib.sha256(b"".join(v.numpy().tobytes() for v in self.net.state_dict().values()))
        self.id = f"roof-segmenter-v{VERSION}[w{WIDTH},d{'-'.join(map(str, DILATIONS))}]-{digest.hexdigest()[:12]}"

    @classmethod
    def fit(cls, paths, seed: int = 0, steps: int | None = None,
            progress: Callable[[int], None] | None = None, augment: str = "roofs") -> "RoofSegmenter":
        """Trained on meta-sim EXR tiles (their RGB as ``read_image`` gives it, and their roof labels)
        for ``steps`` steps (default ``STEPS``), ``progress(1)`` after each, with the augmentation
        ``augment`` (``AUGMENTS``). Deterministic for ``seed``. Raises MetaSimError when there are no
        tiles, they differ in size, or training diverges."""
        if augment not in AUGMENTS:
            raise MetaSimError(f"unknown roof segmenter augmentation {augment!r}; choose one of {', '.join(AUGMENTS)}")
        steps = STEPS if steps is None else steps
        if isinstance(steps, bool) or not isinstance(steps, int) or steps < 1:
            raise MetaSimError(f"the roof segmenter's training steps must be a whole number of at least 1, not "
                               f"{steps!r}")
        rgb, shares = _training_pixels(paths)
        generator = torch.Generator().manual_seed(int(seed))
        torch.manual_seed(int(seed))  # the layers' initial weights
        net = _Net().to(memory_format=MEMORY_FORMAT)
        optimiser = torch.optim.Adam(net.parameters(), lr=LR)
        schedule = torch.optim.lr_scheduler.OneCycleLR(optimiser, max_lr=LR, total_steps=steps)
        n, h, w = rgb.shape[0], rgb.shape[-2], rgb.shape[-1]
        crop_h, crop_w = min(CROP, h), min(CROP, w)
        for _ in range(steps):
            pick = torch.randint(n, (BATCH,), generator=generator)
            top = torch.randint(h - crop_h + 1, (BATCH,), generator=generator)
            left = torch.randint(w - crop_w + 1, (BATCH,), generator=generator)
            view = torch.randint(8, (BATCH,), generator=generator)
            xs, ys = [], []
            for i in range(BATCH):
                window = (slice(None), slice(int(top[i]), int(top[i]) + crop_h),
                          slice(int(left[i]), int(left[i]) + crop_w))
                k, flip = int(view[i]) % 4, bool(view[i] >= 4)
                xs.append(_dihedral(rgb[pick[i]][window], k, flip))
                ys.append(_dihedral(shares[pick[i]][window], k, flip))
            x = torch.stack(xs).float() / 255.0
            y = torch.stack(ys).float() / 4.0
            x = _recolour_roofs(x, y, generator)
            if augment == "scene":
                x = jitter_scene(x, y, generator)
            x = x.contiguous(memory_format=MEMORY_FORMAT)
            target = torch.cat([(1.0 - y.sum(1, keepdim=True)).clamp_min(0.0), y], dim=1)
            loss = -(target * torch.log_softmax(net(x * 2.0 - 1.0), dim=1)).sum(1).mean()
            optimiser.zero_grad()
            loss.backward()
            optimiser.step()
            schedule.step()
            if not torch.isfinite(loss):
                raise MetaSimError("the roof segmenter's training diverged (a non-finite loss)")
            if progress:
                progress(1)
        return cls(net.state_dict())

    @torch.no_grad()
    def weights(self, level1: torch.Tensor) -> torch.Tensor:
        """(N, 2, H, W) p(flat roof), p(sloped roof) for each pixel of an (N, 3, H, W) sRGB batch."""
        x = (level1.float() * 2.0 - 1.0).contiguous(memory_format=MEMORY_FORMAT)
        return torch.softmax(self.net(x), dim=1)[:, 1:].contiguous()

    def to_dict(self) -> dict:
        """The weights for a checkpoint or the cache; ``from_dict`` (or ``roof_finder_from_dict``) reads
        them back."""
        return {"kind": "segmenter", "version": VERSION,
                "state": {k: v.clone() for k, v in self.net.state_dict().items()}}

    @classmethod
    def from_dict(cls, data: Mapping) -> "RoofSegmenter":
        """The segmenter ``to_dict`` stored; MetaSimError for another version or weights that do not fit."""
        if data.get("version") != VERSION:
            raise MetaSimError(f"roof segmenter version {data.get('version')!r}; this meta-sim reads "
                               f"version {VERSION} (train the model again)")
        return cls(data["state"])


def _training_pixels(paths) -> tuple[torch.Tensor, torch.Tensor]:
    """uint8 (N, 3, H/2, W/2) sRGB 2x2-pixel means and (N, 2, H/2, W/2) flat / sloped label shares in
    quarters, of at most ``MAX_TILES`` tiles evenly spaced over ``paths``."""
    from ..sim.imageio import linear_to_srgb
    from ..sim.meshes import FLAT_ROOF, SLOPED_ROOF
    from ..sim.tiles import read_tile
    from .features import _half

    paths = list(paths)
    if not paths:
        raise MetaSimError("no training tiles to learn the roof segmenter on")
    keep = np.unique(np.linspace(0, len(paths) - 1, min(MAX_TILES, len(paths))).round().astype(int))
    rgbs, shares = [], []
    for i in keep:
        tile = read_tile(paths[i])
        h, w = tile.rgb.shape[0] // 2 * 2, tile.rgb.shape[1] // 2 * 2
        rgb = torch.from_numpy(np.clip(linear_to_srgb(tile.rgb[:h, :w]), 0.0, 1.0).astype(np.float32))
        rgbs.append((_half(rgb.permute(2, 0, 1)) * 255.0).round().to(torch.uint8))
        labels = torch.from_numpy(np.stack([tile.roof_class[:h, :w] == FLAT_ROOF,
                                            tile.roof_class[:h, :w] == SLOPED_ROOF]).astype(np.float32))
        shares.append((_half(labels) * 4.0).round().to(torch.uint8))
    if len({tuple(r.shape) for r in rgbs}) != 1:
        raise MetaSimError("the training tiles differ in size; the roof segmenter needs one tile size")
    return torch.stack(rgbs), torch.stack(shares)

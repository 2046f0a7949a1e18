"""The task model: a U-Net building segmenter small enough to train on a CPU, and its checkpoint.

An encoder of ``depth`` levels (two 3x3 convolutions with batch norm per level, channels doubling
from ``width``, max pooling between levels), a decoder of transposed convolutions joined to the
encoder's features at each level, and a 1x1 head giving one logit per pixel (building or not). The
paper's U-Net uses a pre-trained ResNet-50 encoder; none can be downloaded here, so the encoder is a
plug-in: ``load_encoder`` takes the encoder of another checkpoint from a local file (for example a
segmenter trained on a large real source set), and by default the net starts from random weights.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass
from pathlib import Path

import torch
from torch import nn

from ..core.errors import MetaSimError
from ..core.fileio import atomic_path

FORMAT = "meta-sim-segmenter"
VERSION = 1


@dataclass(frozen=True)
class UNetConfig:
    width: int = 16  # channels of the first level; doubled at each level below
    depth: int = 4  # levels; an input side must be a multiple of 2 ** (depth - 1) (``predict`` pads)

    def check(self) -> UNetConfig:
        for name, value, low, high in (("width", self.width, 4, 128), ("depth", self.depth, 2, 6)):
            if isinstance(value, bool) or not isinstance(value, int) or not low <= value <= high:
                raise MetaSimError(f"U-Net {name} must be an integer from {low} to {high}, not {value!r}")
        return self


def _block(inputs: int, outputs: int) -> nn.Sequential:
    return nn.Sequential(nn.Conv2d(inputs, outputs, 3, padding=1, bias=False), nn.BatchNorm2d(outputs),
                         nn.ReLU(inplace=True), nn.Conv2d(outputs, outputs, 3, padding=1, bias=False),
                         nn.BatchNorm2d(outputs), nn.ReLU(inplace=True))


class UNet(nn.Module):
    """Display-sRGB images (N, 3, H, W) in [0, 1] to building logits (N, 1, H, W)."""

    def __init__(self, config: UNetConfig = UNetConfig()):
        super().__init__()
        self.config = config.check()
        channels = [config.width * 2 ** level for level in range(config.depth)]
        self.encoder = nn.ModuleList()
        previous = 3
        for c in channels:
            self.encoder.append(_block(previous, c))
            previous = c
        self.up, self.decoder = nn.ModuleList(), nn.ModuleList()
        for c in reversed(channels[:-1]):
            self.up.append(nn.ConvTranspose2d(previous, c, 2, stride=2))
            self.decoder.append(_block(2 * c, c))
            previous = c
        self.head = nn.Conv2d(previous, 1, 1)

    @property
    def multiple(self) -> int:
        """Input sides must be multiples of this."""
        return 2 ** (self.config.depth - 1)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        skips = []
        for level, block in enumerate(self.encoder):
            x = block(x)
            if level < len(self.encoder) - 1:
                skips.append(x)
                x = nn.functional.max_pool2d(x, 2)
        for up, block in zip(self.up, self.decoder):
            x = block(torch.cat([up(x), skips.pop()], dim=1))
        return self.head(x)


@dataclass
class Segmenter:
    """A trained U-Net with what it was trained on: ``pixel_size_m`` is the working pixel size images
    must be brought to, ``training`` the settings and data it was trained with (JSON-safe)."""

    model: UNet
    pixel_size_m: float
    training: dict


def save_segmenter(path: str | Path, segmenter: Segmenter) -> None:
    """Write a checkpoint: weights and JSON metadata only (loaded with ``weights_only``)."""
    payload = {"format": FORMAT, "version": VERSION, "config": asdict(segmenter.model.config),
               "pixel_size_m": float(segmenter.pixel_size_m), "training": json.dumps(segmenter.training),
               "state": segmenter.model.state_dict()}
    with atomic_path(Path(path)) as tmp:
        torch.save(payload, tmp)


def _read(path: Path) -> dict:
    if not path.is_file():
        raise MetaSimError(f"{path} is not a file")
    try:
        payload = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as e:  # noqa: BLE001  (any unreadable file is the same error to a user)
        raise MetaSimError(f"{path} is not a segmenter checkpoint ({str(e).splitlines()[0][:120]})") from None
    if not isinstance(payload, dict) or payload.get("format") != FORMAT:
        raise MetaSimError(f"{path} is not a segmenter checkpoint (written by `meta-sim task train`)")
    if payload.get("version") != VERSION:
        raise MetaSimError(f"{path}: segmenter format version {payload.get('version')!r}; this meta-sim reads "
                           f"{VERSION}")
    return payload


def load_segmenter(path: str | Path) -> Segmenter:
    """Read a checkpoint written by ``save_segmenter``; MetaSimError when it is not one or is damaged."""
    path = Path(path)
    payload = _read(path)
    try:
        config = UNetConfig(**{k: payload["config"][k] for k in ("width", "depth")})
        model = UNet(config)
        model.load_state_dict(payload["state"])
        size, training = float(payload["pixel_size_m"]), json.loads(payload["training"])
    except (KeyError, TypeError, ValueError, RuntimeError) as e:
        raise MetaSimError(f"{path}: damaged segmenter checkpoint ({str(e).splitlines()[0][:120]})") from None
    if not 0.01 <= size <= 100 or not isinstance(training, dict):
        raise MetaSimError(f"{path}: damaged segmenter checkpoint (pixel size {size!r})")
    return Segmenter(model.eval(), size, training)


def load_encoder(model: UNet, path: str | Path) -> int:
    """Copy the encoder of the segmenter checkpoint at ``path`` into ``model`` (same width and depth);
    returns the number of tensors copied. The decoder and head keep their weights."""
    path = Path(path)
    payload = _read(path)
    encoder = {k[len("encoder."):]: v for k, v in payload.get("state", {}).items() if k.startswith("encoder.")}
    try:
        model.encoder.load_state_dict(encoder)
    except RuntimeError as e:
        raise MetaSimError(f"{path}: its encoder does not fit this U-Net ({str(e).splitlines()[0][:160]})") from None
    return len(encoder)

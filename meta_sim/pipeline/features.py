"""Feature extractors, and the paper's augmentation and averaging (section 4).

An extractor maps a float32 batch ``(N, 3, H, W)`` of display sRGB in
[0, 1] (what ``meta_sim.sim.imageio.read_image`` returns) to ``(N, dim)``
float32 features, deterministically, for any H, W >= 16. Its ``id`` names
it, its version and parameters; checkpoints and feature caches store it so
features from different extractors are never mixed.

* ``ColourTexture`` (the default, no weights): whole-tile colour and texture
  statistics, built so that rooftop materials are recoverable from them.
* ``Backbone``: a pretrained network the user supplies (``export:FILE``,
  ``torchscript:FILE``, or ``torchvision:NAME`` with a state-dict file),
  like the paper's ViT-L/16.

``group_feature`` averages an extractor's features over the tiles of one
design (or target group) and their dihedral views: 9 tiles x 8 views = 72
images in the paper.
"""

from __future__ import annotations

import hashlib
import math
import time
from pathlib import Path
from typing import Protocol

import numpy as np
import torch
import torch.nn.functional as F

from ..core.errors import MetaSimError
from ..core.progress import Progress
from ..sim.imageio import MIN_TILE_PX

VIEW_COUNTS = (1, 2, 4, 8)
_VIEW_ORDER = [(turns, flip) for turns in (0, 2, 1, 3) for flip in (False, True)]  # (quarter turns, h-flip)
IMAGENET_MEAN = (0.485, 0.456, 0.406)
IMAGENET_STD = (0.229, 0.224, 0.225)


class Extractor(Protocol):
    """What every feature extractor offers: an ``id`` stored with its features, the feature width
    ``dim``, and a call mapping an (N, 3, H, W) sRGB batch in [0, 1] to (N, dim) float32 features."""

    id: str
    dim: int
    # True when features do not change under rotations by 90 degrees and flips: views are then skipped.
    dihedral_invariant: bool

    def __call__(self, batch: torch.Tensor) -> torch.Tensor: ...


class ColourTexture:
    """Colour and texture statistics of a whole tile, in torch, without weights.

    Definition (version 1). The input is clipped to [0, 1] (NaN -> 0) and,
    unless both sides are multiples of 8, resized bilinearly to the nearest
    smaller multiples (corners aligned, a symmetric operation). Level 0 is
    the image; levels 1-3 are 2x2 block means of the level below. Luminance
    is ``Y = 0.299 R + 0.587 G + 0.114 B``. Colours are placed in the HSV
    cone of the paper's similarity score (``meta_sim.sim.textures.similarity``)
    with the chroma stretched: ``(c^(1/4) cos 2 pi h, c^(1/4) sin 2 pi h, v)``
    over [-1, 1]^2 x [0, 1] (``v = max``, ``c = max - min``, hexcone hue
    ``h``). Roofs, roads and ground are nearly grey: in the plain cone they
    share the few central bins. All histograms are *soft*: a value is
    shared linearly between the two nearest bin centres on each axis
    (values beyond the outer centres go wholly to the edge bin), so features
    move smoothly with the image.

    1. ``colour`` (488): square root of the joint 8x8x8 histogram of
       level-1 pixels (2x2 means: a quarter of the cost of level 0;
       pixel-scale speckle is item 2's business) in the stretched cone,
       keeping the 488 bins colours can reach. Unit length.
    2. ``contrast`` (3 x 8): for each level k = 1..3, the square root of
       the histogram of the standard deviation of Y over each 2x2 block of
       level k-1 (texture at a scale of 2^(k-1) pixels), as
       log2(sd + 2^-10) over [-9, -1]. Unit length each.
    3. ``contrast given colour`` (64 x 4): for each 4x4-pixel block, its
       mean colour (4x4x4 stretched-cone bins) and the standard deviation
       of Y inside it (log2 over [-8, -2], 4 bins); per colour bin, the
       distribution of that contrast, ``(n(colour, sd) + e / 4) / (n(colour)
       + e)`` with ``e`` about one block of a 384 px tile, so a colour that
       is absent reads uniform. It does not depend on how much of the tile
       the colour covers, so two roofs of one colour but different
       roughness (gravel and membrane, slate and shingles) differ here
       whatever the share of roofs in the tile. Weighted 1/4.
    4. ``anisotropy`` (3 x 2): per level k, from the Haar details of Y's
       2x2 blocks (horizontal H, vertical V, diagonal D), the
       energy-weighted means of ``|H^2 - V^2| / E`` (stripes along the
       image axes) and ``D^2 / E`` (checker-like texture), ``E = H^2 + V^2 +
       D^2``; an image without texture reads 1/3 for both.

    The stretch (1/4 rather than 1/3 or 1/2), the conditional form of
    item 3 and its weight were chosen on "fast" renders of every bank
    texture in two cities (no E1/E2 target), by how often a design's nearest
    neighbour in the other city is the same design: the plain cone and a joint histogram for
    item 3 tell far fewer roof textures apart.

    Every statistic is invariant to rotations by 90 degrees and flips (2x2
    blocks of sides that are multiples of 8 map onto each other), so
    averaging over the dihedral views would average identical vectors:
    ``dihedral_invariant`` lets ``group_feature`` skip them.
    """

    id = "colour-texture-v1[cone8^3c^1/4,contrast3x8,contrast|colour4^3x4,haar3]"
    dihedral_invariant = True
    COLOUR_BINS = 8
    CHROMA_POWER = 0.25
    JOINT_COLOUR_BINS = 4
    JOINT_CONTRAST_BINS = 4
    JOINT_EPS = 1e-4  # a 4x4 block is 1/9216 of a 384 px tile
    JOINT_WEIGHT = 0.25
    CONTRAST_BINS = 8
    LEVELS = 3
    # Energy (luminance^2) that stands for "no texture" in the anisotropy ratios: well below 8-bit noise.
    ANISOTROPY_EPS = 1e-6
    CHUNK = 8  # images per pass: bounds the memory of the histogram index arrays

    def __init__(self):
        self._colour_keep = _reachable_cone_bins(self.COLOUR_BINS, self.CHROMA_POWER)
        self.dim = (int(self._colour_keep.sum()) + self.LEVELS * self.CONTRAST_BINS
                    + self.JOINT_COLOUR_BINS ** 3 * self.JOINT_CONTRAST_BINS + 2 * self.LEVELS)

    @torch.no_grad()
    def __call__(self, batch: torch.Tensor) -> torch.Tensor:
        _check_batch(batch)
        return torch.cat([self._features(chunk) for chunk in batch.split(self.CHUNK)])

    def _features(self, x: torch.Tensor) -> torch.Tensor:
        x = torch.nan_to_num(x.float(), nan=0.0).clamp_(0.0, 1.0)
        side = 2 ** self.LEVELS
        h, w = x.shape[-2] - x.shape[-2] % side, x.shape[-1] - x.shape[-1] % side
        if (h, w) != x.shape[-2:]:
            x = F.interpolate(x, size=(h, w), mode="bilinear", align_corners=True)
        pyramid = [x]
        for _ in range(self.LEVELS):
            pyramid.append(_half(pyramid[-1]))
        colour = _soft_histogram(_cone_axes(pyramid[1], self.COLOUR_BINS, self.CHROMA_POWER))
        parts = [colour[:, self._colour_keep].sqrt()]
        luma = [_luma(level) for level in pyramid]
        anisotropy = []
        for k in range(1, self.LEVELS + 1):
            horizontal, vertical, diagonal = _haar_details(luma[k - 1])
            energy = horizontal ** 2 + vertical ** 2 + diagonal ** 2  # = 4 x the block's variance
            parts.append(_soft_histogram([(_log_sd(energy / 4), -9.0, -1.0, self.CONTRAST_BINS)]).sqrt())
            anisotropy += [_weighted_ratio((horizontal ** 2 - vertical ** 2).abs(), energy, self.ANISOTROPY_EPS),
                           _weighted_ratio(diagonal ** 2, energy, self.ANISOTROPY_EPS)]
        variance = _half(_half(luma[0] ** 2)) - luma[2] ** 2
        joint = _soft_histogram(_cone_axes(pyramid[2], self.JOINT_COLOUR_BINS, self.CHROMA_POWER)
                                + [(_log_sd(variance), -8.0, -2.0, self.JOINT_CONTRAST_BINS)])
        joint = joint.view(len(x), -1, self.JOINT_CONTRAST_BINS)
        given_colour = (joint + self.JOINT_EPS / self.JOINT_CONTRAST_BINS) / (joint.sum(-1, keepdim=True)
                                                                              + self.JOINT_EPS)
        parts += [self.JOINT_WEIGHT * given_colour.flatten(1), torch.stack(anisotropy, dim=1)]
        return torch.cat(parts, dim=1)


def _half(x: torch.Tensor) -> torch.Tensor:
    """Means of the 2x2 blocks of the last two (even) dimensions; a few times faster than avg_pool2d on CPU."""
    rows = x[..., 0::2, :] + x[..., 1::2, :]
    return (rows[..., 0::2] + rows[..., 1::2]) * 0.25


def _luma(rgb: torch.Tensor) -> torch.Tensor:
    return 0.299 * rgb[:, 0] + 0.587 * rgb[:, 1] + 0.114 * rgb[:, 2]


def _haar_details(y: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Orthonormal Haar detail coefficients of each 2x2 block of ``y`` (N, H, W)."""
    a, b = y[:, 0::2, 0::2], y[:, 0::2, 1::2]
    c, d = y[:, 1::2, 0::2], y[:, 1::2, 1::2]
    return (a + b - c - d) / 2, (a - b + c - d) / 2, (a - b - c + d) / 2


def _log_sd(variance: torch.Tensor) -> torch.Tensor:
    # Rounding can make a variance slightly negative; the floor keeps log2 finite on flat images.
    return torch.log2(variance.clamp_min(0.0).sqrt() + 2.0 ** -10)


def _weighted_ratio(part: torch.Tensor, energy: torch.Tensor, eps: float) -> torch.Tensor:
    """Energy-weighted mean of part / energy, i.e. sum(part) / sum(energy), drawn to 1/3 when there is no energy."""
    return (part.mean(dim=(1, 2)) + eps / 3) / (energy.mean(dim=(1, 2)) + eps)


def _cone_axes(rgb: torch.Tensor, bins: int, chroma_power: float) -> list[tuple]:
    """Stretched HSV-cone coordinates of every pixel of ``rgb`` (N, 3, H, W), as histogram axes."""
    r, g, b = rgb[:, 0], rgb[:, 1], rgb[:, 2]
    value = torch.maximum(torch.maximum(r, g), b)
    chroma = value - torch.minimum(torch.minimum(r, g), b)
    safe = torch.where(chroma > 0, chroma, torch.ones_like(chroma))
    sector = torch.where(value == r, torch.remainder((g - b) / safe, 6.0),
                         torch.where(value == g, (b - r) / safe + 2.0, (r - g) / safe + 4.0))
    angle = sector * (math.pi / 3.0)
    radius = chroma.clamp_min(0.0) ** chroma_power
    return [(radius * torch.cos(angle), -1.0, 1.0, bins), (radius * torch.sin(angle), -1.0, 1.0, bins),
            (value, 0.0, 1.0, bins)]


def _soft_histogram(axes: list[tuple], weights: torch.Tensor | None = None) -> torch.Tensor:
    """Joint soft histogram (N, prod(bins)), summing to 1 per image, of per-pixel values.

    With ``weights`` (N, ...) (one per pixel) each pixel counts its weight:
    the histogram then sums to the image's mean weight.
    ``axes`` holds ``(values (N, ...), lo, hi, bins)``; each value is shared
    linearly between its two nearest bin centres, so each pixel adds
    2^len(axes) weighted entries, one ``bincount`` per corner of its cell
    (full-size tensors per corner: broadcasting over a trailing corner axis
    of size 2 is several times slower).
    """
    n = axes[0][0].shape[0]
    base, total = 0, 1  # each pixel's lowest corner bin, and the number of bins
    corners = [(0, None if weights is None else weights.reshape(n, -1))]  # (flat offset from base, weight)
    for values, lo, hi, bins in axes:
        t = ((values.reshape(n, -1) - lo) * (bins / (hi - lo)) - 0.5).clamp_(0.0, bins - 1.0)
        low = t.floor().clamp_(max=bins - 2)
        frac = t.sub_(low)
        base = base * bins + low.long()
        total *= bins
        corners = [(offset * bins + step, part if weight is None else weight * part)
                   for offset, weight in corners for step, part in ((0, 1.0 - frac), (1, frac))]
    base = base + (torch.arange(n) * total).unsqueeze(1)
    hist = sum(torch.bincount((base + offset).flatten(), weight.flatten(), minlength=n * total)
               for offset, weight in corners)
    return hist.view(n, total).float() / base.shape[1]


def _reachable_cone_bins(bins: int, chroma_power: float) -> torch.Tensor:
    """Mask of the stretched-cone histogram's bins that some colour can reach.

    Colours fill ``sqrt(x^2 + y^2) <= z^chroma_power``, ``0 <= z <= 1`` (chroma
    never exceeds value); a bin receives weight from the open box of one bin
    width around its centre (extended to the domain's edge for edge bins).
    It is reachable when the box holds such a point: its nearest (x, y) to
    the axis lies inside the cone at the box's top z.
    """
    centres = -1.0 + (np.arange(bins) + 0.5) * (2.0 / bins)
    lo = np.where(np.arange(bins) == 0, -1.0, centres - 2.0 / bins)
    hi = np.where(np.arange(bins) == bins - 1, 1.0, centres + 2.0 / bins)
    axis_gap = np.where((lo <= 0) & (hi >= 0), 0.0, np.minimum(np.abs(lo), np.abs(hi)))
    top = np.minimum(1.0, (np.arange(bins) + 1.5) / bins) ** chroma_power
    radius = np.hypot(axis_gap[:, None], axis_gap[None, :])
    return torch.from_numpy((radius[:, :, None] < top[None, None, :]).reshape(-1))


class Backbone:
    """A pretrained network as an extractor.

    Tiles are resized to ``input_size`` x ``input_size`` (bilinear,
    antialiased; the whole tile is kept, non-square ones are stretched),
    normalised with ImageNet's mean and standard deviation, and the output
    is flattened (e.g. 1000 ImageNet logits, as in the paper).
    """

    dihedral_invariant = False

    def __init__(self, module, name: str, input_size: int = 224):
        """``module``: a callable network already in inference mode; ``name``: its id without the input size."""
        if not isinstance(input_size, int) or input_size < MIN_TILE_PX:
            raise MetaSimError(f"input size must be an integer of at least {MIN_TILE_PX} px, got {input_size!r}")
        self.module = module
        self.input_size = input_size
        self.id = f"{name}-in{input_size}"
        self._mean = torch.tensor(IMAGENET_MEAN).view(1, 3, 1, 1)
        self._std = torch.tensor(IMAGENET_STD).view(1, 3, 1, 1)
        try:  # two images: a network exported for batches of one fails here, not in the middle of a run
            self.dim = self(torch.zeros(2, 3, input_size, input_size)).shape[1]
        except MetaSimError:
            raise
        except Exception as exc:  # anything the user's network raises on a plain image batch
            raise MetaSimError(f"{name}: the network fails on a (2, 3, {input_size}, {input_size}) image batch "
                               f"({type(exc).__name__}: {_last_line(exc)}); check --input-size, and export "
                               "with a dynamic batch dimension") from None

    @torch.no_grad()
    def __call__(self, batch: torch.Tensor) -> torch.Tensor:
        _check_batch(batch)
        x = torch.nan_to_num(batch.float(), nan=0.0).clamp(0.0, 1.0)
        x = F.interpolate(x, size=(self.input_size, self.input_size), mode="bilinear", antialias=True,
                          align_corners=False)
        out = self.module((x - self._mean) / self._std)
        if isinstance(out, (tuple, list)):  # (logits, aux, ...): the first output is the prediction
            out = out[0]
        if not isinstance(out, torch.Tensor) or out.shape[0] != len(x):
            raise MetaSimError(f"{self.id}: the network must return one tensor row per image, got "
                               f"{type(out).__name__} {tuple(getattr(out, 'shape', ()))}")
        out = out.reshape(len(x), -1).float()
        if not torch.isfinite(out).all():
            raise MetaSimError(f"{self.id}: the network returned NaN or infinite features; check its weights")
        return out


def make_extractor(spec: str = "colour-texture", weights: Path | None = None, input_size: int = 224) -> Extractor:
    """The extractor named by ``spec``.

    * ``colour-texture``: ``ColourTexture`` (the default; no weights).
    * ``export:FILE``: a network in eval mode saved with
      ``torch.export.save`` (``.pt2``), exported at ``input_size`` with a
      dynamic batch dimension (``torch.export.Dim``); torch's successor to
      TorchScript.
    * ``torchscript:FILE``: any network saved with ``torch.jit.save``.
    * ``torchvision:NAME`` with ``weights=FILE`` (a state dict for
      ``torchvision.models.get_model(NAME)``): only where torchvision imports.
      The PyPI torchvision does not import beside this project's torch build:
      export the model instead and use ``export:`` or ``torchscript:``.

    Backbone ids hold the sha256 prefix of the file that carries the weights.
    """
    kind, _, arg = str(spec).partition(":")
    if kind == "colour-texture" and not arg:
        if weights is not None:
            raise MetaSimError("the colour-texture extractor has no weights; drop --weights")
        return ColourTexture()
    if kind in ("export", "torchscript") and arg:
        if weights is not None:
            raise MetaSimError(f"a {kind} file carries its own weights; drop --weights")
        path = _existing(Path(arg), f"{kind} model")
        try:  # torch raises RuntimeError, ValueError, zipfile errors, ... on a file that is not a model
            if kind == "export":
                module = torch.export.load(str(path)).module()  # frozen in the mode it was exported in
            else:
                module = torch.jit.load(str(path), map_location="cpu").eval()
        except Exception as exc:
            what, how = (("torch.export", "torch.export.save(torch.export.export(model, ...), FILE)")
                         if kind == "export" else ("TorchScript", "torch.jit.save(torch.jit.script(model), FILE)"))
            raise MetaSimError(f"{path} is not a {what} model ({type(exc).__name__}); save one with {how}") from None
        return Backbone(module, f"{kind}-{_sha256(path)[:12]}", input_size)
    if kind == "torchvision" and arg:
        return _torchvision_backbone(arg, weights, input_size)
    raise MetaSimError(f"unknown feature extractor {spec!r}; use colour-texture, export:FILE, torchscript:FILE "
                       "or torchvision:NAME with --weights FILE")


def _torchvision_backbone(name: str, weights: Path | None, input_size: int) -> Backbone:
    try:
        import torchvision
    except Exception:  # a build mismatch raises more than ImportError
        raise MetaSimError("torchvision is not importable beside this torch build; export your model with "
                           "torch.export.save (or torch.jit.save) and use export:FILE (or torchscript:FILE)"
                           ) from None
    if weights is None:
        raise MetaSimError(f"torchvision:{name} needs its weights: pass --weights FILE (a state dict)")
    path = _existing(Path(weights), "weights file")
    try:
        module = torchvision.models.get_model(name, weights=None)
    except Exception:
        raise MetaSimError(f"torchvision has no model {name!r}") from None
    try:
        module.load_state_dict(torch.load(path, map_location="cpu", weights_only=True))
    except Exception as exc:
        raise MetaSimError(f"{path} is not a state dict for torchvision {name} ({type(exc).__name__}: "
                           f"{_last_line(exc)})") from None
    return Backbone(module.eval(), f"torchvision-{name}-{_sha256(path)[:12]}", input_size)


def _last_line(exc: Exception) -> str:
    """The gist of a torch error, whose message may carry a whole TorchScript traceback."""
    lines = str(exc).strip().splitlines()
    return lines[-1][:200] if lines else ""


def _existing(path: Path, what: str) -> Path:
    if not path.is_file():
        raise MetaSimError(f"{what} not found: {path}")
    return path


def _sha256(path: Path) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def _check_batch(batch: torch.Tensor) -> None:
    if not isinstance(batch, torch.Tensor) or batch.ndim != 4 or batch.shape[1] != 3:
        raise ValueError(f"need an (N, 3, H, W) tensor, got {getattr(batch, 'shape', type(batch))}")
    if min(batch.shape[-2:]) < MIN_TILE_PX:
        raise MetaSimError(f"images of {batch.shape[-1]}x{batch.shape[-2]} px are smaller than the "
                           f"{MIN_TILE_PX} px minimum")


def views(batch: torch.Tensor, n_views: int = 8) -> list[torch.Tensor]:
    """The first ``n_views`` dihedral views of ``batch`` (N, C, H, W), as a list of (N, C, ., .) tensors.

    The order is identity, horizontal flip, 180 degrees, vertical flip, then
    90 and 270 degrees each with and without the flip: every prefix of 1, 2,
    4 or 8 views is a group, so averaging over it gives a feature invariant
    to those transforms. 90-degree views of non-square images swap H and W.
    """
    if n_views not in VIEW_COUNTS:
        raise MetaSimError(f"views must be one of {VIEW_COUNTS}, got {n_views!r}")
    out = []
    for quarter_turns, flip in _VIEW_ORDER[:n_views]:
        view = torch.rot90(batch, quarter_turns, dims=(-2, -1)) if quarter_turns else batch
        out.append(torch.flip(view, dims=(-1,)) if flip else view)
    return out


def group_feature(tiles: list[np.ndarray], extractor: Extractor, n_views: int = 8,
                  batch_size: int = 32) -> torch.Tensor:
    """One (dim,) feature for a group: the mean over all tiles x views (9 x 8 = 72 in the paper)."""
    return features_for_groups([tiles], extractor, n_views, batch_size)[0]


def features_for_groups(groups: list[list[np.ndarray]], extractor: Extractor, n_views: int = 8,
                        batch_size: int = 32, progress: Progress | None = None) -> torch.Tensor:
    """(G, dim) float32: ``group_feature`` of every group, with tiles of all groups batched together.

    Tiles are float (H, W, 3) arrays in [0, 1]; tiles of one shape are
    batched. Every tile x view counts once in its group's mean, whatever its
    size. An extractor whose features are ``dihedral_invariant`` is run on
    one view only: the mean of identical vectors is that vector.
    ``progress`` is told each batch's tile count.
    """
    if n_views not in VIEW_COUNTS:
        raise MetaSimError(f"views must be one of {VIEW_COUNTS}, got {n_views!r}")
    by_shape: dict[tuple, list[tuple[int, np.ndarray]]] = {}
    for g, tiles in enumerate(groups):
        if len(tiles) == 0:
            raise MetaSimError(f"group {g} has no tiles")
        for tile in tiles:
            tile = np.asarray(tile)
            if tile.ndim != 3 or tile.shape[2] != 3:
                raise MetaSimError(f"group {g}: need (H, W, 3) image tiles, got shape {tile.shape}")
            by_shape.setdefault(tile.shape, []).append((g, tile))
    n_run = 1 if getattr(extractor, "dihedral_invariant", False) else n_views
    sums = torch.zeros(len(groups), extractor.dim, dtype=torch.float64)
    counts = torch.zeros(len(groups), dtype=torch.float64)
    for items in by_shape.values():
        for start in range(0, len(items), batch_size):
            chunk = items[start:start + batch_size]
            index = torch.tensor([g for g, _ in chunk])
            pixels = np.stack([t for _, t in chunk]).astype(np.float32, copy=False)
            batch = torch.from_numpy(pixels).permute(0, 3, 1, 2).contiguous()
            for view in views(batch, n_run):
                sums.index_add_(0, index, extractor(view).double())
            counts.index_add_(0, index, torch.full((len(chunk),), float(n_run), dtype=torch.float64))
            if progress is not None:
                progress(len(chunk))
    return (sums / counts[:, None]).float()


def time_extractor(extractor: Extractor, tile_px: int = 384, n: int = 9, views: int = 8,
                   repeats: int = 3) -> float:
    """Seconds to compute one group feature of ``n`` tiles x ``views`` (median of ``repeats`` after a warm-up)."""
    rng = np.random.default_rng(0)
    coarse = rng.random((n, tile_px // 16 + 1, tile_px // 16 + 1, 3), dtype=np.float32)
    tiles = [np.clip(np.kron(c, np.ones((16, 16, 1), np.float32))[:tile_px, :tile_px]
                     + 0.05 * rng.standard_normal((tile_px, tile_px, 3), dtype=np.float32), 0, 1) for c in coarse]
    group_feature(tiles, extractor, views)
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        group_feature(tiles, extractor, views)
        times.append(time.perf_counter() - start)
    return float(np.median(times))

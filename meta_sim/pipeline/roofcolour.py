"""Roof colour: the colours of the pixels that are likely roofs, found without labels at inference.

Why. The default features describe whole tiles, and the search weighs them
by the simulation noise (``nams.norm.FeatureNorm``): what tells one bank
texture from another in a render. A target roofed with a texture the bank
lacks (E2) then goes to the bank texture of the most similar *structure*,
whatever its colour, while the E2 score -- and an artist -- asks for the
nearest colour. So NAMS also sees, per roof kind, a colour histogram of the
pixels likely to be roofs of that kind, and the search compares those
histograms by their plain distance, not whitened by the noise (see
``FeatureNorm`` and ``nams.search``).

* The roof finder gives each pixel a probability of being a flat and a
  sloped roof. By default ``roofsegment.RoofSegmenter``, a small net learnt
  on the training tiles' labels that sees roofs by shape and shading;
  ``make bench-ablations`` (row ``nams_exhaustive_colour_roof_finder``) measures
  it against the colour-only finder below.
* ``RoofLikelihood``: p(flat roof | colour) and p(sloped roof | colour) for
  each of 16^3 sRGB bins of 2x2-pixel means, counted on the training tiles'
  label passes: ``(n_kind + PRIOR x PRIOR_COUNT) / (n + PRIOR_COUNT)``. A
  colour the training tiles never showed reads PRIOR for each kind (half
  "some roof"): in a city whose ground, roads and trees come from a fixed
  palette, an unseen colour is more likely a roof than not.
* ``RoofColourExtractor``: another extractor's features followed by, per
  roof kind, the soft histogram of the tile's 2x2-pixel means in
  ``ColourTexture``'s stretched HSV cone (its 488 reachable bins), each
  pixel weighted by the finder's probability of that kind raised to
  ``WEIGHT_POWER``, divided by the pixel count. The mean over a group's
  tiles therefore pools their pixels; ``FeatureNorm`` makes each histogram
  sum to 1 and takes its square root. The power keeps the pixels the
  finder is sure of and all but drops the doubtful ones (roof edges, the
  other roof kind, roof-like ground): histograms compared once they sum to
  1 gain more from a purer sample than from a larger one.
* With ``score_cone`` (the default of ``workflow.ModelSettings``), two more
  histograms per roof kind, in the HSV cone of the E1/E2 score itself
  (``sim.textures.similarity``: 8 x 8 x 8 hard bins, chroma not stretched;
  its 220 reachable bins), of the tile's full-resolution pixels, each
  weighted by the finder's probability of its 2x2 block to the same power.
  The stretched, soft histograms of 2x2 means tell close bank textures
  apart (E1); these rank a texture the bank lacks as the score ranks it
  (E2): a 2x2 mean mixes a pattern's colours into colours the texture does
  not have, and the stretched cone spreads the greys the score lumps
  together. ``make bench-ablations`` (row ``nams_exhaustive_no_score_cone``)
  measures what they add.

The finder belongs to the training set it was learnt on; the checkpoint
stores it, so inference needs no labels. The reasoning is in docs/design.md
("Roof colour").
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import math
import time
from pathlib import Path
from typing import Callable, Mapping

import numpy as np
import torch

from ..core.errors import MetaSimError
from ..core.fileio import atomic_path
from ..sim.textures.similarity import BINS as SCORE_BINS
from .features import ColourTexture, _cone_axes, _half, _reachable_cone_bins, _soft_histogram

VERSION = 1
BINS = 16  # per sRGB channel
PRIOR = 0.25  # per roof kind, for a colour without evidence
PRIOR_COUNT = 10.0  # pixels' worth of evidence the prior is worth
KINDS = ("flat", "sloped")
WEIGHT_POWER = 4.0  # a pixel counts p(kind) ** WEIGHT_POWER in its kind's histogram
LIKELIHOOD_FILE = f"roof-likelihood-v{VERSION}.pt"


def _bin_index(level1: torch.Tensor) -> torch.Tensor:
    """(N, H, W) index of each pixel's 16^3 sRGB bin; ``level1`` is (N, 3, H, W) in [0, 1]."""
    q = (level1.clamp(0.0, 1.0) * BINS).long().clamp_(max=BINS - 1)
    return (q[:, 0] * BINS + q[:, 1]) * BINS + q[:, 2]


def _level1(batch: torch.Tensor) -> torch.Tensor:
    """2x2-pixel means of an (N, C, H, W) batch (a last odd row or column is left out)."""
    h, w = batch.shape[-2] - batch.shape[-2] % 2, batch.shape[-1] - batch.shape[-1] % 2
    return _half(batch[..., :h, :w])


class RoofLikelihood:
    """p(roof kind | colour of a 2x2-pixel mean), per 16^3 sRGB bin and roof kind."""

    def __init__(self, tables: torch.Tensor, pixels: int):
        tables = torch.as_tensor(tables, dtype=torch.float32)
        if tables.shape != (len(KINDS), BINS ** 3) or not torch.isfinite(tables).all():
            raise MetaSimError(f"a roof likelihood holds ({len(KINDS)}, {BINS ** 3}) finite probabilities, "
                               f"got {tuple(tables.shape)}")
        self.tables = tables
        self.pixels = int(pixels)
        digest = hashlib.sha256(tables.numpy().tobytes()).hexdigest()[:12]
        self.id = f"roof-colour-v{VERSION}[{BINS}^3,prior{PRIOR:g}x{PRIOR_COUNT:g}]-{digest}"

    @classmethod
    def from_counts(cls, counts: torch.Tensor) -> "RoofLikelihood":
        """From (3, 16^3) pixel counts: all pixels, flat-roof pixels, sloped-roof pixels per bin."""
        counts = counts.double()
        tables = (counts[1:] + PRIOR * PRIOR_COUNT) / (counts[:1] + PRIOR_COUNT)
        return cls(tables.float(), int(round(float(counts[0].sum()))))

    @classmethod
    def fit(cls, paths, progress: Callable[[int], None] | None = None) -> "RoofLikelihood":
        """Counted on meta-sim EXR tiles (their RGB as ``read_image`` gives it, and their roof labels)."""
        from ..sim.imageio import linear_to_srgb
        from ..sim.meshes import FLAT_ROOF, SLOPED_ROOF
        from ..sim.tiles import read_tile

        counts = torch.zeros(3, BINS ** 3, dtype=torch.float64)
        n = 0
        for path in paths:
            tile = read_tile(path)
            rgb = torch.from_numpy(linear_to_srgb(tile.rgb).astype(np.float32)).permute(2, 0, 1)[None]
            labels = torch.from_numpy(np.stack([tile.roof_class == FLAT_ROOF, tile.roof_class == SLOPED_ROOF])
                                      .astype(np.float32))[None]
            index = _bin_index(_level1(rgb)).flatten()
            shares = _level1(labels)[0].flatten(1).double()  # each mean's share of flat / sloped pixels
            counts[0] += torch.bincount(index, minlength=BINS ** 3).double()
            for k in range(len(KINDS)):
                counts[k + 1] += torch.bincount(index, shares[k], minlength=BINS ** 3)
            n += 1
            if progress:
                progress(1)
        if n == 0:
            raise MetaSimError("no training tiles to count roof colours on")
        return cls.from_counts(counts)

    def weights(self, level1: torch.Tensor) -> torch.Tensor:
        """(N, kinds, H, W) likelihood of each roof kind for each pixel of an (N, 3, H, W) batch."""
        return self.tables[:, _bin_index(level1)].permute(1, 0, 2, 3)

    def to_dict(self) -> dict:
        """The tables and pixel count for a checkpoint or the cache; ``from_dict`` reads them back."""
        return {"version": VERSION, "tables": self.tables.clone(), "pixels": self.pixels}

    @classmethod
    def from_dict(cls, data: Mapping) -> "RoofLikelihood":
        """The likelihood ``to_dict`` stored; MetaSimError for another version or tables of the wrong shape."""
        if data.get("version") != VERSION:
            raise MetaSimError(f"roof likelihood version {data.get('version')!r}; this meta-sim reads "
                               f"version {VERSION} (train the model again)")
        return cls(data["tables"], data["pixels"])


# The segmenter (its training recolours the roofs), the segmenter whose training jitters the whole scene's
# colours too (``roofsegment.jitter_scene``), and the colour likelihood.
ROOF_FINDERS = ("segmenter", "colour", "segmenter-jitter")
SEGMENTER_AUGMENT = {"segmenter": "roofs", "segmenter-jitter": "scene"}


def roof_finder_from_dict(data: Mapping):
    """A ``RoofLikelihood`` or a ``roofsegment.RoofSegmenter`` from its ``to_dict()``."""
    if data.get("kind") == "segmenter":
        from .roofsegment import RoofSegmenter

        return RoofSegmenter.from_dict(data)
    return RoofLikelihood.from_dict(data)


def roof_finder_path(folder: Path, finder: str, seed: int, steps: int | None = None) -> Path:
    """Where ``ensure_roof_finder`` caches the roof finder ``finder`` learnt with ``seed`` (a segmenter in
    ``steps`` steps, None: ``roofsegment.STEPS``) in a training set's ``folder``."""
    from .roofsegment import config_id

    if finder in SEGMENTER_AUGMENT:
        return Path(folder) / f"roof-segmenter-{config_id(SEGMENTER_AUGMENT[finder], steps)}-seed{seed}.pt"
    return Path(folder) / LIKELIHOOD_FILE


def ensure_roof_finder(folder: Path, tile_paths: list[Path], finder: str = "segmenter", seed: int = 0,
                       progress: Callable[[int], None] | None = None, steps: int | None = None):
    """A training set's roof finder (``ROOF_FINDERS``: the segmenter, learnt in ``steps`` steps (None:
    ``roofsegment.STEPS``), or the colour likelihood), learnt once on its tiles and cached in its
    ``folder``. ``progress`` gets tiles counted or training steps."""
    if finder not in ROOF_FINDERS:
        raise MetaSimError(f"unknown roof finder {finder!r}; choose one of {', '.join(ROOF_FINDERS)}")
    from .roofsegment import RoofSegmenter

    segmenter = finder in SEGMENTER_AUGMENT
    path = roof_finder_path(folder, finder, seed, steps)
    if path.is_file():
        try:
            data = torch.load(path, weights_only=True)
            if data.get("tiles") == len(tile_paths):
                return roof_finder_from_dict(data)
        except Exception:  # a damaged or outdated cache is learnt again, never trusted
            pass
    started = time.perf_counter()
    if segmenter:
        found = RoofSegmenter.fit(tile_paths, seed, steps, progress=progress, augment=SEGMENTER_AUGMENT[finder])
    else:
        found = RoofLikelihood.fit(tile_paths, progress)
    with atomic_path(path) as tmp:  # with the seconds it took, for the benchmarks' training times
        torch.save({**found.to_dict(), "tiles": len(tile_paths), "seconds": time.perf_counter() - started}, tmp)
    return found


def roof_finder_seconds(folder: Path, finder: str = "segmenter", seed: int = 0,
                        steps: int | None = None) -> float | None:
    """The seconds ``ensure_roof_finder`` took to learn the finder cached in ``folder`` (None when it is
    not cached, or was cached before its time was kept)."""
    try:
        seconds = torch.load(roof_finder_path(folder, finder, seed, steps), weights_only=True).get("seconds")
    except Exception:  # missing or damaged: not known
        return None
    return float(seconds) if isinstance(seconds, float) and math.isfinite(seconds) else None


def roof_weights(finder, level1: torch.Tensor, power: float) -> torch.Tensor:
    """(N, kinds, h, w): ``finder``'s probability of each roof kind for each 2x2 block of ``level1``
    (``_level1`` of an sRGB batch), to ``power``: what a pixel counts in its kind's histograms."""
    weights = finder.weights(level1)
    return weights if power == 1.0 else weights ** power


def per_pixel(weights: torch.Tensor) -> torch.Tensor:
    """(..., h, w) weights of 2x2 blocks -> (..., 2h, 2w), each pixel its block's."""
    return weights.repeat_interleave(2, dim=-2).repeat_interleave(2, dim=-1)


def score_cone_bins() -> torch.Tensor:
    """Mask of the E1/E2 score's HSV-cone bins (``sim.textures.similarity``: 8 x 8 x 8, (x, y) the chroma
    on the hue circle, z the value) that some colour reaches: chroma never exceeds value, so a bin is
    reachable when its (x, y) box comes nearer the axis than the top of its value range."""
    lo = -1.0 + np.arange(SCORE_BINS) * (2.0 / SCORE_BINS)
    hi = lo + 2.0 / SCORE_BINS
    axis_gap = np.where((lo <= 0) & (hi >= 0), 0.0, np.minimum(np.abs(lo), np.abs(hi)))
    top = (np.arange(SCORE_BINS) + 1.0) / SCORE_BINS
    radius = np.hypot(axis_gap[:, None], axis_gap[None, :])
    return torch.from_numpy((radius[:, :, None] < top[None, None, :]).reshape(-1))


def _score_histograms(rgb: torch.Tensor, weights: torch.Tensor, keep: torch.Tensor) -> torch.Tensor:
    """(N, kinds x kept bins): per kind of ``weights`` (N, kinds, H, W), the hard histogram of the
    pixels of ``rgb`` (N, 3, H, W) in the score's HSV cone, each pixel counting its weight, divided by
    the pixel count."""
    n, kinds = weights.shape[:2]
    total = SCORE_BINS ** 3
    index = torch.zeros(n, rgb.shape[-2] * rgb.shape[-1], dtype=torch.long)
    for values, lo, hi, bins in _cone_axes(rgb, SCORE_BINS, 1.0):
        step = ((values.reshape(n, -1) - lo) * (bins / (hi - lo))).floor().clamp_(0, bins - 1).long()
        index = index * bins + step
    index = index + (torch.arange(n) * total).unsqueeze(1)
    parts = [torch.bincount(index.flatten(), weights[:, k].reshape(n, -1).flatten().double(),
                            minlength=n * total).view(n, total)[:, keep] for k in range(kinds)]
    return (torch.cat(parts, dim=1) / index.shape[1]).float()


class RoofColourExtractor:
    """``base``'s features, then per roof kind the colour histogram (488 bins) of the pixels weighted by
    ``finder``'s probability of that roof kind (a ``RoofLikelihood`` or a ``roofsegment.RoofSegmenter``)
    raised to ``power``; with ``score_cone`` then per roof kind the histogram (220 bins) of the
    full-resolution pixels in the score's HSV cone, weighted alike (see the module's docstring)."""

    def __init__(self, base, finder, power: float = WEIGHT_POWER, score_cone: bool = False):
        if not (math.isfinite(power) and power > 0):
            raise MetaSimError(f"the roof weight power must be a positive number, got {power!r}")
        self.base, self.finder, self.power, self.score_cone = base, finder, float(power), bool(score_cone)
        self._keep = _reachable_cone_bins(ColourTexture.COLOUR_BINS, ColourTexture.CHROMA_POWER)
        self._score_keep = score_cone_bins()
        self.hist_blocks = (int(self._keep.sum()),) * len(KINDS)
        if self.score_cone:
            self.hist_blocks += (int(self._score_keep.sum()),) * len(KINDS)
        self.base_dim = base.dim
        self.dim = base.dim + sum(self.hist_blocks)
        self.id = (f"{base.id}+{finder.id}" + (f"^{self.power:g}" if self.power != 1.0 else "")
                   + (f"+score-cone{SCORE_BINS}" if self.score_cone else ""))
        # The histograms do not change under the dihedral views either.
        self.dihedral_invariant = getattr(base, "dihedral_invariant", False)

    def to_dict(self) -> dict:
        """What a checkpoint keeps of the roof-colour part (``checkpoint_extractor`` reads it back):
        the finder's ``to_dict()``, the weight power and whether the score-cone histograms follow."""
        return {**self.finder.to_dict(), "weight_power": self.power, "score_cone": self.score_cone}

    @torch.no_grad()
    def __call__(self, batch: torch.Tensor) -> torch.Tensor:
        return torch.cat([self.base(batch), self.roof_histograms(batch)], dim=1)

    def roof_histograms(self, batch: torch.Tensor) -> torch.Tensor:
        """(N, sum(hist_blocks)): the flat-roof then the sloped-roof histogram (then, with
        ``score_cone``, the same two in the score's cone) of each image of an (N, 3, H, W) sRGB batch,
        each bin divided by the image's pixel count (not made to sum to 1: ``FeatureNorm`` does that
        after the group mean, so that a group pools its tiles' pixels)."""
        parts = []
        for chunk in batch.split(ColourTexture.CHUNK):
            clean = torch.nan_to_num(chunk.float(), nan=0.0).clamp(0.0, 1.0)
            level1 = _level1(clean)
            axes = _cone_axes(level1, ColourTexture.COLOUR_BINS, ColourTexture.CHROMA_POWER)
            weights = roof_weights(self.finder, level1, self.power)
            hists = [_soft_histogram(axes, weights[:, k])[:, self._keep] for k in range(len(KINDS))]
            if self.score_cone:  # a last odd row or column is left out, as by the 2x2 means
                h, w = level1.shape[-2:]
                hists.append(_score_histograms(clean[..., :2 * h, :2 * w], per_pixel(weights), self._score_keep))
            parts.append(torch.cat(hists, dim=1))
        return torch.cat(parts)


def colour_blur(sigma: float, blocks: tuple[int, ...] = (488,)) -> torch.Tensor:
    """A Gaussian blur of ``sigma`` bins over histograms of the widths ``blocks`` (a model's histogram
    blocks, ``FeatureNorm.hist_blocks``), each over its own cone: 488 bins, the stretched cone of 8 x 8 x 8
    (the first histograms); 220, the score's (``score_cone_bins``). Distances are counted in bins on each
    axis; each column sums to 1 so that a histogram keeps its mass. Float64, square, block-diagonal over
    ``blocks``; for ``nams.ColourComparison``. MetaSimError for a sigma or a width it cannot blur."""
    if not (isinstance(sigma, (int, float)) and math.isfinite(sigma) and sigma > 0):
        raise MetaSimError(f"the colour blur's sigma must be a positive number of bins, not {sigma!r}")
    bins = ColourTexture.COLOUR_BINS
    cones = {int(mask.sum()): mask.numpy() for mask in
             (_reachable_cone_bins(bins, ColourTexture.CHROMA_POWER), score_cone_bins())}
    grid = np.stack(np.meshgrid(*(np.arange(bins),) * 3, indexing="ij"), axis=-1).reshape(-1, 3)
    out = torch.zeros(sum(blocks), sum(blocks), dtype=torch.float64)
    start = 0
    for width in blocks:
        if width not in cones:
            raise MetaSimError(f"no colour cone has {width} bins; the roof-colour histograms have "
                               f"{' or '.join(map(str, sorted(cones)))}")
        cells = grid[cones[width]]
        weights = np.exp(-((cells[:, None, :] - cells[None, :, :]) ** 2).sum(axis=-1) / (2.0 * sigma ** 2))
        weights /= weights.sum(axis=0, keepdims=True)
        out[start:start + width, start:start + width] = torch.from_numpy(weights)
        start += width
    return out


def colour_comparison(exponent: float = 0.5, blur_sigma: float = 0.0, blur_weight: float = 0.0,
                      blocks: tuple[int, ...] = (488,), far: tuple[float, float, float, float] | None = None,
                      far_margin: float | None = None, match=None, match_loss: float = math.inf):
    """A ``nams.ColourComparison`` for models with the roof-colour histograms ``blocks``
    (``FeatureNorm.hist_blocks``): the colour error's exponent, and with ``blur_sigma`` > 0 and
    ``blur_weight`` > 0 the histograms also compared blurred by ``colour_blur(blur_sigma, blocks)``. The
    defaults are the plain geometric mean.

    ``far`` (loss, exponent, blur sigma, blur weight): a target whose best design's loss exceeds ``loss`` is
    searched again comparing only the histograms in the score's cone (``score_cone_bins``), with that
    exponent and blur (``ColourComparison.far``), unless the first search's answer is within ``far_margin`` of
    the far search's best (``ColourComparison.far_margin``; None: no such gate). MetaSimError when ``blocks`` has
    no such histograms.

    ``match`` (a ``nams.RoofMatch``, instead of ``far``): a target whose best loss exceeds ``match_loss`` is
    ranked by it, with the same ``far_margin``."""
    from ..nams import ColourComparison

    blocks = tuple(blocks)
    blurred = blur_sigma > 0 and blur_weight > 0
    blur = colour_blur(blur_sigma, blocks) if blurred else None
    if match is not None:
        if far is not None:
            raise MetaSimError("far targets are ranked by a far comparison or by a roof match, not both")
        return ColourComparison(exponent, blur, blur_weight if blurred else 0.0, far_loss=match_loss,
                                far_margin=far_margin, match=match)
    if far is None:
        return ColourComparison(exponent, blur, blur_weight if blurred else 0.0)
    far_loss, far_exponent, far_sigma, far_weight = far
    score_bins = int(score_cone_bins().sum())
    if score_bins not in blocks:
        raise MetaSimError(f"a far-target comparison compares the histograms in the score's cone "
                           f"({score_bins} bins); a model with histogram blocks {blocks} has none")
    keep = torch.cat([torch.full((width,), width == score_bins) for width in blocks])
    far_blurred = far_sigma > 0 and far_weight > 0
    far_blur = None
    if far_blurred:
        far_blur = blur if blurred and far_sigma == blur_sigma else colour_blur(far_sigma, blocks)
    return ColourComparison(exponent, blur, blur_weight if blurred else 0.0,
                            far=ColourComparison(far_exponent, far_blur, far_weight if far_blurred else 0.0, keep),
                            far_loss=far_loss, far_margin=far_margin)


# --- far targets ranked by roof colour under the score's own measure ---------------------------------------
SHIFTS = tuple(np.arange(-16, 9) / 8.0)  # value shifts tried (bins of the score's cone; negative: darker)
MATCH_DESIGNS = 4096  # designs whose predicted histograms fit the shifts (all of a discrete space up to this)


def value_shift(delta: float) -> torch.Tensor:
    """(220, 220) the score cone's histograms moved ``delta`` bins along the value axis (linear between
    bins, the ends held), restricted to its reachable bins: column j is where bin j's mass goes, summing to 1
    less what lands in unreachable bins."""
    keep = score_cone_bins()
    grid = torch.arange(SCORE_BINS ** 3)
    level, rest = grid % SCORE_BINS, grid - grid % SCORE_BINS
    low = math.floor(delta)
    out = torch.zeros(SCORE_BINS ** 3, SCORE_BINS ** 3, dtype=torch.float64)
    for step, share in ((low, 1.0 - (delta - low)), (low + 1, delta - low)):
        if share > 0:
            out[rest + (level + step).clamp(0, SCORE_BINS - 1), grid] += share
    return out[keep][:, keep]


@functools.lru_cache(maxsize=4)
def swatch_histograms(texture_ids: tuple[str, ...]) -> torch.Tensor | None:
    """(textures, 220) each texture's own histogram in the score's cone (``sim.textures.similarity``, what
    E1/E2 rank textures by), read from the default bank the training sets are rendered with; None when one of
    them is not in it."""
    from ..sim.imageio import read_rgb8
    from ..sim.textures import ensure_default_bank
    from ..sim.textures.similarity import hsv_cone_histogram

    bank = ensure_default_bank()
    if not set(texture_ids) <= set(bank.ids()):
        return None
    hists = np.stack([hsv_cone_histogram(read_rgb8(bank.image_path(t))) for t in texture_ids])
    return torch.from_numpy(hists)[:, score_cone_bins()]


def _match_designs(space) -> torch.Tensor:
    """Encoded designs to fit a match's shifts on: every design of a small discrete space, else
    ``MATCH_DESIGNS`` uniform draws (seeded)."""
    from ..nams.search import count_designs, design_grid, uniform_predict

    n = count_designs(space)
    if n is not None and n <= MATCH_DESIGNS:
        return design_grid(space).double()
    draws = uniform_predict(space, MATCH_DESIGNS, torch.Generator().manual_seed(0))
    return torch.from_numpy(np.stack([space.encode(d) for d in draws])).double()


def roof_match(ckpt, swatch_weight: float, unmix: float = 0.0, render_share: float = 0.0):
    """A ``nams.RoofMatch`` for a checkpoint whose features end in the score cone's histograms (None for one
    without, or without a roof-material parameter): per roof kind the parameter whose ``texture_kind`` it is,
    its choices' own histograms (``swatch_histograms``), the histograms the model predicts for each choice
    (mean over ``_match_designs``; a choice none of them has: its own histogram moved back by the shift) and
    the value shift (of ``SHIFTS``) that brings those nearest, by intersection, to the choice's own; ``unmix``
    and ``render_share`` as ``nams.RoofMatch``'s. MetaSimError for a swatch weight, an unmixing or a render
    share outside [0, 1]."""
    from ..nams import RoofMatch
    from ..nams.search import predicted_features, root_histograms
    from ..sim.design import Categorical

    blocks = tuple(ckpt.feature_norm.hist_blocks)
    width = int(score_cone_bins().sum())
    offsets = [sum(blocks[:i]) for i, b in enumerate(blocks) if b == width]
    params = {p.texture_kind: p for p in ckpt.space.parameters
              if isinstance(p, Categorical) and getattr(p, "texture_kind", None)}
    kinds = [(kind, offset) for kind, offset in zip(KINDS, offsets) if kind in params]
    if len(offsets) != len(KINDS) or not kinds:
        return None
    vectors = _match_designs(ckpt.space)
    model = ckpt.model
    lead = model.config.feature_dim - model.config.colour_dims
    predicted = (predicted_features(model, vectors.float(), 4096).double()[:, lead:]
                 * model.feature_scale.double()[lead:])
    slices = {p.name: sl for p, sl in ckpt.space.blocks()}
    out = {"blocks": [], "params": [], "swatches": [], "shifts": [], "renders": []}
    for kind, offset in kinds:
        param = params[kind]
        swatches = swatch_histograms(tuple(param.choices))
        shift, renders = torch.eye(width, dtype=torch.float64), None
        if swatches is not None:
            hists = root_histograms(predicted[:, offset:offset + width])
            choice = vectors[:, slices[param.name]].argmax(dim=1)
            counts = torch.bincount(choice, minlength=param.width)
            seen = counts > 0
            means = torch.zeros(param.width, width, dtype=torch.float64).index_add_(0, choice, hists)
            means = means[seen] / counts[seen, None]
            own = swatches[seen].double()
            agreement = [float(torch.minimum(means @ value_shift(d).T, own).sum(dim=1).mean()) for d in SHIFTS]
            delta = SHIFTS[int(np.argmax(agreement))]  # the first of equals
            shift = value_shift(delta)
            renders = swatches.double() @ value_shift(-delta).T
            renders = renders / renders.sum(dim=1, keepdim=True).clamp_min(1e-300)
            renders[seen] = means
        out["blocks"].append((offset, width))
        out["params"].append(param.name)
        out["swatches"].append(swatches)
        out["shifts"].append(shift)
        out["renders"].append(renders)
    return RoofMatch(tuple(out["blocks"]), tuple(out["params"]), tuple(out["swatches"]), tuple(out["shifts"]),
                     swatch_weight, unmix, tuple(out["renders"]), render_share)


# The search's roof-colour comparison (exponent, blur sigma in bins, blur weight; ``colour_comparison``), and for
# targets far from every design (loss, then the same three over the score cone's histograms alone; for models with
# those histograms), chosen on E1/E2's validation split by `make bench-objective` (docs/design.md, "Roof colour"):
# the comparison on the renders with sun-cast shadows (E2 on heldout-v5), the far search on the older renders with
# E2 on heldout-v4.
SEARCH_COLOUR = (0.35, 2.0, 1.0)
SEARCH_FAR = (10.0, 0.6, 1.0, 10.0)
# How much worse than the far search's best (as a fraction of it, under the far comparison) the first search's
# answer for a far target may be and still be kept (``ColourComparison.far_margin``; None: always ranked again).
SEARCH_FAR_MARGIN: float | None = 0.02
# For a model whose space chooses roof materials: far targets (loss beyond the first) ranked by the roof match
# instead (``roof_match``) with that swatch weight, the first answer kept within the margin (None: never) of the
# match's best, that unmixing and that render share. Chosen on the validation split by `make bench-objective`;
# None: the far comparison above.
SEARCH_MATCH: tuple[float, float, float | None, float, float] | None = (10.0, 1.0, None, 0.5, 0.75)


@functools.lru_cache(maxsize=8)
def _search_colour(blocks: tuple[int, ...]):
    far = SEARCH_FAR if int(score_cone_bins().sum()) in blocks else None
    return colour_comparison(*SEARCH_COLOUR, blocks, far=far, far_margin=SEARCH_FAR_MARGIN if far else None)


_MATCHES: dict = {}  # (model id, swatch weight, unmixing, render share) -> RoofMatch or None, the latest few


def checkpoint_match(ckpt, swatch_weight: float, unmix: float = 0.0, render_share: float = 0.0):
    """``roof_match(ckpt, swatch_weight, unmix, render_share)``, built once per checkpoint and setting (a few
    kept)."""
    key = (ckpt.model_id, float(swatch_weight), float(unmix), float(render_share))
    if key not in _MATCHES:
        while len(_MATCHES) >= 4:
            _MATCHES.pop(next(iter(_MATCHES)))
        _MATCHES[key] = roof_match(ckpt, swatch_weight, unmix, render_share)
    return _MATCHES[key]


def search_colour(ckpt):
    """How the search compares a checkpoint's roof-colour histograms: ``SEARCH_COLOUR`` over its histogram
    blocks; for a model with the score cone's, far targets ranked by the roof match ``SEARCH_MATCH`` when its
    space chooses roof materials, else searched again with ``SEARCH_FAR``; the plain comparison for a model
    without histograms. The blur is one object per layout, so that the exhaustive search blurs a model's design
    table once."""
    from ..nams import PLAIN_COLOUR

    blocks = tuple(ckpt.feature_norm.hist_blocks)
    if not blocks:
        return PLAIN_COLOUR
    base = _search_colour(blocks)
    if SEARCH_MATCH is None or not base.searches_far:
        return base
    loss, weight, margin, unmix, render_share = SEARCH_MATCH
    match = checkpoint_match(ckpt, weight, unmix, render_share)
    if match is None:
        return base
    return dataclasses.replace(base, far=None, far_loss=loss, far_margin=margin, match=match)


def roof_evidence(features: torch.Tensor, extractor) -> dict | None:
    """Per roof kind, (N,) the share of each group's pixels that ``extractor``'s roof finder counts as
    roofs of that kind (each pixel by its probability to the weight power): the sum of the kind's raw
    histogram block in group features (``RoofColourExtractor.roof_histograms``). The histograms are
    compared once they sum to 1, so a share near 0 means the inferred roof colours rest on a few pixels
    (docs/design.md, "On real imagery the roof finder is the weak link"). None for an extractor without
    roof colour."""
    return _evidence(features, tuple(getattr(extractor, "hist_blocks", ())))


def _evidence(features: torch.Tensor, blocks: tuple) -> dict | None:
    """Per roof kind, the sum of its histogram block among the features' trailing ``blocks``."""
    if not blocks:
        return None
    start, out = features.shape[1] - sum(blocks), {}
    for kind, width in zip(KINDS, blocks):
        out[kind] = features[:, start:start + width].sum(dim=1)
        start += width
    return out


# A target group whose roof evidence is below this quantile of the training designs', or above the
# opposite one, is outside what the model saw: its roof finder may be blind to the target's roofs, or see
# roofs everywhere.
EVIDENCE_QUANTILE = 0.05


def training_evidence(features: torch.Tensor, blocks: tuple) -> dict | None:
    """What the checkpoint keeps of its training designs' roof evidence (each design's features being
    the mean over its tiles, as a target group's are): per roof kind its ``EVIDENCE_QUANTILE`` quantile
    ("low"), median and ``1 - EVIDENCE_QUANTILE`` quantile ("high"), and the quantile used. None
    without roof colour."""
    shares = _evidence(features, tuple(blocks))
    if shares is None:
        return None
    out = {"quantile": EVIDENCE_QUANTILE}
    for kind, share in shares.items():
        share = share.double()
        out[kind] = {"low": round(float(torch.quantile(share, EVIDENCE_QUANTILE)), 6),
                     "median": round(float(share.median()), 6),
                     "high": round(float(torch.quantile(share, 1.0 - EVIDENCE_QUANTILE)), 6)}
    return out


def evidence_reference(extra: Mapping) -> dict:
    """Roof kind -> ``(low, high)``, the training designs' range of roof evidence from a checkpoint's
    ``extra`` (``training_evidence``); empty for a checkpoint from before it was kept. A damaged entry (not
    shares in [0, 1] with low <= high) is a MetaSimError: the checkpoint's checksum held, so it was written
    that way."""
    kept = extra.get("roof_evidence")
    if kept is None:
        return {}
    out = {}
    for kind in KINDS:
        entry = kept.get(kind) if isinstance(kept, Mapping) else None
        ends = tuple(entry.get(end) if isinstance(entry, Mapping) else None for end in ("low", "high"))
        if not all(isinstance(v, (int, float)) and not isinstance(v, bool) and 0 <= v <= 1 for v in ends) \
                or ends[0] > ends[1]:
            raise MetaSimError(f"the model's roof_evidence.{kind} must hold shares low <= high in [0, 1], not "
                               f"{entry!r}; retrain it")
        out[kind] = (float(ends[0]), float(ends[1]))
    return out


def finder_agreement(extractor, images, masks) -> dict:
    """How ``extractor``'s roof finder reads labelled imagery: display-sRGB (H, W, 3) images with bool
    building masks, at the pixel size of the training tiles. Per roof kind the share of the pixels it
    counts as that kind (each by its probability to the weight power, as the features count them:
    ``roof_evidence``), beside the true building share; and the IoU, precision and recall of its building
    map (p(flat) + p(sloped) above 0.5, on 2x2-pixel means) against the masks (majority of each 2x2 block)."""
    counted = {kind: 0.0 for kind in KINDS}
    pixels = hits = found = truth = 0
    for image, mask in zip(images, masks):
        batch = torch.from_numpy(np.ascontiguousarray(image, dtype=np.float32)).permute(2, 0, 1)[None]
        level1 = _level1(torch.nan_to_num(batch, nan=0.0).clamp(0.0, 1.0))
        weights = extractor.finder.weights(level1)[0]
        for k, kind in enumerate(KINDS):
            counted[kind] += float((weights[k] ** extractor.power).sum())
        seen = weights.sum(0) > 0.5
        real = _level1(torch.from_numpy(np.asarray(mask, dtype=np.float32))[None, None])[0, 0] > 0.5
        pixels, hits = pixels + seen.numel(), hits + int((seen & real).sum())
        found, truth = found + int(seen.sum()), truth + int(real.sum())
    union = found + truth - hits
    return {"roof_pixels": {kind: counted[kind] / max(pixels, 1) for kind in KINDS},
            "building_share": truth / max(pixels, 1), "iou": hits / union if union else 1.0,
            "precision": hits / found if found else 0.0, "recall": hits / truth if truth else 1.0}


def stored_extractor(spec: str, roof: Mapping | None, weights: Path | None = None):
    """The extractor ``spec`` (``features.make_extractor``), with the roof colour part ``roof`` (a
    ``RoofColourExtractor.to_dict()``, as a checkpoint or a ``FeatureSet`` keeps it) when there is one."""
    from .features import make_extractor

    extractor = make_extractor(spec, weights)
    if roof is not None:  # no power before it was kept: 1; no score cone before it existed
        score_cone = roof.get("score_cone", False)
        if not isinstance(score_cone, bool):
            raise MetaSimError(f"the roof colour's score_cone must be true or false, not {score_cone!r}")
        extractor = RoofColourExtractor(extractor, roof_finder_from_dict(roof), roof.get("weight_power", 1.0),
                                        score_cone)
    return extractor


def checkpoint_extractor(ckpt, weights: Path | None = None):
    """The extractor a checkpoint's features came from: its base extractor, with the roof colour
    part when the checkpoint has one. ``weights``: a backbone's weights file, when it needs one."""
    extractor = stored_extractor(ckpt.extra.get("extractor_spec", "colour-texture"), ckpt.extra.get("roof_likelihood"),
                                 weights)
    if extractor.id != ckpt.extractor_id:
        raise MetaSimError(f"the model was trained on features {ckpt.extractor_id!r} but its extractor now gives "
                           f"{extractor.id!r}; pass the same backbone weights (--weights)")
    return extractor

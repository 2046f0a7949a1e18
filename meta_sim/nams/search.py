"""Inference: from normalised target features to designs.

* ``adjoint_search`` is the paper's neural-adjoint search (section 4): M starts
  per target drawn uniformly in z_mean +- k * z_std, Adam on z through the
  frozen predictor P, the S lowest-loss starts decoded by D and combined by a
  majority vote per categorical parameter (mean for continuous ones). All
  targets and starts run as one (T, M, z_dim) tensor.
* ``exhaustive_search`` scores every design of a small discrete space through
  P(mu(E(d))) and takes the argmin; the table of predictions is computed once
  per model and space.
* ``search`` picks between them (``auto``: exhaustive when the space is
  discrete and small enough).
* ``dr_predict`` and ``uniform_predict`` are the paper's baselines.

Diversify with rejection (paper section 4, eq. for d*; r = 0 for synthetic
targets, 0.25 for real ones): after the search, each target's design d* is
independently replaced, with probability r, by a design drawn uniformly from
the space (u ~ U(0, 1), reject when u < r). It diversifies the population of
designs that the next synthetic dataset is rendered from; it does not change
the vote. ``SearchResult.searched_design`` keeps the search's answer and
``rejected`` says whether ``design`` was replaced.

The loss is the mean squared error of the predicted features in units of
the model's ``feature_scale``; a model whose features end in roof-colour
histograms (``NAMSConfig.colour_dims``, see ``meta_sim.pipeline.roofcolour``) takes
the geometric mean of the error over those and over the rest (``_combined``).
``ColourComparison`` weighs the two differently and can also compare the
histograms blurred over neighbouring colours; its default is the plain
geometric mean.

Targets must be normalised with the checkpoint's ``FeatureNorm``. Every
result is finite, or the call raises MetaSimError.
"""

from __future__ import annotations

import copy
import json
import math
import statistics
import time
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np
import torch

from ..core.errors import MetaSimError
from ..core.progress import Bars
from ..sim.design import Categorical, DesignSpace, diversify
from .model import NAMS, DirectRegression

MAX_EXHAUSTIVE_DESIGNS = 200_000


@dataclass(frozen=True)
class SearchOptions:
    """The neural-adjoint search's settings (the paper's defaults), shared by `infer` and `eval`:
    ``M`` starts drawn in mean +- ``k`` std of the training embeddings, ``iterations`` steps of rate
    ``lr``, the ``S`` best kept, and diversify-with-rejection ``r`` (see ``adjoint_search``)."""

    M: int = 1000
    k: float = 3.0
    S: int = 50
    iterations: int = 200
    lr: float = 0.01
    r: float = 0.0

    def check(self, method: str = "auto") -> None:
        """MetaSimError for settings the search would refuse, so a command fails before any work."""
        _check_common(self.S, self.r)
        if method != "exhaustive":
            _check_adjoint(self.M, self.k, self.S, self.iterations, self.lr)

    def search_options(self) -> dict:
        """The settings as keyword arguments for ``search`` / ``adjoint_search``."""
        return {name: getattr(self, name) for name in ("M", "k", "S", "iterations", "lr", "r")}


@dataclass
class SearchResult:
    """The answer for one target.

    ``votes`` maps each categorical parameter to {choice id: share}, shares
    summing to 1, largest first: among the S kept starts (adjoint), among the
    S best designs (exhaustive), or the regression output (DR). Losses are
    the search objective in normalised feature units (None for DR). ``ranked``
    lists designs with their losses, best first: the S kept starts' own designs
    (adjoint; what the vote summarises) or the best designs (exhaustive).
    """

    design: dict
    votes: dict[str, dict[str, float]]
    best_loss: float | None
    mean_loss: float | None
    method: str
    searched_design: dict
    rejected: bool = False
    ranked: list[tuple[dict, float]] = field(default_factory=list)
    far: bool = False  # ranked again as far from every design (``ColourComparison.far``)

    def to_dict(self) -> dict:
        """Plain JSON-ready values (``ranked`` as a list of {design, loss})."""
        return {"design": self.design, "votes": self.votes, "best_loss": self.best_loss,
                "mean_loss": self.mean_loss, "method": self.method, "searched_design": self.searched_design,
                "rejected": self.rejected, "ranked": [{"design": d, "loss": loss} for d, loss in self.ranked],
                "far": self.far}


# --- shared checks -------------------------------------------------------------------------------
def _targets(targets, feature_dim: int) -> torch.Tensor:
    """(T, F) float32 targets, or a MetaSimError saying what is wrong with them."""
    targets = torch.as_tensor(targets).detach().to(torch.float32)
    if targets.ndim == 1:
        targets = targets.unsqueeze(0)
    if targets.ndim != 2 or targets.shape[0] == 0 or targets.shape[1] != feature_dim:
        raise MetaSimError(f"targets must be (T, {feature_dim}) normalised feature vectors; got shape "
                           f"{tuple(targets.shape)} (was another feature extractor used?)")
    bad = ~torch.isfinite(targets).all(dim=1)
    if bad.any():
        rows = bad.nonzero().flatten().tolist()
        raise MetaSimError(f"target row(s) {rows[:5]}{' ...' if len(rows) > 5 else ''} contain NaN or Inf "
                           f"(or values beyond float32); check those images and the feature extraction")
    return targets


def _check_space(model, space: DesignSpace) -> None:
    if space.dim != model.config.design_dim:
        raise MetaSimError(f"design space {space.name!r} encodes to {space.dim} values; the model was trained "
                           f"on {model.config.design_dim} (use the space stored in its checkpoint)")


def _check_nams(model) -> None:
    if not isinstance(model, NAMS):
        raise MetaSimError(f"this search needs a NAMS model, not {type(model).__name__} (use dr_predict for DR)")


def _check_adjoint(M: int, k: float, S: int, iterations: int, lr: float, boundary_weight: float = 0.1) -> None:
    if M < 1:
        raise MetaSimError(f"M (random starts) must be at least 1, not {M}")
    if S > M:
        raise MetaSimError(f"S must not exceed M (S={S}, M={M})")
    if not (k >= 0 and math.isfinite(k)):
        raise MetaSimError(f"k (start range in latent standard deviations) must be finite and >= 0, not {k}")
    if iterations < 0:
        raise MetaSimError(f"iterations must be at least 0, not {iterations}")
    if not (lr > 0 and math.isfinite(lr) and boundary_weight >= 0):
        raise MetaSimError("lr must be a positive number and boundary_weight non-negative")


def _check_common(S: int, r: float) -> None:
    if S < 1:
        raise MetaSimError(f"S (results kept for the vote) must be at least 1, not {S}")
    if not 0.0 <= r <= 1.0:
        raise MetaSimError(f"r (rejection rate) must be in [0, 1], not {r}")


# --- the objective ------------------------------------------------------------------------------
# Keeps the geometric mean's gradient finite where both errors are 0 (a target P predicts exactly).
GEOMETRIC_MEAN_FLOOR = 1e-30


@dataclass(frozen=True, eq=False)
class RoofMatch:
    """How a target far from every design is ranked: by its roof colours, under the E1/E2 score's own measure
    (the histogram intersection, ``sim.textures.similarity``).

    Per roof kind ``i``: ``blocks[i]`` = (offset among the features' colour values, width) of the kind's
    histogram in the score's colour cone (square roots of a histogram, as ``FeatureNorm`` leaves them), whose
    material the categorical parameter ``params[i]`` chooses; ``swatches[i]`` (choices, width) each choice's
    texture's own histogram in that cone (rows summing to 1; None: no texture to compare with), and
    ``shifts[i]`` (width, width, columns summing to at most 1) what a rendered roof's histogram says its
    texture's is (the renders' roofs are brighter than their textures' images).

    A design's match loss is 1 minus the mean over the kinds of ``(1 - swatch_weight)`` x the intersection of
    the target's histogram with the one the model predicts for the design, plus ``swatch_weight`` x the
    intersection of the target's histogram mapped by ``shifts[i]`` with the design's texture's own: 0 when
    every kind's colours are exactly its design's. The first part ranks the designs as they render; the second
    as the score ranks textures. ``pipeline.roofcolour.roof_match`` builds one for a checkpoint; the reasoning
    is in docs/design.md ("Roof colour").

    ``unmix``: before the second part, each kind's histogram less ``unmix`` times the mean of the other kinds'
    (negative bins cut to 0): the roof finder counts some of a tile's other roofs as roofs of this kind, and a
    texture with their colours is the other roof's, not this one's.

    ``renders[i]`` (choices, width; rows summing to 1, or None) each choice's histogram as it renders: the
    model's predictions averaged over designs with that choice. With ``render_share`` r the second part is
    ``(1 - r)`` x the shifted comparison with the texture's own histogram plus r x the intersection of the
    (unmixed, unshifted) target's histogram with the choice's rendered one: what a texture's colours become in
    a render is learnt from the renders, where the shift only moves them along the value axis.
    """

    blocks: tuple[tuple[int, int], ...]
    params: tuple[str, ...]
    swatches: tuple[torch.Tensor | None, ...]
    shifts: tuple[torch.Tensor, ...]
    swatch_weight: float = 0.5
    unmix: float = 0.0
    renders: tuple[torch.Tensor | None, ...] | None = None
    render_share: float = 0.0

    def __post_init__(self):
        n = len(self.blocks)
        if not n or not (len(self.params) == len(self.swatches) == len(self.shifts) == n):
            raise MetaSimError("a roof match needs, per roof kind, a histogram block, a parameter, swatches (or "
                               "None) and a shift")
        if not (isinstance(self.swatch_weight, (int, float)) and 0.0 <= self.swatch_weight <= 1.0):
            raise MetaSimError(f"the roof match's swatch weight must be between 0 and 1, not {self.swatch_weight!r}")
        if not (isinstance(self.unmix, (int, float)) and 0.0 <= self.unmix <= 1.0):
            raise MetaSimError(f"the roof match's unmixing must be between 0 and 1, not {self.unmix!r}")
        if self.unmix and len({width for _, width in self.blocks}) > 1:
            raise MetaSimError("a roof match unmixes histogram blocks of one width only")
        if not (isinstance(self.render_share, (int, float)) and 0.0 <= self.render_share <= 1.0):
            raise MetaSimError(f"the roof match's render share must be between 0 and 1, not {self.render_share!r}")
        if self.render_share and (self.renders is None or len(self.renders) != n):
            raise MetaSimError("a roof match with a render share needs, per roof kind, its choices' rendered "
                               "histograms (or None)")
        for (_, width), swatches, renders in zip(self.blocks, self.swatches, self.renders or (None,) * n):
            if renders is not None and (swatches is None or renders.shape != swatches.shape
                                        or not torch.isfinite(renders).all() or (renders < 0).any()):
                raise MetaSimError(f"a roof match's rendered histograms must be (choices, {width}) non-negative "
                                   "histograms, one per swatch")
        for (offset, width), swatches, shift in zip(self.blocks, self.swatches, self.shifts):
            if offset < 0 or width < 1:
                raise MetaSimError(f"a roof match's histogram block ({offset}, {width}) is not a block")
            if (shift.shape != (width, width) or not torch.isfinite(shift).all() or (shift < 0).any()
                    or (shift.double().sum(dim=0) > 1 + 1e-6).any()):
                raise MetaSimError(f"a roof match's shift must be a ({width}, {width}) non-negative matrix whose "
                                   "columns sum to at most 1")
            if swatches is not None and (swatches.ndim != 2 or swatches.shape[1] != width
                                         or not torch.isfinite(swatches).all() or (swatches < 0).any()):
                raise MetaSimError(f"a roof match's swatches must be (choices, {width}) non-negative histograms")

    def check(self, colour_dims: int, space: DesignSpace) -> None:
        """MetaSimError when the blocks do not fit a model's ``colour_dims`` or the parameters ``space``."""
        for (offset, width), name, swatches in zip(self.blocks, self.params, self.swatches):
            if offset + width > colour_dims:
                raise MetaSimError(f"the roof match's histogram block ({offset}, {width}) does not fit the model's "
                                   f"{colour_dims} histogram values")
            param = next((p for p in space.parameters if p.name == name), None)
            if not isinstance(param, Categorical):
                raise MetaSimError(f"the roof match compares the choices of {name!r}, which design space "
                                   f"{space.name!r} has no categorical parameter for")
            if swatches is not None and len(swatches) != param.width:
                raise MetaSimError(f"the roof match has {len(swatches)} swatches for {name!r}; it has "
                                   f"{param.width} choices")

    def to_dict(self) -> dict:
        """What a report says about the match."""
        out = {"kinds": len(self.blocks), "params": list(self.params), "swatch_weight": self.swatch_weight,
               "swatches": [s is not None for s in self.swatches]}
        if self.unmix:
            out["unmix"] = self.unmix
        if self.render_share:
            out["render_share"] = self.render_share
        return out

    def losses(self, space: DesignSpace, vectors: torch.Tensor, predicted: torch.Tensor,
               targets: torch.Tensor, chunk: int = 8) -> torch.Tensor:
        """(T, N) float64 match loss of each of N designs (encoded ``vectors``, with ``predicted`` (N,
        colour values), the model's colour values for them) for each of T targets (``targets``, (T, colour
        values)); both in the features' own units (``FeatureNorm``'s, not ``feature_scale``'s)."""
        slices = {p.name: sl for p, sl in space.blocks()}
        total = torch.zeros(len(targets), len(vectors), dtype=torch.float64)
        hists = [root_histograms(targets[:, offset:offset + width]) for offset, width in self.blocks]
        renders = self.renders or (None,) * len(self.blocks)
        for k, ((offset, width), name, swatches, shift) in enumerate(zip(self.blocks, self.params, self.swatches,
                                                                         self.shifts)):
            mine = hists[k]
            weight = self.swatch_weight if swatches is not None else 0.0
            if weight < 1.0:  # the designs' predicted histograms, only where they count
                theirs = root_histograms(predicted[:, offset:offset + width])
                rendered = torch.cat([torch.minimum(mine[i:i + chunk, None, :], theirs[None]).sum(dim=-1)
                                      for i in range(0, len(mine), chunk)])
                total += (1.0 - weight) * rendered
            if weight > 0.0:
                if self.unmix and len(hists) > 1:
                    others = torch.stack([h for j, h in enumerate(hists) if j != k]).mean(dim=0)
                    rest = (mine - self.unmix * others).clamp_min(0.0)
                    mine = rest / rest.sum(dim=-1, keepdim=True).clamp_min(1e-300)
                expected = mine @ shift.double().T
                own = torch.minimum(expected[:, None, :], swatches.double()[None]).sum(dim=-1)  # (T, choices)
                share = self.render_share if renders[k] is not None else 0.0
                if share:
                    as_rendered = torch.minimum(mine[:, None, :], renders[k].double()[None]).sum(dim=-1)
                    own = (1.0 - share) * own + share * as_rendered
                total += weight * own[:, vectors[:, slices[name]].argmax(dim=1)]
        return 1.0 - total / len(self.blocks)


def root_histograms(values: torch.Tensor) -> torch.Tensor:
    """Square-rooted histograms (a prediction may dip below 0: counted as 0) -> histograms summing to 1."""
    h = values.double().clamp_min(0.0).square()
    return h / h.sum(dim=-1, keepdim=True).clamp_min(1e-300)


@dataclass(frozen=True, eq=False)
class ColourComparison:
    """How the search compares a model's roof-colour histograms (the features' last ``colour_dims``).

    The loss is ``rest ** (1 - exponent) * colour ** exponent``, with ``rest`` the error over the other
    features and ``colour`` the error over the histograms plus ``blur_weight`` times the error over the
    histograms blurred: each block of ``blur``'s width (``blur`` maps a block's bins to themselves,
    each column summing to 1) is squared back into a histogram, blurred and square-rooted. Blurred,
    a colour the bank lacks still overlaps the colours near it, where the plain histograms of two
    different colours share nothing and every bank texture is as far as the next. The default
    (exponent 0.5, no blur) is the plain geometric mean of ``_combined``; a blur that fits the
    histograms' bins comes from the features (``pipeline.roofcolour.colour_comparison``).

    ``keep`` (a boolean mask over the ``colour_dims`` histogram values) limits the colour error to some
    histograms (None: all). ``far`` is the comparison for a target far from every design: one whose best
    loss under this comparison exceeds ``far_loss`` is searched again with ``far`` (which has no ``far`` of
    its own), and its ``SearchResult.far`` is True. A target nothing in the bank resembles is then ranked
    by the histograms ``far`` keeps, not by errors over the whole tile that are large for every design.

    ``far_margin`` (None: no gate) keeps the first search's answer for a far target whose best design the far
    comparison finds plausible too: one whose far loss is at most ``1 + far_margin`` times the far search's
    best. A bank texture in a city unlike the training cities is far, yet the first search usually names it
    right; a texture the bank lacks is far, and the first search's answer for it is not what its roof
    colours say.

    ``match`` (instead of ``far``): far targets ranked by a ``RoofMatch`` (roof colours under the score's own
    measure), the margin then in match loss. The adjoint search ranks the match's roof parameters with the
    first answer's other parameters held.
    """

    exponent: float = 0.5
    blur: torch.Tensor | None = None
    blur_weight: float = 0.0
    keep: torch.Tensor | None = None
    far: ColourComparison | None = None
    far_loss: float = math.inf
    far_margin: float | None = None
    match: RoofMatch | None = None

    def __post_init__(self):
        if not (isinstance(self.exponent, (int, float)) and 0.0 < self.exponent < 1.0):
            raise MetaSimError(f"the colour exponent must be between 0 and 1, not {self.exponent!r}")
        if not (isinstance(self.blur_weight, (int, float)) and math.isfinite(self.blur_weight)
                and self.blur_weight >= 0):
            raise MetaSimError(f"the colour blur weight must be finite and at least 0, not {self.blur_weight!r}")
        if self.blur is not None:
            b = self.blur
            if (b.ndim != 2 or b.shape[0] != b.shape[1] or not torch.isfinite(b).all() or (b < 0).any()
                    or not torch.allclose(b.double().sum(dim=0), torch.ones(b.shape[1], dtype=torch.float64),
                                          atol=1e-6)):
                raise MetaSimError("the colour blur must be a square, non-negative matrix whose columns sum to 1")
        if self.keep is not None and (self.keep.dtype != torch.bool or self.keep.ndim != 1 or not self.keep.any()):
            raise MetaSimError("the colour comparison's keep must be a 1-D boolean mask keeping some histogram values")
        if not (isinstance(self.far_loss, (int, float)) and self.far_loss > 0 and not math.isnan(self.far_loss)):
            raise MetaSimError(f"the far-target loss must be a positive number, not {self.far_loss!r}")
        if self.far is not None and (not isinstance(self.far, ColourComparison) or self.far.far is not None):
            raise MetaSimError("the far-target comparison must be a ColourComparison without a far comparison "
                               "of its own")
        if self.match is not None and (not isinstance(self.match, RoofMatch) or self.far is not None):
            raise MetaSimError("a colour comparison ranks far targets by a far comparison or by a roof match, "
                               "not both")
        if self.far_margin is not None and not (isinstance(self.far_margin, (int, float))
                                                and math.isfinite(self.far_margin) and self.far_margin >= 0):
            raise MetaSimError(f"the far-target margin must be a finite number of at least 0 (or None), not "
                               f"{self.far_margin!r}")

    @property
    def blurs(self) -> bool:
        """Whether the blurred histograms count at all."""
        return self.blur is not None and self.blur_weight > 0

    @property
    def searches_far(self) -> bool:
        """Whether targets far from every design are searched again (with ``far``)."""
        return (self.far is not None or self.match is not None) and math.isfinite(self.far_loss)

    def check(self, colour_dims: int) -> None:
        """MetaSimError when the blur or the mask does not fit a model's ``colour_dims`` histogram values."""
        if self.blurs and (not colour_dims or colour_dims % self.blur.shape[0]):
            raise MetaSimError(f"the colour blur has {self.blur.shape[0]} bins per histogram; the model's "
                               f"{colour_dims} histogram values are not whole histograms of that size")
        if self.keep is not None and len(self.keep) != colour_dims:
            raise MetaSimError(f"the colour comparison keeps {len(self.keep)} histogram values; the model has "
                               f"{colour_dims}")
        if self.far is not None:
            self.far.check(colour_dims)
        if self.match is not None and not colour_dims:
            raise MetaSimError("a roof match compares roof-colour histograms; the model has none")

    def to_dict(self) -> dict:
        """What a report says about the comparison (the blur matrix and the mask by their sizes)."""
        out = {"exponent": self.exponent, "blurred": self.blurs, "blur_weight": self.blur_weight}
        if self.keep is not None:
            out["kept_values"] = int(self.keep.sum())
        if self.searches_far:
            out["far_loss"] = self.far_loss
            out["far"] = self.far.to_dict() if self.far is not None else {"match": self.match.to_dict()}
            if self.far_margin is not None:
                out["far_margin"] = self.far_margin
        return out

    def blurred(self, values: torch.Tensor) -> torch.Tensor:
        """(..., colour_dims) square-rooted histograms -> the same, blurred block by block. A negative
        value (a prediction) counts as 0; the square root's floor keeps gradients finite."""
        width = self.blur.shape[0]
        hists = values.clamp_min(0.0).square().unflatten(-1, (-1, width))
        return (hists @ self.blur.T.to(values.dtype) + BLUR_FLOOR).sqrt().flatten(-2)


PLAIN_COLOUR = ColourComparison()
BLUR_FLOOR = 1e-12  # in the blurred histograms' square root (see ColourComparison.blurred)


def _block_mse(diff: torch.Tensor, colour_dims: int, pred: torch.Tensor | None = None,
               target: torch.Tensor | None = None,
               colour: ColourComparison = PLAIN_COLOUR) -> tuple[torch.Tensor, ...]:
    """Mean squared error over the features before the colour histograms, and over those (if any), from
    the differences ``diff``; with ``colour``'s blur also over the blurred histograms of ``pred`` and
    ``target`` (the colour error is then the sum, the blurred one weighed by ``blur_weight``)."""
    squares = diff.square()
    if not colour_dims:
        return (squares.mean(dim=-1),)
    keep = slice(None) if colour.keep is None else colour.keep
    rest, plain = squares[..., :-colour_dims].mean(dim=-1), squares[..., -colour_dims:][..., keep].mean(dim=-1)
    if not colour.blurs:
        return rest, plain
    blurred = (colour.blurred(pred[..., -colour_dims:]) - colour.blurred(target[..., -colour_dims:]))[..., keep]
    return rest, plain + colour.blur_weight * blurred.square().mean(dim=-1)


def _combined(*mses: torch.Tensor, exponent: float = 0.5) -> torch.Tensor:
    """The search's loss from the blocks' errors: the one error, or the weighted geometric mean of two
    (``rest ** (1 - exponent) * colour ** exponent``; by default the plain geometric mean).

    A product does not depend on either block's units, so it needs no
    weight between them, and a far-off target (a texture the bank lacks),
    whose whitened error is huge for every design, is still ranked by its
    roof colours in proportion. The reasoning is in docs/design.md ("Roof
    colour").
    """
    if len(mses) == 1:
        return mses[0]
    if exponent == 0.5:
        return (mses[0] * mses[1] + GEOMETRIC_MEAN_FLOOR).sqrt()
    return (mses[0] + GEOMETRIC_MEAN_FLOOR) ** (1 - exponent) * (mses[1] + GEOMETRIC_MEAN_FLOOR) ** exponent


def _pairwise_mse(a: torch.Tensor, b: torch.Tensor, a_sq: torch.Tensor | None = None,
                  b_sq: torch.Tensor | None = None) -> torch.Tensor:
    """(T, F) and (N, F) -> (T, N) mean squared differences, from the rows' squared norms (``a_sq`` (T, 1)
    and ``b_sq`` (N,), computed when not given)."""
    a_sq = a.square().sum(dim=1, keepdim=True) if a_sq is None else a_sq
    b_sq = b.square().sum(dim=1) if b_sq is None else b_sq
    return (a_sq - 2 * a @ b.T + b_sq).clamp_min(0.0) / a.shape[1]


# --- voting --------------------------------------------------------------------------------------
def _vote(space: DesignSpace, vectors: torch.Tensor) -> list[tuple[dict, dict]]:
    """Majority vote over ranked design vectors (T, S, dim), best first, per parameter.

    A categorical tie goes to the choice held by the best-ranked start;
    continuous parameters take the mean of the clipped values.
    """
    T, S, _ = vectors.shape
    winner_vec = torch.zeros(T, space.dim, dtype=torch.float64)
    shares: list[dict] = [{} for _ in range(T)]
    ranks = torch.arange(S).expand(T, S)
    for p, sl in space.blocks():
        if isinstance(p, Categorical):
            picks = vectors[..., sl].argmax(dim=-1)  # (T, S)
            counts = torch.zeros(T, p.width, dtype=torch.long).scatter_add_(1, picks, torch.ones_like(picks))
            first = torch.full((T, p.width), S).scatter_reduce_(1, picks, ranks, reduce="amin")
            score = counts * (S + 1) + (S - first)
            winner_vec[:, sl] = torch.nn.functional.one_hot(score.argmax(dim=1), p.width).double()
            for t in range(T):
                present = counts[t].nonzero().flatten().tolist()
                present.sort(key=lambda c: -int(score[t, c]))
                shares[t][p.name] = {p.choices[c]: int(counts[t, c]) / S for c in present}
        else:
            winner_vec[:, sl.start] = vectors[..., sl.start].double().clamp(0.0, 1.0).mean(dim=1)
    return [(space.decode(winner_vec[t].numpy()), shares[t]) for t in range(T)]


def near_designs(results: list[SearchResult], n: int) -> list[dict]:
    """The designs a search's answers stand for, where one design per target would hide what the search
    could not tell apart: each target's ``n`` best-ranked designs (its answer alone where the search ranks
    none, as DR), in target order. A population drawn from them keeps the spread of the parameters the
    targets do not pin down, and each target's answer where they agree."""
    if n < 1:
        raise MetaSimError(f"near designs: n must be at least 1, not {n}")
    return [dict(design) for r in results for design in ([d for d, _ in r.ranked[:n]] or [r.design])]


class TorchDraws:
    """The draws ``sim.design`` samples with (``integers``, ``uniform``, ``random`` as a numpy Generator
    has them), taken from a ``torch.Generator`` (None: torch's global one): the searches keep their
    torch streams and share the one sampler."""

    def __init__(self, generator: torch.Generator | None):
        self.generator = generator

    def integers(self, high: int, size: int | None = None):
        return self._one(torch.randint(high, (1 if size is None else size,), generator=self.generator), size)

    def random(self, size: int | None = None):
        return self._one(torch.rand(1 if size is None else size, generator=self.generator, dtype=torch.float64),
                         size)

    def uniform(self, low: float, high: float, size: int | None = None):
        values = [low + u * (high - low) for u in self.random(1 if size is None else size)]
        return values[0] if size is None else values

    @staticmethod
    def _one(draws: torch.Tensor, size: int | None):
        values = draws.tolist()
        return values[0] if size is None else values


def uniform_predict(space: DesignSpace, n: int, generator: torch.Generator | None = None) -> list[dict]:
    """``n`` designs drawn uniformly from the space (the paper's Uniform baseline)."""
    return space.sample(TorchDraws(generator), n, order="parameter")


def _diversify(results: list[SearchResult], space: DesignSpace, r: float,
               generator: torch.Generator | None) -> list[SearchResult]:
    """Diversify with rejection: with probability r, a target's design is replaced by a uniform draw."""
    drawn = diversify(space, TorchDraws(generator), len(results), r, lambda k: results[k].design, coins_first=True)
    for result, (design, replaced) in zip(results, drawn):
        if replaced:
            result.design, result.rejected = design, True
    return results


# --- neural adjoint ------------------------------------------------------------------------------
def adjoint_search(model: NAMS, targets, space: DesignSpace, M: int = 1000, k: float = 3.0, S: int = 50,
                   iterations: int = 200, lr: float = 0.01, r: float = 0.0,
                   generator: torch.Generator | None = None, dtype: torch.dtype = torch.float32,
                   boundary_weight: float = 0.1, bars: Bars | None = None,
                   max_rows: int = 16384, colour: ColourComparison = PLAIN_COLOUR) -> list[SearchResult]:
    """Neural-adjoint search for every target row; one SearchResult per row.

    The per-start objective is MSE(P(z), target), measured in units of the
    model's ``feature_scale``, + boundary_weight * sum_j relu(|z_j - z_mean_j|
    - k z_std_j) (the Neural-Adjoint boundary loss). Gradients are taken on the sum over starts, and Adam acts per
    element, so starts are independent. Starts are ranked by the objective
    recomputed at the final z. ``dtype`` (e.g. torch.bfloat16) is the dtype
    of the networks' forward passes; z, Adam's state and the losses stay
    float32. Targets are processed in groups of at most ``max_rows`` starts
    to bound memory; the answer does not depend on the grouping. ``colour`` says how the roof-colour
    histograms are compared (``ColourComparison``); the targets it finds far from every design are
    searched again with its ``far`` comparison, from new starts.
    """
    _check_nams(model)
    _check_space(model, space)
    _check_common(S, r)
    _check_adjoint(M, k, S, iterations, lr, boundary_weight)
    colour.check(model.config.colour_dims)
    if colour.match is not None:
        colour.match.check(model.config.colour_dims, space)
    targets = _targets(targets, model.config.feature_dim)

    results = _adjoint_pass(model, targets, space, M, k, S, iterations, lr, generator, dtype, bars, max_rows,
                            boundary_weight, colour)
    far = [t for t, result in enumerate(results) if colour.searches_far and result.best_loss > colour.far_loss]
    if far and colour.match is not None:
        for t in far:
            matched = _match_roofs(model, space, results[t], targets[t], colour.match, colour.far_margin, S)
            if matched is not None:
                results[t] = matched
    elif far:
        found = _adjoint_pass(model, targets[far], space, M, k, S, iterations, lr, generator, dtype, bars, max_rows,
                              boundary_weight, colour.far)
        ranked_far = [True] * len(far)
        if colour.far_margin is not None:  # the first answer kept where the far comparison finds it plausible
            firsts = design_losses(model, space, [results[t].design for t in far], targets[far], colour.far)
            agains = design_losses(model, space, [result.design for result in found], targets[far], colour.far)
            ranked_far = (firsts > (1 + colour.far_margin) * agains).tolist()
        for t, result, again in zip(far, found, ranked_far):
            if again:
                result.far = True
                results[t] = result
    return _diversify(results, space, r, generator)


def _match_roofs(model: NAMS, space: DesignSpace, first: SearchResult, target: torch.Tensor, match: RoofMatch,
                 margin: float | None, S: int) -> SearchResult | None:
    """The far target ``target``'s design by ``match``: every combination of the match's roof parameters with
    ``first``'s other parameters, the best by match loss (None when ``first`` is within ``margin`` of it)."""
    base = torch.from_numpy(space.encode(first.design)).double()
    slices = {p.name: (p, sl) for p, sl in space.blocks()}
    names = list(dict.fromkeys(match.params))
    choices = torch.cartesian_prod(*[torch.arange(slices[n][0].width) for n in names]).reshape(-1, len(names))
    vectors = base.repeat(len(choices), 1)
    for column, name in enumerate(names):
        sl = slices[name][1]
        vectors[:, sl] = torch.nn.functional.one_hot(choices[:, column], sl.stop - sl.start).double()
    lead = model.config.feature_dim - model.config.colour_dims
    scale = model.feature_scale.double()[lead:]
    predicted = predicted_features(model, vectors.float(), 4096).double()[:, lead:] * scale
    target = target.double()[None, lead:]
    losses = match.losses(space, vectors, predicted, target)[0]
    order = torch.argsort(losses, stable=True)
    if margin is not None:
        mine = losses[(vectors == base).all(dim=1)]
        if len(mine) and float(mine[0]) <= (1 + margin) * float(losses[order[0]]):
            return None
    kept = order[:min(S, len(order))]
    (design, shares), = _vote(space, vectors[kept][None])
    ranked = [(space.decode(vectors[i].numpy()), float(losses[i])) for i in kept[:10].tolist()]
    return SearchResult(design=dict(ranked[0][0]), votes=shares, best_loss=ranked[0][1],
                        mean_loss=float(losses[kept].mean()), method=first.method, searched_design=dict(ranked[0][0]),
                        ranked=ranked, far=True)


def design_losses(model: NAMS, space: DesignSpace, designs: list[dict], targets,
                  colour: ColourComparison = PLAIN_COLOUR) -> torch.Tensor:
    """(T,) the search's loss (float64, in units of ``feature_scale``, under ``colour``) of ``designs[t]`` for
    target row ``t``: the model's features for the design (its encoding's mean) against the target."""
    _check_nams(model)
    _check_space(model, space)
    targets = _targets(targets, model.config.feature_dim).double() / model.feature_scale.double()
    if len(designs) != len(targets):
        raise MetaSimError(f"{len(designs)} designs for {len(targets)} targets")
    colour.check(model.config.colour_dims)
    vectors = torch.from_numpy(np.stack([space.encode(d) for d in designs]))
    pred = predicted_features(model, vectors, len(vectors)).double()
    return _combined(*_block_mse(pred - targets, model.config.colour_dims, pred, targets, colour),
                     exponent=colour.exponent)


def _adjoint_pass(model: NAMS, targets: torch.Tensor, space: DesignSpace, M: int, k: float, S: int,
                  iterations: int, lr: float, generator: torch.Generator | None, dtype: torch.dtype,
                  bars: Bars | None, max_rows: int, boundary_weight: float,
                  colour: ColourComparison) -> list[SearchResult]:
    """``adjoint_search`` with one comparison, before diversifying."""
    # Frozen copies in the search dtype; the caller's model is left as it is.
    predictor, decoder = (copy.deepcopy(m).eval().requires_grad_(False).to(dtype)
                          for m in (model.predictor, model.decoder))
    mean, std = model.z_mean.detach().float(), model.z_std.detach().float()
    feature_scale = model.feature_scale.detach().float()
    colour_dims = model.config.colour_dims
    half_width = k * std
    # All starts are drawn up front, so grouping targets below cannot change them.
    starts = mean + (2 * torch.rand((len(targets), M, model.config.z_dim), generator=generator) - 1) * half_width
    per_group = max(1, max_rows // M)
    groups = [slice(i, i + per_group) for i in range(0, len(targets), per_group)]
    progress = bars("search", iterations * len(groups)) if bars is not None and iterations else None
    results: list[SearchResult] = []
    for rows in groups:
        z = starts[rows].clone().requires_grad_(True)
        target = targets[rows].double() / feature_scale.double()
        # A huge target would overflow the squared error in float32. Dividing each
        # target's whole objective by its scale^2 leaves Adam's steps unchanged
        # (Adam is invariant to a constant gradient scale) and keeps them finite.
        scale64 = target.abs().amax(dim=1).clamp_min(1.0)[:, None]
        target_scaled = (target / scale64).float()[:, None, :]
        inv_scale = (1 / scale64).float()

        def objective(z: torch.Tensor, inv_scale=inv_scale,
                      target_scaled=target_scaled) -> tuple[torch.Tensor, torch.Tensor]:
            pred = predictor(z.to(dtype)).float() / feature_scale * inv_scale[:, :, None]
            mse_scaled = _combined(*_block_mse(pred - target_scaled, colour_dims, pred, target_scaled, colour),
                                   exponent=colour.exponent)
            boundary = torch.relu((z - mean).abs() - half_width).sum(dim=-1)
            return mse_scaled, boundary

        optimiser = torch.optim.Adam([z], lr=lr, betas=(0.9, 0.999))
        for _ in range(iterations):
            mse_scaled, boundary = objective(z)
            loss = (mse_scaled + boundary_weight * boundary * inv_scale.square()).sum()
            (grad,) = torch.autograd.grad(loss, z)
            z.grad = grad
            optimiser.step()
            if progress is not None:
                progress(1)
        with torch.no_grad():
            mse_scaled, boundary = objective(z)
            losses = mse_scaled.double() * scale64.square() + boundary_weight * boundary.double()
            losses = torch.where(torch.isfinite(losses), losses, torch.full_like(losses, math.inf))
            kept_loss, kept = torch.topk(losses, S, dim=1, largest=False, sorted=True)
            if torch.isinf(kept_loss).any():
                raise MetaSimError(f"the search diverged (fewer than S={S} starts kept a finite loss); lower lr "
                                   f"or check that the checkpoint and targets match")
            kept_z = torch.gather(z.detach(), 1, kept[:, :, None].expand(-1, -1, z.shape[-1]))
            vectors = torch.sigmoid(decoder(kept_z.to(dtype)).float())
        for (design, shares), loss, kept_vectors in zip(_vote(space, vectors), kept_loss, vectors.double().numpy()):
            ranked = [(space.decode(vector), float(value)) for vector, value in zip(kept_vectors, loss)]
            results.append(SearchResult(design=design, votes=shares, best_loss=float(loss[0]),
                                        mean_loss=float(loss.mean()), method="adjoint",
                                        searched_design=dict(design), ranked=ranked))
    return results


# --- exhaustive ----------------------------------------------------------------------------------
class DesignTable(NamedTuple):
    """Every design of a space, encoded, with P(mu(E(d))) in units of the model's ``feature_scale``
    and its squared norms (float64; (n, 2): the features before the colour histograms, and those)."""

    designs: torch.Tensor
    features: torch.Tensor
    sq_norms: torch.Tensor


def count_designs(space: DesignSpace) -> int | None:
    """How many designs a discrete space has; None if it has a continuous parameter."""
    if not all(isinstance(p, Categorical) for p in space.parameters):
        return None
    return math.prod(p.width for p in space.parameters)


def design_grid(space: DesignSpace) -> torch.Tensor:
    """Every design of a discrete space, encoded (n, space.dim): the last parameter's choice varies
    fastest, so the rows reshape to a (width_1, ..., width_k) grid."""
    n = count_designs(space)
    if n is None:
        raise MetaSimError(f"{space.name!r} has continuous parameters; its designs cannot be enumerated")
    index = torch.cartesian_prod(*[torch.arange(p.width) for p in space.parameters]).reshape(n, -1)
    designs = torch.zeros(n, space.dim)
    rows = torch.arange(n)
    for column, (_, sl) in enumerate(space.blocks()):
        designs[rows, sl.start + index[:, column]] = 1.0
    return designs


def design_table(model: NAMS, space: DesignSpace, limit: int = MAX_EXHAUSTIVE_DESIGNS,
                 batch: int = 4096) -> DesignTable:
    """P(mu(E(d))) / feature_scale for every design of ``space``.

    Cached on the model (an eval-mode model only); ``model.train()`` and
    ``model.load_state_dict()`` drop the cache. Edit weights in place any
    other way and the cache is stale: call ``model.train()`` first.
    """
    _check_nams(model)
    _check_space(model, space)
    n = count_designs(space)
    if n is None:
        raise MetaSimError(f"exhaustive search needs a discrete design space; {space.name!r} has continuous "
                           f"parameters (use the adjoint search)")
    if n > limit:
        raise MetaSimError(f"design space {space.name!r} has {n:,} designs; exhaustive search enumerates at "
                           f"most {limit:,} (use the adjoint search)")
    key = json.dumps(space.to_dict(), sort_keys=True)
    cached = model._design_tables.get(key)
    if cached is not None:
        return cached
    designs = design_grid(space)
    features = predicted_features(model, designs, batch)
    if not torch.isfinite(features).all():
        raise MetaSimError("the model predicts NaN/Inf features for some designs; the checkpoint is unusable")
    lead = model.config.feature_dim - model.config.colour_dims
    squares = features.double().square()
    table = DesignTable(designs, features, torch.stack([squares[:, :lead].sum(dim=1), squares[:, lead:].sum(dim=1)], 1))
    if not model.training:  # a model in training mode may change: nothing is kept for it
        model._design_tables[key] = table
    return table


def predicted_features(model: NAMS, vectors: torch.Tensor, batch: int) -> torch.Tensor:
    """(N, F) the model's features for encoded designs (their encodings' means), in units of ``feature_scale``,
    computed in eval mode ``batch`` designs at a time; the model is left in the mode it was in."""
    was_training = model.training
    model.eval()
    with torch.no_grad():
        features = torch.cat([model.predict(model.encode(vectors[i:i + batch])[0])
                              for i in range(0, len(vectors), batch)]) / model.feature_scale
    if was_training:
        model.train()
    return features


# Blurred and kept tables (``_blurred_table``, ``_kept_colours``) kept per model, the most recent first: a search
# reuses its own comparison's, while a grid of comparisons (bench-objective scores some 250) kept one per comparison
# for ever and filled 20 GB.
DERIVED_TABLES_KEPT = 8


def _keep_derived(model: NAMS, key: tuple, value) -> None:
    """Keep ``value`` under ``key`` beside the design tables, dropping the oldest derived tables beyond
    ``DERIVED_TABLES_KEPT`` (the design tables themselves, keyed by a space's JSON, stay)."""
    tables = model._design_tables
    tables.pop(key, None)
    derived = [k for k in tables if isinstance(k, tuple)]
    for old in derived[:max(0, len(derived) - DERIVED_TABLES_KEPT + 1)]:
        del tables[old]
    tables[key] = value


def _blurred_table(model: NAMS, space: DesignSpace, table: DesignTable, colour: ColourComparison,
                   lead: int) -> torch.Tensor:
    """The design table's histograms blurred by ``colour``, cached beside the table per blur matrix (a search
    of one target group would otherwise blur every design's histograms again, the bulk of its time)."""
    key = ("blurred", json.dumps(space.to_dict(), sort_keys=True), id(colour.blur))
    cached = model._design_tables.get(key)
    if cached is not None and cached[0] is colour.blur and cached[1] is table.features:
        return cached[2]
    blurred = colour.blurred(table.features[:, lead:].double())
    if not model.training:  # kept with the blur itself, so that its id is not another's
        _keep_derived(model, key, (colour.blur, table.features, blurred))
    return blurred


def _kept_colours(model: NAMS, space: DesignSpace, table: DesignTable, colour: ColourComparison,
                  lead: int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor | None]:
    """The design table's histogram values that ``colour`` keeps (float64), their squared norms and (with a
    blur) the kept values of the blurred table, cached beside the table like ``_blurred_table``."""
    key = ("kept", json.dumps(space.to_dict(), sort_keys=True), id(colour))
    cached = model._design_tables.get(key)
    if cached is not None and cached[0] is colour and cached[1] is table.features:
        return cached[2]
    kept = table.features[:, lead:][:, colour.keep].double()
    blurred = _blurred_table(model, space, table, colour, lead)[:, colour.keep] if colour.blurs else None
    out = (kept, kept.square().sum(dim=1), blurred)
    if not model.training:
        _keep_derived(model, key, (colour, table.features, out))
    return out


def _table_losses(model: NAMS, space: DesignSpace, table: DesignTable, targets: torch.Tensor,
                  colour: ColourComparison, batch: int) -> torch.Tensor:
    """(T, n) the search's loss of every design of ``table`` for each target row (in units of
    ``feature_scale``, float64), under ``colour``, ``batch`` designs at a time."""
    lead = model.config.feature_dim - model.config.colour_dims
    coloured = bool(model.config.colour_dims)
    keep = coloured and colour.keep is not None
    blur = colour.blurs and coloured
    if keep:
        kept, kept_sq, blurred_table = _kept_colours(model, space, table, colour, lead)
        target_colours = targets[:, lead:][:, colour.keep]
    else:
        target_colours = targets[:, lead:]
        if blur:
            blurred_table = _blurred_table(model, space, table, colour, lead)
    sq_targets = [targets[:, :lead].square().sum(dim=1, keepdim=True),
                  target_colours.square().sum(dim=1, keepdim=True)]
    if blur:  # the blurred histograms, compared like the plain ones
        blurred_targets = colour.blurred(targets[:, lead:])
        if keep:
            blurred_targets = blurred_targets[:, colour.keep]

    def block_mses(rows: slice) -> list[torch.Tensor]:
        features = table.features[rows].double()
        mses = [_pairwise_mse(targets[:, :lead], features[:, :lead], sq_targets[0], table.sq_norms[rows, 0])]
        if not coloured:
            return mses
        if keep:
            mses.append(_pairwise_mse(target_colours, kept[rows], sq_targets[1], kept_sq[rows]))
        else:
            mses.append(_pairwise_mse(target_colours, features[:, lead:], sq_targets[1], table.sq_norms[rows, 1]))
        if blur:
            mses[1] = mses[1] + colour.blur_weight * _pairwise_mse(blurred_targets, blurred_table[rows])
        return mses

    return torch.cat([_combined(*block_mses(slice(i, i + batch)), exponent=colour.exponent)
                      for i in range(0, len(table.designs), batch)], dim=1)


def exhaustive_search(model: NAMS, targets, space: DesignSpace, S: int = 50, top: int = 10, r: float = 0.0,
                      generator: torch.Generator | None = None, batch: int = 16384,
                      colour: ColourComparison = PLAIN_COLOUR) -> list[SearchResult]:
    """The design whose predicted features are nearest (MSE in units of ``feature_scale``) to each target.

    ``ranked`` lists the ``top`` best designs with their losses; the vote
    shares are the distribution of each parameter among the ``S`` best
    designs (at most the number of designs). Distances are computed in
    float64, ``batch`` designs at a time, for all targets at once. ``colour``
    says how the roof-colour histograms are compared (``ColourComparison``); the targets it finds far
    from every design are ranked again by its ``far`` comparison.
    """
    _check_common(S, r)
    if top < 1:
        raise MetaSimError(f"top must be at least 1, not {top}")
    colour.check(model.config.colour_dims)
    if colour.match is not None:
        colour.match.check(model.config.colour_dims, space)
    table = design_table(model, space)
    targets = _targets(targets, model.config.feature_dim).double() / model.feature_scale.double()
    n = len(table.designs)
    losses = _table_losses(model, space, table, targets, colour, batch)
    far = torch.zeros(len(targets), dtype=torch.bool)
    if colour.searches_far:
        far = losses.min(dim=1).values > colour.far_loss
        if far.any():
            if colour.match is not None:
                lead = model.config.feature_dim - model.config.colour_dims
                scale = model.feature_scale.double()[lead:]
                far_losses = colour.match.losses(space, table.designs, table.features[:, lead:].double() * scale,
                                                 targets[far][:, lead:] * scale)
            else:
                far_losses = _table_losses(model, space, table, targets[far], colour.far, batch)
            if colour.far_margin is not None:  # the first answer kept where the far comparison finds it plausible
                first = far_losses.gather(1, losses[far].argmin(dim=1, keepdim=True))[:, 0]
                ranked_far = first > (1 + colour.far_margin) * far_losses.min(dim=1).values
                far[far.nonzero()[:, 0][~ranked_far]] = False
                far_losses = far_losses[ranked_far]
            losses[far] = far_losses
    keep = min(max(S, top), n)
    kept_loss, kept = torch.topk(losses, keep, dim=1, largest=False, sorted=True)
    s = min(S, n)
    votes = _vote(space, table.designs[kept[:, :s]])
    results = []
    for t, (_, shares) in enumerate(votes):
        ranked = [(space.decode(table.designs[i].numpy()), float(loss))
                  for i, loss in zip(kept[t, :top].tolist(), kept_loss[t, :top].tolist())]
        results.append(SearchResult(design=dict(ranked[0][0]), votes=shares, best_loss=ranked[0][1],
                                    mean_loss=float(kept_loss[t, :s].mean()), method="exhaustive",
                                    searched_design=dict(ranked[0][0]), ranked=ranked, far=bool(far[t])))
    return _diversify(results, space, r, generator)


# --- entry points --------------------------------------------------------------------------------
def resolve_method(space: DesignSpace, method: str) -> str:
    """"auto" becomes "exhaustive" for a discrete space of at most MAX_EXHAUSTIVE_DESIGNS, else "adjoint".

    The exhaustive search was made the default on E1/E2's validation split (docs/design.md, "Splits")."""
    if method not in ("auto", "adjoint", "exhaustive"):
        raise MetaSimError(f"unknown search method {method!r}; use auto, adjoint or exhaustive")
    if method != "auto":
        return method
    n = count_designs(space)
    return "exhaustive" if n is not None and n <= MAX_EXHAUSTIVE_DESIGNS else "adjoint"


def search(model: NAMS, targets, space: DesignSpace, method: str = "auto", *, S: int = 50, r: float = 0.0,
           generator: torch.Generator | None = None, top: int = 10, M: int = 1000, k: float = 3.0,
           iterations: int = 200, lr: float = 0.01, dtype: torch.dtype = torch.float32,
           boundary_weight: float = 0.1, bars: Bars | None = None,
           colour: ColourComparison = PLAIN_COLOUR) -> list[SearchResult]:
    """Search designs for the target rows with ``method`` ("auto", "adjoint" or "exhaustive", see
    ``resolve_method``); adjoint-only options are ignored by exhaustive. One SearchResult per row;
    MetaSimError for an unknown method, bad options, or targets that do not fit the model."""
    if resolve_method(space, method) == "exhaustive":
        return exhaustive_search(model, targets, space, S=S, top=top, r=r, generator=generator, colour=colour)
    return adjoint_search(model, targets, space, M=M, k=k, S=S, iterations=iterations, lr=lr, r=r,
                          generator=generator, dtype=dtype, boundary_weight=boundary_weight, bars=bars,
                          colour=colour)


@torch.no_grad()
def dr_predict(model: DirectRegression, targets, space: DesignSpace) -> list[SearchResult]:
    """The direct-regression baseline: one forward pass, argmax per categorical block.

    Vote shares are the regression outputs of each block clipped at 0 and
    normalised (MSE regression onto a one-hot block estimates its choice
    probabilities).
    """
    if not isinstance(model, DirectRegression):
        raise MetaSimError(f"dr_predict needs a DirectRegression model, not {type(model).__name__}")
    _check_space(model, space)
    targets = _targets(targets, model.config.feature_dim)
    was_training = model.training
    model.eval()
    out = model(targets).double()
    model.train(was_training)
    if not torch.isfinite(out).all():
        raise MetaSimError("the DR model predicts NaN/Inf for these targets; the checkpoint is unusable")
    results = []
    for row in out:
        shares = {}
        for p, sl in space.blocks():
            if isinstance(p, Categorical):
                weights = row[sl].clamp_min(0.0)
                if weights.sum() <= 0:  # nothing positive: all weight on the argmax
                    weights = torch.nn.functional.one_hot(row[sl].argmax(), p.width).double()
                weights = weights / weights.sum()
                order = torch.argsort(weights, descending=True, stable=True).tolist()
                shares[p.name] = {p.choices[c]: float(weights[c]) for c in order if weights[c] > 0}
        design = space.decode(row.numpy())
        results.append(SearchResult(design=design, votes=shares, best_loss=None, mean_loss=None, method="dr",
                                    searched_design=dict(design)))
    return results


def time_search(model: NAMS, space: DesignSpace, method: str = "auto", n_targets: int = 1, repeats: int = 1,
                seed: int = 0, **options) -> float:
    """Wall seconds per target of ``search`` on random normalised targets, median over ``repeats``.

    Paid-once costs are left out: the exhaustive design table is built, and
    an adjoint search runs one iteration (creating the kernels for these
    shapes), before the clock starts.
    """
    targets = torch.randn(n_targets, model.config.feature_dim, generator=torch.Generator().manual_seed(seed))
    method = resolve_method(space, method)
    if method == "exhaustive":
        design_table(model, space)
    else:
        search(model, targets, space, method, **{**options, "iterations": 1})
    times = []
    for _ in range(repeats):
        started = time.perf_counter()
        search(model, targets, space, method, generator=torch.Generator().manual_seed(seed), **options)
        times.append((time.perf_counter() - started) / n_targets)
    return statistics.median(times)

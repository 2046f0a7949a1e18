"""Feature normalisation: what every feature vector goes through before NAMS sees it.

Standardisation, then optionally a projection on principal components whitened by the simulation
noise (what the design does not explain), so that the search's squared error is a Mahalanobis
distance under that noise; roof-colour histograms are normalised and square-rooted first.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Mapping

import torch

from ..core.errors import MetaSimError


@dataclass(frozen=True)
class FeatureNorm:
    """Per-dimension standardisation fitted on the training features, optionally followed by
    PCA whitening onto the leading ``components``.

    A constant dimension gets std 1 (it carries no information and must not
    blow up a target that differs there); other stds are clamped below by eps.
    Whitening exists for the search: its MSE over the standardised features is
    dominated by many correlated, noisy dimensions, while unit-variance
    principal components weigh every independent direction once.

    Noise whitening (``designs`` given) goes one step further: within the
    components it whitens by the covariance of the simulation noise -- what
    the city, the tile and the view add to a design's features -- so that
    the search's squared error is the Mahalanobis distance under that noise
    and a direction the noise moves a lot counts little. The noise is the
    residual of an additive least-squares fit of the components to the
    encoded designs (with an intercept), its covariance taken
    over the residual degrees of freedom and shrunk by ``shrink`` towards its
    mean variance. With fewer residual degrees of freedom than components,
    only half as many components as there are degrees of freedom are kept,
    so that the noise covariance stays well estimated; with fewer than 2 the
    total spread is used (``noise_whitened`` is then False). The reasoning is
    in docs/design.md ("Feature space").

    Histogram blocks (``hist_blocks``, the widths of the features' trailing
    histograms, e.g. ``pipeline.roofcolour.RoofColourExtractor``'s two roof-colour
    histograms) are neither standardised nor whitened: each is made to sum
    to 1 and square-rooted (its Euclidean distances are then Hellinger
    distances), and all are multiplied by one ``hist_scale`` that gives them
    the same total variance over the training rows as the leading part. A
    colour the training set never showed is then as far from every bank
    texture as its histogram says, where whitening would keep only the
    directions the training set varies in.
    """

    mean: torch.Tensor
    std: torch.Tensor
    components: torch.Tensor | None = None  # (k, dim): standardised features -> whitened components
    noise_whitened: bool = False
    hist_blocks: tuple[int, ...] = ()
    hist_scale: float = 1.0

    @classmethod
    def fit(cls, features: torch.Tensor, eps: float = 1e-6, whiten: int = 0,
            designs: torch.Tensor | None = None, shrink: float = 0.03,
            hist_blocks: tuple[int, ...] = ()) -> "FeatureNorm":
        """Fit on training ``features`` (N, dim). ``whiten`` > 0 keeps that many principal components;
        ``designs`` (N, design_dim), given with it, whitens them by the simulation noise. The last
        ``hist_blocks`` widths of the features are histograms. Raises MetaSimError when the blocks do
        not fit the features."""
        hist_blocks = tuple(int(b) for b in hist_blocks)
        lead = features.shape[1] - sum(hist_blocks)
        if min(hist_blocks, default=1) < 1 or lead < 1:
            raise MetaSimError(f"histogram blocks {list(hist_blocks)} do not fit {features.shape[1]} features")
        if len(features) and bool((features.amax(dim=0) == features.amin(dim=0)).all()):
            raise MetaSimError(f"the {len(features)} training feature vectors are all the same: no feature tells "
                               "one design from another, so nothing can be learnt (are the training tiles blank, "
                               "or all of one design?)")
        norm = cls._fit_lead(features[:, :lead], eps, whiten, designs, shrink)
        if not hist_blocks:
            return norm
        lead_spread = norm.apply(features[:, :lead]).double().var(dim=0, unbiased=False).sum()
        hists = _sqrt_histograms(features[:, lead:], hist_blocks).double()
        hist_spread = hists.var(dim=0, unbiased=False).sum()
        scale = float((lead_spread / hist_spread).sqrt()) if hist_spread > 0 and lead_spread > 0 else 1.0
        return dataclasses.replace(norm, hist_blocks=hist_blocks, hist_scale=scale)

    @classmethod
    def _fit_lead(cls, features: torch.Tensor, eps: float, whiten: int, designs: torch.Tensor | None,
                  shrink: float) -> "FeatureNorm":
        x = features.double()
        mean = x.mean(dim=0)
        std = x.std(dim=0, unbiased=False).clamp_min(eps)
        constant = x.amax(dim=0) == x.amin(dim=0)
        std = torch.where(constant, torch.ones_like(std), std)
        components = None
        if whiten > 0:
            _, singular, v = torch.linalg.svd((x - mean) / std, full_matrices=False)
            spread = singular / math.sqrt(len(x))
            # Directions without spread in the training set cannot be whitened.
            keep = min(whiten, int((spread > eps * spread[0].clamp_min(eps)).sum()))
            if keep == 0:  # every leading dimension constant (the histograms vary): nothing to whiten
                return cls(mean.float(), std.float())
            dof = None if designs is None else _residual_dof(designs)
            if dof is not None and 2 <= dof < keep:
                keep = dof // 2  # what the noise covariance can be estimated for (see the class docstring)
            components = v[:keep] / spread[:keep, None]
            noise = None if dof is None else _noise_whitening(((x - mean) / std) @ components.T,
                                                              designs, dof, shrink)
            if noise is not None:
                components = noise @ components
            return cls(mean.float(), std.float(), components.float(), noise is not None)
        return cls(mean.float(), std.float(), components)

    @property
    def hist_dim(self) -> int:
        """How many of ``apply``'s values (the last ones) are histogram bins."""
        return sum(self.hist_blocks)

    @property
    def dim(self) -> int:
        """How many values ``apply`` returns per feature vector."""
        return (self.mean.shape[0] if self.components is None else self.components.shape[0]) + self.hist_dim

    def apply(self, features: torch.Tensor) -> torch.Tensor:
        """Raw features (..., dim) -> normalised (..., ``self.dim``); MetaSimError if their width is not
        the one this normalisation was fitted on (features from another extractor)."""
        features = torch.as_tensor(features, dtype=torch.float32)
        lead = self.mean.shape[0]
        if features.shape[-1] != lead + self.hist_dim:
            raise MetaSimError(f"features have {features.shape[-1]} dimensions; this model was trained "
                               f"on {lead + self.hist_dim} (was another feature extractor used?)")
        standardised = (features[..., :lead] - self.mean) / self.std
        out = standardised if self.components is None else standardised @ self.components.T
        if not self.hist_blocks:
            return out
        hists = _sqrt_histograms(features[..., lead:], self.hist_blocks) * self.hist_scale
        return torch.cat([out, hists], dim=-1)

    def to_dict(self) -> dict:
        """Tensors and plain values for a checkpoint; ``from_dict`` reads them back."""
        out = {"mean": self.mean.clone(), "std": self.std.clone()}
        if self.components is not None:
            out["components"] = self.components.clone()
            out["noise_whitened"] = self.noise_whitened
        if self.hist_blocks:
            out["hist_blocks"] = list(self.hist_blocks)
            out["hist_scale"] = self.hist_scale
        return out

    @classmethod
    def from_dict(cls, data: Mapping) -> "FeatureNorm":
        """The normalisation ``to_dict`` stored; MetaSimError if it is missing, malformed or not finite."""
        try:
            mean = torch.as_tensor(data["mean"], dtype=torch.float32)
            std = torch.as_tensor(data["std"], dtype=torch.float32)
            components = data.get("components")
            if components is not None:
                components = torch.as_tensor(components, dtype=torch.float32)
        except (KeyError, TypeError, ValueError, RuntimeError) as exc:
            raise MetaSimError(f"feature normalisation is unreadable ({exc})") from None
        if mean.ndim != 1 or mean.shape != std.shape:
            raise MetaSimError("feature normalisation: mean and std must be vectors of one length")
        if not (torch.isfinite(mean).all() and torch.isfinite(std).all() and (std > 0).all()):
            raise MetaSimError("feature normalisation has NaN/Inf or non-positive std")
        if components is not None and (components.ndim != 2 or components.shape[1] != mean.shape[0]
                                       or not torch.isfinite(components).all()):
            raise MetaSimError("feature normalisation: the whitening components do not fit the features")
        hist_blocks = tuple(int(b) for b in data.get("hist_blocks", ()))
        hist_scale = float(data.get("hist_scale", 1.0))
        if min(hist_blocks, default=1) < 1 or not (math.isfinite(hist_scale) and hist_scale > 0):
            raise MetaSimError("feature normalisation: the histogram blocks or their scale are invalid")
        return cls(mean, std, components, bool(data.get("noise_whitened", False)), hist_blocks, hist_scale)


# The smallest histogram total that is normalised; below it (no pixel counted) a histogram reads all 0.
HIST_TOTAL_MIN = 1e-12


def _sqrt_histograms(counts: torch.Tensor, blocks: tuple[int, ...]) -> torch.Tensor:
    """Each block of ``counts`` (..., sum(blocks)) made to sum to 1 and square-rooted (non-finite -> 0)."""
    counts = torch.nan_to_num(counts.float(), nan=0.0, posinf=0.0, neginf=0.0).clamp_min(0.0)
    parts = [part / part.sum(dim=-1, keepdim=True).clamp_min(HIST_TOTAL_MIN)
             for part in counts.split(list(blocks), dim=-1)]
    return torch.cat(parts, dim=-1).sqrt()


# A ridge just big enough to make the one-hot blocks and the intercept (collinear) solvable; a larger
# one would leave part of the design effect in the residual and count it as noise.
NOISE_RIDGE = 1e-9


def _with_intercept(designs: torch.Tensor) -> torch.Tensor:
    designs = torch.as_tensor(designs, dtype=torch.float64)
    return torch.cat([designs, torch.ones(len(designs), 1, dtype=torch.float64)], 1)


def _residual_dof(designs: torch.Tensor) -> int:
    """Rows minus the rank of the additive model of the designs (with an intercept)."""
    return len(designs) - int(torch.linalg.matrix_rank(_with_intercept(designs)))


def _noise_whitening(components: torch.Tensor, designs: torch.Tensor, dof: int,
                     shrink: float) -> torch.Tensor | None:
    """(k, k) matrix W with W C W^T = I for C the (shrunk) covariance of what an additive model
    of the designs (``dof`` residual degrees of freedom) leaves unexplained in ``components``
    (n, k); None when it cannot be estimated."""
    n, k = components.shape
    a = _with_intercept(designs)
    if dof < k:
        return None
    gram = a.T @ a
    gram = gram + NOISE_RIDGE * gram.diagonal().mean() * torch.eye(a.shape[1], dtype=torch.float64)
    residual = components - a @ torch.linalg.solve(gram, a.T @ components)
    cov = residual.T @ residual / dof
    cov = (1.0 - shrink) * cov + shrink * cov.diagonal().mean() * torch.eye(k, dtype=torch.float64)
    values, vectors = torch.linalg.eigh(cov)
    if not bool(values[0] > 0) or not torch.isfinite(values).all():
        return None
    return vectors.T / values.sqrt()[:, None]

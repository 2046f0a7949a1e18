"""Training NAMS and the direct-regression baseline on (design, feature) pairs.

``train_nams`` / ``train_dr`` take encoded designs (N, design_dim) and raw
features (N, feature_dim), and return a ``Fit``: the trained model (eval mode,
best validation weights restored), the ``FeatureNorm`` fitted on the training
split (search targets must go through ``norm.apply``) and a history dict of
plain Python values.

Simulations with NaN/Inf anywhere are dropped here and only here, with a
warning. Everything random (split, shuffling, initial weights, dropout, the
reparameterisation noise) follows from ``TrainConfig.seed``; the global torch
RNG is seeded inside a fork, so the caller's RNG state is left untouched.
"""

from __future__ import annotations

import copy
import dataclasses
import math
import time
import warnings
from dataclasses import asdict, dataclass
from typing import Callable, Mapping, NamedTuple

import torch

from ..core.errors import MetaSimError
from .model import NAMS, DirectRegression, DRConfig, NAMSConfig, build_model
from .norm import FeatureNorm

# What early stopping, model selection and the LR plateau watch on the validation
# split: the total loss, or "mse" (P's error for NAMS, the whole loss for DR).
# NAMS's total is dominated by the design BCE (lambda_D = 1 against lambda_P =
# 0.005), which levels off long before P does, so stopping on it leaves P, the
# only network the search uses, undertrained.
MONITORS = ("loss", "mse")


@dataclass(frozen=True)
class TrainConfig:
    """Optimiser and stopping settings.

    The paper trains NAMS with Adam, batch 64, for 50,000 epochs and gives no
    learning rate; DR with lr 1e-3, batch 1000, an 80/20 split and a
    "regularizer strength of 0.5" it does not define (``weight_decay`` is
    there for it; 0 by default). Here both default to lr 1e-3, batch 64, a
    10% validation split and early stopping on the validation MSE.
    ``whiten`` > 0 whitens the features onto that many principal components
    (see FeatureNorm); the model's feature_dim follows the normalisation.
    ``whiten_noise`` then whitens those components by the simulation noise
    (the spread of the features a design does not explain; see FeatureNorm)
    rather than by their total spread, with ``noise_shrink`` of the noise
    covariance's mean variance mixed into its diagonal.
    ``plateau_factor`` > 0 turns on ReduceLROnPlateau on the validation loss.

    Patience 60 with the learning rate halved after 15 epochs without
    progress, rather than patience 20 at a fixed rate: P keeps improving
    slowly for hundreds of epochs, and a short patience stops it early.

    ``__post_init__`` raises MetaSimError for a setting out of range; ``from_dict`` also for an
    unknown option name.
    """

    lr: float = 1e-3
    batch_size: int = 64
    val_fraction: float = 0.1
    max_epochs: int = 1000
    patience: int = 60
    min_delta: float = 0.0
    weight_decay: float = 0.0
    plateau_factor: float = 0.5
    plateau_patience: int = 15
    monitor: str = "mse"
    whiten: int = 128
    whiten_noise: bool = True
    noise_shrink: float = 0.03
    seed: int = 0
    norm_eps: float = 1e-6

    def __post_init__(self):
        if not (self.lr > 0 and self.batch_size >= 2 and self.max_epochs >= 1 and self.patience >= 1):
            raise MetaSimError("lr must be positive, batch_size at least 2, max_epochs and patience at least 1")
        if not 0.0 <= self.val_fraction < 1.0:
            raise MetaSimError(f"val_fraction must be in [0, 1), not {self.val_fraction}")
        if self.whiten < 0:
            raise MetaSimError(f"whiten (principal components kept, 0 = off) must be >= 0, not {self.whiten}")
        if not 0.0 <= self.noise_shrink <= 1.0:
            raise MetaSimError(f"noise_shrink must be in [0, 1], not {self.noise_shrink}")
        if self.monitor not in MONITORS:
            raise MetaSimError(f"monitor must be one of {', '.join(MONITORS)}, not {self.monitor!r}")
        if not 0.0 <= self.plateau_factor < 1.0:
            raise MetaSimError(f"plateau_factor must be in [0, 1) (0 = off), not {self.plateau_factor}")

    def to_dict(self) -> dict:
        """Plain values (stored in the training history)."""
        return asdict(self)

    @classmethod
    def from_dict(cls, data: Mapping) -> "TrainConfig":
        """A config from plain values; MetaSimError for an unknown option or an invalid value."""
        unknown = set(data) - set(cls.__dataclass_fields__)
        if unknown:
            raise MetaSimError(f"unknown training option(s) {', '.join(sorted(unknown))}")
        return cls(**data)


class EpochReport(NamedTuple):
    """What ``on_epoch`` is told after each epoch."""

    epoch: int
    max_epochs: int
    train_loss: float
    val_loss: float
    best_epoch: int
    lr: float


class Fit(NamedTuple):
    """What training returns: the model (eval mode, best validation weights), the ``FeatureNorm``
    fitted on the training split, and the history (per-epoch losses, best epoch, seconds, row counts)."""

    model: NAMS | DirectRegression
    norm: FeatureNorm
    history: dict


def train_nams(designs: torch.Tensor, features: torch.Tensor, model_config: NAMSConfig | None = None,
               config: TrainConfig = TrainConfig(), on_epoch: Callable[[EpochReport], None] | None = None,
               hist_blocks: tuple[int, ...] = ()) -> Fit:
    """Train E, D and P on encoded ``designs`` (N, design_dim) and raw ``features`` (N, feature_dim).

    ``model_config`` defaults to the paper's sizes for these widths; its ``feature_dim`` and
    ``colour_dims`` are replaced by the fitted normalisation's. ``on_epoch`` is called after every
    epoch (progress bars). ``hist_blocks``: the widths of the features' trailing histograms (see
    FeatureNorm); the search compares them apart from the rest (``NAMSConfig.colour_dims``).

    Returns a ``Fit`` whose model also holds the spread of the training embeddings (the search's
    starts) and P's error per feature (the search's units). Rows with NaN/Inf are dropped with a
    warning. Raises MetaSimError when the shapes disagree, no row is finite, too few rows are left
    after the validation split, or the loss diverges.
    """
    designs, features, dropped = _clean(designs, features)
    model_config = model_config or NAMSConfig(design_dim=designs.shape[1], feature_dim=features.shape[1])
    return _fit("nams", model_config, designs, features, config, on_epoch, dropped, hist_blocks)


def train_dr(designs: torch.Tensor, features: torch.Tensor, model_config: DRConfig | None = None,
             config: TrainConfig = TrainConfig(), on_epoch: Callable[[EpochReport], None] | None = None,
             hist_blocks: tuple[int, ...] = ()) -> Fit:
    """Train the direct-regression baseline (normalised features -> design vector, MSE) on encoded
    ``designs`` (N, design_dim) and raw ``features`` (N, feature_dim).

    ``model_config`` defaults to the paper's DR for these widths (its ``feature_dim`` follows the
    fitted normalisation); ``on_epoch`` and ``hist_blocks`` are as for ``train_nams``. Returns a
    ``Fit``; raises MetaSimError in the same cases as ``train_nams``.
    """
    designs, features, dropped = _clean(designs, features)
    model_config = model_config or DRConfig(feature_dim=features.shape[1], design_dim=designs.shape[1])
    return _fit("dr", model_config, designs, features, config, on_epoch, dropped, hist_blocks)


def _clean(designs, features) -> tuple[torch.Tensor, torch.Tensor, int]:
    """Float32 2-D tensors of one length, rows with NaN/Inf dropped (the one place that happens)."""
    designs = torch.as_tensor(designs, dtype=torch.float32)
    features = torch.as_tensor(features, dtype=torch.float32)
    if designs.ndim != 2 or features.ndim != 2 or designs.shape[0] != features.shape[0]:
        raise MetaSimError(f"need designs (N, design_dim) and features (N, feature_dim) with one N; "
                           f"got {tuple(designs.shape)} and {tuple(features.shape)}")
    finite = torch.isfinite(designs).all(dim=1) & torch.isfinite(features).all(dim=1)
    dropped = int((~finite).sum())
    if dropped:
        warnings.warn(f"dropped {dropped} of {len(finite)} simulations with NaN/Inf features or designs",
                      stacklevel=3)
    if dropped == len(finite):
        raise MetaSimError("no simulation has finite features and designs; nothing to train on "
                           "(check the renders and the feature extractor)")
    return designs[finite], features[finite], dropped


def _split(n: int, val_fraction: float, generator: torch.Generator) -> tuple[torch.Tensor, torch.Tensor]:
    order = torch.randperm(n, generator=generator)
    n_val = max(1, round(n * val_fraction)) if val_fraction > 0 else 0
    if n - n_val < 2:
        raise MetaSimError(f"need at least 2 training simulations after the validation split; have {n} "
                           f"in all (render more, or lower val_fraction)")
    return order[n_val:], order[:n_val]


def _fit(kind: str, model_config, designs: torch.Tensor, features: torch.Tensor, config: TrainConfig,
         on_epoch: Callable[[EpochReport], None] | None, dropped: int, hist_blocks: tuple[int, ...] = ()) -> Fit:
    started = time.perf_counter()
    generator = torch.Generator().manual_seed(config.seed)
    train_rows, val_rows = _split(len(designs), config.val_fraction, generator)
    norm = FeatureNorm.fit(features[train_rows], config.norm_eps, config.whiten,
                           designs[train_rows] if config.whiten_noise else None, config.noise_shrink, hist_blocks)
    # With whitening the networks see principal components, as many as the training set has.
    model_config = dataclasses.replace(model_config, feature_dim=norm.dim)
    if kind == "nams":
        model_config = dataclasses.replace(model_config, colour_dims=norm.hist_dim)
    features = norm.apply(features)
    d_train, x_train = designs[train_rows], features[train_rows]
    d_val, x_val = designs[val_rows], features[val_rows]

    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(config.seed)  # initial weights and dropout masks
        model = build_model(kind, model_config)
        # Fused: Adam's update in one pass over each tensor instead of several; the same algorithm, rounded
        # differently, and most of an epoch's time beside the matrix products at these widths.
        optimiser = torch.optim.Adam(model.parameters(), lr=config.lr, weight_decay=config.weight_decay,
                                     fused=True)
        scheduler = (torch.optim.lr_scheduler.ReduceLROnPlateau(
            optimiser, factor=config.plateau_factor, patience=config.plateau_patience)
            if config.plateau_factor > 0 else None)
        history: dict = {"train_loss": [], "val_loss": [], "train_terms": {}, "val_terms": {}}
        best_loss, best_epoch, best_state, waited = math.inf, 0, copy.deepcopy(model.state_dict()), 0
        for epoch in range(1, config.max_epochs + 1):
            train_loss, train_terms = _train_epoch(model, optimiser, d_train, x_train, config, generator, epoch)
            if len(val_rows):
                val_loss, val_terms = _evaluate(model, d_val, x_val)
            else:  # no validation split asked for: stop on the training loss
                val_loss, val_terms = train_loss, train_terms
            _append(history, train_loss, train_terms, val_loss, val_terms)
            watched = val_loss if config.monitor == "loss" else val_terms[config.monitor]
            if watched < best_loss - config.min_delta:
                best_loss, best_epoch, waited = watched, epoch, 0
                best_state = copy.deepcopy(model.state_dict())
            else:
                waited += 1
            if scheduler is not None:
                scheduler.step(watched)
            if on_epoch is not None:
                on_epoch(EpochReport(epoch, config.max_epochs, train_loss, val_loss, best_epoch,
                                     optimiser.param_groups[0]["lr"]))
            if waited >= config.patience:
                break
    model.load_state_dict(best_state)
    model.eval()
    if isinstance(model, NAMS):
        _store_search_stats(model, d_train, designs, features)
    history.update(best_epoch=best_epoch, best_val_loss=best_loss, epochs=epoch,
                   stopped_early=epoch < config.max_epochs, seconds=time.perf_counter() - started,
                   n_train=len(train_rows), n_val=len(val_rows), n_dropped=dropped,
                   train_config=config.to_dict())
    return Fit(model, norm, history)


def _train_epoch(model, optimiser, designs, features, config: TrainConfig, generator: torch.Generator,
                 epoch: int) -> tuple[float, dict]:
    model.train()
    order = torch.randperm(len(designs), generator=generator)
    total, terms_sum, seen = 0.0, {}, 0
    for start in range(0, len(order), config.batch_size):
        rows = order[start:start + config.batch_size]
        if len(rows) < 2:  # BatchNorm cannot normalise one sample; it is reshuffled into the next epoch
            continue
        loss, terms = model.loss(designs[rows], features[rows], generator)
        if not torch.isfinite(loss):
            raise MetaSimError(f"training diverged (loss {loss.item()}) in epoch {epoch}; "
                               f"lower the learning rate")
        optimiser.zero_grad(set_to_none=True)
        loss.backward()
        optimiser.step()
        total += loss.item() * len(rows)
        for name, value in terms.items():
            terms_sum[name] = terms_sum.get(name, 0.0) + value * len(rows)
        seen += len(rows)
    return total / seen, {name: value / seen for name, value in terms_sum.items()}


@torch.no_grad()
def _evaluate(model, designs, features, chunk: int = 4096) -> tuple[float, dict]:
    """Loss in eval mode (z = mu, no dropout), weighted over chunks."""
    model.eval()
    total, terms_sum = 0.0, {}
    for start in range(0, len(designs), chunk):
        loss, terms = model.loss(designs[start:start + chunk], features[start:start + chunk])
        n = len(designs[start:start + chunk])
        total += loss.item() * n
        for name, value in terms.items():
            terms_sum[name] = terms_sum.get(name, 0.0) + value * n
    n = len(designs)
    return total / n, {name: value / n for name, value in terms_sum.items()}


def _append(history: dict, train_loss: float, train_terms: dict, val_loss: float, val_terms: dict) -> None:
    history["train_loss"].append(train_loss)
    history["val_loss"].append(val_loss)
    for key, terms in (("train_terms", train_terms), ("val_terms", val_terms)):
        for name, value in terms.items():
            history[key].setdefault(name, []).append(value)


# The search draws its starts uniformly in mean +- k * std of these embeddings;
# a collapsed dimension keeps a tiny positive std so that k * std stays defined.
Z_STD_MIN = 1e-6
# Floor of the per-feature error scale, in normalised feature units: a feature P
# happens to fit almost exactly must not get an unbounded weight in the search.
FEATURE_SCALE_MIN = 0.03


@torch.no_grad()
def _store_search_stats(model: NAMS, train_designs: torch.Tensor, designs: torch.Tensor,
                        features: torch.Tensor) -> None:
    """z_mean/z_std from the training split; feature_scale from P's error over all rows.

    The error scale uses the validation rows too: a variance per feature needs
    more rows than the validation split alone has, and scales estimated from
    that split alone are too noisy to weigh the search by.
    """
    mu, _ = model.encode(train_designs)
    model.z_mean.copy_(mu.mean(dim=0))
    model.z_std.copy_(mu.std(dim=0, unbiased=False).clamp_min(Z_STD_MIN))
    error = model.predict(model.encode(designs)[0]) - features
    scale = error.square().mean(dim=0)
    colour = model.config.colour_dims
    if colour:  # one scale for the histograms: per-bin scales would weigh rare colours up (see FeatureNorm)
        scale[-colour:] = scale[-colour:].mean()
    model.feature_scale.copy_(scale.sqrt().clamp_min(FEATURE_SCALE_MIN))

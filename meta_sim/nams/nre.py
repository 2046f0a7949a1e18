"""The sbi baseline: neural ratio estimation over the whole design grid, with the `sbi` package.

A classifier learns the log ratio log r(d, x) = log p(x | d) / p(x) between the joint distribution of
(design, features) pairs and the product of their marginals, from the training set's pairs alone:
sbi's ``NRE_C`` (contrastive NRE, Miller et al. 2022) contrasts each pair with ``num_classes`` designs
drawn from the rest of its batch and with one drawn independently, a loss whose optimum is the exact
ratio. The design d is the space's encoding (one-hot per categorical parameter), the features x are
the training set's, normalised as NAMS normalises them (the NAMS checkpoint's ``FeatureNorm``); neither
is z-scored again inside the network (a one-hot column the training set rarely holds would blow up).

Inference evaluates r for every design of the space and every target: with the training set's
uniform prior over the grid, log r(d, x) is the log posterior up to a constant (sbi's
``RatioBasedPotential`` adds the log prior, a constant here, and samples with MCMC; enumerating the
grid needs neither). The design is the argmax; each parameter's posterior marginal, the log-sum-exp
of the normalised grid over the other parameters, gives its vote shares. So the baseline needs a
discrete space small enough to enumerate, like the exhaustive search; a space with continuous
parameters raises MetaSimError.

``sbi`` (the ``sbi`` extra) is imported only when a classifier is built or trained.
"""

from __future__ import annotations

import contextlib
import io
import math
import time
import warnings
from dataclasses import asdict, dataclass
from typing import Callable, Mapping, NamedTuple

import torch
from torch import nn

from ..core.errors import MetaSimError
from ..core.extras import require
from ..sim.design import Categorical, DesignSpace
from .search import MAX_EXHAUSTIVE_DESIGNS, SearchResult, _check_space, _targets, count_designs, design_grid
from .train import _clean

KIND = "sbi_nre"
CLASSIFIERS = ("resnet", "mlp", "linear")
MIN_SPLIT_ROWS = 3


def _positive_int(value, name: str) -> None:
    if isinstance(value, bool) or not isinstance(value, int) or value < 1:
        raise MetaSimError(f"{name} must be an integer of at least 1, not {value!r}")


@dataclass(frozen=True)
class NREConfig:
    """The classifier: one of sbi's (``CLASSIFIERS``) with ``hidden`` units per layer, on a design
    vector of ``design_dim`` values beside a normalised feature vector of ``feature_dim``."""

    design_dim: int
    feature_dim: int
    classifier: str = "resnet"
    hidden: int = 256

    def __post_init__(self):
        for name in ("design_dim", "feature_dim", "hidden"):
            _positive_int(getattr(self, name), name)
        if self.classifier not in CLASSIFIERS:
            raise MetaSimError(f"unknown sbi classifier {self.classifier!r}; use one of {', '.join(CLASSIFIERS)}")

    def to_dict(self) -> dict:
        """Plain values for a checkpoint."""
        return asdict(self)

    @classmethod
    def from_dict(cls, data: Mapping) -> "NREConfig":
        """A config from ``to_dict``'s values; MetaSimError for an unknown key or an invalid value."""
        unknown = set(data) - set(cls.__dataclass_fields__)
        if unknown:
            raise MetaSimError(f"unknown sbi classifier option(s) {', '.join(sorted(unknown))}")
        try:
            return cls(**data)
        except TypeError as exc:
            raise MetaSimError(f"sbi classifier options are incomplete ({exc})") from None


@dataclass(frozen=True)
class NRETrainConfig:
    """How sbi's ``NRE_C.train`` runs: ``num_classes`` contrasting designs per pair and ``gamma`` (the
    weight of the dependently drawn classes against the independent one), Adam at ``lr`` on batches of
    ``batch_size`` pairs, a ``val_fraction`` validation split, stopping after ``patience`` epochs
    without a better validation loss or at ``max_epochs``. sbi's ``gamma``, ``lr`` and split; more
    contrasts, smaller batches and more patience than sbi's defaults (5, 200, 20), which stop a few
    hundred training designs short of learning them (docs/design.md, "sbi baseline"). Everything random
    follows from ``seed``."""

    num_classes: int = 10
    gamma: float = 1.0
    batch_size: int = 64
    lr: float = 5e-4
    val_fraction: float = 0.1
    patience: int = 50
    max_epochs: int = 2000
    seed: int = 0

    def __post_init__(self):
        for name in ("num_classes", "patience", "max_epochs"):
            _positive_int(getattr(self, name), name)
        if isinstance(self.batch_size, bool) or not isinstance(self.batch_size, int) or self.batch_size < 2:
            raise MetaSimError(f"batch_size must be an integer of at least 2, not {self.batch_size!r}")
        if not (math.isfinite(self.lr) and self.lr > 0 and math.isfinite(self.gamma) and self.gamma > 0):
            raise MetaSimError(f"lr and gamma must be finite and positive, not {self.lr!r} and {self.gamma!r}")
        if not 0.0 < self.val_fraction < 1.0:
            raise MetaSimError(f"val_fraction must be in (0, 1): sbi stops on a validation split, not "
                               f"{self.val_fraction!r}")

    def to_dict(self) -> dict:
        """Plain values (stored in the training history)."""
        return asdict(self)


class RatioClassifier(nn.Module):
    """sbi's ratio estimator behind the project's model interface (``kind``, ``config``), so that the
    checkpoint file stores it as it stores NAMS and DR: ``forward(designs, features)`` is log r."""

    kind = KIND

    def __init__(self, config: NREConfig, estimator: nn.Module | None = None):
        super().__init__()
        self.config = config
        self.estimator = estimator if estimator is not None else build_estimator(config)(
            torch.zeros(2, config.design_dim), torch.zeros(2, config.feature_dim))

    def forward(self, designs: torch.Tensor, features: torch.Tensor) -> torch.Tensor:
        """Encoded designs (N, design_dim) and normalised features (N, feature_dim) -> log r (N,)."""
        return self.estimator(designs, features)


def build_estimator(config: NREConfig):
    """sbi's builder of the classifier ``config`` describes (called with a batch of designs and features,
    from which it reads the input sizes only: no z-scoring, see the module docstring)."""
    require("sbi", "the sbi baseline")
    from sbi.neural_nets import classifier_nn

    return classifier_nn(config.classifier, z_score_theta="none", z_score_x="none", hidden_features=config.hidden)


class _NoLogs:
    """sbi's tracker protocol, keeping nothing: its default writes TensorBoard logs into ./sbi-logs."""

    log_dir = None

    def log_metric(self, name, value, step=None) -> None:
        pass

    def log_metrics(self, metrics, step=None) -> None:
        pass

    def log_params(self, params) -> None:
        pass

    def add_figure(self, name, figure, step=None) -> None:
        pass

    def flush(self) -> None:
        pass


class NREFit(NamedTuple):
    """What ``train_nre`` returns: the classifier (eval mode, best validation weights) and its history."""

    model: RatioClassifier
    history: dict


def check_space(space: DesignSpace) -> int:
    """The number of designs of ``space``; MetaSimError if the baseline cannot enumerate them."""
    continuous = [p.name for p in space.parameters if not isinstance(p, Categorical)]
    if continuous:
        raise MetaSimError(f"the sbi baseline evaluates every design of a discrete space; {space.name!r} has "
                           f"continuous parameter(s) {', '.join(continuous)} (use NAMS's adjoint search there)")
    n = count_designs(space)
    if n > MAX_EXHAUSTIVE_DESIGNS:
        raise MetaSimError(f"design space {space.name!r} has {n:,} designs; the sbi baseline evaluates at most "
                           f"{MAX_EXHAUSTIVE_DESIGNS:,}")
    return n


def train_nre(designs: torch.Tensor, features: torch.Tensor, space: DesignSpace,
              model_config: NREConfig | None = None, config: NRETrainConfig = NRETrainConfig(),
              on_epoch: Callable[[int], None] | None = None) -> NREFit:
    """Train the ratio classifier on encoded ``designs`` (N, space.dim) and normalised ``features``
    (N, F) with sbi's ``NRE_C``.

    ``model_config`` defaults to ``NREConfig`` for these widths; ``on_epoch(1)`` is called after every
    epoch (progress bars). Rows with NaN/Inf are dropped with a
    warning (as for NAMS). On a tiny training set the validation split grows to 3 rows and
    ``num_classes`` is capped so that a batch holds enough other designs to contrast with. The global
    torch RNG is seeded inside a fork, so the result depends on ``config.seed`` only and the caller's
    RNG state is left untouched. Raises MetaSimError for a space the baseline cannot enumerate, shapes
    that disagree with it, or fewer than 6 rows.
    """
    check_space(space)
    designs, features, dropped = _clean(designs, features)
    if designs.shape[1] != space.dim:
        raise MetaSimError(f"designs have {designs.shape[1]} values; space {space.name!r} encodes to {space.dim}")
    n = len(designs)
    # NRE-C contrasts a pair with at least 2 other designs of its batch, so both splits need 3 rows: a
    # tiny training set gets a larger validation split.
    if n < 2 * MIN_SPLIT_ROWS:
        raise MetaSimError(f"the sbi baseline needs at least {2 * MIN_SPLIT_ROWS} simulations with finite "
                           f"features; have {n} (render more designs)")
    val_fraction = max(config.val_fraction, MIN_SPLIT_ROWS / n)
    n_val = n - int((1 - val_fraction) * n)  # sbi's split
    model_config = model_config or NREConfig(design_dim=designs.shape[1], feature_dim=features.shape[1])
    if (model_config.design_dim, model_config.feature_dim) != (designs.shape[1], features.shape[1]):
        raise MetaSimError("the sbi classifier's sizes do not match the designs and features")
    # A pair is contrasted with num_classes + 1 designs of its batch; sbi caps that at the smaller batch.
    num_classes = min(config.num_classes, min(config.batch_size, n_val, n - n_val) - 1)
    require("sbi", "the sbi baseline")
    from sbi.inference import NRE_C

    class Trainer(NRE_C):
        def _summarize_epoch(self, *args, **kwargs) -> None:  # sbi's hook after each epoch
            super()._summarize_epoch(*args, **kwargs)
            if on_epoch is not None:
                on_epoch(1)

    started = time.perf_counter()
    # sbi prints its convergence and warns at max_epochs (the history below records both) and about
    # constant feature dimensions (harmless: nothing is z-scored).
    with (torch.random.fork_rng(devices=[]), contextlib.redirect_stdout(io.StringIO()),
          warnings.catch_warnings()):
        warnings.filterwarnings("ignore", message="Maximum number of epochs")
        warnings.filterwarnings("ignore", message="Data has constant values")
        torch.manual_seed(config.seed)  # split, batches, contrasting draws and initial weights
        trainer = Trainer(classifier=build_estimator(model_config), tracker=_NoLogs(), show_progress_bars=False)
        estimator = trainer.append_simulations(designs, features).train(
            num_classes=num_classes, gamma=config.gamma, training_batch_size=config.batch_size,
            learning_rate=config.lr, validation_fraction=val_fraction, stop_after_epochs=config.patience,
            max_num_epochs=config.max_epochs - 1)  # sbi counts from 0 to max_num_epochs inclusive
    model = RatioClassifier(model_config, estimator).eval()
    summary = trainer._summary
    history = {"train_loss": [float(v) for v in summary["training_loss"]],
               "val_loss": [float(v) for v in summary["validation_loss"]],
               "epochs": int(summary["epochs_trained"][-1]),
               "stopped_early": int(summary["epochs_trained"][-1]) < config.max_epochs,
               "best_val_loss": float(summary["best_validation_loss"][-1]),
               "num_classes": num_classes, "val_fraction": val_fraction, "n_rows": n, "n_dropped": dropped,
               "seconds": time.perf_counter() - started, "train_config": config.to_dict()}
    return NREFit(model, history)


@torch.no_grad()
def log_ratios(model: RatioClassifier, targets, space: DesignSpace, batch: int = 65536) -> torch.Tensor:
    """log r(d, x) for every design d of ``space`` (``design_grid``'s order) and every normalised target
    row x: a (T, designs) float64 tensor. MetaSimError for targets that do not fit, or a non-finite
    output (an unusable checkpoint)."""
    if not isinstance(model, RatioClassifier):
        raise MetaSimError(f"the sbi baseline needs its ratio classifier, not {type(model).__name__}")
    check_space(space)
    _check_space(model, space)
    targets = _targets(targets, model.config.feature_dim)
    grid = design_grid(space)
    model.eval()
    pairs = len(grid)
    out = torch.empty(len(targets), pairs, dtype=torch.float64)
    per_step = max(1, batch // pairs)  # targets per forward pass, each against the whole grid
    for start in range(0, len(targets), per_step):
        chunk = targets[start:start + per_step]
        x = chunk.repeat_interleave(pairs, dim=0)
        d = grid.repeat(len(chunk), 1)
        out[start:start + len(chunk)] = model(d, x).double().reshape(len(chunk), pairs)
    if not torch.isfinite(out).all():
        raise MetaSimError("the sbi classifier gives NaN/Inf log ratios for these targets; the checkpoint is unusable")
    return out


def nre_predict(model: RatioClassifier, targets, space: DesignSpace, top: int = 10) -> list[SearchResult]:
    """The sbi baseline's answer for every normalised target row: the design of the largest log ratio
    (the posterior's mode under the uniform prior); ``votes``: each parameter's posterior marginal
    (normalised grid log-sum-exp'd over the other parameters), largest first, so its first ``top``
    are its top-``top`` ranking; ``ranked``: the ``top`` designs with their negative log posterior as the loss."""
    if top < 1:
        raise MetaSimError(f"top must be at least 1, not {top}")
    log_r = log_ratios(model, targets, space)
    log_post = log_r - torch.logsumexp(log_r, dim=1, keepdim=True)
    grid = design_grid(space)
    shape = tuple(p.width for p in space.parameters)
    keep = min(top, log_post.shape[1])
    results = []
    for row in log_post:
        cube = row.reshape(shape)
        votes = {}
        for axis, p in enumerate(space.parameters):
            others = tuple(a for a in range(len(shape)) if a != axis)
            marginal = torch.logsumexp(cube, dim=others).exp() if others else cube.exp()
            order = torch.argsort(marginal, descending=True, stable=True).tolist()
            votes[p.name] = {p.choices[c]: float(marginal[c]) for c in order if marginal[c] > 0}
        best_loss, best = torch.topk(-row, keep, largest=False, sorted=True)
        ranked = [(space.decode(grid[i].numpy()), float(loss)) for i, loss in zip(best.tolist(), best_loss.tolist())]
        results.append(SearchResult(design=dict(ranked[0][0]), votes=votes, best_loss=ranked[0][1],
                                    mean_loss=float(best_loss.mean()), method=KIND,
                                    searched_design=dict(ranked[0][0]), ranked=ranked))
    return results

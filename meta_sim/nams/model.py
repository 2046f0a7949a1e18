"""The networks: NAMS (encoder E, decoder D, predictor P) and the direct-regression baseline.

Sizes follow the paper (section 5.3): E, D and P each have two hidden layers of
1024 and 2048 units, every one followed by BatchNorm, LeakyReLU(0.2) and
Dropout(0.5); the design embedding z has 10 dimensions. DR has five hidden
layers of 500 units with BatchNorm and ReLU. Every size is a config option.

Architectures (``ARCHITECTURES``, `--architecture`): "paper" is the above.
"factorised" gives each design parameter its own E and D and its own slice
of z. "additive" (the default) also splits P into one network per
parameter's slice of z, summed: a tile's features are close to a sum over
its flat and its sloped roofs, and a sum carries what one texture does to
pairings the training set never rendered, which the joint P does not.
The reasoning is in docs/design.md ("Architectures"); the three compared
on one training set are rows of `make bench-nams` in docs/benchmarks.md.

Loss reductions (the paper does not state them): BCE and MSE are means over
all entries, KL is summed over the z dimensions and averaged over the batch,
so that no term depends on the batch size.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, fields
from typing import Mapping, NamedTuple

import torch
from torch import nn
from torch.nn import functional as F

from ..core.errors import MetaSimError


def _from_dict(cls, data: Mapping):
    """A config dataclass from a plain dict; unknown keys are a user error, not silently dropped."""
    names = {f.name for f in fields(cls)}
    unknown = set(data) - names
    if unknown:
        raise MetaSimError(f"unknown {cls.__name__} option(s) {', '.join(sorted(unknown))}")
    return cls(**data)


def _check_sizes(config, names: tuple[str, ...]) -> None:
    # Frozen dataclass: lists (from JSON or a caller) become the tuple the field promises.
    object.__setattr__(config, "hidden", tuple(int(h) for h in config.hidden))
    for name in names:
        if int(getattr(config, name)) < 1:
            raise MetaSimError(f"{name} must be at least 1, not {getattr(config, name)}")
    if any(int(h) < 1 for h in config.hidden):
        raise MetaSimError(f"hidden layer sizes must be at least 1, not {list(config.hidden)}")


class MLP(nn.Sequential):
    """An nn.Sequential that maps (..., in) to (..., out): BatchNorm1d wants 2-D input, and the
    search feeds (targets, starts, z_dim) tensors."""

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """The layers applied over the last dimension of ``x``, whatever the leading ones."""
        lead = x.shape[:-1]
        return super().forward(x.reshape(-1, x.shape[-1])).reshape(*lead, -1)


def mlp(in_dim: int, hidden: tuple[int, ...], out_dim: int, activation: nn.Module, dropout: float) -> MLP:
    """Linear -> BatchNorm -> activation (-> Dropout) per hidden layer, then a linear output layer."""
    layers: list[nn.Module] = []
    width = in_dim
    for size in hidden:
        layers += [nn.Linear(width, size), nn.BatchNorm1d(size), activation]
        if dropout > 0:
            layers.append(nn.Dropout(dropout))
        width = size
    layers.append(nn.Linear(width, out_dim))
    return MLP(*layers)


class Blockwise(nn.Module):
    """One network per block: input block i (of widths ``in_blocks``) -> output block i. The outputs are
    concatenated, or summed (``sum=True``, outputs of one width: an additive model)."""

    def __init__(self, in_blocks, out_blocks, make, sum: bool = False) -> None:
        super().__init__()
        self.in_blocks, self.sum = tuple(in_blocks), sum
        self.nets = nn.ModuleList(make(i, o) for i, o in zip(in_blocks, out_blocks))

    def parts(self, x: torch.Tensor) -> list[torch.Tensor]:
        """Each block's network applied to its block of ``x``: one output per block."""
        return [net(part) for net, part in zip(self.nets, x.split(self.in_blocks, dim=-1))]

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """The blocks' outputs, concatenated or summed."""
        parts = self.parts(x)
        return torch.stack(parts).sum(dim=0) if self.sum else torch.cat(parts, dim=-1)


def soft_clamp(x: torch.Tensor, bound: float) -> torch.Tensor:
    """``bound * tanh(x / bound)``: the identity for |x| << bound, never beyond it, never a dead gradient."""
    return bound * torch.tanh(x / bound)


def kl_to_standard_normal(mu: torch.Tensor, logvar: torch.Tensor) -> torch.Tensor:
    """KL(N(mu, exp(logvar)) || N(0, I)) per row, summed over dimensions.

    ``expm1(lv) - lv`` is ``exp(lv) - 1 - lv`` without the cancellation near lv = 0.
    """
    return 0.5 * (mu.square() + torch.expm1(logvar) - logvar).sum(dim=-1)


PREDICTORS = ("joint", "additive")

# What `--architecture` offers: name -> (factorised E and D, predictor, hidden sizes, description).
# The factorised networks are half as wide as the paper's: each sees one parameter, so it needs less
# capacity, and six of them at (512, 1024) cost about half what the paper's three at (1024, 2048) do.
ARCHITECTURES = {
    "paper": (False, "joint", (1024, 2048), "the paper's NAMS: E, D and P each see the whole design (all of z)"),
    "factorised": (True, "joint", (512, 1024), "one E and one D per design parameter, each with its own "
                                               "slice of z; a joint P"),
    "additive": (True, "additive", (512, 1024), "factorised E and D, and P a sum of one network per "
                                                "parameter: a tile's features add up over its flat and "
                                                "sloped roofs"),
}
# Chosen on E1/E2's validation split (bench-ablations's rows per architecture; docs/design.md, "Splits").
DEFAULT_ARCHITECTURE = "additive"


# A factorised model gives each parameter this many of z's dimensions (the default z of 10 holds two).
Z_PER_PARAMETER = 5


def architecture_options(name: str, widths) -> dict:
    """NAMSConfig fields for architecture ``name`` on a design space with parameter block ``widths``."""
    if name not in ARCHITECTURES:
        raise MetaSimError(f"unknown architecture {name!r}; use one of {', '.join(ARCHITECTURES)}")
    factorised, predictor, hidden, _ = ARCHITECTURES[name]
    out = {"blocks": [int(w) for w in widths] if factorised else [], "predictor": predictor, "hidden": list(hidden)}
    if factorised and len(widths) * Z_PER_PARAMETER > NAMSConfig.z_dim:
        out["z_dim"] = len(widths) * Z_PER_PARAMETER  # a space of many parameters: each keeps its share of z
    return out


@dataclass(frozen=True)
class NAMSConfig:
    """NAMS sizes, loss weights and architecture; ``__post_init__`` raises MetaSimError for a
    combination that cannot be built (sizes below 1, blocks not summing to ``design_dim``, ...)."""

    design_dim: int
    feature_dim: int
    z_dim: int = 10
    hidden: tuple[int, ...] = (1024, 2048)
    dropout: float = 0.5
    negative_slope: float = 0.2
    lambda_d: float = 1.0
    lambda_kld: float = 0.0005
    lambda_p: float = 0.005
    # mu and log-variance are soft-clamped (NVAE-style) so that KL, exp(logvar)
    # and the reparameterised z stay finite whatever the encoder weights are.
    # Both bounds sit far outside what a trained encoder produces.
    mu_bound: float = 100.0
    logvar_bound: float = 20.0
    # The architecture (see ARCHITECTURES). ``blocks`` are the widths of the
    # design parameters' blocks in the encoded vector: empty, E and D see the
    # whole design at once (the paper); given, E and D are factorised, one
    # network per parameter with its own slice of z. ``predictor``: "joint" P
    # sees all of z (the paper), "additive" P is a sum of one network per
    # parameter's slice of z, "both" adds the two.
    blocks: tuple[int, ...] = ()
    predictor: str = "joint"
    # The last ``colour_dims`` features are roof-colour histograms (FeatureNorm's histogram blocks):
    # the search takes the geometric mean of their error and the other features' (nams.search).
    colour_dims: int = 0

    def __post_init__(self):
        _check_sizes(self, ("design_dim", "feature_dim", "z_dim"))
        if not 0 <= int(self.colour_dims) < self.feature_dim:
            raise MetaSimError(f"colour_dims must be in [0, feature_dim), not {self.colour_dims}")
        object.__setattr__(self, "blocks", tuple(int(b) for b in self.blocks))
        if self.predictor not in PREDICTORS:
            raise MetaSimError(f"predictor must be one of {', '.join(PREDICTORS)}, not {self.predictor!r}")
        if self.predictor != "joint" and not self.blocks:
            raise MetaSimError(f"an {self.predictor!r} predictor needs the design's parameter blocks")
        if self.blocks:
            if any(b < 1 for b in self.blocks) or sum(self.blocks) != self.design_dim:
                raise MetaSimError(f"blocks {list(self.blocks)} must be positive widths summing to "
                                   f"design_dim {self.design_dim}")
            if self.z_dim < len(self.blocks):
                raise MetaSimError(f"a factorised model needs z_dim >= the number of parameters "
                                   f"({len(self.blocks)}), not {self.z_dim}")
        if not 0.0 <= self.dropout < 1.0:
            raise MetaSimError(f"dropout must be in [0, 1), not {self.dropout}")
        if min(self.lambda_d, self.lambda_kld, self.lambda_p) < 0:
            raise MetaSimError("loss weights lambda_d, lambda_kld, lambda_p must not be negative")
        if not (self.mu_bound > 0 and self.logvar_bound > 0):
            raise MetaSimError("mu_bound and logvar_bound must be positive")

    def to_dict(self) -> dict:
        """Plain values for a checkpoint (tuples as lists)."""
        out = asdict(self)
        out["hidden"] = list(self.hidden)
        out["blocks"] = list(self.blocks)
        return out

    @property
    def architecture(self) -> str:
        """The ``ARCHITECTURES`` name this config's blocks and predictor amount to."""
        for name, (factorised, predictor, _, _) in ARCHITECTURES.items():
            if factorised == bool(self.blocks) and predictor == self.predictor:
                return name
        raise AssertionError("unreachable: __post_init__ admits only the combinations ARCHITECTURES names")

    @property
    def z_blocks(self) -> tuple[int, ...]:
        """z's width per parameter block: z_dim split as evenly as it goes, earlier blocks first."""
        n = len(self.blocks)
        return tuple(self.z_dim // n + (i < self.z_dim % n) for i in range(n))

    @classmethod
    def from_dict(cls, data: Mapping) -> "NAMSConfig":
        """A config from ``to_dict``'s values; MetaSimError for an unknown key or an invalid value."""
        return _from_dict(cls, data)


class NAMSOutput(NamedTuple):
    """What ``NAMS.forward`` returns: E's mean and log-variance, the z used (sampled when training,
    mu otherwise), D's design logits and P's normalised features."""

    mu: torch.Tensor
    logvar: torch.Tensor
    z: torch.Tensor
    design_logits: torch.Tensor
    features: torch.Tensor


class NAMS(nn.Module):
    """E: d -> (mu, logvar); D: z -> design logits; P: z -> (normalised) features.

    ``z_mean`` and ``z_std`` hold the spread of mu(E(d)) over the training
    designs; the adjoint search draws its starts from them. ``feature_scale``
    is the RMS error of P(mu(E(d))) per (normalised) feature over the training
    set: the search measures errors in these units, so that features P cannot
    predict well (tile-to-tile noise) do not outvote the ones it can. Training
    sets all three.
    """

    kind = "nams"

    def __init__(self, config: NAMSConfig):
        super().__init__()
        self.config = config
        c = config

        def net(in_dim: int, out_dim: int) -> MLP:
            return mlp(in_dim, c.hidden, out_dim, nn.LeakyReLU(c.negative_slope), c.dropout)

        if c.blocks:
            self.encoder = Blockwise(c.blocks, [2 * w for w in c.z_blocks], net)
            self.decoder = Blockwise(c.z_blocks, c.blocks, net)
        else:
            self.encoder = net(c.design_dim, 2 * c.z_dim)
            self.decoder = net(c.z_dim, c.design_dim)
        if c.predictor == "joint":
            self.predictor = net(c.z_dim, c.feature_dim)
        else:
            self.predictor = Blockwise(c.z_blocks, [c.feature_dim] * len(c.blocks), net, sum=True)
        self.register_buffer("z_mean", torch.zeros(c.z_dim))
        self.register_buffer("z_std", torch.ones(c.z_dim))
        self.register_buffer("feature_scale", torch.ones(c.feature_dim))
        self._design_tables: dict = {}

    # The exhaustive search caches P(mu(E(d))) for every design of a space
    # (see search.design_table). Anything that may change the weights drops it.
    def train(self, mode: bool = True):
        """``nn.Module.train``; entering training mode drops the cached design tables."""
        if mode:
            self._design_tables.clear()
        return super().train(mode)

    def load_state_dict(self, state_dict, strict: bool = True, assign: bool = False):
        """``nn.Module.load_state_dict``, dropping the cached design tables."""
        self._design_tables.clear()
        return super().load_state_dict(state_dict, strict=strict, assign=assign)

    def encode(self, designs: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """E: encoded designs (..., design_dim) -> soft-clamped (mu, logvar), each (..., z_dim)."""
        if self.config.blocks:
            pairs = [out.chunk(2, dim=-1) for out in self.encoder.parts(designs)]
            mu, logvar = torch.cat([m for m, _ in pairs], dim=-1), torch.cat([v for _, v in pairs], dim=-1)
        else:
            mu, logvar = self.encoder(designs).chunk(2, dim=-1)
        return soft_clamp(mu, self.config.mu_bound), soft_clamp(logvar, self.config.logvar_bound)

    def decode(self, z: torch.Tensor) -> torch.Tensor:
        """Design logits; sigmoid gives the [0, 1] design vector."""
        return self.decoder(z)

    def predict(self, z: torch.Tensor) -> torch.Tensor:
        """P: z (..., z_dim) -> normalised features (..., feature_dim)."""
        return self.predictor(z)

    def forward(self, designs: torch.Tensor, generator: torch.Generator | None = None) -> NAMSOutput:
        """E, then z (sampled with ``generator`` in training mode, mu otherwise), then D and P."""
        mu, logvar = self.encode(designs)
        if self.training:
            eps = torch.randn(mu.shape, generator=generator, dtype=mu.dtype, device=mu.device)
            z = mu + eps * torch.exp(0.5 * logvar)
        else:
            z = mu
        return NAMSOutput(mu, logvar, z, self.decode(z), self.predict(z))

    def loss(self, designs: torch.Tensor, features: torch.Tensor,
             generator: torch.Generator | None = None) -> tuple[torch.Tensor, dict[str, float]]:
        """lambda_D * BCE + lambda_KLD * KL + lambda_P * MSE, and the three terms for the history."""
        out = self(designs, generator)
        bce = F.binary_cross_entropy_with_logits(out.design_logits, designs)
        kld = kl_to_standard_normal(out.mu, out.logvar).mean()
        mse = F.mse_loss(out.features, features)
        c = self.config
        total = c.lambda_d * bce + c.lambda_kld * kld + c.lambda_p * mse
        return total, {"bce": bce.item(), "kld": kld.item(), "mse": mse.item()}


@dataclass(frozen=True)
class DRConfig:
    """Direct-regression sizes: features in, design vector out, ``hidden`` layer widths."""

    feature_dim: int
    design_dim: int
    hidden: tuple[int, ...] = (500,) * 5

    def __post_init__(self):
        _check_sizes(self, ("feature_dim", "design_dim"))

    def to_dict(self) -> dict:
        """Plain values for a checkpoint (tuples as lists)."""
        out = asdict(self)
        out["hidden"] = list(self.hidden)
        return out

    @classmethod
    def from_dict(cls, data: Mapping) -> "DRConfig":
        """A config from ``to_dict``'s values; MetaSimError for an unknown key or an invalid value."""
        return _from_dict(cls, data)


class DirectRegression(nn.Module):
    """Features -> design vector, trained with MSE against the encoded design (paper section 3.3).

    Regressing a one-hot block with MSE estimates the probability of each
    choice, so the outputs double as vote shares.
    """

    kind = "dr"

    def __init__(self, config: DRConfig):
        super().__init__()
        self.config = config
        self.net = mlp(config.feature_dim, config.hidden, config.design_dim, nn.ReLU(), dropout=0.0)

    def forward(self, features: torch.Tensor) -> torch.Tensor:
        """Normalised features (N, feature_dim) -> design vectors (N, design_dim)."""
        return self.net(features)

    def loss(self, designs: torch.Tensor, features: torch.Tensor,
             generator: torch.Generator | None = None) -> tuple[torch.Tensor, dict[str, float]]:
        """MSE of the predicted design vector, and that term for the history (``generator`` is unused:
        the signature matches ``NAMS.loss`` so that one training loop serves both)."""
        mse = F.mse_loss(self(features), designs)
        return mse, {"mse": mse.item()}


MODELS: dict[str, tuple[type[nn.Module], type]] = {"nams": (NAMS, NAMSConfig), "dr": (DirectRegression, DRConfig)}


def build_model(kind: str, config: Mapping | NAMSConfig | DRConfig) -> NAMS | DirectRegression:
    """A fresh model of ``kind`` ("nams" or "dr") from its config (dataclass or dict)."""
    if kind not in MODELS:
        raise MetaSimError(f"unknown model kind {kind!r}; use one of {', '.join(MODELS)}")
    model_cls, config_cls = MODELS[kind]
    if not isinstance(config, config_cls):
        config = config_cls.from_dict(config)
    return model_cls(config)

"""Meta-Sim2 (Devaranjan et al. 2020), the paper's MS2 baseline, re-implemented.

MS2's code was never published; this follows the NAMS paper's description
(section "Meta-Sim2"). Each categorical design parameter has a categorical
distribution with logits theta; p^G and p^T are Gaussian kernel density
estimates of generated and target image features; theta minimises the KL
estimate E_{d ~ p_theta}[log p^G(G(d)) - log p^T(G(d))] by REINFORCE,
N = 500 samples per step, 200 steps.

Choices made here, where the paper leaves room:

* Simulations come from a pre-rendered pool, as in the paper's experiments:
  pool tile j is one simulation G(d_j) of a known design. Sampling is
  restricted to the pool's designs: tile j is drawn with probability
  pi(j) proportional to p_theta(d_j) = prod over parameters of
  softmax(theta_param)[choice of j], with replacement. The REINFORCE term
  uses log pi(j) (autograd through theta). Choices absent from the pool get
  no gradient and are left out of the answer.
* Variance reduction: a moving-average baseline of the per-step KL
  estimate, b <- alpha b + (1 - alpha) mean, alpha = 0.7 (Meta-Sim's),
  started at the first step's mean; Adam on theta, which starts at 0
  (uniform). Each group's loss is divided by a fixed positive constant (the
  range of log p^T over the pool): Adam is invariant to it, and it keeps
  far-off targets from overflowing Adam's second moments.
* KDE: isotropic Gaussian kernels of one bandwidth h for p^G and p^T (so
  their normalising constants cancel in the loss and are left out). h comes
  from the pool by ``MS2Config.bandwidth`` times ``bandwidth_scale``:
  ``"scott"`` (default), sigma * N^(-1/(F+4)) with sigma^2 the pool's
  per-feature variance averaged over features; ``"median"``, the median
  distance between two pool tiles. Should the rule give 0 (most tiles
  coincide), h^2 is the mean squared distance between two pool tiles, or 1
  if all coincide. The default scale is 2: with Scott's h itself MS2
  settles on the nearest pool design, which for a target whose design the
  pool lacks gets few parameters right; twice as wide gets most of those
  parameters right and still nearly all targets the pool holds; the median
  rule is far wider and blurs designs together.
* p^G(x_i) averages the kernels of all N samples, x_i's own included (no
  leave-one-out): with a finite pool a draw often repeats a tile, and a
  repeat is a genuine sample of p^G. So log p^G >= -log N, always finite.
* p^T averages the kernels of the group's target tiles, by log-sum-exp in
  float64: finite however far the targets lie, and defined for one tile.
* Features are centred and scaled (by the largest absolute value) before
  any distance; every quantity above is invariant to that, and it keeps
  huge features finite.

The answer for each group: per parameter, the learned marginal softmax(theta)
over the choices present in the pool gives the vote shares, its argmax the
design; ``best_loss`` is the KL estimate of a last draw of N samples from
the final theta (``mean_loss`` is None). All groups run as one batch:
(groups, pool) tensors, one Adam.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass

import torch

from ..core.errors import MetaSimError
from ..core.progress import Bars
from ..sim.design import Categorical, DesignSpace
from .search import SearchResult

BANDWIDTH_RULES = ("scott", "median")
KERNEL_FLOOR = 1e-30


@dataclass(frozen=True)
class MS2Config:
    """MS2 settings; the defaults are MS2's (N = 500, 200 iterations, alpha = 0.7).

    ``max_pool``: pool tiles kept (a random subset, with a warning, beyond
    it); the pool's (P, P) kernel matrix is held in memory.
    """

    samples: int = 500
    iterations: int = 200
    lr: float = 0.05
    baseline_alpha: float = 0.7
    bandwidth: str = "scott"
    bandwidth_scale: float = 2.0
    max_pool: int = 4096

    def __post_init__(self):
        if not (isinstance(self.samples, int) and self.samples >= 1):
            raise MetaSimError(f"MS2 samples per step must be an integer of at least 1, not {self.samples!r}")
        if not (isinstance(self.iterations, int) and self.iterations >= 0):
            raise MetaSimError(f"MS2 iterations must be an integer of at least 0, not {self.iterations!r}")
        if not (isinstance(self.lr, (int, float)) and math.isfinite(self.lr) and self.lr > 0):
            raise MetaSimError(f"MS2 lr must be a finite positive number, not {self.lr!r}")
        if not (isinstance(self.baseline_alpha, (int, float)) and 0.0 <= self.baseline_alpha < 1.0):
            raise MetaSimError(f"MS2 baseline_alpha must be in [0, 1), not {self.baseline_alpha!r}")
        if self.bandwidth not in BANDWIDTH_RULES:
            raise MetaSimError(f"unknown MS2 bandwidth rule {self.bandwidth!r}; use one of "
                               f"{', '.join(BANDWIDTH_RULES)}")
        if not (isinstance(self.bandwidth_scale, (int, float)) and math.isfinite(self.bandwidth_scale)
                and self.bandwidth_scale > 0):
            raise MetaSimError(f"MS2 bandwidth_scale must be a finite positive number, not "
                               f"{self.bandwidth_scale!r}")
        if not (isinstance(self.max_pool, int) and self.max_pool >= 1):
            raise MetaSimError(f"MS2 max_pool must be an integer of at least 1, not {self.max_pool!r}")


def ms2_search(pool_features, pool_designs, target_groups, space: DesignSpace, config: MS2Config = MS2Config(),
               generator: torch.Generator | None = None,
               bars: Bars | None = None) -> list[SearchResult]:
    """MS2 for each target group; one SearchResult per group.

    ``pool_features`` (P, F): one feature vector per pool tile;
    ``pool_designs`` (P, space.dim): their designs as ``space.encode`` gives
    them; ``target_groups``: one (T_i, F) tensor of per-tile target features
    per group (a (F,) tensor is one tile). Features are expected normalised
    (the NAMS checkpoint's FeatureNorm), but any common scale works. Pool
    rows with NaN/Inf are dropped with a warning; every other problem raises
    MetaSimError. Deterministic for a given ``generator`` state.
    """
    _check_categorical(space)
    features, designs = _clean_pool(pool_features, pool_designs, space)
    groups = _target_groups(target_groups, features.shape[1])
    if len(features) > config.max_pool:
        warnings.warn(f"MS2 uses a random {config.max_pool} of the {len(features)} pool tiles (max_pool)",
                      stacklevel=2)
        keep = torch.randperm(len(features), generator=generator)[:config.max_pool].sort().values
        features, designs = features[keep], designs[keep]

    pool, targets = _centre_and_scale(features, groups)
    sq_pool = _squared_distances(pool, pool)
    two_h2 = 2 * _bandwidth_squared(pool, sq_pool, config)
    kernel = torch.exp(-sq_pool / two_h2).float()  # (P, P), symmetric, ones on the diagonal
    # Next to the diagonal's 1 these do not count, and float32 subnormals slow the matmul tenfold.
    kernel[kernel < KERNEL_FLOOR] = 0.0
    log_target = torch.stack([torch.logsumexp(-_squared_distances(pool, t) / two_h2, dim=1) - math.log(len(t))
                              for t in targets])  # (G, P): log p^T at every pool tile
    loss_scale = (log_target.amax(dim=1) - log_target.amin(dim=1)).clamp_min(1.0)[:, None]

    n_groups, n_pool, n = len(targets), len(pool), config.samples
    logits = torch.zeros(n_groups, space.dim, dtype=torch.float64, requires_grad=True)

    def draw() -> tuple[torch.Tensor, torch.Tensor]:
        """N pool tiles per group from the restricted p_theta: their losses and log pi, each (G, N)."""
        log_pi = torch.log_softmax(logits @ designs.T, dim=1)
        cdf = log_pi.detach().exp().cumsum(dim=1)
        u = torch.rand(n_groups, n, generator=generator, dtype=torch.float64) * cdf[:, -1:]
        picks = torch.searchsorted(cdf, u, right=True).clamp_max(n_pool - 1)
        counts = torch.zeros(n_groups, n_pool).scatter_add_(1, picks, torch.ones(n_groups, n))
        log_generated = torch.log((counts @ kernel).double() / n)  # p^G = (1/N) sum of the N samples' kernels
        loss = log_generated.gather(1, picks) - log_target.gather(1, picks)
        return loss, log_pi.gather(1, picks)

    optimiser = torch.optim.Adam([logits], lr=config.lr)
    baseline = None
    progress = bars("MS2 search", config.iterations) if bars is not None else None
    for _step in range(config.iterations):
        loss, log_prob = draw()
        kl = loss.mean(dim=1)
        baseline = kl if baseline is None else baseline
        surrogate = (((loss - baseline[:, None]) / loss_scale) * log_prob).mean(dim=1).sum()
        (logits.grad,) = torch.autograd.grad(surrogate, logits)
        optimiser.step()
        baseline = config.baseline_alpha * baseline + (1 - config.baseline_alpha) * kl
        if progress is not None:
            progress(1)
    with torch.no_grad():
        final_kl = draw()[0].mean(dim=1)
    if not torch.isfinite(final_kl).all():
        raise MetaSimError("MS2 produced a non-finite KL estimate; check the pool and target features")
    return _results(space, logits.detach(), designs.sum(dim=0) > 0, final_kl)


def _results(space: DesignSpace, logits: torch.Tensor, present: torch.Tensor,
             final_kl: torch.Tensor) -> list[SearchResult]:
    """Per group: the marginals over the pool's choices as vote shares, their argmax as the design."""
    results = []
    for g in range(len(logits)):
        design, votes = {}, {}
        for p, sl in space.blocks():
            block = logits[g, sl].masked_fill(~present[sl], -math.inf)
            shares = torch.softmax(block, dim=0)
            order = torch.argsort(shares, descending=True, stable=True).tolist()
            design[p.name] = p.choices[order[0]]
            votes[p.name] = {p.choices[c]: float(shares[c]) for c in order if shares[c] > 0}
        results.append(SearchResult(design=design, votes=votes, best_loss=float(final_kl[g]), mean_loss=None,
                                    method="ms2", searched_design=dict(design)))
    return results


# --- inputs --------------------------------------------------------------------------------------
def _check_categorical(space: DesignSpace) -> None:
    continuous = [p.name for p in space.parameters if not isinstance(p, Categorical)]
    if continuous:
        raise MetaSimError(f"MS2 here handles categorical design parameters only; {space.name!r} has "
                           f"continuous ones ({', '.join(continuous)}): use the NAMS adjoint search")


def _clean_pool(pool_features, pool_designs, space: DesignSpace) -> tuple[torch.Tensor, torch.Tensor]:
    """Float32 features and float64 one-hot designs of the pool's finite rows (a warning names the others)."""
    features = torch.as_tensor(pool_features).detach().to(torch.float32)
    designs = torch.as_tensor(pool_designs).detach().to(torch.float64)
    if features.ndim != 2 or designs.ndim != 2 or len(features) != len(designs):
        raise MetaSimError(f"MS2 needs pool features (P, F) and pool designs (P, design_dim) with one P; got "
                           f"{tuple(features.shape)} and {tuple(designs.shape)}")
    if designs.shape[1] != space.dim:
        raise MetaSimError(f"pool designs have {designs.shape[1]} values; design space {space.name!r} encodes "
                           f"to {space.dim} (encode them with this space)")
    finite = torch.isfinite(features).all(dim=1) & torch.isfinite(designs).all(dim=1)
    dropped = int((~finite).sum())
    if dropped:
        warnings.warn(f"MS2 dropped {dropped} of {len(finite)} pool tiles with NaN/Inf features or designs "
                      f"(or features beyond float32)", stacklevel=3)
    features, designs = features[finite], designs[finite]
    if len(features) == 0:
        raise MetaSimError("the MS2 pool has no tile with finite features and design; render or pass a pool")
    for p, sl in space.blocks():
        block = designs[:, sl]
        if not (((block == 0) | (block == 1)).all() and (block.sum(dim=1) == 1).all()):
            raise MetaSimError(f"pool designs must be one-hot in each block (as DesignSpace.encode gives); "
                               f"parameter {p.name!r} is not")
    return features, designs


def _target_groups(target_groups, feature_dim: int) -> list[torch.Tensor]:
    if isinstance(target_groups, torch.Tensor) or len(target_groups) == 0:
        raise MetaSimError("MS2 needs a non-empty list of target groups, one (tiles, features) tensor each")
    groups = []
    for i, group in enumerate(target_groups):
        group = torch.as_tensor(group).detach().to(torch.float32)
        if group.ndim == 1:
            group = group.unsqueeze(0)
        if group.ndim != 2 or len(group) == 0 or group.shape[1] != feature_dim:
            raise MetaSimError(f"target group {i} must be (tiles, {feature_dim}) features like the pool's; got "
                               f"shape {tuple(group.shape)} (was another feature extractor used?)")
        if not torch.isfinite(group).all():
            raise MetaSimError(f"target group {i} contains NaN or Inf features (or values beyond float32); "
                               f"check its images and the feature extraction")
        groups.append(group)
    return groups


# --- kernels -------------------------------------------------------------------------------------
def _centre_and_scale(pool: torch.Tensor, groups: list[torch.Tensor]) -> tuple[torch.Tensor, list[torch.Tensor]]:
    """Float64 pool and targets, minus the pool mean, divided by their largest absolute value."""
    mean = pool.double().mean(dim=0)
    pool = pool.double() - mean
    groups = [g.double() - mean for g in groups]
    scale = max([float(pool.abs().max())] + [float(g.abs().max()) for g in groups])
    scale = scale if scale > 0 else 1.0
    return pool / scale, [g / scale for g in groups]


def _squared_distances(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    distances = (a.square().sum(dim=1)[:, None] + b.square().sum(dim=1)[None, :] - 2 * a @ b.T).clamp_min(0.0)
    if a is b:
        distances.fill_diagonal_(0.0)
    return distances


def _bandwidth_squared(pool: torch.Tensor, sq_pool: torch.Tensor, config: MS2Config) -> float:
    """h^2 by the configured rule (see the module docstring); positive whatever the pool."""
    n_pool, feature_dim = pool.shape
    if config.bandwidth == "scott":
        h2 = float(pool.var(dim=0, correction=0).mean()) * config.samples ** (-2 / (feature_dim + 4))
    else:
        pairs = sq_pool[torch.triu_indices(n_pool, n_pool, offset=1).unbind()]
        h2 = float(pairs.median()) if len(pairs) else 0.0
    if h2 <= 0 and n_pool > 1:  # most tiles coincide: the mean squared distance still sees the others
        h2 = float(sq_pool.sum()) / (n_pool * (n_pool - 1))
    return (h2 if h2 > 0 else 1.0) * config.bandwidth_scale ** 2

"""Recommended training and search settings (`--profile` on `meta-sim dataset|train|eval|infer`)."""

from __future__ import annotations

from dataclasses import dataclass

from ..core.errors import MetaSimError
from .dataset import DatasetConfig


@dataclass(frozen=True)
class Profile:
    """A recommended combination of the knobs, for `--profile` and the bench."""

    description: str
    dataset: DatasetConfig
    views: int = 8
    method: str = "exhaustive"
    M: int = 1000
    iterations: int = 200
    group_size: int = 9

    def search_options(self) -> dict:
        """The adjoint search's M and iterations as keyword arguments (none for another method)."""
        return {"M": self.M, "iterations": self.iterations} if self.method == "adjoint" else {}


# Chosen on `make bench-tradeoff`'s training-set rows (docs/benchmarks.md, "Speed against accuracy"), on E1's
# validation split (docs/design.md, "Splits"):
# the number of designs matters, the tiles per design do not. balanced is the default; fast halves
# its rendering; paper is the paper's protocol.
PROFILES = {
    "fast": Profile("300 designs x 2 rasterised tiles (half the default's rendering), exhaustive search",
                    DatasetConfig(designs=300, tiles=2)),
    "balanced": Profile("the default: 600 designs x 2 rasterised tiles, exhaustive search", DatasetConfig()),
    "paper": Profile("the paper's protocol: 1,700 designs x 9 tiles, 8 views, neural-adjoint search "
                     "M=1000 for 200 iterations", DatasetConfig.paper(), method="adjoint"),
}


def get_profile(name: str) -> Profile:
    """The profile called ``name``; MetaSimError listing the profiles for an unknown one."""
    try:
        return PROFILES[name]
    except KeyError:
        raise MetaSimError(f"unknown profile {name!r}; choose one of {', '.join(PROFILES)}") from None

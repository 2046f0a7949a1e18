"""The cache folder: texture banks, training sets, features and models are kept there by what went in."""

from __future__ import annotations

import os
from pathlib import Path


def cache_root(cache_dir: str | os.PathLike | None = None) -> Path:
    """``cache_dir``, else ``$META_SIM_CACHE``, else ``~/.cache/meta-sim``."""
    if cache_dir is not None:
        return Path(cache_dir)
    env = os.environ.get("META_SIM_CACHE")
    return Path(env) if env else Path.home() / ".cache" / "meta-sim"

"""Optional dependencies: which extra of ``pyproject.toml`` brings each, and one message when it is missing."""

from __future__ import annotations

import importlib.util

from .errors import MetaSimError

EXTRAS = {"bpy": "render", "distributed": "farm", "matplotlib": "bench", "pyproj": "geo", "sbi": "sbi"}


def require(module: str, what: str) -> None:
    """Raise MetaSimError naming the extra to install when ``module`` is not importable (found without
    importing it, so a check costs nothing)."""
    try:
        found = importlib.util.find_spec(module) is not None
    except (ImportError, ValueError):
        found = False
    if not found:
        raise MetaSimError(f"{what} needs the {module} package: pip install 'meta-sim[{EXTRAS[module]}]'")

"""Names that become parts of paths, and paths that must stay inside their folder.

Task names, design choice ids and texture ids come from files that travel between machines and
people (manifests, design spaces, banks); each becomes part of a file name. Every one of them
must be a safe name: letters, digits and ``. _ + -``, no path separator, not starting with a
dot, at most ``MAX_NAME`` characters. Everything read from such a file is checked before it is
used, and every output path is checked to resolve inside its output folder.
"""

from __future__ import annotations

import os
import re
from pathlib import Path

from .errors import MetaSimError

MAX_NAME = 200
SAFE_NAME = re.compile(r"[A-Za-z0-9_+-][A-Za-z0-9._+-]*")


def is_safe_name(value) -> bool:
    return isinstance(value, str) and len(value) <= MAX_NAME and SAFE_NAME.fullmatch(value) is not None


def safe_name(value, what: str) -> str:
    """``value`` when it is a safe name, else MetaSimError naming ``what`` it is."""
    if not is_safe_name(value):
        raise MetaSimError(f"{what} {value!r} is not a safe name: use letters, digits and . _ + - only "
                           f"(no '/' or '\\', not starting with '.', at most {MAX_NAME} characters)")
    return value


def inside(folder: str | os.PathLike, path: str | os.PathLike, what: str) -> Path:
    """``folder / path`` resolved (symbolic links followed), when it lies inside ``folder``;
    MetaSimError otherwise."""
    root = Path(folder).resolve()
    resolved = (root / path).resolve()
    if resolved != root and root not in resolved.parents:
        raise MetaSimError(f"{what} {str(path)!r} points outside its folder {root}")
    return resolved

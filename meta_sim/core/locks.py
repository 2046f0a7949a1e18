"""One process at a time per cache entry or shared file, across processes (and machines sharing a disk
that honours file locks).

Two runs sharing ``META_SIM_CACHE`` (or two renders into one ``--out``) take the entry's lock before
they look at it: the first does the work, the second waits, then finds it done. The lock is a file
``.NAME.lock`` beside the entry, held with the ``filelock`` library (a base dependency).
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from .errors import MetaSimError


def lock_path(entry: str | os.PathLike) -> Path:
    """The lock file of ``entry`` (a folder or a file): ``.NAME.lock`` beside it."""
    entry = Path(entry)
    return entry.with_name(f".{entry.name}.lock")


@contextmanager
def locked(entry: str | os.PathLike) -> Iterator[None]:
    """Hold ``entry``'s lock for the block (waiting for another process that holds it).

    Blender's own Python has no ``filelock``; the render worker run by a stock Blender then works
    without the lock, as before, which only matters for two renders into one folder at once."""
    path = lock_path(entry)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:  # a cache or output folder that cannot be made: the user's to change
        raise MetaSimError(f"cannot make the folder {path.parent}: {exc.strerror or exc}") from None
    try:
        from filelock import FileLock
    except ImportError:
        yield
        return
    with FileLock(path):
        yield

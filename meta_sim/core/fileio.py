"""Atomic file writes: a reader sees the old file or the new one, never half of one.

Every writer of the project goes through ``atomic_path``: tiles, JSON (manifests, presets,
reports, banks), PNGs, checkpoints, feature caches and roof finders. The file is written to a
temporary name in the destination folder, flushed to disk, given the mode a plain ``open`` would
give it (0666 less the umask, typically 0644) and renamed over the destination; on any error the
temporary file is removed and the destination is left as it was. ``atomic_dir`` does the same for
a whole folder (a texture bank).
"""

from __future__ import annotations

import functools
import os
import shutil
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

TEMP_MARK = ".tmp"  # temporary files are named .NAME.tmpXXXXXXXX.SUFFIX beside the destination


@functools.cache
def _umask() -> int:
    umask = os.umask(0o022)  # reading the umask means setting it: once, and put straight back
    os.umask(umask)
    return umask


def _file_mode() -> int:
    return 0o666 & ~_umask()


@contextmanager
def atomic_path(path: str | os.PathLike) -> Iterator[Path]:
    """A temporary path beside ``path`` to write to (for writers that take a file name, such as
    OpenImageIO or ``torch.save``); moved onto ``path`` when the block ends without an error."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.stem}{TEMP_MARK}", suffix=path.suffix, dir=path.parent)
    os.close(fd)
    try:
        yield Path(tmp)
        with open(tmp, "rb+") as fh:
            os.fsync(fh.fileno())
        os.chmod(tmp, _file_mode())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


@contextmanager
def atomic_dir(path: str | os.PathLike) -> Iterator[Path]:
    """A temporary folder beside ``path`` to build a whole folder in (a texture bank); renamed onto
    ``path`` when the block ends without an error, with the mode a plain ``mkdir`` would give it.
    When another process renamed its own build into place first, that one is kept and this one
    removed; on any error the temporary folder is removed."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{path.name}{TEMP_MARK}", dir=path.parent))
    try:
        yield tmp
        os.chmod(tmp, 0o777 & ~_umask())
        try:
            os.rename(tmp, path)
        except OSError:
            if not path.is_dir():  # not a concurrent build that won the race
                raise
    finally:
        if tmp.exists():
            shutil.rmtree(tmp, ignore_errors=True)


def write_bytes_atomic(path: str | os.PathLike, data: bytes) -> Path:
    """Write ``data`` to ``path`` atomically (see the module docstring); returns the path."""
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)
    return Path(path)


def write_text_atomic(path: str | os.PathLike, text: str) -> Path:
    """Write ``text`` as UTF-8 to ``path`` atomically; returns the path."""
    return write_bytes_atomic(path, text.encode("utf-8"))

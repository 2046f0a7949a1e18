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
import itertools
import os
import re
import shutil
import socket
import tempfile
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from .errors import MetaSimError

TEMP_MARK = ".tmp"  # temporary files are named .NAME.tmpPID-HOST-XXXXXXXX.SUFFIX beside the destination
# A temporary file whose writer cannot be asked whether it lives (another host) counts as abandoned after this.
STALE_SECONDS = 3600.0


@functools.cache
def _host() -> str:
    return re.sub(r"[^A-Za-z0-9]", "", socket.gethostname())[:24] or "host"


def temp_owner(name: str) -> tuple[int, str] | None:
    """(pid, host) of the process that writes the temporary file called ``name``, or None when the name
    is not one of ``atomic_path``'s."""
    match = re.search(re.escape(TEMP_MARK) + r"(\d+)-([A-Za-z0-9]+)-", name)
    return (int(match[1]), match[2]) if match else None


def abandoned(path: str | os.PathLike, now: float | None = None) -> bool:
    """Whether the temporary file at ``path`` is left over by a writer that is gone: its process no longer
    runs on this host, or (written on another host) it has not changed for ``STALE_SECONDS``."""
    owner = temp_owner(Path(path).name)
    try:
        age = (time.time() if now is None else now) - Path(path).stat().st_mtime
    except FileNotFoundError:
        return False
    if owner is None or owner[1] != _host():
        return age > STALE_SECONDS
    try:
        os.kill(owner[0], 0)
    except ProcessLookupError:
        return True
    except PermissionError:  # alive, another account's
        return False
    return _zombie(owner[0])


def _zombie(pid: int) -> bool:
    """A killed process nobody has reaped yet still answers ``kill(pid, 0)``; Linux says it is a zombie."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return False
    return stat.rpartition(")")[2].split()[:1] == ["Z"]


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
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{path.stem}{TEMP_MARK}{os.getpid()}-{_host()}-", suffix=path.suffix,
                                   dir=path.parent)
    except OSError as exc:
        raise MetaSimError(f"cannot write {path}: {exc.strerror or exc}") from None
    os.close(fd)
    try:
        yield Path(tmp)
        with open(tmp, "rb+") as fh:
            os.fsync(fh.fileno())
        os.chmod(tmp, _file_mode())
        os.replace(tmp, path)
    except OSError as exc:  # disk full, quota, permissions: one line for the user, nothing left behind
        Path(tmp).unlink(missing_ok=True)
        raise MetaSimError(f"cannot write {path}: {exc.strerror or exc}") from None
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


@contextmanager
def atomic_dir(path: str | os.PathLike, replace: bool = False) -> Iterator[Path]:
    """A temporary folder beside ``path`` to build a whole folder in (a texture bank, the outputs of
    `meta-sim infer`); renamed onto ``path`` when the block ends without an error, with the mode a
    plain ``mkdir`` would give it. ``replace``: an existing ``path`` is swapped out whole and removed.
    Otherwise, when another process put its own build in place first, that one is kept and this one
    removed. On any error the temporary folder is removed and ``path`` is left as it was."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{path.name}{TEMP_MARK}", dir=path.parent))
    try:
        yield tmp
        os.chmod(tmp, 0o777 & ~_umask())
        if replace and path.exists():
            old = Path(tempfile.mkdtemp(prefix=f".{path.name}.old", dir=path.parent))
            os.rename(path, old / path.name)
            os.rename(tmp, path)
            shutil.rmtree(old, ignore_errors=True)
            return
        try:
            os.rename(tmp, path)
        except OSError:
            if not path.is_dir():  # not a concurrent build that won the race
                raise
    finally:
        if tmp.exists():
            shutil.rmtree(tmp, ignore_errors=True)


def writable_dir(path: str | os.PathLike, option: str = "--out") -> Path:
    """``path`` as a folder this process can write in (created if missing); MetaSimError naming
    ``option`` otherwise. Commands call it before any long work, so a bad folder fails in a second."""
    path = Path(path)
    try:
        path.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryFile(dir=path):  # a unique name: concurrent workers share the folder
            pass
    except OSError as exc:
        raise MetaSimError(f"cannot write to folder {path}: {exc.strerror}; choose another {option}") from None
    return path


@contextmanager
def made_folder(path: str | os.PathLike, option: str = "--out") -> Iterator[Path]:
    """``path`` as a folder this process can write in (``writable_dir``) for a block that writes into it.
    When the block fails, the folders made for it are removed again if they are still empty, so a command
    that fails leaves no empty folder behind."""
    path = Path(path)
    made = list(itertools.takewhile(lambda folder: not folder.exists(), (path, *path.parents)))
    try:
        yield writable_dir(path, option)
    except BaseException:
        for folder in made:  # the deepest first: a parent empties as its child goes
            try:
                folder.rmdir()
            except OSError:
                break
        raise


def write_bytes_atomic(path: str | os.PathLike, data: bytes) -> Path:
    """Write ``data`` to ``path`` atomically (see the module docstring); returns the path."""
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)
    return Path(path)


def write_text_atomic(path: str | os.PathLike, text: str) -> Path:
    """Write ``text`` as UTF-8 to ``path`` atomically; returns the path."""
    return write_bytes_atomic(path, text.encode("utf-8"))

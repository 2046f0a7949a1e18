"""Where the add-on's textures and designs come from: the texture bank chosen in the panel and its design space.

The default bank is the command line's (`meta-sim textures build`): byte-identical
on every machine, so presets written by `meta-sim infer` name the same texture
ids. It lives in the cache folder of the preferences (see ``preferences.cache_dir``).
A scene's Folder source without a folder of its own uses the preferences' default bank folder.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import bpy

from ..meta_sim.core.errors import MetaSimError
from ..meta_sim.sim.design import DesignSpace
from ..meta_sim.sim.textures import MANIFEST, TextureBank, default_bank_dir, ensure_default_bank, load_bank, procedural
from . import preferences, tasks


@dataclass(frozen=True)
class Library:
    """A loaded texture bank and the design space over its textures."""

    bank: TextureBank
    space: DesignSpace

    def texture_parameter(self, kind: str):
        return self.space.texture_parameter(kind)


_loaded: dict[str, Library] = {}  # bank folder -> library; banks are immutable once built


def bank_folder(settings) -> Path | None:
    """The folder of a scene's Folder source: its own, else the preferences' default; None when neither is set."""
    if settings.bank_folder.strip():
        return Path(bpy.path.abspath(settings.bank_folder)).resolve()
    return preferences.default_bank_folder()


def _folder(settings) -> Path:
    if settings.bank_source == "DEFAULT":
        return default_bank_dir(cache_dir=preferences.cache_dir())
    folder = bank_folder(settings)
    if folder is None:
        raise MetaSimError("choose a texture bank folder (one written by `meta-sim textures build`), here or as "
                           "the default bank folder in the add-on's preferences")
    return folder


def get(settings, build: bool = False) -> Library | None:
    """The library the settings point at; None if it is not loaded yet and ``build`` is off.

    ``build`` builds the default bank on first use (a few seconds) and reads a user's
    bank from disk; without it nothing slow happens (panels and enum callbacks call this).
    """
    folder = _folder(settings)
    if str(folder) in _loaded:
        return _loaded[str(folder)]
    if not build and not (folder / MANIFEST).is_file():
        return None
    return tasks.run(load_steps(settings))


def load_steps(settings):
    """Steps (see ``tasks``): load the library, building the default bank first on first use (on a thread:
    Blender stays responsive, and a cancelled build leaves no bank behind); returns the library."""
    folder = _folder(settings)
    if str(folder) in _loaded:
        return _loaded[str(folder)]
    if settings.bank_source == "DEFAULT":
        cache = preferences.cache_dir()
        work = tasks.Threaded(lambda progress: ensure_default_bank(cache_dir=cache, progress=progress),
                              total=len(procedural.recipes()))
        library = Library((yield from work.wait("building the default texture bank")), DesignSpace.load())
    else:
        bank = load_bank(folder)
        library = Library(bank, DesignSpace.for_textures(f"bank:{bank.name}", bank.ids("flat"), bank.ids("sloped")))
    _loaded[str(folder)] = library
    return library


def get_quietly(settings) -> Library | None:
    """`get` for drawing code: a bad folder shows as 'no bank loaded' instead of raising."""
    try:
        return get(settings)
    except MetaSimError:
        return None


def require(settings) -> Library:
    library = get(settings)
    if library is None:
        raise MetaSimError("load a texture bank first (Texture Bank > Load)")
    return library


def clear() -> None:
    _loaded.clear()

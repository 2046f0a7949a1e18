"""Where the add-on's textures and designs come from: the texture bank and the design space chosen in the panel.

The default bank is the command line's (`meta-sim textures build`): byte-identical
on every machine, so presets written by `meta-sim infer` name the same texture
ids. It lives in the cache folder of the preferences (see ``preferences.cache_dir``).
A scene's Folder source without a folder of its own uses the preferences' default bank folder.

The design space is the command line's ``--space``: a shipped one by name or a JSON file; "Bank's
Roofs" is what `meta-sim render` takes without it (rooftops-v1 with the default bank, one parameter
per roof kind of a folder bank). A space naming textures its bank lacks finds them, as a render
does, in the default bank and then the held-out banks, built on first use.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import bpy

from ..meta_sim.core.errors import MetaSimError
from ..meta_sim.sim.design import DEFAULT_SPACE, DesignSpace, builtin_spaces
from ..meta_sim.sim.textures import (
    MANIFEST,
    TextureBank,
    default_bank_dir,
    ensure_default_bank,
    ensure_heldout_bank,
    heldout_bank_dir,
    load_bank,
    procedural,
)
from . import preferences, tasks

BANK_SPACE = "BANK"  # the space choice of `meta-sim render` without --space
FILE_SPACE = "FILE"


@dataclass(frozen=True)
class Library:
    """A loaded texture bank, the design space of the scene, and the banks its texture ids are found in
    (the bank first)."""

    bank: TextureBank
    space: DesignSpace
    banks: tuple

    def texture_parameter(self, kind: str):
        return self.space.texture_parameter(kind)

    def bank_of(self, texture_id: str) -> TextureBank | None:
        """The first bank holding ``texture_id``, or None."""
        return next((bank for bank in self.banks if bank.contains(texture_id)), None)


_banks: dict[str, TextureBank] = {}  # bank folder -> bank; banks are immutable once built
_spaces: dict[tuple, DesignSpace] = {}  # space key -> space
_loaded: dict[tuple, Library] = {}  # (bank folder, space key) -> library


# The design space menu: Bank's Roofs, every shipped space, a file.
SPACE_ITEMS = [(BANK_SPACE, "Bank's Roofs", "A parameter per roof kind: rooftops-v1 with the default bank, the "
                 "bank's own textures with a folder bank (as `meta-sim render` without --space)"),
                *[(name, name, f"The design space {name} that meta-sim ships") for name in builtin_spaces()],
                (FILE_SPACE, "File", "A design space JSON file (format meta-sim-design-space)")]


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


def _space_key(settings) -> tuple:
    """What names the scene's space: the menu's choice, and for a file its path and modification time (an
    edited file is read again)."""
    if settings.space != FILE_SPACE:
        return (settings.space,)
    if not settings.space_file.strip():
        raise MetaSimError("choose a design space file (City > Design Space > File)")
    path = Path(bpy.path.abspath(settings.space_file)).resolve()
    try:
        return (FILE_SPACE, str(path), path.stat().st_mtime_ns)
    except OSError:
        raise MetaSimError(f"design space file {path} does not exist; choose another") from None


def space(settings, bank: TextureBank | None = None) -> DesignSpace:
    """The scene's design space (quick: read from its JSON, kept); Bank's Roofs of a folder bank needs ``bank``."""
    key = _space_key(settings)
    if key[0] == BANK_SPACE and settings.bank_source == "FOLDER":
        if bank is None:
            raise MetaSimError("load the texture bank first: the design space is its roofs")
        key = (BANK_SPACE, str(bank.root))
    if key not in _spaces:
        if key[0] == BANK_SPACE and len(key) > 1:
            _spaces[key] = DesignSpace.for_textures(f"bank:{bank.name}", bank.ids("flat"), bank.ids("sloped"))
        else:
            _spaces[key] = DesignSpace.load(key[1] if key[0] == FILE_SPACE else
                                            DEFAULT_SPACE if key[0] == BANK_SPACE else key[0])
    return _spaces[key]


def space_quietly(settings) -> DesignSpace | None:
    """`space` for drawing code: None when it cannot be read yet."""
    try:
        return space(settings, _banks.get(str(_folder(settings))))
    except MetaSimError:
        return None


def _missing(space_: DesignSpace, banks) -> list[str]:
    """The texture choices of the space that none of ``banks`` holds."""
    return [choice for p in space_.parameters if getattr(p, "texture_kind", None) for choice in p.choices
            if not any(bank.contains(choice) for bank in banks)]


def _needed(chosen: DesignSpace, bank: TextureBank, cache: Path) -> list[tuple[str, Path, Callable]]:
    """The banks after ``bank`` that hold the textures of ``chosen`` it lacks, in the order `meta-sim render`
    looks ids up (the default bank, then the held-out banks), told by their recipes' ids (nothing is read or
    built here): each bank's name, folder and what builds it."""
    fallbacks = [("default", default_bank_dir(cache_dir=cache), procedural.recipes(),
                  lambda: ensure_default_bank(cache_dir=cache))]
    fallbacks += [(name, heldout_bank_dir(cache_dir=cache, name=name), procedural.recipes(heldout=name),
                   lambda name=name: ensure_heldout_bank(cache_dir=cache, name=name))
                  for name in procedural.HELDOUT_SETS]
    missing, out = set(_missing(chosen, [bank])), []
    for name, where, recipes, build in fallbacks:
        ids = {recipe.id for recipe in recipes}
        if where != bank.root and missing & ids:
            out.append((name, where, build))
            missing -= ids
    return out


def get(settings, build: bool = False) -> Library | None:
    """The library the settings point at; None if it is not loaded yet and ``build`` is off.

    ``build`` builds the banks it needs on first use (seconds) and reads a user's bank from disk; without
    it nothing slow happens (panels and enum callbacks call this).
    """
    folder = _folder(settings)
    key = (str(folder), _space_key(settings))
    if key in _loaded:
        return _loaded[key]
    if not build:
        if not (folder / MANIFEST).is_file():
            return None
        if str(folder) not in _banks:
            _banks[str(folder)] = load_bank(folder)
        bank = _banks[str(folder)]
        if any(not (where / MANIFEST).is_file() for _, where, _ in _needed(space(settings, bank), bank,
                                                                          preferences.cache_dir())):
            return None  # a bank still to be built: Load builds it, with progress
    return tasks.run(load_steps(settings))


def load_steps(settings):
    """Steps (see ``tasks``): load the library, building the default bank and the held-out banks the space
    needs on first use (on a thread: Blender stays responsive, and a cancelled build leaves no bank behind);
    returns the library."""
    folder, cache = _folder(settings), preferences.cache_dir()
    key = (str(folder), _space_key(settings))
    if key in _loaded:
        return _loaded[key]
    if str(folder) not in _banks:
        if settings.bank_source == "DEFAULT":
            work = tasks.Threaded(lambda progress: ensure_default_bank(cache_dir=cache, progress=progress),
                                  total=len(procedural.recipes()))
            _banks[str(folder)] = yield from work.wait("building the default texture bank")
        else:
            _banks[str(folder)] = load_bank(folder)
    bank = _banks[str(folder)]
    chosen = space(settings, bank)
    banks = [bank]
    needed = _needed(chosen, bank, cache)
    for k, (name, where, build) in enumerate(needed):
        if str(where) not in _banks and (where / MANIFEST).is_file():
            _banks[str(where)] = load_bank(where)
        elif str(where) not in _banks:  # built on a thread, as the default bank is
            work = tasks.Threaded(lambda progress, build=build: build())
            text = f"building the texture bank {name} (design space {chosen.name} names its textures)"
            _banks[str(where)] = yield from work.wait(text, k / len(needed), (k + 1) / len(needed))
        banks.append(_banks[str(where)])
    missing = _missing(chosen, banks)
    if missing:
        raise MetaSimError(f"design space {chosen.name!r} names texture {missing[0]!r}, which no texture bank "
                           "holds; choose another bank or space")
    _loaded[key] = Library(bank, chosen, tuple(banks))
    return _loaded[key]


def switch(settings, chosen: DesignSpace) -> Library:
    """Make ``chosen`` the scene's design space (the current one, or a shipped one by name: what a preset's
    space can be, see ``design_assets.preset_space``) and load its library."""
    if chosen.name != space(settings, _banks.get(str(_folder(settings)))).name:
        settings.space = chosen.name
    return tasks.run(load_steps(settings))


def get_quietly(settings) -> Library | None:
    """`get` for drawing code: a bad folder or space shows as 'no bank loaded' instead of raising."""
    try:
        return get(settings)
    except MetaSimError:
        return None


def require(settings) -> Library:
    library = get(settings)
    if library is None:
        raise MetaSimError("load the texture bank first (Design > Load Texture Bank)")
    return library


def clear() -> None:
    _banks.clear()
    _spaces.clear()
    _loaded.clear()

"""From render options (``meta_sim.render.options``) to validated jobs and settings."""

from __future__ import annotations

from pathlib import Path

from ..core.errors import MetaSimError
from ..sim.design import DesignSpace
from ..sim.quality import get_preset
from ..sim.textures import ensure_default_bank, ensure_heldout_bank, load_bank
from .jobs import RenderSettings, design_jobs, sample_designs, single_job

# Bounds of the whole-number options: a city seed is a numpy seed (not negative); beyond these a render
# would not fit a machine's memory (tile pixels) or a folder (tiles, designs).
LIMITS = (("seed", 0, 2**63 - 1), ("tiles", 1, 4096), ("tile_px", 16, 8192), ("cities", 1, 100_000))
MAX_DESIGNS = 10_000_000


def plan(options: dict):
    """Validated (jobs, settings) from parsed options (``RENDER_OPTIONS`` dests); MetaSimError on bad input.

    The design space comes from ``space`` (a built-in name or a JSON file), else from ``bank`` (one
    parameter per roof kind it has), else the default; held-out texture ids are accepted in designs.
    """
    if options.get("out") is None:
        raise MetaSimError("give an output folder with --out")
    if (options.get("design") is None) == (options.get("random_designs") is None):
        raise MetaSimError("give exactly one of --design or --random-designs")
    for name, low, high in LIMITS:
        value = options[name]
        if isinstance(value, bool) or not isinstance(value, int) or not low <= value <= high:
            raise MetaSimError(f"--{name.replace('_', '-')} must be a whole number from {low} to {high}, not {value!r}")
    if options.get("random_designs") is not None and not 1 <= options["random_designs"] <= MAX_DESIGNS:
        raise MetaSimError(f"--random-designs must be from 1 to {MAX_DESIGNS}")
    if not 0.01 <= options["gsd"] <= 10.0:
        raise MetaSimError("--gsd must be between 0.01 and 10 metres per pixel")
    preset = get_preset(options["preset"])
    banks = [load_bank(options["bank"])] if options.get("bank") else [ensure_default_bank()]
    if options.get("space"):
        space = DesignSpace.load(options["space"])
    elif options.get("bank"):
        space = DesignSpace.for_textures(f"bank:{banks[0].name}", banks[0].ids("flat"), banks[0].ids("sloped"))
    else:
        space = DesignSpace.load()
    heldout = ensure_heldout_bank()
    extra = {p.name: heldout.ids(p.texture_kind) for p in space.parameters
             if getattr(p, "texture_kind", None)}
    if options.get("design") is not None:
        jobs = [single_job(space, space.parse(options["design"], extra), options["seed"])]
    else:
        designs = sample_designs(space, options["random_designs"], options["seed"])
        jobs = design_jobs(space, designs, options["seed"], options["cities"])
    settings = RenderSettings(space=space, banks=banks + [heldout], preset=preset,
                              out_dir=Path(options["out"]), n_tiles=options["tiles"],
                              tile_px=options["tile_px"], pixel_size_m=options["gsd"],
                              preview=bool(options.get("preview")))
    return jobs, settings

"""From render options (``meta_sim.render.options``) to validated jobs and settings."""

from __future__ import annotations

from pathlib import Path

from ..core.errors import MetaSimError
from ..sim.design import DesignSpace
from ..sim.quality import get_preset
from ..sim.textures import ensure_default_bank, ensure_heldout_bank, load_bank
from .jobs import RenderSettings, design_jobs, sample_designs, single_job


def plan(options: dict):
    """Validated (jobs, settings) from parsed options (``RENDER_OPTIONS`` dests); MetaSimError on bad input.

    The design space comes from ``space`` (a built-in name or a JSON file), else from ``bank`` (one
    parameter per roof kind it has), else the default; held-out texture ids are accepted in designs.
    """
    if options.get("out") is None:
        raise MetaSimError("give an output folder with --out")
    if (options.get("design") is None) == (options.get("random_designs") is None):
        raise MetaSimError("give exactly one of --design or --random-designs")
    for name, low in (("tiles", 1), ("tile_px", 16), ("cities", 1)):
        if options[name] < low:
            raise MetaSimError(f"--{name.replace('_', '-')} must be at least {low}")
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
        if options["random_designs"] < 1:
            raise MetaSimError("--random-designs must be at least 1")
        designs = sample_designs(space, options["random_designs"], options["seed"])
        jobs = design_jobs(space, designs, options["seed"], options["cities"])
    settings = RenderSettings(space=space, banks=banks + [heldout], preset=preset,
                              out_dir=Path(options["out"]), n_tiles=options["tiles"],
                              tile_px=options["tile_px"], pixel_size_m=options["gsd"],
                              preview=bool(options.get("preview")))
    return jobs, settings

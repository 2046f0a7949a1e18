"""From render options (``meta_sim.render.options``) to validated jobs and settings."""

from __future__ import annotations

from pathlib import Path

from ..core.errors import MetaSimError
from ..sim.design import DesignSpace
from ..sim.ground import get_mix
from ..sim.jitter import check_strength
from ..sim.layout import parse_style, style_text
from ..sim.presets import load_preset
from ..sim.quality import get_preset
from ..sim.sensor import get_sensor
from ..sim.textures import ensure_default_bank, ensure_heldout_banks, load_bank
from .jobs import RenderSettings, design_jobs, sample_designs, sample_population, single_job

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
    given = [name for name in ("design", "random_designs", "population") if options.get(name) is not None]
    if len(given) != 1:
        raise MetaSimError("give exactly one of --design, --random-designs or --population")
    for name, low, high in LIMITS:
        value = options[name]
        if isinstance(value, bool) or not isinstance(value, int) or not low <= value <= high:
            raise MetaSimError(f"--{name.replace('_', '-')} must be a whole number from {low} to {high}, not {value!r}")
    if options.get("random_designs") is not None and not 1 <= options["random_designs"] <= MAX_DESIGNS:
        raise MetaSimError(f"--random-designs must be from 1 to {MAX_DESIGNS}")
    if options.get("population") is not None:
        images, r = options.get("images", 100), options.get("r", 0.25)
        if isinstance(images, bool) or not isinstance(images, int) or not 1 <= images <= MAX_DESIGNS:
            raise MetaSimError(f"--images must be from 1 to {MAX_DESIGNS}, not {images!r}")
        if not (isinstance(r, (int, float)) and 0.0 <= r <= 1.0):
            raise MetaSimError(f"-r must be a probability from 0 to 1, not {r!r}")
    if not 0.01 <= options["gsd"] <= 10.0:
        raise MetaSimError("--gsd must be between 0.01 and 10 metres per pixel")
    preset = get_preset(options["preset"])
    sensor = get_sensor(options.get("sensor"))
    roof_jitter = check_strength(options.get("roof_jitter", 0.0))
    ground = options.get("ground") or "plain"
    get_mix(ground)
    style = style_text(parse_style(options.get("style") or "suburban"))  # checked, in one spelling
    banks = [load_bank(options["bank"])] if options.get("bank") else [ensure_default_bank()]
    if options.get("space"):
        space = DesignSpace.load(options["space"])
    elif options.get("bank"):
        space = DesignSpace.for_textures(f"bank:{banks[0].name}", banks[0].ids("flat"), banks[0].ids("sloped"))
    else:
        space = DesignSpace.load()
    heldout = ensure_heldout_banks()
    # Held-out textures a design may name (heldout-v5 holds heldout-v4's: each once).
    extra = {p.name: list(dict.fromkeys(t for bank in heldout for t in bank.ids(p.texture_kind)))
             for p in space.parameters if getattr(p, "texture_kind", None)}
    if options.get("design") is not None:
        jobs = [single_job(space, space.parse(options["design"], extra), options["seed"])]
    elif options.get("population") is not None:
        population = load_preset(options["population"], space, extra)
        if population.kind != "population" or not population.designs:
            raise MetaSimError(f"{options['population']}: not a population preset (the population.json that "
                               "`meta-sim infer` writes)")
        designs = [space.validate(entry["design"], extra) for entry in population.designs]
        sampled = sample_population(space, designs, [entry["count"] for entry in population.designs],
                                    options.get("images", 100), options.get("r", 0.25), options["seed"])
        jobs = design_jobs(space, sampled, options["seed"], options["cities"])
    else:
        designs = sample_designs(space, options["random_designs"], options["seed"])
        jobs = design_jobs(space, designs, options["seed"], options["cities"])
    settings = RenderSettings(space=space, banks=banks + heldout, preset=preset,
                              out_dir=Path(options["out"]), n_tiles=options["tiles"],
                              tile_px=options["tile_px"], pixel_size_m=options["gsd"],
                              preview=bool(options.get("preview")), sensor=sensor, roof_jitter=roof_jitter,
                              ground=ground, style=style)
    if style != "suburban" and "style" in space.layout:
        raise MetaSimError(f"design space {space.name!r} declares a city style already; "
                           "drop --style or the space's layout style")
    return jobs, settings

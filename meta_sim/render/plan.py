"""From render options (``meta_sim.render.options``) to validated jobs and settings."""

from __future__ import annotations

from pathlib import Path

from ..core.errors import MetaSimError
from ..core.progress import Bars
from ..sim.design import DEFAULT_SPACE, DesignSpace, builtin_spaces
from ..sim.ground import get_mix
from ..sim.jitter import check_strength
from ..sim.layout import MAX_CITY_M, MIN_CITY_M, city_size_m, parse_style, style_text
from ..sim.presets import load_preset
from ..sim.quality import get_preset
from ..sim.sensor import get_sensor
from ..sim.textures import build_steps, ensure_default_bank, ensure_heldout_banks, heldout_ids, load_bank
from .jobs import RenderSettings, design_jobs, sample_designs, sample_population, single_job

# Bounds of the whole-number options: a city seed is a numpy seed (not negative); beyond these a render
# would not fit a machine's memory (tile pixels) or a folder (tiles, designs).
LIMITS = (("seed", 0, 2**63 - 1), ("tiles", 1, 4096), ("tile_px", 16, 8192), ("cities", 1, 100_000))
MAX_DESIGNS = 10_000_000


def plan(options: dict, bars: Bars | None = None):
    """Validated (jobs, settings) from parsed options (``RENDER_OPTIONS`` dests); MetaSimError on bad input.

    The design space comes from ``space`` (a built-in name or a JSON file), else from ``bank`` (one
    parameter per roof kind it has), else from the population preset (the space it was inferred in), else
    the default; held-out texture ids are accepted in designs. ``bars`` shows the texture banks built on
    first use: the default bank, and only those held-out sets whose textures the designs name.
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
    _check_city_size(options["tiles"], options["tile_px"], options["gsd"])
    preset = get_preset(options["preset"])
    sensor = get_sensor(options.get("sensor"))
    roof_jitter = check_strength(options.get("roof_jitter", 0.0))
    ground = options.get("ground") or "plain"
    get_mix(ground)
    style = style_text(parse_style(options.get("style") or "suburban"))  # checked, in one spelling
    bank = load_bank(options["bank"]) if options.get("bank") else None
    population = load_preset(options["population"]) if options.get("population") is not None else None
    if options.get("space"):
        space = DesignSpace.load(options["space"])
    elif options.get("bank"):
        space = DesignSpace.for_textures(f"bank:{bank.name}", bank.ids("flat"), bank.ids("sloped"))
    elif population is not None:
        space = population_space(population, options["population"])
    else:
        space = DesignSpace.load()
    if population is not None and population.design_space and population.design_space != space.name:
        raise MetaSimError(f"{options['population']}: the population was inferred in design space "
                           f"{population.design_space!r}, not {space.name!r}; drop --space (and --bank) or give "
                           f"that space's JSON with --space FILE")
    if style != "suburban" and "style" in space.layout:
        raise MetaSimError(f"design space {space.name!r} declares a city style already; "
                           "drop --style or the space's layout style")
    extra = {p.name: heldout_ids(p.texture_kind) for p in space.parameters if getattr(p, "texture_kind", None)}
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
    named = {job.design[name] for job in jobs for name in extra}
    # The banks last, so that bad input fails before a fresh cache spends seconds building them.
    bank = bank or ensure_default_bank(progress=bars("texture bank default", build_steps()) if bars else None)
    heldout = ensure_heldout_banks(ids=[t for t in named if not bank.contains(t)], bars=bars)
    settings = RenderSettings(space=space, banks=[bank, *heldout], preset=preset,
                              out_dir=Path(options["out"]), n_tiles=options["tiles"],
                              tile_px=options["tile_px"], pixel_size_m=options["gsd"],
                              preview=bool(options.get("preview")), sensor=sensor, roof_jitter=roof_jitter,
                              ground=ground, style=style)
    return jobs, settings


def population_space(population, path) -> DesignSpace:
    """The design space a population preset was inferred in, when the package ships it by that name (the
    default space when it records none); MetaSimError naming --space otherwise (a space from a file is not
    found by its name alone)."""
    name = population.design_space
    if not name or name in builtin_spaces():
        return DesignSpace.load(name or DEFAULT_SPACE)
    raise MetaSimError(f"{path}: the population was inferred in design space {name!r}, which meta-sim does not "
                       "ship; give that space's JSON with --space FILE")


def _check_city_size(n_tiles: int, tile_px: int, gsd: float) -> None:
    """MetaSimError naming the options to change when the city the tiles cover is smaller or larger than
    the layout lays out, so that it fails here, before a folder or a farm job is made, not mid-render."""
    width, height = city_size_m(n_tiles, tile_px * gsd)
    covers = f"--tiles {n_tiles} of --tile-px {tile_px} at --gsd {gsd:g} cover {width:.1f} x {height:.1f} m"
    if min(width, height) < MIN_CITY_M:
        raise MetaSimError(f"{covers}, less than the {MIN_CITY_M:g} m a city needs across; raise --tile-px or --gsd")
    if max(width, height) > MAX_CITY_M:
        raise MetaSimError(f"{covers}, more than the {MAX_CITY_M:g} m a city spans at most; lower --tile-px, --gsd or "
                           "--tiles")

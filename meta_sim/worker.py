"""Headless render worker: one entry point for `meta-sim render`, `python -m` and `blender -b`.

    python -m meta_sim.worker --design flat_roof=3,sloped_roof=7 --seed 1 --tiles 9 --out DIR
    blender -b --python-exit-code 1 --python jobs/render_tiles.py -- --design ... --out DIR
    python -m meta_sim.worker --job job.json [--shard 0/4]   # the tasks of a farm job manifest

Blender's own Python has neither click nor tqdm, so the options are declared
once here as data; argparse reads them in a worker and the click CLI builds
its ``render`` command from the same table.
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import dataclass
from pathlib import Path

from .errors import MetaSimError


@dataclass(frozen=True)
class Option:
    flag: str
    type: type
    default: object
    help: str
    is_flag: bool = False

    @property
    def dest(self) -> str:
        return self.flag.lstrip("-").replace("-", "_")


RENDER_OPTIONS = (
    Option("--design", str, None, "design to render, e.g. flat_roof=3,sloped_roof=sloped-clay-red "
           "(0-based index or texture id; held-out texture ids are accepted)"),
    Option("--random-designs", int, None, "render N uniformly sampled designs (a training set) instead"),
    Option("--seed", int, 1, "city seed (random designs: also the design sampling seed)"),
    Option("--cities", int, 8, "random designs: design k is rendered in city seed + k % CITIES"),
    Option("--tiles", int, 9, "tiles per design (a near-square grid of adjacent tiles)"),
    Option("--preset", str, "fast", "render quality preset: fast (Workbench), balanced or quality (Cycles)"),
    Option("--out", Path, None, "output folder for the EXR tiles (created if missing)"),
    Option("--bank", Path, None, "texture bank folder (default: the built-in bank, built on first use)"),
    Option("--space", str, None, "design space: a built-in name or a JSON file (default: rooftops-v1, "
           "or with --bank, one parameter per roof kind of that bank)"),
    Option("--tile-px", int, 384, "tile width and height in pixels"),
    Option("--gsd", float, 0.3, "ground sampling distance: metres per pixel"),
    Option("--preview", bool, False, "also write an RGB PNG and a colour-coded label PNG per tile", True),
)


def build_argparser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="meta_sim.worker", description=__doc__.splitlines()[0])
    for opt in RENDER_OPTIONS:
        if opt.is_flag:
            parser.add_argument(opt.flag, action="store_true", help=opt.help)
        else:
            parser.add_argument(opt.flag, type=opt.type, default=opt.default, help=opt.help)
    parser.add_argument("--job", type=Path, default=None,
                        help="render the tasks of a job manifest (`meta-sim jobs plan`) instead of the options above")
    parser.add_argument("--shard", default=None, help="with --job: only the i-th of n shards of its tasks, e.g. 0/4")
    return parser


def plan(options: dict):
    """Validated (jobs, settings) from parsed options; MetaSimError on bad input."""
    from .design import DesignSpace
    from .render import RenderSettings, design_jobs, sample_designs, single_job
    from .render_presets import get_preset
    from .textures import ensure_default_bank, ensure_heldout_bank, load_bank

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


def run(options: dict, progress=None):
    from .render import render_jobs

    jobs, settings = plan(options)
    return render_jobs(jobs, settings, progress), len(jobs) * settings.n_tiles


def run_job(path: Path, shard: str | None = None, progress=None) -> list[tuple[str, str]]:
    """Render every task of a job manifest (or of one shard), each task on its own so a task
    that cannot render (a missing texture, ...) is reported while the others still render.

    Returns the failed tasks as (name, message).
    """
    from .farm import manifest as farm
    from .render import render_jobs

    manifest = farm.load(path)
    if shard is not None:
        manifest = manifest.shard(*farm.parse_shard(shard))
    jobs, settings = farm.render_setup(manifest)
    failures = []
    for job in jobs:
        try:
            render_jobs([job], settings, progress, record=False)
        except MetaSimError as exc:
            failures.append((job.name, str(exc)))
            print(f"meta-sim worker: task {job.name} failed: {exc}", file=sys.stderr, flush=True)
        else:
            print(f"meta-sim worker: task {job.name} done", flush=True)
    return failures


def main(argv: list[str] | None = None) -> int:
    """Exit code 0 when everything rendered, 1 when some job tasks failed, 2 on bad input."""
    args = build_argparser().parse_args(argv)
    started = time.perf_counter()
    done = [0]

    def progress(n: int) -> None:
        done[0] += n
        print(f"meta-sim worker: {done[0]} tiles done", flush=True)

    try:
        if args.job is not None:
            if args.design is not None or args.random_designs is not None or args.out is not None:
                raise MetaSimError("--job takes its designs and output folder from the manifest; "
                                   "drop --design, --random-designs and --out")
            failures = run_job(args.job, args.shard, progress)
            print(f"meta-sim worker: {done[0]} tiles done, {len(failures)} tasks failed "
                  f"in {time.perf_counter() - started:.1f} s", flush=True)
            return 1 if failures else 0
        if args.shard is not None:
            raise MetaSimError("--shard needs --job")
        summary, total = run(vars(args), progress)
    except MetaSimError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(f"meta-sim worker: {summary.written} written, {summary.skipped} already done, "
          f"{total} tiles in {time.perf_counter() - started:.1f} s", flush=True)
    return 0


def blender_argv(argv: list[str]) -> list[str]:
    """The arguments after ``--`` (Blender keeps everything before it for itself)."""
    return argv[argv.index("--") + 1:] if "--" in argv else []


if __name__ == "__main__":
    sys.exit(main())

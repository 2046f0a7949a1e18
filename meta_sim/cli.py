"""`meta-sim`: the command line. It only parses options and calls the modules that do the work."""

from __future__ import annotations

import functools
import json
import os
import sys
from pathlib import Path

import click

from .errors import MetaSimError
from .fileio import write_text_atomic

# nams.model.ARCHITECTURES, named here so that `--help` does not import torch (a test keeps them equal).
ARCHITECTURE_NAMES = ("paper", "factorised", "additive")


class _Group(click.Group):
    """Prints MetaSimError as one line and exits 2, without a traceback."""

    def invoke(self, ctx):
        try:
            return super().invoke(ctx)
        except MetaSimError as exc:
            click.echo(f"error: {exc}", err=True)
            sys.exit(2)


@click.group(cls=_Group, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(package_name="meta-sim")
def main():
    """meta-sim: design synthetic overhead imagery by Neural-Adjoint Meta-Simulation."""


# --- textures ------------------------------------------------------------------
@main.group()
def textures():
    """Build, inspect and compare texture banks."""


@textures.command("build")
@click.option("--out", type=click.Path(path_type=Path), default=None,
              help="folder for the bank (default: the cache folder the renderer uses)")
@click.option("--from", "source", type=click.Path(path_type=Path), default=None,
              help="build from your own photos: a folder with flat/ and sloped/ subfolders")
@click.option("--heldout", is_flag=True, help="build the held-out set (design-gap textures) instead")
@click.option("--size", type=int, default=256, show_default=True, help="texture size in pixels")
@click.option("--repeat-m", type=float, default=8.0, show_default=True,
              help="with --from: physical size of one photo repeat in metres")
def textures_build(out, source, heldout, size, repeat_m):
    """Write a texture bank: images, manifest.json and the HSV similarity matrix."""
    from . import textures as tx

    if source is not None:
        if out is None:
            raise MetaSimError("with --from, give the bank folder to write with --out")
        bank = tx.build_bank_from_folder(source, out, repeat_m=repeat_m, size=size)
    elif out is None:
        bank = tx.ensure_heldout_bank() if heldout else tx.ensure_default_bank()
    else:
        bank = tx.build_default_bank(out, size=size, heldout=heldout)
    counts = {kind: len(bank.ids(kind)) for kind in ("flat", "sloped")}
    click.echo(f"bank {bank.root}: {counts['flat']} flat, {counts['sloped']} sloped textures")


def _bank(path):
    from . import textures as tx

    return tx.load_bank(path) if path else tx.ensure_default_bank()


@textures.command("list")
@click.option("--bank", type=click.Path(path_type=Path), default=None, help="bank folder (default: built-in)")
def textures_list(bank):
    """Print index, id, kind, repeat size and name of every texture."""
    bank = _bank(bank)
    for kind in ("flat", "sloped"):
        for index, texture_id in enumerate(bank.ids(kind)):
            entry = bank.by_id(texture_id)
            click.echo(f"{kind:6s} {index:3d}  {entry.id:32s} {entry.repeat_m:5.1f} m  {entry.name}")


@textures.command("sheet")
@click.option("--bank", type=click.Path(path_type=Path), default=None, help="bank folder (default: built-in)")
@click.option("--out", type=click.Path(path_type=Path), required=True, help="PNG file to write")
@click.option("--thumb", type=int, default=96, show_default=True, help="thumbnail size in pixels")
def textures_sheet(bank, out, thumb):
    """Write a contact sheet PNG of a bank (flat textures first, then sloped)."""
    from . import textures as tx

    tx.contact_sheet(_bank(bank), out, thumb=thumb)
    click.echo(f"wrote {out}")


@textures.command("similarity")
@click.option("--bank", type=click.Path(path_type=Path), default=None, help="bank folder (default: built-in)")
@click.option("--against", type=click.Path(path_type=Path), default=None,
              help="score this bank's textures (rows) against --bank (columns), e.g. the held-out set")
@click.option("--out", type=click.Path(path_type=Path), required=True, help="JSON file to write")
def textures_similarity(bank, against, out):
    """Write the HSV colour similarity matrix (histogram intersection on the HSV cone)."""
    from . import textures as tx

    base = _bank(bank)
    if against is None:
        tx.write_similarity(base, out)
    else:
        tx.write_similarity(tx.load_bank(against), out, other_bank=base)
    click.echo(f"wrote {out}")


# --- render --------------------------------------------------------------------
def _render_command():
    from .worker import RENDER_OPTIONS

    def render(**options):
        """Render tiles of a city with a design (or many random designs) to EXR files.

        Each tile is one EXR with RGB and exact label channels (building mask,
        roof class, instance id) plus the design, seed and settings in its
        header. A rerun skips tiles already written and valid.
        """
        from tqdm import tqdm

        from .worker import plan
        from .render import render_jobs

        jobs, settings = plan(options)
        with tqdm(total=len(jobs) * settings.n_tiles, unit="tile", desc="render") as bar:
            summary = render_jobs(jobs, settings, bar.update)
        click.echo(f"{summary.written} tiles written, {summary.skipped} already done, in {settings.out_dir}")

    command = render
    for opt in reversed(RENDER_OPTIONS):
        if opt.is_flag:
            command = click.option(opt.flag, is_flag=True, help=opt.help)(command)
        else:
            kind = click.Path(path_type=Path) if opt.type is Path else opt.type
            command = click.option(opt.flag, type=kind, default=opt.default, show_default=opt.default is not None,
                                   help=opt.help)(command)
    return main.command("render")(command)


_render_command()


# --- NAMS: dataset, train, infer, eval ---------------------------------------------
def _torch_threads(command):
    """Run a torch-side command with META_SIM_THREADS intra-op threads, else all CPUs but one.

    Torch's default (one thread per CPU) collapses when anything else runs: on 2 CPUs while Blender
    rendered, a NAMS training epoch took 2.9 s with 2 threads and 0.96 s with 1.
    """

    @functools.wraps(command)
    def run(*args, **kwargs):
        import torch

        wanted = os.environ.get("META_SIM_THREADS")
        try:
            threads = int(wanted) if wanted else max(1, (os.cpu_count() or 1) - 1)
        except ValueError:
            raise MetaSimError(f"META_SIM_THREADS must be a whole number, not {wanted!r}") from None
        torch.set_num_threads(max(1, threads))
        return command(*args, **kwargs)

    return run


class _Bars:
    """One tqdm bar per stage; opening the next closes the previous one. A bar appears with the
    stage's first step, so a stage that finds everything cached shows none."""

    def __init__(self):
        self.bar = None
        self.stage = 0

    def __call__(self, label: str, total: int):
        from tqdm import tqdm

        self.close()
        self.stage += 1
        stage = self.stage

        def update(n: int = 1) -> None:
            if stage != self.stage:  # a stage already closed
                return
            if self.bar is None:
                self.bar = tqdm(total=total, desc=label, unit="it", leave=True)
            self.bar.update(n)

        return update

    def close(self):
        if self.bar is not None:
            self.bar.close()
            self.bar = None


def _dataset_options(command):
    for decorator in reversed([
        click.option("--designs", type=int, default=None, help="training designs [default: 600; paper: 1700]"),
        click.option("--tiles", type=int, default=None, help="tiles per design [default: 2; paper: 9]"),
        click.option("--paper-scale", is_flag=True, help="the paper's scale: 1,700 designs x 9 tiles"),
        click.option("--profile", type=click.Choice(["fast", "balanced", "paper"]), default=None,
                     help="a recommended training set (see `make bench-tradeoff`); --designs/--tiles override it"),
        click.option("--dataset-seed", type=int, default=1, show_default=True, help="design sampling and city seed"),
        click.option("--cities", type=int, default=8, show_default=True, help="cities the designs are spread over"),
        click.option("--preset", default="fast", show_default=True, help="render preset of the training tiles"),
        click.option("--tile-px", type=int, default=384, show_default=True, help="training tile size in pixels"),
        click.option("--gsd", type=float, default=0.3, show_default=True, help="training tiles' metres per pixel"),
        click.option("--extractor", default="colour-texture", show_default=True,
                     help="features: colour-texture, torchscript:FILE, export:FILE or torchvision:NAME"),
        click.option("--weights", type=click.Path(path_type=Path), default=None,
                     help="weights file for a torchvision backbone"),
        click.option("--views", type=click.Choice(["1", "2", "4", "8"]), default="8", show_default=True,
                     help="augmentation views per tile (rotations x flip) averaged into a design's features"),
        click.option("--max-epochs", type=int, default=None, help="training epochs at most (early stopping)"),
        click.option("--architecture", type=click.Choice(list(ARCHITECTURE_NAMES)), default="additive",
                     show_default=True,
                     help="NAMS networks: paper (joint E, D, P), factorised (E and D per design parameter) or "
                          "additive (factorised, P a sum over parameters)"),
        click.option("--hidden", default=None,
                     help="hidden layer sizes of each network, e.g. 1024,2048 (default: the architecture's, "
                          "1024,2048 for paper, 512,1024 for the factorised ones)"),
        click.option("--roof-colour/--no-roof-colour", default=True, show_default=True,
                     help="add colour histograms of the likely roof pixels to the features (counted on the "
                          "training tiles' labels; see `make bench-nams` for what they change)"),
        click.option("--roof-finder", type=click.Choice(["segmenter", "colour"]), default="segmenter",
                     show_default=True,
                     help="what finds the roofs whose colours are counted: a small net learnt on the training "
                          "tiles' labels (segmenter) or a pixel's colour alone (colour)"),
        click.option("--roof-weight-power", type=click.FloatRange(min=0.0, min_open=True), default=4.0,
                     show_default=True,
                     help="a pixel counts p(roof kind) to this power in its kind's colour histogram: higher "
                          "keeps only the pixels the roof finder is sure of (see `make bench-nams`)"),
        click.option("--cache", type=click.Path(path_type=Path), default=None,
                     help="cache folder (default: $META_SIM_CACHE or ~/.cache/meta-sim)"),
    ]):
        command = decorator(command)
    return command


def _configs(o):
    from .dataset import DatasetConfig
    from .workflow import ModelSettings

    if o["profile"] and o["paper_scale"]:
        raise MetaSimError("give --profile or --paper-scale, not both")
    if o["profile"]:
        from .tradeoff import get_profile

        base = get_profile(o["profile"]).dataset
    else:
        base = DatasetConfig.paper() if o["paper_scale"] else DatasetConfig()
    overrides = {k: v for k, v in (("designs", o["designs"]), ("tiles", o["tiles"])) if v is not None}
    dataset = DatasetConfig(**{**base.__dict__, **overrides, "seed": o["dataset_seed"], "cities": o["cities"],
                               "preset": o["preset"], "tile_px": o["tile_px"], "pixel_size_m": o["gsd"]})
    nams = {}
    if o["hidden"]:
        try:
            nams["hidden"] = [int(x) for x in o["hidden"].split(",")]
        except ValueError:
            raise MetaSimError("--hidden takes comma-separated integers, e.g. 1024,2048") from None
    train = {"max_epochs": o["max_epochs"]} if o["max_epochs"] else {}
    return dataset, ModelSettings(extractor=o["extractor"], weights=str(o["weights"]) if o["weights"] else None,
                                  views=int(o["views"]), nams=nams, train=train, architecture=o["architecture"],
                                  roof_colour=o["roof_colour"], roof_finder=o["roof_finder"],
                                  roof_weight_power=o["roof_weight_power"])


@main.command("dataset")
@_dataset_options
@_torch_threads
def dataset_command(**o):
    """Render a training set of uniformly sampled designs and cache its features (resumable)."""
    from .workflow import dataset_dir, prepare_features

    dataset, settings = _configs(o)
    bars = _Bars()
    features, seconds = prepare_features(dataset, settings, o["cache"], bars)
    bars.close()
    click.echo(f"{len(features.names)} designs x {dataset.tiles} tiles, features {tuple(features.features.shape)} "
               f"in {dataset_dir(dataset, o['cache'])} (render {seconds['render']:.0f} s, "
               f"features {seconds['features']:.0f} s)")


@main.command("train")
@_dataset_options
@click.option("--out", type=click.Path(path_type=Path), required=True, help="folder for nams.pt and dr.pt")
@_torch_threads
def train_command(out, **o):
    """Train NAMS (and the DR baseline) on the training set; builds the set first if needed."""
    import shutil

    from .workflow import ensure_models

    dataset, settings = _configs(o)
    bars = _Bars()
    models = ensure_models(dataset, settings, o["cache"], bars)
    bars.close()
    out.mkdir(parents=True, exist_ok=True)
    shutil.copy2(models.nams_path, out / "nams.pt")
    shutil.copy2(models.dr_path, out / "dr.pt")
    click.echo(f"wrote {out / 'nams.pt'} ({settings.architecture} NAMS) and {out / 'dr.pt'} "
               + ", ".join(f"{k} {v:.0f} s" for k, v in models.seconds.items()))


def _search_options(command):
    for decorator in reversed([
        click.option("-M", "--starts", "M", type=int, default=1000, show_default=True, help="adjoint: random starts"),
        click.option("-k", type=float, default=3.0, show_default=True, help="adjoint: starts within +-k sigma"),
        click.option("-S", "--keep", "S", type=int, default=50, show_default=True, help="best results voting"),
        click.option("--iterations", type=int, default=200, show_default=True, help="adjoint: Adam steps"),
        click.option("--lr", type=float, default=0.01, show_default=True, help="adjoint: Adam learning rate"),
        click.option("-r", "--rejection", "r", type=float, default=0.0, show_default=True,
                     help="diversify with rejection rate (paper: 0.25 on real imagery)"),
    ]):
        command = decorator(command)
    return command


@main.command("infer")
@click.argument("target_dir", type=click.Path(path_type=Path))
@click.option("--model", type=click.Path(path_type=Path), required=True, help="NAMS checkpoint (nams.pt)")
@click.option("--out", type=click.Path(path_type=Path), required=True, help="folder for presets and report")
@click.option("--group-size", type=int, default=9, show_default=True, help="target tiles per inferred design")
@click.option("--gsd", type=float, default=None,
              help="metres per pixel of the targets (default: GeoTIFF/EXR metadata, else the render's)")
@click.option("--views", type=click.Choice(["1", "2", "4", "8"]), default=None,
              help="augmentation views per tile (default: as trained)")
@click.option("--weights", type=click.Path(path_type=Path), default=None, help="backbone weights, if needed")
@click.option("--seed", type=int, default=0, show_default=True, help="search seed")
@click.option("--search", "method", type=click.Choice(["auto", "adjoint", "exhaustive"]), default="auto",
              show_default=True, help="exhaustive evaluates every design; adjoint is the paper's search")
@click.option("--profile", type=click.Choice(["fast", "balanced", "paper"]), default=None,
              help="recommended search settings (fast/balanced: exhaustive; paper: adjoint M=1000, 200 "
                   "iterations, 8 views); options given explicitly win")
@_search_options
@click.pass_context
@_torch_threads
def infer_command(ctx, target_dir, model, out, group_size, gsd, views, weights, seed, method, profile, M, k, S,
                  iterations, lr, r):
    """Infer rooftop designs for a folder of target images; write presets and a report."""
    from .infer import InferSettings, infer

    if profile:
        from .tradeoff import get_profile

        chosen = get_profile(profile)
        given = {name for name in ctx.params
                 if ctx.get_parameter_source(name) is not click.core.ParameterSource.DEFAULT}
        method = method if "method" in given else chosen.method
        M = M if "M" in given else chosen.M
        iterations = iterations if "iterations" in given else chosen.iterations
        views = views if "views" in given else str(chosen.views)
        group_size = group_size if "group_size" in given else chosen.group_size
    settings = InferSettings(group_size=group_size, method=method, M=M, k=k, S=S, iterations=iterations, lr=lr,
                             r=r, seed=seed, gsd=gsd, views=int(views) if views else None,
                             weights=str(weights) if weights else None)
    bars = _Bars()
    try:
        report = infer(target_dir, model, out, settings, bars)
    finally:
        bars.close()
    for s in report["skipped"]:
        click.echo(f"skipped {s['path']}: {s['reason']}", err=True)
    click.echo((out / "report.md").read_text())
    click.echo(f"{report['group_count']} presets in {out / 'presets'}, population in {out / 'population.json'}")


@main.command("eval")
@click.argument("experiment", type=click.Choice(["e1", "e2"]))
@click.option("--out", type=click.Path(path_type=Path), required=True, help="folder for results and nams.pt")
@click.option("--targets", type=int, default=20, show_default=True, help="target groups")
@click.option("--target-tiles", type=int, default=9, show_default=True,
              help="tiles per target group (the paper's groups have 9)")
@click.option("--seed", type=int, default=1, show_default=True, help="target seed")
@click.option("--ms2/--no-ms2", default=True, show_default=True,
              help="run the MS2 baseline (computes and caches features of every training tile once)")
@_dataset_options
@_search_options
@_torch_threads
def eval_command(experiment, out, targets, target_tiles, seed, ms2, M, k, S, iterations, lr, r, **o):
    """E1 (bank designs, unseen cities) or E2 (held-out textures): top-1/top-10 for all methods."""
    from .evaluate import EvalSettings, results_markdown, run_eval

    dataset, settings = _configs(o)
    bars = _Bars()
    results = run_eval(experiment, out, dataset, settings,
                       EvalSettings(targets=targets, tiles=target_tiles, seed=seed, ms2=ms2, M=M, k=k, S=S,
                                    iterations=iterations, lr=lr, r=r), o["cache"], bars)
    bars.close()
    click.echo(results_markdown(results))
    click.echo(f"results, sheet.png and the checkpoint nams.pt are in {out}")


# --- render farm: job manifests and executors ------------------------------------
@main.group()
def jobs():
    """Render jobs for a farm: plan a manifest, run it locally or on Dask, check it, export it."""


_PLAN_FLAGS = ("--design", "--random-designs", "--seed", "--cities", "--tiles", "--preset", "--bank", "--space",
               "--tile-px", "--gsd")


def _plan_options(command):
    from .worker import RENDER_OPTIONS

    chosen = {opt.flag: opt for opt in RENDER_OPTIONS}
    for flag in reversed(_PLAN_FLAGS):
        opt = chosen[flag]
        kind = click.Path(path_type=Path) if opt.type is Path else opt.type
        command = click.option(flag, type=kind, default=opt.default, show_default=opt.default is not None,
                               help=opt.help)(command)
    return command


@jobs.command("plan")
@_plan_options
@click.option("--out", "manifest_path", type=click.Path(path_type=Path), required=True,
              help="manifest file to write (JSON)")
@click.option("--out-dir", type=click.Path(path_type=Path), default=None,
              help="folder for the tiles [default: MANIFEST-tiles beside the manifest]")
def jobs_plan(manifest_path, out_dir, **options):
    """Write a job manifest: one task per design and city, named by its content (replanning is idempotent)."""
    from .farm import manifest as farm

    manifest = farm.plan(options, out_dir or farm.default_out_dir(manifest_path))
    farm.save(manifest, manifest_path)
    click.echo(f"{len(manifest.tasks)} tasks, {manifest.n_outputs} tiles -> {manifest.out_dir}; "
               f"wrote {manifest_path}")


@jobs.command("status")
@click.argument("manifest_path", type=click.Path(path_type=Path))
@click.option("--list", "show", is_flag=True, help="also list the missing and corrupt tiles")
def jobs_status(manifest_path, show):
    """Count done, missing and corrupt tiles of a job (tiles are read and checked as the worker does)."""
    from .farm import manifest as farm

    manifest = farm.load(manifest_path)
    status = farm.check(manifest)
    click.echo(f"{len(status.complete_tasks)}/{len(manifest.tasks)} tasks complete; tiles: "
               f"{status.count(farm.DONE)} done, {status.count(farm.MISSING)} missing, "
               f"{status.count(farm.CORRUPT)} corrupt (of {manifest.n_outputs}) in {manifest.out_dir}")
    if status.temporaries:
        click.echo(f"{len(status.temporaries)} half-written temporary files (the next `jobs run` removes them)")
    if show:
        for state in (farm.MISSING, farm.CORRUPT):
            for path in status.paths(state):
                click.echo(f"{state:8s} {path}")


@jobs.command("run")
@click.argument("manifest_path", type=click.Path(path_type=Path))
@click.option("--executor", type=click.Choice(["local", "dask"]), default="local", show_default=True,
              help="local worker processes, or dask.distributed (a LocalCluster without --scheduler)")
@click.option("--workers", type=int, default=2, show_default=True,
              help="worker processes rendering at once (with --scheduler: the cluster decides)")
@click.option("--scheduler", default=None, help="Dask scheduler address, e.g. tcp://HOST:8786")
@click.option("--blender", default=None,
              help="Blender binary to render with [default: $META_SIM_BLENDER, else the bpy module]")
@click.option("--timeout", type=float, default=None, help="seconds allowed per task before its worker is killed")
@click.option("--retries", type=int, default=2, show_default=True, help="retries of a task that failed")
@click.option("--recycle", type=int, default=4, show_default=True, help="tasks per worker process before a fresh one")
def jobs_run(manifest_path, **options):
    """Render every task not yet complete; valid tiles are kept, corrupt or partial ones re-rendered."""
    from .farm import executors, manifest as farm

    summary = executors.run(farm.load(manifest_path), executors.RunOptions(**options))
    click.echo(f"{summary.tiles_done}/{summary.tiles} tiles done ({summary.rendered} rendered now, "
               f"{summary.already_done} already valid), {summary.failed_tiles} failed, "
               f"{summary.tiles_per_second:.2f} tiles/s over {summary.seconds:.1f} s, {summary.retried} retries")
    for name, reason in summary.failed.items():
        click.echo(f"failed: {name}: {reason}", err=True)
    if summary.failed:
        sys.exit(1)


@jobs.command("export-flamenco")
@click.argument("manifest_path", type=click.Path(path_type=Path))
@click.option("--out", type=click.Path(path_type=Path), required=True,
              help="folder for the job type (put it in the Flamenco manager's scripts/ folder)")
@click.option("--shards", type=int, default=None, help="default shard count in the job form [default: tasks/8]")
def jobs_export_flamenco(manifest_path, out, shards):
    """Write a Flamenco v3 custom job type that renders the manifest in shards (jobs/farm_shard.py)."""
    from .farm import flamenco, manifest as farm

    path = flamenco.export(farm.load(manifest_path), Path(manifest_path), out, shards)
    click.echo(f"wrote {path}")


# --- benchmarks ----------------------------------------------------------------
@main.group()
def bench():
    """Measure speed; results go to benchmarks/*.json."""


@bench.command("render")
@click.option("--out", type=click.Path(path_type=Path), default=Path("benchmarks/render.json"), show_default=True)
@click.option("--designs", type=int, default=4, show_default=True, help="designs rendered per preset")
@click.option("--tiles", type=int, default=9, show_default=True, help="tiles per design")
@click.option("--repeats", type=int, default=3, show_default=True, help="runs per preset; medians are reported")
@click.option("--presets", default="fast,balanced,quality", show_default=True, help="comma-separated presets")
def bench_render(out, designs, tiles, repeats, presets):
    """Seconds per tile per preset (render + label pass + EXR write) and city build time."""
    from .bench import bench_render as run, format_render_table

    result = run(designs=designs, tiles=tiles, repeats=repeats, presets=presets.split(","))
    write_text_atomic(out, json.dumps(result, indent=2) + "\n")
    click.echo(format_render_table(result))
    click.echo(f"wrote {out}")


@bench.command("nams")
@click.option("--out", type=click.Path(path_type=Path), default=Path("benchmarks/nams.json"), show_default=True)
@click.option("--targets", type=int, default=100, show_default=True, help="target groups per experiment")
@click.option("--adjoint-targets", type=int, default=20, show_default=True,
              help="target groups for the (slow) neural-adjoint settings")
@click.option("--cache", type=click.Path(path_type=Path), default=None, help="cache folder")
@_torch_threads
def bench_nams_command(out, targets, adjoint_targets, cache):
    """Training, feature and search time, and E1/E2 accuracy per method and search setting (default scale)."""
    from .bench import bench_nams, format_nams_table

    bars = _Bars()
    result = bench_nams(targets=targets, adjoint_targets=adjoint_targets, root=cache, bar=bars)
    bars.close()
    write_text_atomic(out, json.dumps(result, indent=2) + "\n")
    click.echo(format_nams_table(result))
    click.echo(f"wrote {out}")


@bench.command("reference")
@click.option("--out", type=click.Path(path_type=Path), default=Path("benchmarks/reference.json"), show_default=True)
@click.option("--targets", type=int, default=100, show_default=True, help="target groups per experiment")
@click.option("--cache", type=click.Path(path_type=Path), default=None, help="cache folder")
def bench_reference_command(out, targets, cache):
    """E1/E2 of the roof-colour reference: how far the renders' roof colours (found with the roof labels)
    agree with the swatch similarity that scores every method."""
    from .reference import bench_reference, format_reference_table

    bars = _Bars()
    result = bench_reference(targets=targets, root=cache, bar=bars)
    bars.close()
    write_text_atomic(out, json.dumps(result, indent=2) + "\n")
    click.echo(format_reference_table(result))
    click.echo(f"wrote {out}")


@bench.command("tradeoff")
@click.option("--out", type=click.Path(path_type=Path), default=Path("benchmarks/tradeoff.json"), show_default=True)
@click.option("--plot", type=click.Path(path_type=Path), default=Path("benchmarks/tradeoff.png"), show_default=True)
@click.option("--targets", type=int, default=100, show_default=True, help="E1 target groups of 9 tiles")
@click.option("--adjoint-targets", type=int, default=20, show_default=True,
              help="target groups for the (slow) neural-adjoint settings")
@click.option("--presets", default="fast,balanced", show_default=True, help="render presets to compare")
@click.option("--profiles", default="fast,balanced,paper", show_default=True,
              help="profiles measured end to end (paper renders 15,300 tiles)")
@click.option("--cache", type=click.Path(path_type=Path), default=None, help="cache folder")
@_torch_threads
def bench_tradeoff_command(out, plot, targets, adjoint_targets, presets, profiles, cache):
    """E1 accuracy against time for every knob that costs time, and the fast/balanced/paper profiles."""
    from .tradeoff import bench_tradeoff, format_tradeoff_table, get_profile, plot_tradeoff

    names = [p for p in profiles.split(",") if p]
    for name in names:
        get_profile(name)
    bars = _Bars()
    result = bench_tradeoff(targets=targets, adjoint_targets=adjoint_targets, root=cache,
                            presets=[p for p in presets.split(",") if p], profiles=names, bar=bars)
    bars.close()
    write_text_atomic(out, json.dumps(result, indent=2) + "\n")
    plot_tradeoff(result, plot)
    click.echo(format_tradeoff_table(result))
    click.echo(f"wrote {out} and {plot}")


@bench.command("farm")
@click.option("--out", type=click.Path(path_type=Path), default=Path("benchmarks/farm.json"), show_default=True)
@click.option("--designs", type=int, default=16, show_default=True, help="tasks of the job (one design each)")
@click.option("--tiles", type=int, default=4, show_default=True, help="tiles per task")
def bench_farm_command(out, designs, tiles):
    """Tiles per second and peak memory per worker: 1 and 2 local workers, and a Dask LocalCluster."""
    from .farm.bench import bench_farm, format_farm_table

    result = bench_farm(designs=designs, tiles=tiles)
    write_text_atomic(out, json.dumps(result, indent=2) + "\n")
    click.echo(format_farm_table(result))
    click.echo(f"wrote {out}")


if __name__ == "__main__":
    main()

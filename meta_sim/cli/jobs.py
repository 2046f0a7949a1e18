"""`meta-sim jobs`: plan, check, run and export render-farm job manifests."""

from __future__ import annotations

import sys
from pathlib import Path

import click

from ..core.errors import MetaSimError
from .base import _Bars, main

# A job beyond this is more often a slip of the keyboard than a plan: days of farm time, a manifest too big to read.
MANY_TILES = 1_000_000


@main.group()
def jobs():
    """Render jobs for a farm: plan a manifest, run it locally or on Dask, check it, export it."""


_PLAN_FLAGS = ("--design", "--random-designs", "--population", "--images", "-r", "--seed", "--cities", "--tiles",
               "--preset", "--sensor", "--roof-jitter", "--ground", "--style", "--bank", "--space", "--tile-px",
               "--gsd")


def _plan_options(command):
    from ..render.options import RENDER_OPTIONS

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
@click.option("--yes", is_flag=True, help=f"plan a job of more than {MANY_TILES:,} tiles")
def jobs_plan(manifest_path, out_dir, yes, **options):
    """Write a job manifest: one task per design and city, named by its content (replanning is idempotent)."""
    from ..farm import manifest as farm

    designs = options["random_designs"] or (options["images"] if options["population"] else 1)
    if designs * options["tiles"] > MANY_TILES and not yes:
        raise MetaSimError(f"this job asks for {designs * options['tiles']:,} tiles ({designs:,} designs x "
                           f"--tiles {options['tiles']}); pass --yes to plan more than {MANY_TILES:,}")
    bars = _Bars()
    try:
        manifest = farm.plan(options, out_dir or farm.default_out_dir(manifest_path), bars)
    finally:
        bars.close()
    farm.save(manifest, manifest_path)
    click.echo(f"{len(manifest.tasks)} tasks, {manifest.n_outputs} tiles -> {manifest.out_dir}; "
               f"wrote {manifest_path}")


@jobs.command("status")
@click.argument("manifest_path", type=click.Path(path_type=Path))
@click.option("--list", "show", is_flag=True, help="also list the missing and corrupt tiles")
def jobs_status(manifest_path, show):
    """Count done, missing and corrupt tiles of a job (tiles are read and checked as the worker does).

    Exits 0 when every tile is done, 1 when some are missing or corrupt (a script can wait on it)."""
    from ..farm import manifest as farm

    manifest = farm.load(manifest_path)
    status = farm.check(manifest)
    click.echo(f"{len(status.complete_tasks)}/{len(manifest.tasks)} tasks complete; tiles: "
               f"{status.count(farm.DONE)} done, {status.count(farm.MISSING)} missing, "
               f"{status.count(farm.CORRUPT)} corrupt (of {manifest.n_outputs}) in {manifest.out_dir}")
    if status.temporaries:
        click.echo(f"{len(status.temporaries)} half-written temporary files "
                   "(`jobs run` removes those whose worker is gone)")
    if show:
        for state in (farm.MISSING, farm.CORRUPT):
            for path in status.paths(state):
                click.echo(f"{state:8s} {path}")
    if status.count(farm.DONE) < manifest.n_outputs:
        sys.exit(1)


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
    from ..farm import executors
    from ..farm import manifest as farm

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
    from ..farm import flamenco
    from ..farm import manifest as farm

    path = flamenco.export(farm.load(manifest_path), Path(manifest_path), out, shards)
    click.echo(f"wrote {path}")

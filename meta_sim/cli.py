"""`meta-sim`: the command line. It only parses options and calls the modules that do the work."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import click

from .errors import MetaSimError


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
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(result, indent=2) + "\n")
    click.echo(format_render_table(result))
    click.echo(f"wrote {out}")


if __name__ == "__main__":
    main()

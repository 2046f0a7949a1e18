"""`meta-sim export`: rendered tiles as PNG image/mask pairs or a COCO instance-segmentation set."""

from __future__ import annotations

import sys
from pathlib import Path

import click

from ..core.fileio import made_folder
from .base import _Bars, main


@main.command("export")
@click.argument("tile_dir", type=click.Path(path_type=Path))
@click.option("--format", "fmt", type=click.Choice(["png", "coco"]), default="png", show_default=True,
              help="png: images/, masks/ (255 on buildings), roof_class/ (0, 1 flat, 2 sloped) and manifest.json; "
                   "coco: images/ and annotations.json (building polygons)")
@click.option("--out", type=click.Path(path_type=Path), required=True, help="folder to write the export to")
@click.option("--overwrite", is_flag=True, help="replace an earlier export in --out (as a whole)")
def export_command(tile_dir, fmt, out, overwrite):
    """Export the rendered tiles (*.exr) of TILE_DIR as 8-bit sRGB PNGs with their labels."""
    from ..pipeline.export import export_tiles

    bars = _Bars()
    try:
        with made_folder(out.parent):
            summary = export_tiles(tile_dir, out, fmt, bars, overwrite=overwrite)
    finally:
        bars.close()
    what = f", {summary['annotations']} building annotations" if fmt == "coco" else ""
    click.echo(f"{summary['tiles']} tiles exported as {fmt}{what} to {out}")
    for path, reason in summary["skipped"]:
        click.echo(f"skipped {path}: {reason}", err=True)
    if summary["skipped"]:
        click.echo(f"error: {len(summary['skipped'])} unreadable tiles left out; render them again and export anew",
                   err=True)
        sys.exit(1)

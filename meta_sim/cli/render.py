"""`meta-sim render`: its options come from ``meta_sim.render.options``, shared with the worker."""

from __future__ import annotations

from pathlib import Path

import click

from ..core.extras import require
from ..core.fileio import made_folder
from ..core.progress import LineBar, on_terminal
from .base import _Bars, main


def _render_command():
    from ..render.options import RENDER_OPTIONS

    def render(**options):
        """Render tiles of a city with a design (or many random designs) to EXR files.

        Each tile is one EXR with RGB and exact label channels (building mask,
        roof class, instance id) plus the design, seed and settings in its
        header. A rerun skips tiles already written and valid.
        """
        from tqdm import tqdm

        from ..render.loop import render_jobs
        from ..render.plan import plan

        require("bpy", "rendering")  # before planning builds the banks
        bars = _Bars()
        try:
            jobs, settings = plan(options, bars)
        finally:
            bars.close()
        total = len(jobs) * settings.n_tiles
        with made_folder(settings.out_dir):
            bar = tqdm(total=total, unit="tile", desc="render") if on_terminal() else LineBar(total, "render", "tile")
            with bar:
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

"""Headless render worker: one entry point for `python -m` and `blender -b`.

    python -m meta_sim.render.worker --design flat_roof=3,sloped_roof=7 --seed 1 --tiles 9 --out DIR
    blender -b --python-exit-code 1 --python jobs/render_tiles.py -- --design ... --out DIR

The tasks of a farm job manifest run through ``meta_sim.farm.worker`` instead.
"""

from __future__ import annotations

import argparse
import sys
import time

from ..core.errors import MetaSimError
from .options import RENDER_OPTIONS
from .plan import plan


def build_argparser() -> argparse.ArgumentParser:
    """An argparse parser for ``RENDER_OPTIONS`` (Blender's Python has no click)."""
    parser = argparse.ArgumentParser(prog="meta_sim.render.worker", description=__doc__.splitlines()[0])
    for opt in RENDER_OPTIONS:
        if opt.is_flag:
            parser.add_argument(opt.flag, action="store_true", help=opt.help)
        else:
            parser.add_argument(opt.flag, type=opt.type, default=opt.default, help=opt.help)
    return parser


def run(options: dict, progress=None):
    """Render what ``options`` ask for; returns the render summary and the number of tiles asked for."""
    from .loop import render_jobs

    jobs, settings = plan(options)
    return render_jobs(jobs, settings, progress), len(jobs) * settings.n_tiles


def print_progress() -> tuple[list, callable]:
    """A progress callback for a worker's log (no tqdm in Blender's Python) and its running count."""
    done = [0]

    def progress(n: int) -> None:
        done[0] += n
        print(f"meta-sim worker: {done[0]} tiles done", flush=True)

    return done, progress


def main(argv: list[str] | None = None) -> int:
    """Exit code 0 when everything rendered, 2 on bad input."""
    args = build_argparser().parse_args(argv)
    started = time.perf_counter()
    _, progress = print_progress()
    try:
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

"""Render-farm entry point: `blender -b --python-exit-code 1 --python jobs/render_tiles.py -- ARGS`.

ARGS are those of `meta-sim render` (see `python -m meta_sim.render.worker --help`).
Blender's Python needs numpy and OpenImageIO (both ship with Blender 4+) and
this repository on its path, which this script adds.
"""

import os
import sys

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

from meta_sim.render.worker import blender_argv, main  # noqa: E402

code = main(blender_argv(sys.argv))
if code:
    sys.exit(code)

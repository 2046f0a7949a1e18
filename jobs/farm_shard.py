"""Render-farm shard: `blender -b --python-exit-code 1 --python jobs/farm_shard.py -- --manifest M --shard i/n`.

Renders the i-th of n shards of a job manifest (`meta-sim jobs plan`): every
n-th task from task i (without --shard: every task). Tiles already valid are
skipped, so a shard that a farm reruns after a crash resumes. Exit code 1 when
a task failed, 2 on bad input. Blender's Python needs numpy and OpenImageIO
(both ship with Blender 4+) and this repository on its path, which this script
adds. The bpy module runs it too: `python jobs/farm_shard.py -- --manifest M --shard 0/2`.
"""

import os
import sys

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

from meta_sim.farm.worker import main  # noqa: E402
from meta_sim.render.worker import blender_argv  # noqa: E402

code = main(blender_argv(sys.argv))
if code:
    sys.exit(code)

"""Render-farm shard: `blender -b --python-exit-code 1 --python jobs/farm_shard.py -- --manifest M --shard i/n`.

Renders the i-th of n shards of a job manifest (`meta-sim jobs plan`): every
n-th task from task i. Tiles already valid are skipped, so a shard that a farm
reruns after a crash resumes. Exit code 1 when a task failed, 2 on bad input.
Blender's Python needs numpy and OpenImageIO (both ship with Blender 4+) and
this repository on its path, which this script adds. The bpy module runs it
too: `python jobs/farm_shard.py -- --manifest M --shard 0/2`.
"""

import argparse
import os
import sys

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

from meta_sim.worker import blender_argv, main  # noqa: E402

parser = argparse.ArgumentParser(prog="farm_shard.py", description=__doc__.splitlines()[0])
parser.add_argument("--manifest", required=True, help="job manifest written by `meta-sim jobs plan`")
parser.add_argument("--shard", required=True, help="i/n: the i-th (from 0) of n shards")
args = parser.parse_args(blender_argv(sys.argv))
code = main(["--job", args.manifest, "--shard", args.shard])
if code:
    sys.exit(code)

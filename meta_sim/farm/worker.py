"""Farm worker: renders the tasks of a job manifest, or one shard of them, in one process.

    python -m meta_sim.farm.worker --job job.json [--shard 0/4]
    blender -b --python-exit-code 1 --python jobs/farm_shard.py -- --manifest job.json [--shard 0/4]

Each task renders on its own, so a task that cannot render (a missing texture, ...) is reported
(``meta-sim worker: task NAME failed: ...``, which the executors read) while the others render.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from ..core.errors import MetaSimError
from ..render.loop import render_jobs
from ..render.worker import print_progress
from . import manifest as farm


def run_job(path: Path, shard: str | None = None, progress=None) -> list[tuple[str, str]]:
    """Render every task of the manifest at ``path`` (or of one shard ``i/n``); returns the failed
    tasks as (name, message)."""
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
    """Exit code 0 when every task rendered, 1 when some failed, 2 on bad input."""
    parser = argparse.ArgumentParser(prog="meta_sim.farm.worker", description=__doc__.splitlines()[0])
    parser.add_argument("--job", "--manifest", dest="job", type=Path, required=True,
                        help="job manifest written by `meta-sim jobs plan`")
    parser.add_argument("--shard", default=None, help="only the i-th (from 0) of n shards of its tasks, e.g. 0/4")
    args = parser.parse_args(argv)
    started = time.perf_counter()
    done, progress = print_progress()
    try:
        failures = run_job(args.job, args.shard, progress)
    except MetaSimError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(f"meta-sim worker: {done[0]} tiles done, {len(failures)} tasks failed "
          f"in {time.perf_counter() - started:.1f} s", flush=True)
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())

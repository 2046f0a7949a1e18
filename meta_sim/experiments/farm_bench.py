"""The farm benchmark behind `make bench-farm`: one small job, rendered by each executor setting.

Every setting renders the same manifest into a fresh folder. Peak memory is
the maximum resident set size of each Blender worker process, read by the
executor from ``os.wait4`` when the process ends (exact per process; no psutil).
"""

from __future__ import annotations

import os
import platform
import statistics
import tempfile
from pathlib import Path

from ..farm import executors
from ..farm import manifest as farm

# (label, executor, workers, tasks per worker process)
SETTINGS = (("local, 1 worker", "local", 1, 4), ("local, 2 workers", "local", 2, 4),
            ("local, 2 workers, 1 task per process", "local", 2, 1), ("dask LocalCluster, 2 workers", "dask", 2, 4))


def bench_farm(designs: int = 16, tiles: int = 4, tile_px: int = 384, preset: str = "fast", seed: int = 7) -> dict:
    """Plan one job of ``designs`` random designs x ``tiles`` tiles and render it with each of
    ``SETTINGS`` into a temporary folder; returns per setting the time, throughput and peak memory
    per worker process, and the machine's load before and after."""
    options = {"design": None, "random_designs": designs, "seed": seed, "cities": 4, "tiles": tiles,
               "preset": preset, "bank": None, "space": None, "tile_px": tile_px, "gsd": 0.3}
    load_before = os.getloadavg()
    rows = []
    with tempfile.TemporaryDirectory(prefix="meta-sim-bench-farm-") as tmp:
        for label, executor, workers, recycle in SETTINGS:
            manifest = farm.plan(options, Path(tmp) / label.replace(" ", "_").replace(",", ""))
            summary = executors.run(manifest, executors.RunOptions(executor=executor, workers=workers,
                                                                   recycle=recycle, progress=False))
            rss = [b["max_rss_mb"] for b in summary.batches]
            rows.append({"setting": label, "executor": executor, "workers": workers, "tasks_per_process": recycle,
                         "tiles": summary.rendered, "failed_tiles": summary.failed_tiles,
                         "seconds": round(summary.seconds, 2), "tiles_per_second": round(summary.tiles_per_second, 2),
                         "worker_processes": len(summary.batches),
                         "peak_rss_mb_per_worker": round(max(rss), 1) if rss else None,
                         "median_peak_rss_mb": round(statistics.median(rss), 1) if rss else None})
    return {"job": {"tasks": len(manifest.tasks), "tiles_per_task": tiles, "tile_px": tile_px, "preset": preset},
            "settings": rows, "memory": "max RSS of each worker process (os.wait4), max and median over processes",
            "machine": {"cpus": os.cpu_count(), "python": platform.python_version(),
                        "load_average_before": [round(x, 2) for x in load_before],
                        "load_average_after": [round(x, 2) for x in os.getloadavg()]}}


def format_farm_table(result: dict) -> str:
    """``bench_farm``'s result as the Markdown table of docs/benchmarks.md, with a note under it."""
    lines = ["| setting | worker processes | tiles | s | tiles/s | peak RSS per worker (MB, max / median) |",
             "|---|---|---|---|---|---|"]
    for r in result["settings"]:
        lines.append(f"| {r['setting']} | {r['worker_processes']} | {r['tiles']} | {r['seconds']:.1f} | "
                     f"{r['tiles_per_second']:.2f} | {r['peak_rss_mb_per_worker']} / {r['median_peak_rss_mb']} |")
    job, machine = result["job"], result["machine"]
    lines.append("")
    lines.append(f"{job['tasks']} tasks x {job['tiles_per_task']} tiles of {job['tile_px']} px, preset "
                 f"{job['preset']}; {machine['cpus']} CPUs, load average {machine['load_average_before'][0]:.1f} "
                 f"before, {machine['load_average_after'][0]:.1f} after.")
    return "\n".join(lines)

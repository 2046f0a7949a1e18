"""Benchmarks behind the README's tables (`make bench-*`). Medians over repeats."""

from __future__ import annotations

import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path


def _blender_import_seconds() -> float:
    """Start-up cost of a worker process: a fresh Python importing bpy."""
    started = time.perf_counter()
    subprocess.run([sys.executable, "-c", "import bpy"], check=True, capture_output=True)
    return time.perf_counter() - started


def bench_render(designs: int = 4, tiles: int = 9, repeats: int = 3, presets=("fast", "balanced", "quality"),
                 seed: int = 101) -> dict:
    """Seconds per tile (render + label pass + EXR write) for each preset, one city of ``designs`` designs."""
    from .design import DesignSpace
    from .render import RenderSettings, design_jobs, render_jobs, sample_designs
    from .render_presets import get_preset
    from .textures import ensure_default_bank, ensure_heldout_bank

    space = DesignSpace.load()
    banks = [ensure_default_bank(), ensure_heldout_bank()]
    jobs = design_jobs(space, sample_designs(space, designs, seed), seed, cities=1)
    startup = statistics.median(_blender_import_seconds() for _ in range(repeats))
    result = {"presets": {}, "designs_per_city": designs, "tiles_per_design": tiles, "repeats": repeats,
              "blender_import_seconds": round(startup, 3),
              "machine": {"cpus": os.cpu_count(), "python": platform.python_version()}}
    builds, first_frames = [], []
    for name in presets:
        preset = get_preset(name)
        runs = []
        for repeat in range(repeats + 1):  # run 0 warms up the engine (GL context, kernels)
            with tempfile.TemporaryDirectory() as out:
                settings = RenderSettings(space=space, banks=banks, preset=preset, out_dir=Path(out),
                                          n_tiles=tiles)
                started = time.perf_counter()
                summary = render_jobs(jobs, settings)
                wall = time.perf_counter() - started
            if repeat == 0:
                first_frames.append(wall)
                continue
            s = summary.seconds
            n = summary.written
            runs.append({"seconds_per_tile": (s["render"] + s["labels"] + s["write"]) / n,
                         "render_seconds_per_tile": s["render"] / n,
                         "label_seconds_per_tile": s["labels"] / n,
                         "write_seconds_per_tile": s["write"] / n,
                         "wall_seconds_per_tile": wall / n})
            builds.append(s["layout"] + s["build"])
        entry = {key: round(statistics.median(r[key] for r in runs), 4) for key in runs[0]}
        entry.update(engine=preset.engine, samples=preset.samples, description=preset.description)
        result["presets"][name] = entry
    result["city_build_seconds"] = round(statistics.median(builds), 4)
    return result


def format_render_table(result: dict) -> str:
    lines = ["| preset | engine | s/tile (render+labels+write) | render | labels | EXR write |",
             "|---|---|---|---|---|---|"]
    for name, p in result["presets"].items():
        lines.append(f"| {name} | {p['engine']} {p['samples']} spp | {p['seconds_per_tile']:.3f} | "
                     f"{p['render_seconds_per_tile']:.3f} | {p['label_seconds_per_tile']:.3f} | "
                     f"{p['write_seconds_per_tile']:.3f} |")
    lines.append("")
    lines.append(f"City build (layout + Blender geometry, {result['tiles_per_design']} tiles): "
                 f"{result['city_build_seconds']:.3f} s; Blender start-up (import bpy): "
                 f"{result['blender_import_seconds']:.2f} s; "
                 f"{result['designs_per_city']} designs per city, medians of {result['repeats']} runs, "
                 f"{result['machine']['cpus']} CPUs.")
    return "\n".join(lines)

"""`make bench-exposure`: the fast preset's exposure, measured.

Workbench's studio light renders a surface far darker than the path-traced sun and sky, so the fast preset
multiplies its render by ``quality.FAST_EXPOSURE`` (docs/design.md, "The fast preset's exposure"). This
renders the first designs of the default training set (the training renders: no E1/E2 target) with the
``balanced`` preset and with the fast preset at exposure 1 and no tone curve, in the same cities, and takes
per tile the ratio of the median linear luminance of the flat roofs, balanced over fast; the exposure is the
median over tiles. Only pixels where the balanced render lies below its tone curve's knee (where the curve is
the identity) count, and only those away from a roof's edge.
"""

from __future__ import annotations

import dataclasses
import statistics
import tempfile
from pathlib import Path

import numpy as np

from ..core.progress import Bars

LUMA = np.array([0.2126, 0.7152, 0.0722], np.float32)
MIN_PIXELS = 50  # flat-roof pixels a tile needs to count


def bench_exposure(designs: int = 100, tiles: int = 2, seed: int = 1, cities: int = 8,
                   bars: Bars | None = None) -> dict:
    """The median ratio of flat-roof brightness, ``balanced`` over ``fast`` at exposure 1, over the tiles of
    the first ``designs`` designs of the training set of ``seed`` (``tiles`` each, over ``cities`` cities),
    with its quartiles, the same for sloped roofs and bare ground, and the exposure in use."""
    from scipy import ndimage

    from ..render.jobs import RenderSettings, design_jobs, sample_designs
    from ..render.loop import render_jobs
    from ..sim import tiles as tile_io
    from ..sim.design import DesignSpace
    from ..sim.meshes import FLAT_ROOF, SLOPED_ROOF
    from ..sim.quality import FAST_EXPOSURE, get_preset
    from ..sim.textures import ensure_default_bank

    space = DesignSpace.load()
    jobs = design_jobs(space, sample_designs(space, designs, seed), seed, cities)
    traced = get_preset("balanced")
    raw = dataclasses.replace(get_preset("fast"), exposure=1.0, tone=None)
    knee = traced.tone[0] if traced.tone else np.inf
    ratios = {"flat roofs": [], "sloped roofs": [], "ground": []}
    with tempfile.TemporaryDirectory() as scratch:
        folders = {}
        for preset in (raw, traced):
            folders[preset.name] = Path(scratch) / preset.name
            settings = RenderSettings(space=space, banks=[ensure_default_bank()], preset=preset,
                                      out_dir=folders[preset.name], n_tiles=tiles)
            render_jobs(jobs, settings, bars(f"render {preset.name}", len(jobs) * tiles) if bars else None)
        for job in jobs:
            for j in range(tiles):
                name = f"{job.name}_t{j:02d}.exr"
                fast, slow = (tile_io.read_tile(folders[p.name] / name) for p in (raw, traced))
                linear = slow.rgb.max(axis=-1) < knee
                parts = {"flat roofs": fast.roof_class == FLAT_ROOF, "sloped roofs": fast.roof_class == SLOPED_ROOF,
                         "ground": fast.building == 0}
                for part, mask in parts.items():
                    keep = ndimage.binary_erosion(mask, iterations=2) & linear
                    if keep.sum() >= MIN_PIXELS:
                        ratios[part].append(float(np.median(slow.rgb[keep] @ LUMA) / np.median(fast.rgb[keep] @ LUMA)))
    summary = {part: _summary(values) for part, values in ratios.items()}
    return {"designs": designs, "tiles_per_design": tiles, "seed": seed, "cities": cities,
            "measured": round(summary["flat roofs"]["median"], 1), "in_use": FAST_EXPOSURE, "ratios": summary}


def _summary(values: list[float]) -> dict:
    q1, median, q3 = np.percentile(values, [25, 50, 75]) if values else (np.nan,) * 3
    return {"tiles": len(values), "median": float(median), "q1": float(q1), "q3": float(q3),
            "mean": statistics.fmean(values) if values else float("nan")}


def format_exposure_table(result: dict) -> str:
    """``bench_exposure``'s result as the Markdown table of docs/benchmarks.md, with a note under it."""
    lines = ["| surface | tiles | median ratio, balanced / fast at exposure 1 | quartiles |", "|---|---|---|---|"]
    for part, s in result["ratios"].items():
        lines.append(f"| {part} | {s['tiles']} | {s['median']:.2f} | {s['q1']:.2f} - {s['q3']:.2f} |")
    lines += ["", f"The fast preset's exposure: {result['measured']:.1f} measured (the flat roofs' median), "
                  f"{result['in_use']:g} in use (`quality.FAST_EXPOSURE`). The first {result['designs']} designs of "
                  f"the training set of seed {result['seed']} x {result['tiles_per_design']} tiles over "
                  f"{result['cities']} cities; pixels 2 away from a surface's edge where the balanced render is "
                  "below its tone curve's knee."]
    return "\n".join(lines)

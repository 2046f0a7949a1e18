"""How sharp should each named sensor make a render? ``make bench-sensor`` fits it to the real domains.

A rasterised render at the tile's own pixel holds less fine detail than a drone orthomosaic resampled from a
finer pixel, and the named sensors (``sim.sensor``) blurred renders further by eye. The realism bench's
classifier in its "blur" view showed that fine detail is part of what gives renders away. This fit measures
it: cities of the richest built-in scene (``FIT_SPACE`` without its sensor parameter, designs drawn uniformly)
are rendered once with no sensor; each candidate sharpness (``FIT_BLUR`` x ``FIT_SHARPEN``, the sensor's
other settings kept) is applied to those renders, and its fine detail
(``sim.sensor.fine_detail``, median over the tiles) is set against the median over the ``adapt`` scenes of the
real domains that sensor stands for (``realdomains.SENSOR_OF``; validation scenes, never the test scenes).
The candidate nearest in the mean absolute log ratio is the fitted sharpness. Numpy after the renders: the
grid takes seconds.
"""

from __future__ import annotations

import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from ..core.errors import MetaSimError
from ..core.progress import Bars
from ..sim.sensor import fine_detail
from . import realdomains

FIT_SPACE = "overhead-towns-v5"
FIT_DESIGNS = 24
FIT_TILES = 2
FIT_SEED = 2026
FIT_BLUR = (0.0, 0.3, 0.6, 0.9, 1.2)
FIT_SHARPEN = (0.0, 0.25, 0.5, 0.75, 1.0, 1.5)


def _raw_renders(root: Path, bars: Bars | None) -> list[np.ndarray]:
    """Linear renders (no sensor) of ``FIT_DESIGNS`` uniform designs of ``FIT_SPACE`` without its sensor
    parameter, at the working pixel size (cached under ``root``)."""
    from ..pipeline.trainsets import TileDataset
    from ..render.jobs import Job, RenderSettings
    from ..render.loop import render_jobs
    from ..sim.design import DesignSpace
    from ..sim.quality import get_preset
    from ..sim.textures import ensure_default_bank

    data = DesignSpace.load(FIT_SPACE).to_dict()
    data["parameters"] = [p for p in data["parameters"] if p.get("appearance") != "sensor"]
    data["name"] = f"{FIT_SPACE}-no-sensor"
    space = DesignSpace.from_dict(data)
    designs = space.sample(np.random.default_rng(FIT_SEED), FIT_DESIGNS)
    jobs = [Job(design, FIT_SEED + k, f"d{k:03d}") for k, design in enumerate(designs)]
    folder = root / "sensor-fit" / f"{FIT_SPACE}-{FIT_DESIGNS}x{FIT_TILES}-s{FIT_SEED}"
    settings = RenderSettings(space=space, banks=[ensure_default_bank()], preset=get_preset("fast"),
                              out_dir=folder, n_tiles=FIT_TILES)
    render_jobs(jobs, settings, bars("render the fit's cities (no sensor)", len(jobs) * FIT_TILES) if bars else None)
    data = TileDataset(folder, "linear", settings.pixel_size_m)
    return [np.ascontiguousarray(data[k]["image"].numpy().transpose(1, 2, 0)) for k in range(len(data))]


def _display(linear: np.ndarray) -> np.ndarray:
    from ..sim.imageio import linear_to_srgb

    return np.clip(linear_to_srgb(np.clip(linear, 0.0, None), np.float32), 0.0, 1.0)


def rendered_detail(renders: list[np.ndarray], sensor) -> float:
    """The median fine detail of ``renders`` (linear) seen through ``sensor``."""
    return float(np.median([fine_detail(_display(sensor.apply(image, [FIT_SEED, k])))
                            for k, image in enumerate(renders)]))


def real_detail(domain: str, realdata: Path, pixel_size_m: float = 0.3) -> float:
    """The median fine detail of a real domain's ``adapt`` scenes at ``pixel_size_m``."""
    adapt, _ = realdomains.split(realdomains.scenes(domain, realdata))
    return float(np.median([fine_detail(realdomains.at_pixel_size(scene, pixel_size_m)[0]) for scene in adapt]))


def fit_sensors(renders: list[np.ndarray], real: dict[str, float]) -> dict:
    """Per named sensor standing for some of ``real``'s domains (domain -> fine detail): every candidate's
    rendered fine detail, its distance (mean absolute log ratio to those domains) and the nearest."""
    from ..sim.sensor import get_sensor

    out = {}
    for name in sorted(set(realdomains.SENSOR_OF.values())):
        domains = [d for d, s in realdomains.SENSOR_OF.items() if s == name and d in real]
        if not domains:
            continue
        current = get_sensor(name)
        grid = []
        for blur in FIT_BLUR:
            for sharpen in FIT_SHARPEN:
                detail = rendered_detail(renders, replace(current, blur_px=blur, sharpen=sharpen))
                distance = float(np.mean([abs(np.log(detail / real[d])) for d in domains]))
                grid.append({"blur_px": blur, "sharpen": sharpen, "detail": detail, "distance": distance})
        best = min(grid, key=lambda g: (round(g["distance"], 9), g["sharpen"], -g["blur_px"]))
        today = rendered_detail(renders, current)
        out[name] = {"domains": {d: real[d] for d in domains},
                     "current": {"blur_px": current.blur_px, "sharpen": current.sharpen, "detail": today,
                                 "distance": float(np.mean([abs(np.log(today / real[d])) for d in domains]))},
                     "grid": grid, "fitted": best}
    return out


def bench_sensor(cache_dir=None, realdata: Path | None = None, bars: Bars | None = None) -> dict:
    """``make bench-sensor``: the fit above, with the renders, the real figures and the time it took."""
    from ..core.cache import cache_root

    started = time.perf_counter()
    realdata = realdomains.require(realdata or realdomains.REALDATA)
    renders = _raw_renders(cache_root(cache_dir), bars)
    if not renders:
        raise MetaSimError("the sensor fit rendered no tiles")
    real = {d: real_detail(d, realdata) for d in realdomains.DOMAINS}
    return {"sensors": fit_sensors(renders, real), "renders": len(renders), "space": FIT_SPACE,
            "designs": FIT_DESIGNS, "tiles": FIT_TILES, "seed": FIT_SEED, "seconds": time.perf_counter() - started}


def format_sensor_table(result: dict) -> str:
    """The fit as Markdown: per sensor, the real fine detail, today's and the fitted sharpness."""
    lines = ["| sensor | stands for (fine detail of their adapt scenes) | today: blur px / sharpen | rendered fine "
             "detail | nearest: blur px / sharpen | rendered fine detail | mean abs log ratio: today / nearest |",
             "|---|---|---|---|---|---|---|"]
    for name, fit in result["sensors"].items():
        current, best = fit["current"], fit["fitted"]
        domains = ", ".join(f"{d} {v:.3f}" for d, v in fit["domains"].items())
        lines.append(f"| {name} | {domains} | {current['blur_px']:g} / {current['sharpen']:g} | "
                     f"{current['detail']:.3f} | {best['blur_px']:g} / {best['sharpen']:g} | {best['detail']:.3f} | "
                     f"{current['distance']:.2f} / {best['distance']:.2f} |")
    lines += ["", f"{result['renders']} tiles of {result['designs']} uniform designs of `{result['space']}` (its "
              f"sensor parameter left out), rendered once with the fast preset and no sensor, then seen through each "
              f"candidate (blur {', '.join(f'{b:g}' for b in FIT_BLUR)} px x sharpen "
              f"{', '.join(f'{s:g}' for s in FIT_SHARPEN)}, the sensor's noise, tone curve and JPEG kept). Fine "
              "detail: the standard deviation of the display brightness minus its Gaussian blur of one pixel, median "
              f"over the images, at 0.3 m. {result['seconds']:.0f} s."]
    return "\n".join(lines) + "\n"

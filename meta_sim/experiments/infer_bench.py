"""The inference benchmark behind `make bench-infer`: memory and speed of `meta-sim infer` as folders grow.

Folders of 180, 1,440 and 11,520 images are made of links to the shared real tiles (Kampala, Banepa,
Rio, taken in turn, never copied into the repository), and one 16,000 x 16,000 px image is made by
repeating a real mosaic. Each is inferred by a fresh `meta-sim infer` process; its peak memory is the
maximum resident set size ``os.wait4`` reports when it ends, its speed images (or tiles) per second.
"""

from __future__ import annotations

import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from ..core.errors import MetaSimError

SIZES = (180, 1440, 11520)
BIG_PX = 16000
REALDATA = Path(__file__).resolve().parents[3] / "shared" / "realdata"
SOURCES = ("kampala/ramp-data/sample_2/input", "banepa/images", "rio/images")


def real_images(realdata: Path = REALDATA) -> list[Path]:
    """The shared real tiles, interleaved by source, in a fixed order."""
    lists = [sorted((Path(realdata) / s).glob("*.png")) for s in SOURCES]
    if not all(lists):
        raise MetaSimError(f"the shared real tiles are not in {realdata} ({', '.join(SOURCES)}); "
                           "pass --realdata")
    order = []
    for i in range(max(map(len, lists))):
        order += [images[i] for images in lists if i < len(images)]
    return order


def _folder(images: list[Path], n: int, folder: Path) -> Path:
    folder.mkdir(parents=True)
    for i in range(n):
        source = images[i % len(images)]
        os.symlink(source, folder / f"{i:06d}-{source.name}")
    return folder


def _big_image(mosaic: Path, path: Path, side: int) -> Path:
    """A ``side`` x ``side`` PNG repeating ``mosaic``, written a band of rows at a time."""
    import OpenImageIO as oiio

    from ..sim.imageio import read_rgb8

    pattern = read_rgb8(mosaic)
    h, w = pattern.shape[:2]
    out = oiio.ImageOutput.create(str(path))
    if out is None or not out.open(str(path), oiio.ImageSpec(side, side, 3, oiio.UINT8)):
        raise MetaSimError(f"cannot write {path}: {oiio.geterror()}")
    try:
        band = 512
        for y0 in range(0, side, band):
            rows = np.arange(y0, min(side, y0 + band)) % h
            strip = np.take(np.take(pattern, rows, axis=0), np.arange(side) % w, axis=1)
            if not out.write_scanlines(y0, y0 + len(rows), 0, np.ascontiguousarray(strip)):
                raise MetaSimError(f"cannot write {path}: {out.geterror()}")
    finally:
        out.close()
    return path


def _infer(folder: Path, model: Path, out: Path) -> dict:
    """One `meta-sim infer` process: seconds, peak RSS and what its report counted."""
    import json

    started = time.perf_counter()
    process = subprocess.Popen([sys.executable, "-m", "meta_sim.cli", "infer", str(folder), "--model", str(model),
                                "--out", str(out)], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    stderr = process.stderr.read()
    _, status, usage = os.wait4(process.pid, 0)
    seconds = time.perf_counter() - started
    if os.waitstatus_to_exitcode(status) != 0:
        raise MetaSimError(f"meta-sim infer {folder} failed: {stderr.strip().splitlines()[-1:]}")
    report = json.loads((out / "report.json").read_text())
    return {"images": report["images"], "tiles": report["tiles"], "groups": report["group_count"],
            "seconds": round(seconds, 1), "images_per_second": round(report["images"] / seconds, 2),
            "tiles_per_second": round(report["tiles"] / seconds, 2),
            "peak_rss_mb": round(usage.ru_maxrss / 1024, 1)}


def bench_infer(model: Path, sizes=SIZES, big_px: int = BIG_PX, realdata: Path = REALDATA) -> dict:
    """Infer folders of ``sizes`` real images and one ``big_px`` square image with ``model``; returns
    each run's time, throughput and peak memory, and the checks of the streaming targets."""
    images = real_images(realdata)
    mosaic = sorted((Path(realdata) / "kampala" / "mosaics_0p3m").glob("*.png"))
    rows = []
    load_before = os.getloadavg()
    with tempfile.TemporaryDirectory(prefix="meta-sim-bench-infer-") as tmp:
        for n in sizes:
            folder = _folder(images, n, Path(tmp) / f"folder-{n}")
            rows.append({"run": f"{n} images", **_infer(folder, model, Path(tmp) / f"out-{n}")})
        if big_px and mosaic:
            folder = Path(tmp) / "big"
            folder.mkdir()
            _big_image(mosaic[0], folder / f"big-{big_px}.png", big_px)
            rows.append({"run": f"one {big_px} x {big_px} image", **_infer(folder, model, Path(tmp) / "out-big")})
    folders = [r for r in rows if r["run"].endswith(" images")]
    checks = {}
    if len(folders) >= 2:
        checks["rss_growth_smallest_to_largest"] = round(folders[-1]["peak_rss_mb"] / folders[0]["peak_rss_mb"] - 1, 3)
        checks["throughput_ratio_largest_to_smallest"] = round(
            folders[-1]["images_per_second"] / folders[0]["images_per_second"], 3)
    return {"model": str(model), "runs": rows, "checks": checks,
            "memory": "max RSS of the `meta-sim infer` process (os.wait4)",
            "machine": {"cpus": os.cpu_count(), "python": platform.python_version(),
                        "load_average_before": [round(x, 2) for x in load_before],
                        "load_average_after": [round(x, 2) for x in os.getloadavg()]}}


def format_infer_table(result: dict) -> str:
    """``bench_infer``'s result as the Markdown table of docs/benchmarks.md, with a note under it."""
    lines = ["| run | images | tiles | s | images/s | tiles/s | peak RSS (MB) |", "|---|---|---|---|---|---|---|"]
    for r in result["runs"]:
        lines.append(f"| {r['run']} | {r['images']} | {r['tiles']} | {r['seconds']:.1f} | "
                     f"{r['images_per_second']:.2f} | {r['tiles_per_second']:.2f} | {r['peak_rss_mb']:.0f} |")
    checks, machine = result["checks"], result["machine"]
    lines.append("")
    if checks:
        lines.append(f"Peak RSS from the smallest to the largest folder: "
                     f"{checks['rss_growth_smallest_to_largest']:+.1%}; throughput largest / smallest: "
                     f"{checks['throughput_ratio_largest_to_smallest']:.2f}.")
    lines.append(f"{machine['cpus']} CPUs, load average {machine['load_average_before'][0]:.1f} before, "
                 f"{machine['load_average_after'][0]:.1f} after.")
    return "\n".join(lines)

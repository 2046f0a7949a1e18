"""What the renders' roof colours alone tell: a reference for the E1/E2 scores, not a method.

E1 and E2 score an inferred texture by the HSV similarity of texture
swatches (``meta_sim.sim.textures.similarity``), while every method sees
rendered tiles, where lighting, shadows and the texture's scale on the roof
change the colours. This reference asks how far the renders agree with the
score, with information no method has -- the tiles' roof labels:

* for each bank texture, the HSV-cone histogram (the score's own
  definition) of every pixel of its roof kind in the training tiles whose
  design uses it;
* for each target group, the same histogram of its roof pixels of that
  kind over its tiles; the "inferred" texture is the bank texture with the
  highest histogram intersection, scored like the methods.

A low figure means the renders' roof colours rank the bank differently from
the swatches, whatever the features and the model; ``make bench-reference``
writes ``benchmarks/reference.json``. Like ``make bench-nams`` it measures
each experiment on its test and its validation split (``splits.py``).
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from ..core.progress import Bars
from ..sim.imageio import linear_to_srgb
from ..sim.meshes import FLAT_ROOF, SLOPED_ROOF
from ..sim.textures import hsv_cone_histogram
from .evaluate import KIND_OF, mean_scores, rankings, render_split_targets, score
from .splits import SPLIT_NAMES, get_split

ROOF_CLASS_OF = {"flat": FLAT_ROOF, "sloped": SLOPED_ROOF}


def roof_histograms(paths) -> dict[str, np.ndarray]:
    """Per roof kind, the HSV-cone pixel counts (512,) of that kind's roof pixels over the tiles at ``paths``."""
    from ..sim.tiles import read_tile

    counts = {kind: np.zeros(512) for kind in ROOF_CLASS_OF}
    for path in paths:
        tile = read_tile(path)
        rgb8 = np.round(linear_to_srgb(tile.rgb) * 255.0).astype(np.uint8)
        for kind, roof_class in ROOF_CLASS_OF.items():
            pixels = rgb8[tile.roof_class == roof_class]
            if len(pixels):
                counts[kind] += hsv_cone_histogram(pixels[:, None, :]) * len(pixels)
    return counts


def nearest(histogram: np.ndarray, references: dict[str, np.ndarray]) -> str | None:
    """The reference id whose normalised histogram intersects ``histogram`` (normalised) most; None without pixels."""
    if histogram.sum() == 0:
        return None
    target = histogram / histogram.sum()
    return max(references, key=lambda t: (np.minimum(references[t], target).sum(), t))


def bench_reference(targets: int = 100, tiles: int = 9, root: Path | None = None, bars: Bars | None = None,
                    dataset=None) -> dict:
    """E1 and E2 top-1/top-10 of the roof-colour reference on bench-nams' training set and targets:
    ``targets`` groups per seed of each split (``dataset``: another training set, a ``DatasetConfig``;
    its tile size and pixel size are the targets')."""
    from ..core.cache import cache_root
    from ..pipeline.dataset import DatasetConfig, render_training_set
    from ..pipeline.workflow import dataset_dir
    from ..sim.textures import ensure_default_bank, ensure_heldout_bank

    root = Path(root or cache_root())
    dataset = dataset or DatasetConfig()
    folder = dataset_dir(dataset, root)
    jobs, _ = render_training_set(folder, dataset, bars("render training set", dataset.designs * dataset.tiles)
                               if bars else None)
    update = bars("training roofs", len(jobs)) if bars else None
    sums = {kind: {} for kind in ROOF_CLASS_OF}
    for job in jobs:
        counts = roof_histograms(folder / "tiles" / f"{job.name}_t{j:02d}.exr" for j in range(dataset.tiles))
        for param, kind in KIND_OF.items():
            if param in job.design:
                texture = job.design[param]
                sums[kind][texture] = sums[kind].get(texture, 0.0) + counts[kind]
        if update:
            update(1)
    references = {kind: {t: c / c.sum() for t, c in by_texture.items() if c.sum() > 0}
                  for kind, by_texture in sums.items()}
    bank = ensure_default_bank()
    result = {"dataset": {"designs": dataset.designs, "tiles": dataset.tiles, "preset": dataset.preset},
              "targets_per_seed": targets, "tiles_per_target": tiles,
              "bank_textures_seen": {kind: len(refs) for kind, refs in references.items()},
              "machine": {"cpus": os.cpu_count()}, "splits": {name: {"experiments": {}} for name in SPLIT_NAMES}}
    for split_name, experiment in ((s, e) for s in SPLIT_NAMES for e in ("e1", "e2")):
        split = get_split(experiment, split_name)
        target_jobs, folders = render_split_targets(split, targets, tiles, dataset.preset, root, dataset.tile_px,
                                                    dataset.pixel_size_m, bars)
        ranks = rankings(experiment, bank, ensure_heldout_bank(name=split.heldout or "heldout-v1"))
        update = bars(f"{experiment} {split_name} target roofs", len(target_jobs)) if bars else None
        rows, missing = [], {kind: 0 for kind in ROOF_CLASS_OF}
        for job, target_folder in zip(target_jobs, folders):
            counts = roof_histograms(target_folder / f"{job.name}_t{j:02d}.exr" for j in range(tiles))
            predicted = {}
            for param, kind in KIND_OF.items():
                choice = nearest(counts[kind], references[kind])
                if choice is None:  # no roof of this kind in the group: the reference cannot guess
                    missing[kind] += 1
                    choice = ""
                predicted[param] = choice
            rows.append(score(predicted, job.design, ranks))
            if update:
                update(1)
        result["splits"][split_name]["experiments"][experiment] = {"roof_colour_reference": {
            **{key: round(value, 3) for key, value in mean_scores(rows).items()},
            "targets": len(rows), "seeds": list(split.seeds), "heldout": split.heldout,
            "groups_without_roofs": missing}}
    return result


def format_reference_table(result: dict) -> str:
    """The reference's result as the Markdown table of docs/benchmarks.md."""
    lines = ["| experiment | split | flat top-1 | flat top-10 | sloped top-1 | sloped top-10 | targets |",
             "|---|---|---|---|---|---|---|"]
    for experiment in ("e1", "e2"):
        for split in ("test", "validation"):
            r = result["splits"][split]["experiments"][experiment]["roof_colour_reference"]
            lines.append(f"| {experiment.upper()} | {split} | {r['flat_top1']:.2f} | {r['flat_top10']:.2f} | "
                         f"{r['sloped_top1']:.2f} | {r['sloped_top10']:.2f} | {r['targets']} |")
    return "\n".join(lines)

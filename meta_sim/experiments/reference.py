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

A second row finds the roof pixels without labels, as the default features
do: each pixel counts the default model's roof finder's probability of the
kind (to the weight power), histogrammed the same way. The gap between the
two rows is what finding roofs without labels costs; the gap between the
finder's row and NAMS's is what the model and its features cost.

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
from ..sim.textures import hsv_cone_bins
from .evaluate import KIND_OF, mean_scores, rankings, render_split_targets, score
from .splits import FIRST_HELDOUT, SPLIT_NAMES, get_split

ROOF_CLASS_OF = {"flat": FLAT_ROOF, "sloped": SLOPED_ROOF}
# How the roof pixels are found: by the tiles' labels, or by the default model's roof finder (no labels).
WAYS = ("labels", "finder")
ROW_OF = {"labels": "roof_colour_reference", "finder": "roof_finder_reference"}


def roof_histograms(paths, finder=None) -> dict[str, dict[str, np.ndarray]]:
    """Per way of finding the roofs, per roof kind, the HSV-cone pixel counts (512,) of that kind's roof
    pixels over the tiles at ``paths``: "labels", the tiles' roof labels; with ``finder`` (a
    ``(finder, power)`` pair, as a model's ``RoofColourExtractor`` holds them) also "finder", every pixel
    counting the finder's probability of that kind for its 2x2 block to the power, as the default
    features count it."""
    from ..sim.tiles import read_tile

    counts = {way: {kind: np.zeros(512) for kind in ROOF_CLASS_OF} for way in WAYS[:1 + bool(finder)]}
    for path in paths:
        tile = read_tile(path)
        rgb8 = np.round(linear_to_srgb(tile.rgb) * 255.0).astype(np.uint8)
        bins = hsv_cone_bins(rgb8)
        for kind, roof_class in ROOF_CLASS_OF.items():
            counts["labels"][kind] += np.bincount(bins, weights=(tile.roof_class == roof_class).ravel(), minlength=512)
        if finder:
            for kind, weights in zip(ROOF_CLASS_OF, _finder_weights(rgb8, *finder)):
                counts["finder"][kind] += np.bincount(bins, weights=weights.ravel(), minlength=512)
    return counts


def _finder_weights(rgb8: np.ndarray, finder, power: float) -> list[np.ndarray]:
    """Per roof kind, (H, W) float64: ``finder``'s probability of that kind for each pixel's 2x2 block
    (a last odd row or column gets 0), to ``power``, as the features weigh the pixels."""
    import torch

    from ..pipeline.roofcolour import _level1, per_pixel, roof_weights

    h, w = rgb8.shape[0] // 2 * 2, rgb8.shape[1] // 2 * 2
    batch = torch.from_numpy(rgb8[:h, :w].astype(np.float32) / 255.0).permute(2, 0, 1)[None]
    with torch.no_grad():
        weights = per_pixel(roof_weights(finder, _level1(batch), power))[0].double().numpy()
    return [np.pad(kind, ((0, rgb8.shape[0] - h), (0, rgb8.shape[1] - w))) for kind in weights]


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
    from ..pipeline.dataset import DatasetConfig, render_training_set, training_tiles
    from ..pipeline.roofcolour import ensure_roof_finder
    from ..pipeline.workflow import ModelSettings, dataset_dir
    from ..sim.textures import ensure_default_bank, ensure_heldout_bank

    root = Path(root or cache_root())
    dataset = dataset or DatasetConfig()
    folder = dataset_dir(dataset, root)
    jobs, _ = render_training_set(folder, dataset, bars("render training set", dataset.designs * dataset.tiles)
                               if bars else None)
    settings = ModelSettings()
    paths = training_tiles(folder, dataset)
    finder = (ensure_roof_finder(folder, paths, settings.roof_finder, settings.seed,
                                 bars("roof finder", len(paths)) if bars else None, settings.roof_finder_steps),
              settings.roof_weight_power)
    update = bars("training roofs", len(jobs)) if bars else None
    sums = {way: {kind: {} for kind in ROOF_CLASS_OF} for way in WAYS}
    for job in jobs:
        counts = roof_histograms((folder / "tiles" / f"{job.name}_t{j:02d}.exr" for j in range(dataset.tiles)),
                                 finder)
        for way, param, kind in ((w, p, k) for w in WAYS for p, k in KIND_OF.items()):
            if param in job.design:
                texture = job.design[param]
                sums[way][kind][texture] = sums[way][kind].get(texture, 0.0) + counts[way][kind]
        if update:
            update(1)
    references = {way: {kind: {t: c / c.sum() for t, c in by_texture.items() if c.sum() > 0}
                        for kind, by_texture in by_kind.items()} for way, by_kind in sums.items()}
    bank = ensure_default_bank()
    result = {"dataset": {"designs": dataset.designs, "tiles": dataset.tiles, "preset": dataset.preset},
              "targets_per_seed": targets, "tiles_per_target": tiles,
              "bank_textures_seen": {kind: len(refs) for kind, refs in references["labels"].items()},
              "roof_finder": {"finder": settings.roof_finder, "weight_power": settings.roof_weight_power},
              "machine": {"cpus": os.cpu_count()}, "splits": {name: {"experiments": {}} for name in SPLIT_NAMES}}
    for split_name, experiment in ((s, e) for s in SPLIT_NAMES for e in ("e1", "e2")):
        split = get_split(experiment, split_name)
        target_jobs, folders = render_split_targets(split, targets, tiles, dataset.preset, root, dataset.tile_px,
                                                    dataset.pixel_size_m, bars)
        ranks = rankings(experiment, bank, ensure_heldout_bank(name=split.heldout or FIRST_HELDOUT))
        update = bars(f"{experiment} {split_name} target roofs", len(target_jobs)) if bars else None
        rows = {way: [] for way in WAYS}
        missing = {way: {kind: 0 for kind in ROOF_CLASS_OF} for way in WAYS}
        for job, target_folder in zip(target_jobs, folders):
            counts = roof_histograms((target_folder / f"{job.name}_t{j:02d}.exr" for j in range(tiles)), finder)
            for way in WAYS:
                predicted = {}
                for param, kind in KIND_OF.items():
                    choice = nearest(counts[way][kind], references[way][kind])
                    if choice is None:  # no roof of this kind in the group: the reference cannot guess
                        missing[way][kind] += 1
                        choice = ""
                    predicted[param] = choice
                rows[way].append(score(predicted, job.design, ranks))
            if update:
                update(1)
        result["splits"][split_name]["experiments"][experiment] = {
            ROW_OF[way]: {**{key: round(value, 3) for key, value in mean_scores(rows[way]).items()},
                          "targets": len(rows[way]), "seeds": list(split.seeds), "heldout": split.heldout,
                          "groups_without_roofs": missing[way]} for way in WAYS}
    return result


def format_reference_table(result: dict) -> str:
    """The reference's result as the Markdown table of docs/benchmarks.md: per experiment and split, the
    roofs found by their labels, then (a result from before it was measured lacks it) by the roof finder."""
    lines = ["| experiment | split | roofs found by | flat top-1 | flat top-10 | sloped top-1 | sloped top-10 "
             "| targets |",
             "|---|---|---|---|---|---|---|---|"]
    for experiment in ("e1", "e2"):
        for split in ("test", "validation"):
            rows = result["splits"][split]["experiments"][experiment]
            for way in WAYS:
                r = rows.get(ROW_OF[way])
                if r is not None:
                    lines.append(f"| {experiment.upper()} | {split} | {way} | {r['flat_top1']:.2f} | "
                                 f"{r['flat_top10']:.2f} | {r['sloped_top1']:.2f} | {r['sloped_top10']:.2f} | "
                                 f"{r['targets']} |")
    return "\n".join(lines)

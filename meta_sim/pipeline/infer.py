"""`meta-sim infer`: target imagery -> design presets, with a report a person can read.

Target images of any size are brought to the render pixel size and cut into
tiles; tiles are grouped (9 per group by default, in file-name order); each
group's averaged features are searched with NAMS; one preset is written per
group plus a population preset, a Markdown/JSON report and a PNG sheet of
each group beside the textures of its inferred design.
"""

from __future__ import annotations

import json
import math
import re
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from ..core.errors import MetaSimError
from ..core.fileio import atomic_dir, writable_dir, write_text_atomic
from ..core.progress import Bars
from ..nams.search import SearchOptions
from ..sim.presets import DesignPreset, population, save_preset

METHODS = ("auto", "adjoint", "exhaustive")


@dataclass(frozen=True)
class InferSettings(SearchOptions):
    """How `meta-sim infer` searches: the search settings (``SearchOptions``), then tiles per target
    group, the search ``method`` ("auto", "adjoint" or "exhaustive"), the seed of the search's random
    starts and rejection draws, the targets' metres per pixel (``gsd``; None: each file's own, else
    the render's), the dihedral views averaged per tile, and a backbone's weights file."""

    group_size: int = 9
    method: str = "auto"
    seed: int = 0
    gsd: float | None = None
    views: int | None = None  # default: what the model was trained with
    weights: str | None = None  # backbone weights, when the model's extractor needs them

    def check(self) -> None:
        """MetaSimError for any setting ``infer`` would refuse, before an image is read."""
        from .features import VIEW_COUNTS

        if self.method not in METHODS:
            raise MetaSimError(f"--method must be one of {', '.join(METHODS)}, not {self.method!r}")
        super().check(self.method)
        if isinstance(self.group_size, bool) or not isinstance(self.group_size, int) or self.group_size < 1:
            raise MetaSimError(f"--group-size must be at least 1, not {self.group_size!r}")
        if self.gsd is not None and not (math.isfinite(self.gsd) and 0.01 <= self.gsd <= 100):
            raise MetaSimError(f"--gsd must be between 0.01 and 100 metres per pixel, not {self.gsd}")
        if self.views is not None and self.views not in VIEW_COUNTS:
            raise MetaSimError(f"--views must be one of {', '.join(map(str, VIEW_COUNTS))}, not {self.views}")


def _slug(text: str) -> str:
    return re.sub(r"[^a-z0-9]+", "-", text.lower()).strip("-") or "target"


def group_tiles(tiles: list, group_size: int) -> list[list]:
    """Consecutive groups of ``group_size`` (the last one may be smaller)."""
    if group_size < 1:
        raise MetaSimError("--group-size must be at least 1")
    return [tiles[i:i + group_size] for i in range(0, len(tiles), group_size)]


def infer(target_dir: Path, checkpoint_path: Path, out_dir: Path, settings: InferSettings = InferSettings(),
          bars: Bars | None = None, overwrite: bool = False) -> dict:
    """Infer the designs behind the images in ``target_dir`` with the NAMS checkpoint at
    ``checkpoint_path``; write presets and a report into ``out_dir`` and return the report.

    Every readable image directly in ``target_dir`` (unreadable files are skipped and listed in the
    report) is brought to the checkpoint's render pixel size (from ``settings.gsd``, else the file's
    metadata; without either it is taken as rendered) and cut into tiles of the checkpoint's size;
    the tiles, in file-name order, form groups of ``settings.group_size``. Each group's features
    (the checkpoint's extractor, averaged over tiles and views) are normalised and searched, and
    ``out_dir`` gets ``presets/<folder>-NNN.json`` (one design preset per group, with its vote
    shares), ``population.json`` (the distribution of the groups' designs), and ``report.json``,
    ``report.md`` and ``report.png`` (each group's first tile beside the textures of its design,
    for the first 12 groups). The returned dict is what ``report.json`` holds: counts, skipped
    files, model id, method, seconds, the population and each group's design and confidence.

    The outputs are written into a new folder beside ``out_dir`` and put in its place at the end, so
    ``out_dir`` holds one whole run: an existing ``out_dir`` with files in it is replaced only with
    ``overwrite`` (else MetaSimError before any work).

    Raises MetaSimError when the checkpoint is missing, unreadable or not a NAMS model, its
    extractor cannot be rebuilt (e.g. a backbone without ``settings.weights``), ``target_dir`` is
    not a folder or holds no readable image, an image is too small for a tile, or a setting is out
    of range.
    """
    from ..nams import load_checkpoint, search
    from ..sim.imageio import list_images, load_targets
    from .features import features_for_groups
    from .roofcolour import checkpoint_extractor

    settings.check()
    out_dir = Path(out_dir)
    if out_dir.exists() and not (out_dir.is_dir() and (overwrite or not any(out_dir.iterdir()))):
        raise MetaSimError(f"{out_dir} already exists and holds files; pass --overwrite to replace the earlier "
                           "run's outputs, or choose another --out")
    writable_dir(out_dir.parent)
    started = time.perf_counter()
    ckpt = load_checkpoint(checkpoint_path, "nams")
    extractor = checkpoint_extractor(ckpt, Path(settings.weights) if settings.weights else None)
    paths, skipped = list_images(target_dir)
    tile_px = int(ckpt.extra.get("tile_px", 384))
    render_gsd = float(ckpt.extra.get("pixel_size_m", 0.3))
    targets = load_targets(paths, tile_px, settings.gsd, render_gsd,
                           bars("read target images", len(paths)) if bars else None)
    groups = group_tiles(targets, settings.group_size)
    views = settings.views or int(ckpt.extra.get("views", 8))
    feats = features_for_groups([[t for _, t in g] for g in groups], extractor, views,
                                progress=bars("target features", len(targets)) if bars else None)
    read_seconds = time.perf_counter() - started

    started = time.perf_counter()
    normed = ckpt.feature_norm.apply(feats)
    generator = torch.Generator().manual_seed(settings.seed)
    results = search(ckpt.model, normed, ckpt.space, settings.method, generator=generator,
                     bars=bars, **settings.search_options())
    search_seconds = time.perf_counter() - started

    with atomic_dir(out_dir, replace=True) as folder:
        return _write_outputs(folder, target_dir, ckpt, settings, groups, results, views, paths, targets, skipped,
                              read_seconds, search_seconds)


def _write_outputs(out_dir: Path, target_dir, ckpt, settings, groups, results, views, paths, targets, skipped,
                   read_seconds, search_seconds) -> dict:
    stem = _slug(Path(target_dir).resolve().name)
    presets = []
    for index, (group, result) in enumerate(zip(groups, results)):
        sources = sorted({str(p) for p, _ in group})
        preset = DesignPreset(kind="group", name=f"{stem}-{index:03d}", design_space=ckpt.space.name,
                              design=result.design, vote_shares=result.votes,
                              search={"method": result.method, "loss": result.best_loss,
                                      "mean_loss": result.mean_loss, **settings.search_options(),
                                      "views": views, "tiles": len(group)},
                              source_images=sources, model_id=ckpt.model_id)
        save_preset(out_dir / "presets" / f"{preset.name}.json", preset)
        presets.append(preset)
    pop = population(presets, ckpt.space, f"{stem}-population", ckpt.model_id)
    save_preset(out_dir / "population.json", pop)
    report = {"target_dir": str(target_dir), "images": len(paths), "tiles": len(targets),
              "group_count": len(groups),
              "skipped": [{"path": str(p), "reason": r} for p, r in skipped], "model_id": ckpt.model_id,
              "architecture": ckpt.model.config.architecture,
              "method": results[0].method if results else settings.method,
              "seconds": {"read_and_features": read_seconds, "search": search_seconds,
                          "search_per_group": search_seconds / max(1, len(groups))},
              "population": pop.distribution,
              "groups": [{"name": p.name, "design": p.design,
                          "confidence": {n: p.confidence(n) for n in ckpt.space.names},
                          "sources": p.source_images} for p in presets]}
    _write_report(out_dir, report, groups, presets, ckpt.space)
    return report


def _write_report(out_dir: Path, report: dict, groups, presets, space) -> None:
    from ..sim.textures import ensure_default_bank, ensure_heldout_bank
    from ..sim.textures.pngio import write_png
    from ..sim.textures.sheet import render_sheet

    write_text_atomic(out_dir / "report.json", json.dumps(report, indent=2) + "\n")
    lines = [f"# meta-sim infer: {report['target_dir']}", "",
             f"{report['images']} images, {report['tiles']} tiles, {report['group_count']} groups; "
             f"search `{report['method']}`, {report['seconds']['search_per_group']:.4f} s per group; "
             f"model `{report['model_id']}` ({report['architecture']} NAMS).", "",
             "| group | " + " | ".join(space.names) + " |",
             "|---|" + "---|" * len(space.names)]
    for g in report["groups"]:
        cells = " | ".join(f"{g['design'][n]} ({g['confidence'][n]:.0%})" for n in space.names)
        lines.append(f"| {g['name']} | {cells} |")
    if report["skipped"]:
        lines += ["", "Skipped files:", ""] + [f"- {s['path']}: {s['reason']}" for s in report["skipped"]]
    lines += ["", "Population (share of groups per choice):", ""]
    for name, shares in report["population"].items():
        lines.append(f"- {name}: " + ", ".join(f"{k} {v:.0%}" for k, v in shares.items()))
    write_text_atomic(out_dir / "report.md", "\n".join(lines) + "\n")

    banks = [ensure_default_bank(), ensure_heldout_bank()]

    def swatch(texture_id):
        bank = next((b for b in banks if b.contains(texture_id)), None)
        return bank.load_image(texture_id) if bank else np.zeros((8, 8, 3), np.uint8)

    rows = []
    for group, preset in list(zip(groups, presets))[:12]:
        tile = np.floor(np.clip(group[0][1], 0, 1) * 255 + 0.5).astype(np.uint8)
        row = [(f"G{preset.name[-3:]}", tile)]
        for name in space.names:
            value = preset.design[name]
            row.append((f"{name.split('_')[0].upper()} {preset.confidence(name):.0%}", swatch(value)))
        rows.append(row)
    write_png(out_dir / "report.png", render_sheet(rows, 160, 1 + len(space.names)))

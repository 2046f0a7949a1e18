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
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Callable

import numpy as np
import torch

from ..core.errors import MetaSimError
from ..core.fileio import atomic_dir, writable_dir, write_text_atomic
from ..core.progress import Bars
from ..nams.search import SearchOptions
from ..sim.presets import DesignPreset, population, save_preset
from .roofcolour import EVIDENCE_QUANTILE, evidence_reference, roof_evidence, search_colour

METHODS = ("auto", "adjoint", "exhaustive")
# Groups featurised and searched together: memory stays that of one batch whatever the folder holds.
# A larger batch is no faster and peaks higher (`make bench-infer`, docs/benchmarks.md).
BATCH_GROUPS = 4
REPORT_GROUPS = 12  # groups drawn in report.png


@dataclass(frozen=True)
class InferSettings(SearchOptions):
    """How `meta-sim infer` searches: the search settings (``SearchOptions``), then tiles per target
    group, the search ``method`` ("auto", "adjoint" or "exhaustive"), the seed of the search's random
    starts and rejection draws, the metres per pixel of targets nothing else states (``gsd``, below the
    folder's own ways: ``pixelsize``; None: the render's, with a warning), the dihedral views averaged per
    tile, and a backbone's weights file."""

    group_size: int = 9
    method: str = "auto"
    seed: int = 0
    gsd: float | None = None
    views: int | None = None  # default: what the model was trained with
    weights: str | None = None  # backbone weights, when the model's extractor needs them
    near: int = 0  # > 0: the population's designs are each group's ``near`` best-ranked designs

    def check(self) -> None:
        """MetaSimError for any setting ``infer`` would refuse, before an image is read."""
        from .features import VIEW_COUNTS

        if self.method not in METHODS:
            raise MetaSimError(f"--method must be one of {', '.join(METHODS)}, not {self.method!r}")
        super().check(self.method)
        if isinstance(self.group_size, bool) or not isinstance(self.group_size, int) or self.group_size < 1:
            raise MetaSimError(f"--group-size must be at least 1, not {self.group_size!r}")
        if isinstance(self.near, bool) or not isinstance(self.near, int) or not 0 <= self.near <= self.S:
            raise MetaSimError(f"--population-near must be between 0 and --keep/-S ({self.S}), not {self.near!r}")
        if self.gsd is not None and not (math.isfinite(self.gsd) and 0.01 <= self.gsd <= 100):
            raise MetaSimError(f"--gsd must be between 0.01 and 100 metres per pixel, not {self.gsd}")
        if self.views is not None and self.views not in VIEW_COUNTS:
            raise MetaSimError(f"--views must be one of {', '.join(map(str, VIEW_COUNTS))}, not {self.views}")


def _slug(text: str) -> str:
    return re.sub(r"[^a-z0-9]+", "-", text.lower()).strip("-") or "target"


def infer(target_dir, checkpoint_path: Path, out_dir: Path, settings: InferSettings = InferSettings(),
          bars: Bars | None = None, overwrite: bool = False, warn: Callable[[str], None] | None = None) -> dict:
    """Infer the designs behind the images in ``target_dir`` (a path, or a ``pixelsize.ImageFolder`` that
    states their pixel size) with the NAMS checkpoint at ``checkpoint_path``; write presets and a report
    into ``out_dir`` and return the report.

    Every readable image directly in ``target_dir`` (unreadable files are skipped and listed in the
    report) is brought to the checkpoint's render pixel size from its own, as ``pixelsize.resolve_pixel_size``
    finds it before any image is read (``settings.gsd`` for images nothing else states; without it they are
    taken as rendered, and ``warn`` gets one line saying so), and cut into tiles of the checkpoint's size;
    the tiles, in file-name order, form groups of ``settings.group_size``. Each group's features
    (the checkpoint's extractor, averaged over tiles and views) are normalised and searched, and
    ``out_dir`` gets ``presets/<folder>-NNN.json`` (one design preset per group, with its vote
    shares), ``population.json`` (the distribution of the groups' designs; with ``settings.near`` its designs to
    sample are each group's ``near`` best-ranked ones), and ``report.json``,
    ``report.md`` and ``report.png`` (each group's first tile beside the textures of its design,
    for the first 12 groups). The returned dict is what ``report.json`` holds: counts, skipped
    files, model id, method, seconds, the pixel sizes the images were read at and what stated them,
    the population and each group's design and confidence.

    The outputs are written into a new folder beside ``out_dir`` and put in its place at the end, so
    ``out_dir`` holds one whole run: an existing ``out_dir`` with files in it is replaced only with
    ``overwrite`` (else MetaSimError before any work).

    Raises MetaSimError when the checkpoint is missing, unreadable or not a NAMS model, its
    extractor cannot be rebuilt (e.g. a backbone without ``settings.weights``), ``target_dir`` is
    not a folder or holds no readable image, an image's pixel size is stated two ways that disagree
    or by a malformed file, an image is too small for a tile, or a setting is out of range.
    """
    from ..nams import load_checkpoint
    from ..sim.imageio import list_images
    from ..sim.pixelsize import ImageFolder, assumed_warning, resolve_pixel_size
    from .roofcolour import checkpoint_extractor

    settings.check()
    out_dir = Path(out_dir)
    if out_dir.exists() and not out_dir.is_dir():
        raise MetaSimError(f"{out_dir} is a file; give --out a folder for the outputs")
    if out_dir.is_dir() and not overwrite and any(out_dir.iterdir()):
        raise MetaSimError(f"{out_dir} already exists and holds files; pass --overwrite to replace the earlier "
                           "run's outputs, or choose another --out")
    writable_dir(out_dir.parent)
    ckpt = load_checkpoint(checkpoint_path, "nams")
    extractor = checkpoint_extractor(ckpt, Path(settings.weights) if settings.weights else None)
    render_gsd = float(ckpt.extra.get("pixel_size_m", 0.3))
    targets = replace(ImageFolder.of(target_dir, flag=f"{target_dir}:METRES"), fallback_m=settings.gsd,
                      fallback_flag="--gsd", assumed_m=render_gsd)
    paths, skipped = list_images(targets.path)
    sizes = {path: resolve_pixel_size(path, targets) for path in paths}
    warning = assumed_warning(targets, list(sizes.values()))
    if warning and warn:
        warn(warning)
    run = _Run(ckpt, extractor, settings, _slug(targets.path.resolve().name))
    progress = bars("target images", len(paths)) if bars else None
    nodata = {}
    tiles = _tile_stream(sizes, skipped, nodata, int(ckpt.extra.get("tile_px", 384)), render_gsd, progress)
    with atomic_dir(out_dir, replace=True) as folder:
        for batch in _chunks(_chunks(tiles, settings.group_size), BATCH_GROUPS):
            run.search(batch, folder)
        if not run.presets:
            listing = "; ".join(f"{p.name} ({why})" for p, why in skipped[:5])
            raise MetaSimError(f"no readable images in {targets.path}; {len(skipped)} files skipped: {listing}")
        return run.finish(folder, targets.path, sizes, skipped, nodata)


def _tile_stream(sizes: dict, skipped: list, nodata: dict, tile_px: int, render_gsd: float, progress):
    """``(path, tile)`` for every tile of every image (``sizes``: each path's ``PixelSize``), in order, read
    one image (or one window of a large one) at a time. An image whose pixels cannot be read is added to
    ``skipped`` with the reason; tiles left out as no-data are counted per image in ``nodata``."""
    from ..sim.imageio import image_tiles

    for path, size in sizes.items():
        dropped = []
        try:
            for tile in image_tiles(path, tile_px, size.metres, render_gsd, dropped):
                yield path, tile
        except MetaSimError as exc:
            skipped.append((path, str(exc).removeprefix(f"{path}: ")))
        if dropped:
            nodata[str(path)] = len(dropped)
        if progress:
            progress(1)


def _chunks(items, size: int):
    """Lists of ``size`` consecutive items (the last may be shorter), drawn as they are needed."""
    chunk = []
    for item in items:
        chunk.append(item)
        if len(chunk) == size:
            yield chunk
            chunk = []
    if chunk:
        yield chunk


class _Run:
    """What an inference keeps while its groups stream past: one small preset per group, the first
    groups' first tiles for the report's picture, counts and times."""

    def __init__(self, ckpt, extractor, settings: InferSettings, stem: str):
        self.ckpt, self.extractor, self.settings, self.stem = ckpt, extractor, settings, stem
        self.views = settings.views or int(ckpt.extra.get("views", 8))
        self.generator = torch.Generator().manual_seed(settings.seed)
        self.presets, self.thumbnails, self.tiles, self.near = [], [], 0, []
        self.seconds = {"features": 0.0, "search": 0.0}
        self.method = settings.method
        self.evidence_reference = evidence_reference(ckpt.extra)
        self.colour = search_colour(ckpt)  # built once: the search blurs the model's design table once

    def search(self, groups: list, out_dir: Path) -> None:
        """Features, search and one preset file per group, for one batch of groups."""
        from ..nams import near_designs, search
        from .features import features_for_groups

        started = time.perf_counter()
        feats = features_for_groups([[t for _, t in g] for g in groups], self.extractor, self.views)
        self.seconds["features"] += time.perf_counter() - started
        started = time.perf_counter()
        results = search(self.ckpt.model, self.ckpt.feature_norm.apply(feats), self.ckpt.space, self.settings.method,
                         generator=self.generator, colour=self.colour, **self.settings.search_options())
        self.seconds["search"] += time.perf_counter() - started
        if self.settings.near:
            self.near += near_designs(results, self.settings.near)
        evidence = roof_evidence(feats, self.extractor) or {}
        for k, (group, result) in enumerate(zip(groups, results)):
            index = len(self.presets)
            roof_pixels = {f"roof_pixels_{kind}": round(float(share[k]), 6) for kind, share in evidence.items()}
            for kind, span in self.evidence_reference.items():
                if kind in evidence:
                    roof_pixels.update({f"roof_pixels_low_{kind}": span[0], f"roof_pixels_high_{kind}": span[1]})
            preset = DesignPreset(kind="group", name=f"{self.stem}-{index:03d}", design_space=self.ckpt.space.name,
                                  design=result.design, vote_shares=result.votes,
                                  search={"method": result.method, "loss": result.best_loss,
                                          "mean_loss": result.mean_loss, "far": result.far,
                                          **self.settings.search_options(),
                                          "views": self.views, "tiles": len(group), **roof_pixels},
                                  source_images=sorted({str(p) for p, _ in group}), model_id=self.ckpt.model_id)
            save_preset(out_dir / "presets" / f"{preset.name}.json", preset)
            self.presets.append(preset)
            if len(self.thumbnails) < REPORT_GROUPS:
                self.thumbnails.append(group[0][1])
            self.tiles += len(group)
            self.method = result.method

    def finish(self, out_dir: Path, target_dir: Path, sizes: dict, skipped, nodata: dict) -> dict:
        """The population preset and the report, once every group is written; returns the report."""
        from ..sim.pixelsize import summary

        ckpt, presets = self.ckpt, self.presets
        read = [size for path, size in sizes.items() if path not in {s for s, _ in skipped}]
        near = self.settings.near
        pop = population(presets, ckpt.space, f"{self.stem}-population", ckpt.model_id,
                         self.near if near else None, near)
        save_preset(out_dir / "population.json", pop)
        evidence = [p.roof_evidence() for p in presets]
        outside = {kind: {end: sum(e[kind]["outside"] == end for e in evidence) for end in ("low", "high")}
                   for kind in self.evidence_reference if evidence and kind in evidence[0]}
        report = {"target_dir": str(target_dir), "images": len(read), "tiles": self.tiles,
                  "pixel_sizes": {str(target_dir): summary(read)},
                  "group_count": len(presets),
                  "skipped": [{"path": str(p), "reason": r} for p, r in skipped], "model_id": ckpt.model_id,
                  "nodata_tiles": nodata,
                  "architecture": ckpt.model.config.architecture, "method": self.method,
                  "colour_comparison": self.colour.to_dict(),
                  "groups_far_from_every_design": sum(bool(p.search.get("far")) for p in presets),
                  "seconds": {"read_and_features": self.seconds["features"], "search": self.seconds["search"],
                              "search_per_group": self.seconds["search"] / len(presets)},
                  "population": pop.distribution, "population_designs": len(pop.designs),
                  "population_near": near,
                  "roof_pixels_range": {k: list(span) for k, span in self.evidence_reference.items()},
                  "groups_outside_roof_pixels_range": outside,
                  "groups": [{"name": p.name, "design": p.design, "far": bool(p.search.get("far")),
                              "confidence": {n: p.confidence(n) for n in ckpt.space.names},
                              "roof_pixels": {k: e["share"] for k, e in ev.items()},
                              "roof_pixels_outside": {k: e["outside"] for k, e in ev.items() if e["outside"]},
                              "sources": p.source_images} for p, ev in zip(presets, evidence)]}
        _write_report(out_dir, report, self.thumbnails, presets, ckpt.space)
        return report


def _write_report(out_dir: Path, report: dict, thumbnails: list, presets, space) -> None:
    from ..sim.pixelsize import summary_line
    from ..sim.textures import ensure_default_bank, ensure_heldout_banks
    from ..sim.textures.pngio import write_png
    from ..sim.textures.sheet import render_sheet

    write_text_atomic(out_dir / "report.json", json.dumps(report, indent=2) + "\n")
    kinds = list(report["groups"][0]["roof_pixels"]) if report["groups"] else []
    lines = [f"# meta-sim infer: {report['target_dir']}", "",
             f"{report['images']} images, {report['tiles']} tiles, {report['group_count']} groups; "
             f"search `{report['method']}`, {report['seconds']['search_per_group']:.4f} s per group; "
             f"model `{report['model_id']}` ({report['architecture']} NAMS).", "",
             *[f"Pixel size of {folder}: {summary_line(sizes)}." for folder, sizes in report["pixel_sizes"].items()],
             "",
             "| group | " + " | ".join(space.names) + " |" + "".join(f" {k} roof pixels |" for k in kinds),
             "|---|" + "---|" * (len(space.names) + len(kinds))]
    for g in report["groups"]:
        cells = " | ".join(f"{g['design'][n]} ({g['confidence'][n]:.0%})" for n in space.names)
        evidence = "".join(f" {g['roof_pixels'][k]:.2%}"
                           + (f" ({g['roof_pixels_outside'][k]})" if k in g['roof_pixels_outside'] else "") + " |"
                           for k in kinds)
        lines.append(f"| {g['name']}{' (far)' if g.get('far') else ''} | {cells} |{evidence}")
    if report.get("groups_far_from_every_design"):
        lines += ["", f"(far): {report['groups_far_from_every_design']} of {report['group_count']} groups are unlike "
                  "every design the model knows (their best design's loss exceeded "
                  f"{report['colour_comparison']['far_loss']:g}); their roof textures were chosen by the roof "
                  "colours alone, the bank texture nearest in colour to what the roof finder sees."]
    if kinds:
        lines += ["", "Roof pixels: the share of a group's pixels the model's roof finder counts as roofs of each "
                  "kind, which the inferred roof textures rest on. The roof finder learnt roofs from renders: near 0 "
                  "it sees few roofs here and the roof textures rest on a few pixels; near 100% it takes the ground "
                  "for roofs too and the roof textures are the colours of the whole image."]
        span = report["roof_pixels_range"]
        if span:
            lines += ["", f"(low), (high): outside the range all but {2 * EVIDENCE_QUANTILE:.0%} of the model's "
                      "training cities span (" + ", ".join(f"{k} {lo:.2%}-{hi:.2%}" for k, (lo, hi) in span.items())
                      + "). Low: the roof finder sees few roofs of that kind. High: it sees them nearly everywhere, "
                      "ground included. Either way the inferred roof texture of that kind is unreliable."]
            for kind, ends in report["groups_outside_roof_pixels_range"].items():
                for end, count in ends.items():
                    if count:
                        lines += ["", f"**Warning**: {count} of {report['group_count']} groups have {end} {kind}-roof "
                                  f"evidence; their inferred {kind} roof textures are unreliable."]
        else:
            lines += ["", "This model predates the training range of roof pixels (retrain it to have groups outside "
                      "it flagged)."]
    if report["skipped"]:
        lines += ["", "Skipped files:", ""] + [f"- {s['path']}: {s['reason']}" for s in report["skipped"]]
    if report["nodata_tiles"]:
        lines += ["", "Tiles left out as more than 5% no-data:", ""]
        lines += [f"- {p}: {n}" for p, n in report["nodata_tiles"].items()]
    lines += ["", "Population (share of groups per choice):", ""]
    for name, shares in report["population"].items():
        lines.append(f"- {name}: " + ", ".join(f"{k} {v:.0%}" for k, v in shares.items()))
    drawn_from = (f"each group's {report['population_near']} best-ranked designs of the search"
                  if report.get("population_near") else "the groups' designs")
    lines += ["", f"`render --population` samples {report['population_designs']} distinct designs: {drawn_from}."]
    write_text_atomic(out_dir / "report.md", "\n".join(lines) + "\n")

    named = [value for preset in presets for value in preset.design.values() if isinstance(value, str)]
    banks = [ensure_default_bank(), *ensure_heldout_banks(ids=named)]

    def swatch(texture_id):
        bank = next((b for b in banks if b.contains(texture_id)), None)
        return bank.load_image(texture_id) if bank else np.zeros((8, 8, 3), np.uint8)

    rows = []
    for first_tile, preset in zip(thumbnails, presets):
        tile = np.floor(np.clip(first_tile, 0, 1) * 255 + 0.5).astype(np.uint8)
        row = [(f"G{preset.name[-3:]}", tile)]
        for name in space.names:
            value = preset.design[name]
            row.append((f"{name.split('_')[0].upper()} {preset.confidence(name):.0%}", swatch(value)))
        rows.append(row)
    write_png(out_dir / "report.png", render_sheet(rows, 160, 1 + len(space.names)))

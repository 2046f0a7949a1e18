"""`meta-sim task train | eval`: the building segmenter trained on real and rendered images, and scored."""

from __future__ import annotations

import json
from pathlib import Path

import click

from ..core.errors import MetaSimError
from ..core.fileio import made_folder, write_text_atomic
from .base import _Bars, _torch_threads, main

SHEET_ROWS = 8


@main.group("task")
def task():
    """The task model: a building segmenter (U-Net) for the target imagery."""


@task.command("train")
@click.option("--real", metavar="DIR[:METRES]", multiple=True,
              help="labelled real images: a folder with images/ and masks/ (same names), with its metres per "
                   "pixel after a colon unless its files state it (GeoTIFF, world files, a pixel_size.txt in DIR); "
                   "repeatable")
@click.option("--synthetic", type=click.Path(path_type=Path), multiple=True,
              help="rendered tiles (*.exr, e.g. from `meta-sim render --population`); repeatable")
@click.option("--mix", default="6:1", show_default=True,
              help="real:synthetic crops per batch when both are given (the paper's 6:1)")
@click.option("--steps", type=int, default=500, show_default=True, help="training steps (batches)")
@click.option("--batch", type=int, default=7, show_default=True, help="crops per step")
@click.option("--crop", type=int, default=96, show_default=True, help="crop side in working pixels")
@click.option("--lr", type=float, default=2e-3, show_default=True, help="Adam learning rate (dropped 10x at 5/8)")
@click.option("--gsd", type=float, default=0.6, show_default=True,
              help="working metres per pixel: every image is brought to it")
@click.option("--real-gsd", type=float, default=None,
              help="metres per pixel of the real images that nothing else states (DIR:METRES, GeoTIFF tags, "
                   "world files, pixel_size.txt)")
@click.option("--augment/--no-augment", default=True, show_default=True,
              help="random rotations, flips and colour balance of the crops")
@click.option("--colour-augment", type=click.Choice(["light", "ground", "camera", "scene"]), default="light",
              show_default=True,
              help="with --augment, of the rendered crops: light (a small colour balance and exposure change, as "
                   "real crops get), ground (that, then the ground recoloured apart from the buildings), camera "
                   "(light, then another camera's exposure, contrast, gamma, blur and noise) or scene (both)")
@click.option("--width", type=int, default=16, show_default=True, help="U-Net channels at the first level")
@click.option("--depth", type=int, default=4, show_default=True, help="U-Net levels")
@click.option("--encoder", type=click.Path(path_type=Path), default=None,
              help="start from the encoder of this segmenter checkpoint (a local file)")
@click.option("--seed", type=int, default=0, show_default=True, help="weights and crops")
@click.option("--out", type=click.Path(path_type=Path), required=True, help="the checkpoint to write (.pt)")
@_torch_threads
def train_command(real, synthetic, mix, steps, batch, crop, lr, gsd, real_gsd, augment, colour_augment, width, depth,
                  encoder, seed, out):
    """Train a building segmenter on real and/or rendered images; deterministic for a seed."""
    from ..sim.pixelsize import ImageFolder, summary, summary_line
    from ..task.data import merge, real_pools, tile_pool
    from ..task.train import TrainSettings, parse_mix, train_segmenter
    from ..task.unet import save_segmenter

    if not real and not synthetic:
        raise MetaSimError("give --real and/or --synthetic training folders")
    if out.is_dir():
        raise MetaSimError(f"--out {out} is a folder; give the checkpoint file to write, such as {out / 'seg.pt'}")
    folders = [ImageFolder.parse(f, "--real", fallback_m=real_gsd, fallback_flag="--real-gsd") for f in real]
    settings = TrainSettings(steps=steps, batch=batch, crop=crop, lr=lr, mix=parse_mix(mix, batch)
                             if real and synthetic else (batch, 0), pixel_size_m=gsd, augment=augment,
                             colour=colour_augment, seed=seed,
                             width=width, depth=depth, encoder=str(encoder) if encoder else None).check()
    bars = _Bars()
    with made_folder(out.parent):
        try:
            real = real_pools(folders, gsd, bars)
            real_images = merge(real)
            rendered = merge([tile_pool(f, gsd, bars) for f in synthetic])
            segmenter = train_segmenter(real_images, rendered, settings, bars("train segmenter", steps))
        finally:
            bars.close()
        save_segmenter(out, segmenter)
    for folder, pool in zip(folders, real):
        click.echo(f"{folder.path}: {summary_line(summary(pool.own_sizes))}")
    crops = segmenter.training["crops"]
    click.echo(f"wrote {out}: {steps} steps of {crops[0]} real + {crops[1]} synthetic crops of {crop} px "
               f"at {gsd} m per pixel")


@task.command("eval")
@click.argument("model", type=click.Path(path_type=Path))
@click.argument("labelled", metavar="LABELLED[:METRES]")
@click.option("--real-gsd", type=float, default=None,
              help="metres per pixel of the real images that nothing else states (LABELLED:METRES, GeoTIFF tags, "
                   "world files, pixel_size.txt); without any, the model's own, with a warning")
@click.option("--out", type=click.Path(path_type=Path), required=True,
              help="folder for scores.json and predictions.png")
@_torch_threads
def eval_command(model, labelled, real_gsd, out):
    """Score a segmenter on LABELLED (rendered tiles, or images/ and masks/, LABELLED:METRES stating the real
    images' metres per pixel): IoU, precision, recall."""
    from ..sim.pixelsize import ImageFolder, assumed_warning, summary
    from ..task.data import labelled_pool
    from ..task.score import all_building, count, overlay, prediction_sheet, truth_picture
    from ..task.unet import load_segmenter

    segmenter = load_segmenter(model)
    folder = ImageFolder.parse(labelled, fallback_m=real_gsd, fallback_flag="--real-gsd",
                               assumed_m=segmenter.pixel_size_m)
    bars = _Bars()
    with made_folder(out):
        try:
            pool = labelled_pool(folder, segmenter.pixel_size_m, bars)
            warning = assumed_warning(folder, pool.own_sizes)
            if warning:
                click.echo(warning, err=True)
            counts, called = count(segmenter, pool.images, pool.masks)
        finally:
            bars.close()
        metrics = counts.metrics()
        scores = {**metrics, "all_building_iou": all_building(pool.masks).iou(), "images": len(pool),
                  "pixel_size_m": segmenter.pixel_size_m, "model": str(model), "labelled": str(folder.path),
                  "pixel_sizes": {str(folder.path): summary(pool.own_sizes)},
                  "per_image": [{"source": s, "tp": int(tp), "fp": int(fp), "fn": int(fn)}
                                for s, tp, fp, fn in zip(pool.sources, counts.tp, counts.fp, counts.fn)]}
        write_text_atomic(out / "scores.json", json.dumps(scores, indent=2) + "\n")
        rows = [[("LABELS", truth_picture(image, mask)), ("PREDICTED", overlay(image, mask, c))]
                for image, mask, c in list(zip(pool.images, pool.masks, called))[:SHEET_ROWS]]
        prediction_sheet(out / "predictions.png", rows)
    click.echo(f"IoU {metrics['iou']:.3f}  precision {metrics['precision']:.3f}  recall {metrics['recall']:.3f}  "
               f"(all-building IoU {scores['all_building_iou']:.3f}) on {len(pool)} images")
    click.echo(f"wrote {out / 'scores.json'} and {out / 'predictions.png'} (green hits, red false alarms, "
               f"blue misses)")

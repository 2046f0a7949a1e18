"""Scoring a segmenter on labelled images: IoU, precision and recall, and a picture of its predictions.

A pixel is called building when the segmenter's probability is at least one half. Scores pool the
pixels of all images (the IoU is total intersection over total union, as building-segmentation
benchmarks report it); ``Counts`` keeps each image's counts so that intervals can resample images.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from .unet import Segmenter

WINDOW = 512  # predict images in windows of this many pixels (with a margin), to bound memory
MARGIN = 32


@dataclass(frozen=True)
class Counts:
    """Per image: true positive, false positive and false negative pixel counts."""

    tp: np.ndarray
    fp: np.ndarray
    fn: np.ndarray

    def metrics(self, pick: np.ndarray | None = None) -> dict:
        """Pooled IoU, precision and recall (over the images ``pick``, default all; repeats count)."""
        tp, fp, fn = ((x if pick is None else x[pick]).sum() for x in (self.tp, self.fp, self.fn))
        return {"iou": _ratio(tp, tp + fp + fn), "precision": _ratio(tp, tp + fp), "recall": _ratio(tp, tp + fn)}

    def iou(self, pick: np.ndarray | None = None) -> float:
        return self.metrics(pick)["iou"]


def _ratio(a, b) -> float:
    return float(a / b) if b > 0 else 0.0


@torch.no_grad()
def predict(segmenter: Segmenter, image: np.ndarray) -> np.ndarray:
    """Building probability (H, W) of a display-sRGB image (H, W, 3) at the segmenter's pixel size."""
    model = segmenter.model.eval()
    h, w = image.shape[:2]
    out = np.zeros((h, w), np.float32)
    for y0 in range(0, h, WINDOW):
        for x0 in range(0, w, WINDOW):
            # the window with a margin of context on every side, cut to the image
            ya, xa = max(0, y0 - MARGIN), max(0, x0 - MARGIN)
            yb, xb = min(h, y0 + WINDOW + MARGIN), min(w, x0 + WINDOW + MARGIN)
            piece = _padded(image[ya:yb, xa:xb], model.multiple)
            logits = model(torch.from_numpy(piece.transpose(2, 0, 1)).unsqueeze(0))[0, 0].numpy()
            y1, x1 = min(h, y0 + WINDOW), min(w, x0 + WINDOW)
            out[y0:y1, x0:x1] = 1.0 / (1.0 + np.exp(-logits[y0 - ya:y1 - ya, x0 - xa:x1 - xa]))
    return out


def _padded(image: np.ndarray, multiple: int) -> np.ndarray:
    h, w = image.shape[:2]
    ph, pw = -h % multiple, -w % multiple
    if ph or pw:
        image = np.pad(image, ((0, ph), (0, pw), (0, 0)), mode="reflect" if min(h, w) > max(ph, pw) else "edge")
    return np.ascontiguousarray(image, dtype=np.float32)


def count(segmenter: Segmenter, images: list[np.ndarray], masks: list[np.ndarray]) -> tuple[Counts, list]:
    """The counts of every image and the predicted building masks."""
    tp, fp, fn, predictions = [], [], [], []
    for image, mask in zip(images, masks):
        called = predict(segmenter, image) >= 0.5
        truth = mask > 0
        tp.append(int((called & truth).sum()))
        fp.append(int((called & ~truth).sum()))
        fn.append(int((~called & truth).sum()))
        predictions.append(called)
    return Counts(np.array(tp), np.array(fp), np.array(fn)), predictions


def all_building(masks: list[np.ndarray]) -> Counts:
    """The counts of the trivial answer "building everywhere" (its IoU is the building share)."""
    tp = np.array([int((m > 0).sum()) for m in masks])
    return Counts(tp, np.array([m.size for m in masks]) - tp, np.zeros(len(masks), np.int64))


def overlay(image: np.ndarray, truth: np.ndarray, called: np.ndarray) -> np.ndarray:
    """An 8-bit picture of a prediction: hits green, false alarms red, misses blue, over the image."""
    base = (np.clip(image, 0, 1) * 255).astype(np.float32) * 0.55
    colour = np.zeros_like(base)
    colour[called & truth] = (40, 220, 60)
    colour[called & ~truth] = (235, 50, 40)
    colour[~called & truth] = (40, 110, 255)
    marked = (called | truth)[:, :, None]
    return np.where(marked, 0.45 * base + 0.55 * colour, base + 0.0).clip(0, 255).astype(np.uint8)


def prediction_sheet(path, rows: list[list[tuple[str, np.ndarray]]], thumb: int = 160) -> None:
    """A PNG of labelled pictures, one list per row (``sim.textures.sheet`` lays them out)."""
    from ..sim.textures.pngio import write_png
    from ..sim.textures.sheet import render_sheet

    write_png(path, render_sheet(rows, thumb, max(len(r) for r in rows)))


def truth_picture(image: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """The image with its building labels outlined in yellow."""
    base = (np.clip(image, 0, 1) * 255).astype(np.uint8)
    edge = truth & ~(np.roll(truth, 1, 0) & np.roll(truth, -1, 0) & np.roll(truth, 1, 1) & np.roll(truth, -1, 1))
    base[edge] = (255, 220, 0)
    return base

"""Stability at the extremes as a table (`meta-sim bench stability`, `make bench-stability`).

The tests already drive each extreme case through the code that handles it; this benchmark runs them
once more end to end, the way a user meets them, and records what each ended in: a finite preset (and
the design it holds) or the clear error a user would read. A case that ends in anything else (a
non-finite loss, an invalid design, another exception) is recorded as such and fails ``check``.

Everything is made in the run, in a scratch cache, with no download: a tiny training set rendered
with the fast preset (16 designs x 1 tile of 96 px at 1.2 m per pixel), NAMS and DR trained on it
with the roof-colour features counted on the pixels the colour roof finder picks (the segmenter would
add minutes of learning and changes nothing the cases test), and four target tiles of two E1 cities
rendered the same way. Cases:

* targets: images of constant grey, black, white, HDR (a float EXR 1,000 times over-exposed with
  highlights at the half-float maximum), with NaN and Inf pixels, and with nothing but NaN, read by
  `meta-sim infer` (``pipeline.infer.infer``) as any image would be;
* one-tile groups: ``--group-size 1``;
* the neural-adjoint search at M=1, S=M, k=0, r=0 and r=1;
* a model trained in a space of one flat and one sloped texture, searched both ways;
* zero-variance features: models trained on features of which every, or every other, dimension is
  constant (``workflow.train_models``, then `meta-sim infer` with the checkpoint);
* bfloat16: the adjoint search run in bfloat16 on the targets' features (``nams.search``).
"""

from __future__ import annotations

import dataclasses
import itertools
import json
import math
import os
import platform
import tempfile
import time
import traceback
from pathlib import Path
from typing import Callable

import numpy as np

from ..core.errors import MetaSimError
from ..core.progress import Bars

FINITE, ERROR, UNSTABLE = "finite preset", "clear error", "UNSTABLE"
TARGET_PX = 96
# The adjoint search's settings where a case does not set them: small, since stability, not accuracy, is asked.
ADJOINT = {"method": "adjoint", "M": 64, "S": 16, "iterations": 50}


def tiny_configs():
    """(DatasetConfig, ModelSettings) of the benchmark's model: a few minutes on 2 CPUs (module docstring)."""
    from ..pipeline.dataset import DatasetConfig
    from ..pipeline.workflow import ModelSettings

    return (DatasetConfig(designs=16, tiles=1, cities=2, tile_px=TARGET_PX, pixel_size_m=1.2),
            ModelSettings(nams={"hidden": [64, 128]}, train={"max_epochs": 40}, roof_finder="colour"))


@dataclasses.dataclass(frozen=True)
class Case:
    """One extreme case: its name, its kind (a row group of the table), what ran, and the run itself,
    which returns the outcome's detail (``_preset_outcome``) or raises."""

    name: str
    kind: str
    how: str
    run: Callable[[], dict]


def _outcome(case: Case) -> dict:
    """What ``case`` ended in: its outcome dict, the clear error's message, or UNSTABLE with what went wrong."""
    started = time.perf_counter()
    try:
        out = case.run()
    except MetaSimError as exc:
        out = {"ended": ERROR, "detail": str(exc)}
    except Exception as exc:  # recorded, not raised: the table must show every case, and check() fails it
        frames = traceback.extract_tb(exc.__traceback__)
        where = f" at {Path(frames[-1].filename).name}:{frames[-1].lineno}" if frames else ""
        out = {"ended": UNSTABLE, "detail": f"{type(exc).__name__}: {exc}{where}"}
    return {"case": case.name, "kind": case.kind, "how": case.how, **out,
            "seconds": round(time.perf_counter() - started, 2)}


def _describe(design: dict) -> str:
    return ", ".join(f"{value:.3g}" if isinstance(value, float) else str(value) for value in design.values())


def _finite_results(designs: list[dict], losses: list, space) -> dict:
    """FINITE with the designs and losses when every loss is finite (or None: no loss) and every design
    valid in ``space``; UNSTABLE saying which is not."""
    bad = [i for i, loss in enumerate(losses) if loss is not None and not math.isfinite(loss)]
    if bad:
        return {"ended": UNSTABLE, "detail": f"non-finite loss in group(s) {bad}: {[losses[i] for i in bad]}"}
    for design in designs:
        try:
            space.validate(design)
        except MetaSimError as exc:
            return {"ended": UNSTABLE, "detail": f"an invalid design {design}: {exc}"}
    shown = "; ".join(dict.fromkeys(_describe(d) for d in designs))
    finite = [loss for loss in losses if loss is not None]
    span = f"{min(finite):.3g}" + (f" to {max(finite):.3g}" if max(finite) > min(finite) else "") if finite else ""
    loss = f" (loss {span})" if finite else ""
    return {"ended": FINITE, "detail": f"{len(designs)} group(s): {shown}{loss}", "designs": designs,
            "losses": losses}


def _infer(model: Path, targets: Path, out: Path, **settings) -> dict:
    """`meta-sim infer` on ``targets`` with ``model``; the outcome of its presets."""
    from ..nams import load_checkpoint
    from ..pipeline.infer import InferSettings, infer
    from ..sim.presets import load_preset

    infer(targets, model, out, InferSettings(**settings))
    space = load_checkpoint(model, "nams").space
    presets = [load_preset(p, space) for p in sorted((out / "presets").glob("*.json"))]
    return _finite_results([p.design for p in presets], [p.search["loss"] for p in presets], space)


def _write_float_exr(path: Path, linear: np.ndarray) -> Path:
    """A plain float RGB EXR, as a camera pipeline or another renderer would write it."""
    import OpenImageIO as oiio

    height, width = linear.shape[:2]
    out = oiio.ImageOutput.create(str(path))
    if out is None or not out.open(str(path), oiio.ImageSpec(width, height, 3, oiio.FLOAT)):
        raise MetaSimError(f"cannot write {path}: {oiio.geterror()}")
    try:
        if not out.write_image(np.ascontiguousarray(linear, dtype=np.float32)):
            raise MetaSimError(f"cannot write {path}: {out.geterror()}")
    finally:
        out.close()
    return path


def _target_folders(scratch: Path, tiles: list[np.ndarray]) -> dict[str, Path]:
    """Folders of target images, one per extreme image case, and "rendered": the rendered tiles as PNGs."""
    from ..sim.textures.pngio import write_png

    folders = {}

    def folder(name: str) -> Path:
        path = scratch / "targets" / name
        path.mkdir(parents=True)
        folders[name] = path
        return path

    rendered = folder("rendered")
    for i, tile in enumerate(tiles):
        write_png(rendered / f"tile{i}.png", np.floor(tile * 255 + 0.5).astype(np.uint8))
    shape = (TARGET_PX, TARGET_PX, 3)
    for name, value in (("grey", 128), ("black", 0), ("white", 255)):
        write_png(folder(name) / f"{name}.png", np.full(shape, value, np.uint8))
    linear = np.stack([np.clip(t, 0.0, 1.0) ** 2.2 for t in tiles])  # about the render's linear light
    rng = np.random.default_rng(0)
    hdr = linear * 1000.0
    hdr[rng.random(hdr.shape[:3]) < 0.05] = 65504.0
    nan = linear.copy()
    for value in (np.nan, np.inf, -np.inf):
        nan[rng.random(nan.shape[:3]) < 0.04] = value
    for name, images in (("hdr", hdr), ("nan-inf", nan), ("all-nan", np.full_like(linear, np.nan))):
        path = folder(name)
        for i, image in enumerate(images):
            _write_float_exr(path / f"{name}{i}.exr", image)
    return folders


def _one_choice_space(scratch: Path) -> Path:
    """A design space of one flat and one sloped bank texture: every design is the same one."""
    from ..sim.design import DesignSpace
    from ..sim.textures import ensure_default_bank

    bank = ensure_default_bank()
    space = DesignSpace.for_textures("one-choice", bank.ids("flat")[:1], bank.ids("sloped")[:1])
    path = scratch / "one-choice.json"
    path.write_text(json.dumps({**space.to_dict(), "name": "one-choice"}))
    return path


def _zero_variance_model(features, dataset, settings, out: Path, every: int) -> Path:
    """``workflow.train_models`` on ``features`` with every ``every``-th dimension set to its mean."""
    from ..pipeline.workflow import train_models

    constant = features.features.clone()
    constant[:, ::every] = constant[:, ::every].mean(dim=0)
    train_models(dataclasses.replace(features, features=constant), out, settings, dataset)
    return out / "nams.pt"


def _bfloat16(model: Path, tiles: list[np.ndarray]) -> dict:
    """The adjoint search in bfloat16 on the targets' features, one group."""
    import torch

    from ..nams import load_checkpoint, search
    from ..pipeline.features import features_for_groups
    from ..pipeline.roofcolour import checkpoint_extractor, search_colour

    ckpt = load_checkpoint(model, "nams")
    features = features_for_groups([tiles], checkpoint_extractor(ckpt), 1)
    options = {k: v for k, v in ADJOINT.items() if k != "method"}
    results = search(ckpt.model, ckpt.feature_norm.apply(features), ckpt.space, "adjoint", dtype=torch.bfloat16,
                     generator=torch.Generator().manual_seed(0), colour=search_colour(ckpt), **options)
    return _finite_results([r.design for r in results], [r.best_loss for r in results], ckpt.space)


def bench_stability(root: Path | None = None, bars: Bars | None = None) -> dict:
    """Run every case (module docstring) and return a JSON-able dict: the cases' outcomes, the models'
    settings, and the wall time. ``root`` (a scratch folder when None) holds the cache and outputs."""
    import torch

    from ..pipeline.workflow import ensure_models
    from ..sim.imageio import read_image
    from .evaluate import render_targets

    started = time.perf_counter()
    dataset, settings = tiny_configs()
    with tempfile.TemporaryDirectory(prefix="meta-sim-stability-") as scratch_name:
        scratch = Path(root) if root else Path(scratch_name)
        model = ensure_models(dataset, settings, scratch, bars).nams_path
        jobs, folder = render_targets("e1", 2, 2, 1, dataset.preset, scratch, dataset.tile_px, dataset.pixel_size_m,
                                      bars)
        tiles = [read_image(folder / f"{job.name}_t{j:02d}.exr") for job in jobs for j in range(2)]
        targets = _target_folders(scratch, tiles)
        one_choice = dataclasses.replace(dataset, space=str(_one_choice_space(scratch)), designs=4)
        runs = itertools.count()

        def out() -> Path:
            return scratch / "runs" / f"run{next(runs)}"

        def infer_case(name, kind, how, folder="rendered", checkpoint=lambda: model, **options):
            return Case(name, kind, how, lambda: _infer(checkpoint(), targets[folder], out(), **options))

        adjoint = "the adjoint search (M=64, S=16, 50 steps)"
        cases = [
            infer_case("constant grey target", "targets", "`meta-sim infer` on a 96 px PNG of grey 128", "grey"),
            infer_case("black target", "targets", "`meta-sim infer` on an all-black PNG", "black"),
            infer_case("white target", "targets", "`meta-sim infer` on an all-white PNG", "white"),
            infer_case("HDR target", "targets", "`meta-sim infer` on float EXRs of the rendered targets 1,000 "
                       "times over-exposed, 5% of pixels at 65504", "hdr"),
            infer_case("NaN and Inf pixels", "targets", "`meta-sim infer` on float EXRs of the rendered targets, "
                       "4% of pixels each NaN, +Inf and -Inf", "nan-inf"),
            infer_case("NaN target", "targets", "`meta-sim infer` on float EXRs of nothing but NaN", "all-nan"),
            infer_case("one-tile groups", "groups", "`meta-sim infer --group-size 1` on the 4 rendered targets",
                       group_size=1),
            infer_case("M=1", "search", "`meta-sim infer` with the adjoint search, M=1 start, S=1",
                       **{**ADJOINT, "M": 1, "S": 1}),
            infer_case("S=M", "search", "`meta-sim infer` with the adjoint search, M=S=16", **{**ADJOINT, "M": 16}),
            infer_case("k=0", "search", f"`meta-sim infer` with {adjoint}, every start at the latent mean (k=0)",
                       k=0.0, **ADJOINT),
            infer_case("r=0", "search", f"`meta-sim infer` with {adjoint}, no rejection (r=0)", r=0.0, **ADJOINT),
            infer_case("r=1", "search", f"`meta-sim infer` with {adjoint}, every design rejected (r=1)", r=1.0,
                       **ADJOINT),
            Case("bfloat16", "precision", f"{adjoint} in bfloat16 on the rendered targets' features",
                 lambda: _bfloat16(model, tiles)),
        ]
        one_choice_model = _cached(lambda: ensure_models(one_choice, settings, scratch, bars).nams_path)
        cases += [
            infer_case("one-choice space, exhaustive", "model", "a model trained on 4 renders of a space of one flat "
                       "and one sloped texture; `meta-sim infer` (exhaustive)", checkpoint=one_choice_model),
            infer_case("one-choice space, adjoint", "model", f"the same model; `meta-sim infer` with {adjoint}",
                       checkpoint=one_choice_model, **ADJOINT),
        ]
        features = _cached(lambda: ensure_models(dataset, settings, scratch).features)
        for every, label in ((1, "every"), (2, "every other")):
            trained = _cached(lambda every=every: _zero_variance_model(features(), dataset, settings,
                                                                       scratch / f"zero-variance-{every}", every))
            cases.append(infer_case(f"zero-variance features ({label} dimension)", "model",
                                    f"NAMS trained on the tiny training set's features with {label} dimension "
                                    "constant; `meta-sim infer` with it", checkpoint=trained))
        progress = bars("stability cases", len(cases)) if bars else None
        outcomes = []
        for case in cases:
            outcomes.append(_outcome(case))
            if progress:
                progress(1)
    return {"cases": outcomes, "dataset": dataclasses.asdict(dataset),
            "models": {"nams": settings.nams, "train": settings.train, "roof_finder": settings.roof_finder},
            "seconds": round(time.perf_counter() - started, 1),
            "machine": {"cpus": os.cpu_count(), "torch_threads": torch.get_num_threads(),
                        "python": platform.python_version()}}


def _cached(make: Callable[[], object]) -> Callable[[], object]:
    """``make`` called once, when first needed (a case that needs a model trains it inside its own run, so
    a failure to train is that case's outcome)."""
    done = []

    def get():
        if not done:
            done.append(make())
        return done[0]

    return get


def check(result: dict) -> None:
    """MetaSimError naming every case that ended in neither a finite preset nor a clear error."""
    unstable = [f"{c['case']}: {c['detail']}" for c in result["cases"] if c["ended"] not in (FINITE, ERROR)]
    if unstable:
        raise MetaSimError("unstable at the extremes: " + "; ".join(unstable))


def format_stability_table(result: dict) -> str:
    """The outcomes as the Markdown table of docs/benchmarks.md, with a note on the run."""
    lines = ["| case | what ran | ended in | inferred design, or the error |", "|---|---|---|---|"]
    for c in result["cases"]:
        detail = c["detail"].replace("|", "\\|").replace("\n", " ")
        lines.append(f"| {c['case']} | {c['how']} | {c['ended']} | {detail} |")
    d = result["dataset"]
    lines += ["", f"Tiny models made in the run: {d['designs']} designs x {d['tiles']} tile of {d['tile_px']} px at "
              f"{d['pixel_size_m']} m per pixel ({d['preset']} preset), NAMS hidden layers "
              f"{result['models']['nams'].get('hidden')}, {result['models']['train'].get('max_epochs')} epochs, "
              f"{result['models']['roof_finder']} roof finder; {result['seconds'] / 60:.1f} min on "
              f"{result['machine']['cpus']} CPUs."]
    return "\n".join(lines)

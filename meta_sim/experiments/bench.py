"""Benchmarks behind the tables of docs/benchmarks.md (`make bench-render`, `make bench-nams`); their
results go to ``benchmarks/*.json`` and the tables into the docs through ``publish``. Times are
medians over repeats."""

from __future__ import annotations

import os
import platform
import re
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from ..core.progress import Bars
from .splits import E2_INTERVALS


def _blender_import_seconds() -> float:
    """Start-up cost of a worker process: a fresh Python importing bpy."""
    started = time.perf_counter()
    subprocess.run([sys.executable, "-c", "import bpy"], check=True, capture_output=True)
    return time.perf_counter() - started


# The richer scene bench-render also times: the space the README has users try first on real towns, whose
# designs bring dense towns, street details, cars, pools, real-sized trees, ground cover, open water, painted and
# varied roofs and a sensor (issue 18's speed limits hold for it; older rows measured overhead-v1).
RICH_SPACE = "overhead-towns-v5"

# Cities bench-render generates without Blender (name -> width m, height m, LayoutParams knobs): a nine-tile and a
# square-kilometre city of the default knobs, a dense-styled one, and the heaviest clutter (every knob on) alone
# and in a mix of styles.
_EVERY_KNOB = {"tree_size": "real", "street_details": True, "car_density": 0.7, "pool_share": 0.6,
               "shrub_density": 0.7}
LAYOUT_CASES = {
    "default_350m": (350.0, 350.0, {}),
    "default_1km": (1000.0, 1000.0, {}),
    "dense_345m": (345.6, 345.6, {"style": "dense"}),
    "every_knob_1km": (1000.0, 1000.0, _EVERY_KNOB),
    "style_mix_every_knob_700x600m": (700.0, 600.0, {
        "style": {"suburban": 0.3, "dense": 0.3, "downtown": 0.2, "industrial": 0.2}, **_EVERY_KNOB}),
}


def bench_render(designs: int = 4, tiles: int = 9, repeats: int = 3, presets=("fast", "balanced", "quality"),
                 seed: int = 101, rich: bool = True, layouts: dict = LAYOUT_CASES) -> dict:
    """Seconds per tile (render + label pass + EXR write) for each preset, one city of ``designs`` designs
    of the default space; with ``rich`` also of designs of ``RICH_SPACE`` (under "rich"); and the seconds
    ``generate_layout`` takes for each city of ``layouts`` (under "layout_seconds")."""
    startup = statistics.median(_blender_import_seconds() for _ in range(repeats))
    result = {**_render_costs("rooftops-v1", designs, tiles, repeats, presets, seed), "designs_per_city": designs,
              "tiles_per_design": tiles, "repeats": repeats, "blender_import_seconds": round(startup, 3),
              "layout_seconds": _layout_seconds(layouts, repeats),
              "machine": {"cpus": os.cpu_count(), "python": platform.python_version()}}
    if rich:
        result["rich"] = {"space": RICH_SPACE, **_render_costs(RICH_SPACE, designs, tiles, repeats, presets, seed)}
    return result


def _layout_seconds(layouts: dict, repeats: int) -> dict:
    """Per city of ``layouts``: its size, knobs and the median seconds of ``generate_layout`` over seeds
    0 .. ``repeats`` - 1."""
    from ..sim.layout import LayoutParams, generate_layout

    result = {}
    for name, (width, height, knobs) in layouts.items():
        params = LayoutParams(**knobs)
        runs = []
        for seed in range(repeats):
            started = time.perf_counter()
            generate_layout(seed, width, height, params)
            runs.append(time.perf_counter() - started)
        result[name] = {"width_m": width, "height_m": height, "knobs": knobs,
                        "seconds": round(statistics.median(runs), 4)}
    return result


def _render_costs(space_name: str, designs: int, tiles: int, repeats: int, presets, seed: int) -> dict:
    """Per preset: the medians of the stage times per tile over ``repeats`` runs (after a warm-up run),
    rendering ``designs`` designs of ``space_name`` (their cities may differ: a design's look can)."""
    from ..render.jobs import RenderSettings, design_jobs, sample_designs
    from ..render.loop import render_jobs
    from ..sim.design import DesignSpace
    from ..sim.quality import get_preset
    from ..sim.textures import ensure_default_bank, ensure_heldout_bank

    space = DesignSpace.load(space_name)
    banks = [ensure_default_bank(), ensure_heldout_bank()]
    jobs = design_jobs(space, sample_designs(space, designs, seed), seed, cities=1)
    result = {"presets": {}}
    builds, first_frames = [], []
    for name in presets:
        preset = get_preset(name)
        runs = []
        for repeat in range(repeats + 1):  # run 0 warms up the engine (GL context, kernels)
            with tempfile.TemporaryDirectory() as out:
                settings = RenderSettings(space=space, banks=banks, preset=preset, out_dir=Path(out),
                                          n_tiles=tiles)
                started = time.perf_counter()
                summary = render_jobs(jobs, settings)
                wall = time.perf_counter() - started
            if repeat == 0:
                first_frames.append(wall)
                continue
            s = summary.seconds
            n = summary.written
            runs.append({"seconds_per_tile": (s["render"] + s["labels"] + s["write"]) / n,
                         "render_seconds_per_tile": s["render"] / n,
                         "label_seconds_per_tile": s["labels"] / n,
                         "write_seconds_per_tile": s["write"] / n,
                         "wall_seconds_per_tile": wall / n})
            builds.append(s["layout"] + s["build"])
        entry = {key: round(statistics.median(r[key] for r in runs), 4) for key in runs[0]}
        entry.update(engine=preset.engine, samples=preset.samples, description=preset.description)
        result["presets"][name] = entry
    result["city_build_seconds"] = round(statistics.median(builds), 4)
    return result


def format_render_table(result: dict) -> str:
    """``bench_render``'s result as the Markdown table of docs/benchmarks.md, with a note under it."""
    lines = ["| scene | preset | engine | s/tile (render+labels+write) | render | labels | EXR write | "
             "s/tile with the city build |", "|---|---|---|---|---|---|---|---|"]
    scenes = [("rooftops-v1", result)] + ([(result["rich"]["space"], result["rich"])] if "rich" in result else [])
    for scene, costs in scenes:
        for name, p in costs["presets"].items():
            lines.append(f"| {scene} | {name} | {p['engine']} {p['samples']} spp | {p['seconds_per_tile']:.3f} | "
                         f"{p['render_seconds_per_tile']:.3f} | {p['label_seconds_per_tile']:.3f} | "
                         f"{p['write_seconds_per_tile']:.3f} | {p.get('wall_seconds_per_tile', 0):.3f} |")
    lines.append("")
    lines.append(f"City build (layout + Blender geometry, {result['tiles_per_design']} tiles): "
                 f"{result['city_build_seconds']:.3f} s; Blender start-up (import bpy): "
                 f"{result['blender_import_seconds']:.2f} s; "
                 f"{result['designs_per_city']} designs per city, medians of {result['repeats']} runs, "
                 f"{result['machine']['cpus']} CPUs.")
    lines.append("")
    layouts = "; ".join(f"{name} {case['seconds']:.3f} s" for name, case in result["layout_seconds"].items())
    lines.append(f"City layout alone (`generate_layout`, no Blender; medians of {result['repeats']} seeds): {layouts}.")
    return "\n".join(lines)


# Adjoint settings swept by bench_adjoint, paper first: (starts M, iterations).
ADJOINT_SWEEP = ((1000, 200), (250, 200), (250, 100), (64, 100), (64, 50), (16, 50))
# bench_nams's one adjoint setting: the continuous spaces' default (evaluate.CONTINUOUS_SEARCH).
NAMS_ADJOINT = ((64, 100),)


def bench_nams(targets: int = 100, adjoint_targets: int = 20, root: Path | None = None, bars: Bars | None = None,
               dataset=None, settings=None, tiles: int = 9, sweep=NAMS_ADJOINT, time_training: bool = True) -> dict:
    """Training time, feature time per target group, and search time and E1/E2 accuracy per method, on
    the validation and the test split of each experiment (``splits.py``).

    Uses the default training set and model (``dataset`` and ``settings``: others), built or reused
    from the cache. Each split has ``targets`` groups of ``tiles`` tiles (9, as in the paper) per
    target seed; every rate comes with a 95% interval from resampling the groups (E2: the held-out textures,
    ``evaluate.texture_clusters``). The neural-adjoint
    settings of ``sweep`` (the continuous spaces' default) run on ``adjoint_targets`` groups only, spread over
    the seeds: a group costs seconds, not milliseconds. On the same targets, ``bench_adjoint`` sweeps the
    adjoint's settings from the paper's down and ``bench_ablations`` scores the other architectures and the
    ablations of the roof-colour features. With ``time_training`` training (the roof
    segmenter, NAMS, DR and the sbi baseline) is timed: as this run trained them, or else on a fresh run into a
    temporary folder (``_training_times``).
    """
    import torch

    from ..core.cache import cache_root
    from ..nams import load_checkpoint
    from ..pipeline.dataset import DatasetConfig
    from ..pipeline.features import time_extractor
    from ..pipeline.roofcolour import checkpoint_extractor
    from ..pipeline.workflow import ModelSettings, ensure_models
    from .splits import SPLIT_NAMES, get_split

    started_at = time.time()  # models trained after this were trained by this run
    root = Path(root or cache_root())
    dataset, settings = dataset or DatasetConfig(), settings or ModelSettings()
    result = {"dataset": {"designs": dataset.designs, "tiles": dataset.tiles, "preset": dataset.preset},
              "architecture": settings.architecture,
              "roof_finder": settings.roof_finder,
              "roof_weight_power": settings.roof_weight_power,
              "targets_per_seed": targets, "e2_intervals": E2_INTERVALS, "adjoint_targets": adjoint_targets,
              "tiles_per_target": tiles,
              "machine": {"cpus": os.cpu_count(), "torch_threads": torch.get_num_threads()}, "splits": {}}
    for split_name in SPLIT_NAMES:
        experiments, seeds, breakdowns = {}, {}, {}
        for experiment in ("e1", "e2"):
            split = get_split(experiment, split_name)
            experiments[experiment], breakdown = _nams_rows(split, targets, tiles, adjoint_targets, sweep, dataset,
                                                            settings, root, bars)
            seeds[experiment] = split.to_dict()
            if breakdown is not None:
                breakdowns[experiment] = breakdown
        result["splits"][split_name] = {"settings": seeds, "experiments": experiments, "breakdown": breakdowns}
    models = ensure_models(dataset, settings, root)
    extractor = checkpoint_extractor(load_checkpoint(models.nams_path, "nams"))
    result["feature_seconds_per_group"] = round(time_extractor(extractor, dataset.tile_px, tiles, 8), 4)
    if time_training:
        result.update(_training_times(models, dataset, settings, root, started_at))
    return result


def _training_times(models, dataset, settings, root: Path, since: float) -> dict:
    """bench_nams's training times for ``models`` (what ``ensure_models`` returned): "train_seconds" (NAMS, DR, the
    sbi baseline) and, for the segmenter roof finder, "roof_segmenter_seconds". When this run trained all of them
    (cache files written after ``since``) the times it measured then are reported ("training_timed": "in this
    run"); otherwise they are trained again into a temporary folder and timed there ("fresh run"), so that no
    time measured on another day, or on a busier machine, is reported as today's."""
    from ..nams import load_checkpoint
    from ..pipeline.roofcolour import roof_finder_path, roof_finder_seconds
    from ..pipeline.workflow import dataset_dir, ensure_nre, train_models

    sbi_path, _ = ensure_nre(models, dataset, settings)
    segmenter = settings.roof_colour and settings.roof_finder.startswith("segmenter")
    folder = dataset_dir(dataset, root)
    paths = [models.nams_path, models.dr_path, sbi_path]
    if segmenter:
        paths.append(roof_finder_path(folder, settings.roof_finder, settings.seed, settings.roof_finder_steps))
    finder_seconds = (roof_finder_seconds(folder, settings.roof_finder, settings.seed, settings.roof_finder_steps)
                      if segmenter else None)
    if all(path.stat().st_mtime >= since for path in paths) and (not segmenter or finder_seconds is not None):
        times = {"training_timed": "in this run", "train_seconds": {
            f"train_{kind}": round(load_checkpoint(path, kind).extra["seconds"], 2)
            for kind, path in (("nams", models.nams_path), ("dr", models.dr_path), ("sbi_nre", sbi_path))}}
        if segmenter:
            times["roof_segmenter_seconds"] = round(finder_seconds, 1)
        return times
    times = {"training_timed": "fresh run"}
    if segmenter:
        from ..pipeline.dataset import training_tiles
        from ..pipeline.roofcolour import SEGMENTER_AUGMENT
        from ..pipeline.roofsegment import RoofSegmenter

        started = time.perf_counter()
        RoofSegmenter.fit(training_tiles(folder, dataset), settings.seed, settings.roof_finder_steps,
                          augment=SEGMENTER_AUGMENT[settings.roof_finder])
        times["roof_segmenter_seconds"] = round(time.perf_counter() - started, 1)
    with tempfile.TemporaryDirectory() as out:
        from ..pipeline.workflow import train_nre_checkpoint

        feature_set = models.features
        seconds = train_models(feature_set, Path(out), settings, dataset)
        seconds["train_sbi_nre"] = train_nre_checkpoint(feature_set, load_checkpoint(Path(out) / "nams.pt", "nams"),
                                                        Path(out) / "sbi_nre.pt", settings, dataset)
        times["train_seconds"] = {k: round(v, 2) for k, v in seconds.items()}
    return times


def _nams_rows(split, targets: int, tiles: int, adjoint_targets: int, sweep, dataset, settings, root: Path,
               bars: Bars | None) -> tuple[dict, dict | None]:
    """bench_nams's rows of one experiment on one split (method name -> metrics, intervals, targets) and, in
    E2, where NAMS's top-10 misses come from (``breakdown.error_breakdown``; None in E1)."""
    from ..sim.textures import ensure_default_bank, ensure_heldout_bank
    from .breakdown import error_breakdown
    from .evaluate import EvalSettings, best_nams_name, method_runs, prepare_eval, score_method
    from .ranking import rankings
    from .splits import spread

    seed = split.seeds[0]  # of the searches' random starts
    ctx = prepare_eval(split.experiment, dataset, settings, EvalSettings(targets=targets, tiles=tiles, split=split),
                       root, bars)
    few = ctx.subset(spread(len(split.seeds), targets, adjoint_targets))
    rows, predictions = {}, {}
    for name, run in method_runs(ctx, seed, {}).items():
        if name != "nams_adjoint":
            rows[name], predictions[name] = score_method(ctx, run)
            rows[name]["targets"] = len(ctx.jobs)
    breakdown = None
    method = best_nams_name(predictions)
    if split.experiment == "e2" and method in predictions:  # not when NAMS's best ran on the adjoint's few only
        detail = [{"truth": job.design, "predicted": {method: design}}
                  for job, design in zip(ctx.jobs, predictions[method])]
        other_roof = rankings("e2", ensure_default_bank(), ensure_heldout_bank(name=split.heldout), across=True)
        breakdown = error_breakdown(detail, ctx.ranks, method, other_roof)
    if "sbi_nre" in rows:
        rows["sbi_nre"]["train_seconds"] = round(ctx.sbi.extra["seconds"], 1)
    rows.update(_adjoint_rows(few, seed, sweep, bars))
    return rows, breakdown


def _adjoint_rows(few, seed: int, sweep, bars: Bars | None = None) -> dict:
    """The neural-adjoint search's row for each (starts, iterations) of ``sweep`` on the targets of ``few`` (with
    ``bars``, a progress bar of each setting's steps)."""
    from .evaluate import method_runs, score_method

    rows = {}
    for starts, iterations in sweep:
        settings = {"M": starts, "iterations": iterations, "S": min(50, starts)}
        if bars is not None:
            settings["bars"] = _labelled(bars, f"adjoint M={starts} x {iterations} steps, {len(few.jobs)} groups")
        run = method_runs(few, seed, settings)["nams_adjoint"]
        row, _ = score_method(few, run)
        rows[f"nams_adjoint_M{starts}_it{iterations}"] = {**row, "targets": len(few.jobs)}
    return rows


def _labelled(bars: Bars, label: str) -> Bars:
    """``bars`` with every stage it opens named ``label``."""
    return lambda _label, total: bars(label, total)


def _split_contexts(dataset, settings, targets: int, tiles: int, root: Path, bars: Bars | None):
    """(split name, experiment, split, EvalContext) for each split of ``splits.SPLIT_NAMES`` and each experiment:
    bench_nams's targets featurised for the model ``settings`` names, without the baselines' extras (MS2's pool,
    the sbi baseline)."""
    from .evaluate import EvalSettings, prepare_eval
    from .splits import SPLIT_NAMES, get_split

    for split_name in SPLIT_NAMES:
        for experiment in ("e1", "e2"):
            split = get_split(experiment, split_name)
            scored = EvalSettings(targets=targets, tiles=tiles, split=split, ms2=False, sbi=False)
            yield split_name, experiment, split, prepare_eval(experiment, dataset, settings, scored, root, bars)


def bench_adjoint(targets: int = 100, adjoint_targets: int = 20, root: Path | None = None, bars: Bars | None = None,
                  dataset=None, settings=None, tiles: int = 9, sweep=ADJOINT_SWEEP) -> dict:
    """The neural-adjoint search at each (starts M, iterations) of ``sweep``, the paper's (1000, 200) first, on
    ``adjoint_targets`` of bench_nams's target groups per split and experiment (spread over the seeds), beside
    the exhaustive search on the same groups: E1/E2 accuracy with 95% intervals and seconds per group. The
    fastest setting that keeps E1 (``fastest_adjoint``) is chosen on the validation split. Long: at the paper's
    setting a group costs a minute or more on 2 CPUs."""
    import torch

    from ..core.cache import cache_root
    from ..pipeline.dataset import DatasetConfig
    from ..pipeline.workflow import ModelSettings
    from .splits import spread

    root = Path(root or cache_root())
    dataset, settings = dataset or DatasetConfig(), settings or ModelSettings()
    result = {"dataset": {"designs": dataset.designs, "tiles": dataset.tiles, "preset": dataset.preset},
              "architecture": settings.architecture, "targets_per_seed": targets, "e2_intervals": E2_INTERVALS,
              "adjoint_targets": adjoint_targets,
              "tiles_per_target": tiles, "sweep": [list(si) for si in sweep],
              "machine": {"cpus": os.cpu_count(), "torch_threads": torch.get_num_threads()}, "splits": {}}
    for split_name, experiment, split, ctx in _split_contexts(dataset, settings, targets, tiles, root, bars):
        few = ctx.subset(spread(len(split.seeds), targets, adjoint_targets))
        seed = split.seeds[0]  # of the searches' random starts, as in bench_nams
        rows = {"nams_exhaustive": _exhaustive_row(few, seed), **_adjoint_rows(few, seed, sweep, bars)}
        part = result["splits"].setdefault(split_name, {"settings": {}, "experiments": {}})
        part["settings"][experiment], part["experiments"][experiment] = split.to_dict(), rows
    result["fastest_adjoint_keeping_e1"] = fastest_adjoint(result["splits"]["validation"]["experiments"]["e1"],
                                                           sweep)
    return result


def _interval_note(result: dict) -> str:
    """What the tables' 95% intervals resample, as the result says."""
    if result.get("e2_intervals") == E2_INTERVALS:
        return ("[95% interval] from resampling the target groups (E1) or the held-out textures of the roof kind "
                "(E2: a texture's groups hit or miss together), 2,000 draws.")
    return "[95% interval] from resampling the groups (2,000 draws)."


def format_adjoint_table(result: dict) -> str:
    """``bench_adjoint``'s result as the Markdown of docs/benchmarks.md: the accuracy table (test first) and
    the chosen setting."""
    f = result["fastest_adjoint_keeping_e1"]
    note = (f"{result['adjoint_targets']} target groups of {result['tiles_per_target']} tiles per split and "
            f"experiment, spread over the seeds of bench-nams' targets ({result['targets_per_seed']} groups per "
            f"seed); `nams_exhaustive` on the same groups. {_interval_note(result)} "
            f"{result['machine']['cpus']} CPUs, torch on {result['machine']['torch_threads']} thread(s). Fastest "
            "setting within 0.05 of the paper setting's E1 top-1 on the validation split: "
            f"M={f['M']}, {f['iterations']} iterations.")
    return "\n".join([*_accuracy_table(result["splits"]), "", note])


# bench_ablations's rows besides the default's: what each variant of the default model changes.
ABLATIONS = {
    "no_roof_colour": "the default without the roof-colour histograms",
    "no_score_cone": "without those in the score's own colour cone",
    "colour_roof_finder": "roofs for those histograms found by colour alone, not by the roof finder",
    "roof_weight_power_1": "each pixel counted with its plain roof probability, not to the weight power",
}
# Cheaper training: rows roof_finder_steps_N and max_epochs_N (the trade study's knobs for the training time).
ABLATION_FINDER_STEPS = 1000
ABLATION_MAX_EPOCHS = 300


def ablation_meaning(name: str) -> str:
    """What the bench_ablations row ``nams_exhaustive_NAME`` changes (its name when unknown)."""
    from ..nams import ARCHITECTURES, TrainConfig
    from ..pipeline.roofsegment import STEPS

    if name in ARCHITECTURES:
        return "the other NAMS architecture of that name"
    steps = re.fullmatch(r"roof_finder_steps_(\d+)", name)
    if steps:
        return f"the roof segmenter learnt in {int(steps[1]):,} steps, not the default's {STEPS:,} (what its steps buy)"
    epochs = re.fullmatch(r"max_epochs_(\d+)", name)
    if epochs:
        return (f"NAMS trained for at most {int(epochs[1]):,} epochs, not the default's {TrainConfig.max_epochs:,} "
                "with early stopping (what its epochs buy)")
    return ABLATIONS.get(name, name)


def ablation_settings(settings) -> tuple[dict, dict]:
    """The variants of the default ``settings`` bench_ablations scores: (name -> ModelSettings whose features are
    the default's or their leading part, scored on the default's target features; name -> ModelSettings whose
    features differ, scored on targets featurised by their own extractor). The first holds the other
    architectures too."""
    import dataclasses

    from ..nams import ARCHITECTURES, TrainConfig

    same = {name: dataclasses.replace(settings, architecture=name) for name in ARCHITECTURES
            if name != settings.architecture}
    from ..pipeline.roofsegment import STEPS

    if TrainConfig.from_dict({"seed": settings.seed, **settings.train}).max_epochs > ABLATION_MAX_EPOCHS:
        same[f"max_epochs_{ABLATION_MAX_EPOCHS}"] = dataclasses.replace(
            settings, train={**settings.train, "max_epochs": ABLATION_MAX_EPOCHS})
    if settings.roof_colour:
        same["no_roof_colour"] = dataclasses.replace(settings, roof_colour=False)
        if settings.roof_score_cone:
            same["no_score_cone"] = dataclasses.replace(settings, roof_score_cone=False)
    own = {}
    if settings.roof_colour:
        if settings.roof_finder != "colour":
            own["colour_roof_finder"] = dataclasses.replace(settings, roof_finder="colour")
        if settings.roof_weight_power != 1.0:
            own["roof_weight_power_1"] = dataclasses.replace(settings, roof_weight_power=1.0)
        steps = settings.roof_finder_steps or STEPS
        if settings.roof_finder.startswith("segmenter") and steps > ABLATION_FINDER_STEPS:
            own[f"roof_finder_steps_{ABLATION_FINDER_STEPS}"] = dataclasses.replace(
                settings, roof_finder_steps=ABLATION_FINDER_STEPS)
    return same, own


def bench_ablations(targets: int = 100, root: Path | None = None, bars: Bars | None = None, dataset=None,
                    settings=None, tiles: int = 9) -> dict:
    """E1/E2 accuracy with the exhaustive search of the default model beside each variant of it
    (``ablation_settings``: the other NAMS architectures, the roof-colour ablations), on bench_nams's targets
    (``targets`` groups of ``tiles`` tiles per seed of the validation and the test split of each experiment), with
    95% intervals. Each variant's model is trained on the same training set (or taken from the cache) and its
    training time kept. The defaults were chosen on the validation rows."""
    from ..core.cache import cache_root
    from ..nams import load_checkpoint
    from ..pipeline.dataset import DatasetConfig
    from ..pipeline.workflow import ModelSettings, ensure_models
    from .evaluate import EvalSettings, prepare_eval, score_other_model

    root = Path(root or cache_root())
    dataset, settings = dataset or DatasetConfig(), settings or ModelSettings()
    same, own = ablation_settings(settings)
    others = {name: load_checkpoint(ensure_models(dataset, variant, root, bars).nams_path, "nams")
              for name, variant in same.items()}
    own_models = {name: load_checkpoint(ensure_models(dataset, variant, root, bars).nams_path, "nams")
                  for name, variant in own.items()}
    result = {"dataset": {"designs": dataset.designs, "tiles": dataset.tiles, "preset": dataset.preset},
              "architecture": settings.architecture, "roof_finder": settings.roof_finder,
              "roof_weight_power": settings.roof_weight_power, "targets_per_seed": targets,
              "e2_intervals": E2_INTERVALS, "tiles_per_target": tiles,
              "train_seconds": {name: round(ckpt.extra["seconds"], 1)
                                for name, ckpt in {**others, **own_models}.items()},
              "roof_segmenter_seconds": _finder_seconds(dataset, {"default": settings, **same, **own}, root),
              "splits": {}}
    for split_name, experiment, split, ctx in _split_contexts(dataset, settings, targets, tiles, root, bars):
        seed = split.seeds[0]  # of the searches' random starts, as in bench_nams
        rows = {"nams_exhaustive": _exhaustive_row(ctx, seed)}
        rows.update({f"nams_exhaustive_{name}": score_other_model(ctx, ckpt, seed) for name, ckpt in others.items()})
        for name, variant in own.items():
            scored = EvalSettings(targets=targets, tiles=tiles, split=split, ms2=False, sbi=False)
            rows[f"nams_exhaustive_{name}"] = _exhaustive_row(
                prepare_eval(experiment, dataset, variant, scored, root, bars), seed)
        part = result["splits"].setdefault(split_name, {"settings": {}, "experiments": {}})
        part["settings"][experiment], part["experiments"][experiment] = split.to_dict(), rows
    return result


def _finder_seconds(dataset, variants: dict, root: Path) -> dict:
    """Per variant (name -> ModelSettings) with a segmenter roof finder of its own (the default's and those
    with other steps): the seconds its cached segmenter took to learn, where that was kept."""
    from ..pipeline.roofcolour import roof_finder_seconds
    from ..pipeline.workflow import dataset_dir

    out, seen = {}, set()
    for name, variant in variants.items():
        key = (variant.roof_finder, variant.roof_finder_steps)
        if not (variant.roof_colour and variant.roof_finder.startswith("segmenter")) or key in seen:
            continue
        seen.add(key)
        seconds = roof_finder_seconds(dataset_dir(dataset, root), variant.roof_finder, variant.seed,
                                      variant.roof_finder_steps)
        if seconds is not None:
            out[name] = round(seconds, 1)
    return out


def _exhaustive_row(ctx, seed: int) -> dict:
    from .evaluate import method_runs, score_method

    row, _ = score_method(ctx, method_runs(ctx, seed, {})["nams_exhaustive"])
    return {**row, "targets": len(ctx.jobs)}


def fastest_adjoint(e1_rows: dict, sweep=ADJOINT_SWEEP) -> dict:
    """The fastest adjoint setting of ``sweep`` whose E1 top-1 rates (flat and sloped) are within 0.05 of
    the first (the paper's) setting's, from bench_nams's E1 rows of the validation split: a choice."""
    def row(si):
        return e1_rows[f"nams_adjoint_M{si[0]}_it{si[1]}"]

    paper = row(sweep[0])
    keeps = [si for si in sweep if all(row(si)[k] >= paper[k] - 0.05 for k in ("flat_top1", "sloped_top1"))]
    fastest = min(keeps, key=lambda si: row(si)["seconds_per_target"])
    return {"M": fastest[0], "iterations": fastest[1]}


def format_nams_table(result: dict) -> str:
    """``bench_nams``'s result as the Markdown tables of docs/benchmarks.md: accuracy with 95% intervals
    and search time per experiment, method and split (test first, validation beside it), a note on
    the splits, training and feature times, the stage times (E4), and per split where NAMS's E2
    top-10 misses come from (``breakdown.breakdown_markdown``; results from before it lack them)."""
    from .breakdown import breakdown_markdown, breakdown_title

    splits = result["splits"]
    order = [name for name in ("test", "validation") if name in splits]
    lines = _accuracy_table(splits)
    described = "; ".join(f"{split}: E1 seeds {', '.join(map(str, s['settings']['e1']['seeds']))}, E2 seeds "
                          f"{', '.join(map(str, s['settings']['e2']['seeds']))} with {s['settings']['e2']['heldout']}"
                          for split, s in ((n, splits[n]) for n in order))
    notes = [f"Splits ({described}); {result['targets_per_seed']} target groups of {result['tiles_per_target']} "
             "tiles per seed in unseen cities, the neural-adjoint rows on "
             f"{result['adjoint_targets']} of them spread over the seeds; {_interval_note(result)} "
             "Choices are made on the validation rows only."
             + (f" {result['machine']['cpus']} CPUs, torch on {result['machine']['torch_threads']} thread(s)."
                if "machine" in result else ""),
             f"Training set {result['dataset']['designs']} designs x {result['dataset']['tiles']} tiles "
             f"({result['dataset']['preset']}). NAMS architecture {result['architecture']}"]
    if result.get("train_seconds_other_architectures"):  # results from before bench-ablations held the variants
        notes[-1] += " (rows nams_exhaustive_NAME: variants of the default, now measured by `make bench-ablations`)"
    notes[-1] += "."
    if "train_seconds" in result:
        t = result["train_seconds"]
        notes.append("Training" + {"in this run": " (timed as this run trained the models)",
                                   "fresh run": " (timed on a fresh run)"}.get(result.get("training_timed"), "")
                     + f": NAMS {t['train_nams']:.0f} s, DR {t['train_dr']:.0f} s"
                     + (f", sbi_nre {t['train_sbi_nre']:.0f} s" if "train_sbi_nre" in t else "")
                     + "".join(f", {name} {s:.0f} s (when its cached model was trained)"
                               for name, s in result.get("train_seconds_other_architectures", {}).items()) + ".")
    notes.append(f"Features: {result['feature_seconds_per_group']:.3f} s per group of {result['tiles_per_target']} "
                 "tiles x 8 views"
                 + (f"; the roof segmenter learns in {result['roof_segmenter_seconds']:.0f} s, once per training set"
                    if "roof_segmenter_seconds" in result else "") + "."
                 + ("" if "fastest_adjoint_keeping_e1" not in result else  # before bench-adjoint held the sweep
                    " Fastest adjoint setting within 0.05 of the paper setting's E1 top-1 on the validation split: "
                    "M={M}, {iterations} iterations.".format(**result["fastest_adjoint_keeping_e1"])))
    lines += ["", " ".join(notes)]
    stages = stage_times(result)
    if stages:
        lines += ["", "| stage (E4) | seconds | paper |", "|---|---|---|"]
        lines += [f"| {name} | {seconds:.3f} | {paper} |" if seconds < 10 else f"| {name} | {seconds:.0f} | {paper} |"
                  for name, seconds, paper in stages]
    for split in order:
        for experiment, breakdown in splits[split].get("breakdown", {}).items():
            title = breakdown_title(experiment, splits[split]["settings"][experiment])
            lines += ["", breakdown_markdown(breakdown, title).rstrip("\n")]
    return "\n".join(lines)


def _accuracy_table(splits: dict) -> list[str]:
    """The accuracy table of bench_nams and bench_ablations: a row per experiment, method and split (test
    first, validation beside it), rates with 95% intervals, search seconds per target."""
    from .evaluate import with_interval

    lines = ["| experiment | method | split | flat top-1 | flat top-10 | sloped top-1 | sloped top-10 | "
             "closeness flat / sloped | s per target | targets | top-1 flat / sloped, unseen designs |",
             "|---" * 11 + "|"]
    order = [name for name in ("test", "validation") if name in splits]
    for experiment in splits[order[0]]["experiments"]:
        for name in splits[order[0]]["experiments"][experiment]:
            for split in order:
                m = splits[split]["experiments"][experiment].get(name)
                if m is None:
                    continue
                unseen = (f"{m['unseen']['flat_top1']:.3f} / {m['unseen']['sloped_top1']:.3f} "
                          f"({m['unseen_targets']})" if m.get("unseen") else "-")
                cells = " | ".join(with_interval(m, k) for k in ("flat_top1", "flat_top10", "sloped_top1",
                                                                  "sloped_top10"))
                closeness = (f"{m['flat_closeness']:.3f} / {m['sloped_closeness']:.3f}" if "flat_closeness" in m
                             else "-")  # rows measured before it lack it
                lines.append(f"| {experiment.upper()} | {name} | {split} | {cells} | {closeness} "
                             f"| {m['seconds_per_target']:.4f} | {m['targets']} | {unseen} |")
    return lines


def format_ablations_table(result: dict) -> str:
    """``bench_ablations``'s result as the Markdown of docs/benchmarks.md: the accuracy table, what each row
    is and how long each variant's model took to train."""
    splits = result["splits"]
    power = f" ({result['roof_weight_power']:g})"
    rows = sorted({name.removeprefix("nams_exhaustive_") for s in splits.values() for e in s["experiments"].values()
                   for name in e if name != "nams_exhaustive"})
    described = "; ".join(f"`nams_exhaustive_{name}`: {ablation_meaning(name)}"
                          + (power if name == "roof_weight_power_1" else "")
                          + (f" ({result['roof_finder']})" if name == "colour_roof_finder" else "") for name in rows)
    trained = ", ".join(f"{name} {s:.0f} s" for name, s in result["train_seconds"].items())
    finders = result.get("roof_segmenter_seconds", {})  # results from before the steps variant lack it
    if finders:
        trained += "; the roof segmenter: " + ", ".join(f"{name} {s:.0f} s" for name, s in finders.items())
    note = (f"The default ({result['architecture']} NAMS, row `nams_exhaustive`) beside its variants, each trained "
            f"on the same training set ({result['dataset']['designs']} designs x {result['dataset']['tiles']} tiles, "
            f"{result['dataset']['preset']}) and scored with the exhaustive search on bench-nams' targets "
            f"({result['targets_per_seed']} groups of {result['tiles_per_target']} tiles per seed): {described}. "
            f"Training (when each cached model was trained): {trained}. The defaults were chosen on the validation "
            f"rows; {_interval_note(result)}")
    return "\n".join([*_accuracy_table(splits), "", note])


def stage_times(result: dict, render_bench: Path = Path("benchmarks/render.json")) -> list[tuple[str, float, str]]:
    """The paper's E4 (time per stage) from measured parts: rendering from ``make bench-render``'s
    seconds per tile, training and features from this benchmark, search from its exhaustive row."""
    import json

    try:
        per_tile = json.loads(render_bench.read_text())["presets"][result["dataset"]["preset"]]["seconds_per_tile"]
    except (OSError, ValueError, KeyError):
        return []
    if "train_seconds" not in result:
        return []
    tiles = result["dataset"]["designs"] * result["dataset"]["tiles"]
    search = result["splits"]["test"]["experiments"]["e1"]["nams_exhaustive"]["seconds_per_target"]
    group = result["feature_seconds_per_group"] + search
    segmenter = ([("learning the roof segmenter", result["roof_segmenter_seconds"], "-")]
                 if "roof_segmenter_seconds" in result else [])
    return [(f"simulation: training set of {tiles} tiles", per_tile * tiles, "15,300 images, 1.6 s each"),
            *segmenter,
            ("training NAMS", result["train_seconds"]["train_nams"], "13 h"),
            ("inference per target group of 9 tiles (features + exhaustive search)", group, "0.5 s per image"),
            ("inference per 5,000-image domain", group * 5000 / 9, "0.7 h")]


APPEARANCE_SPACE = "overhead-v1"


def bench_appearance(targets: int = 100, seed: int = 11, root: Path | None = None, bars: Bars | None = None,
                     out: Path | None = None, designs: int = 1200, space: str = APPEARANCE_SPACE) -> dict:
    """E1 in ``space`` (``overhead-v1``; a realism space such as ``overhead-towns-v3`` shares the model of
    `bench realism`'s run in it): can NAMS infer a target's look (ground, greenness, sun, brightness, roof
    jitter, sensor, city style, densities) as well as its roofs? A model trained on ``designs`` random
    designs of the space (twice the default training set: more parameters to learn), scored on
    ``targets`` groups of target ``seed`` (11: no setting was chosen on it) against uniform guessing
    and DR. Every metric of NAMS comes with a 95% bootstrap interval over target groups. ``out``
    receives ``sheet.png`` (targets beside their inferred designs)."""
    from ..pipeline.dataset import DatasetConfig
    from ..pipeline.workflow import ModelSettings
    from ..sim.design import DesignSpace
    from ..sim.textures import ensure_default_bank, ensure_heldout_bank
    from .evaluate import CONTINUOUS_SEARCH, EvalSettings, bootstrap_intervals, rankings, run_eval, score

    dataset = DatasetConfig(space=space, designs=designs)
    settings = EvalSettings(targets=targets, seed=seed, ms2=False, sbi=False, **CONTINUOUS_SEARCH)
    import shutil

    with tempfile.TemporaryDirectory(prefix="meta-sim-appearance-") as scratch:  # the checkpoints stay out
        result = run_eval("e1", Path(scratch), dataset, ModelSettings(), settings, root, bars)
        if out is not None:
            Path(out).mkdir(parents=True, exist_ok=True)
            shutil.copy2(Path(scratch) / "sheet.png", Path(out) / "sheet.png")
    result["seed"] = seed
    space = DesignSpace.load(space)
    ranks = rankings("e1", ensure_default_bank(), ensure_heldout_bank())
    rows = [score(t["predicted"]["nams_adjoint"], t["truth"], ranks, space) for t in result["targets_detail"]]
    result["nams_intervals"] = bootstrap_intervals(rows)
    result["space"] = space.to_dict()
    del result["targets_detail"]
    return result


def format_appearance_table(result: dict) -> str:
    """``bench_appearance``'s result as Markdown: per parameter, each method's score and NAMS's interval."""
    methods = result["methods"]
    keys = [k for k in methods["nams_adjoint"] if k.endswith(("_top1", "_top10", "_hit", "_error"))]
    names = [m for m in ("uniform", "dr", "nams_adjoint") if m in methods]
    space = result.get("space", {}).get("name", APPEARANCE_SPACE)
    lines = [f"E1 in `{space}` ({result['targets']} target groups of {result['tiles_per_target']} tiles, "
             f"target seed {result.get('seed', 11)}; a model trained on {result['training']['designs']} designs x "
             f"{result['training']['tiles']} tiles). Roofs: rate of inferring one of the n nearest textures; "
             "categorical parameters: rate of the true choice (`hit`); continuous ones: mean absolute error as a "
             "share of the parameter's range (`error`; uniform guessing: 1/3). NAMS: the neural-adjoint search "
             f"(M = {result['adjoint']['M']} starts, {result['adjoint']['iterations']} steps), with a 95% bootstrap "
             "interval over target groups.", "",
             "| metric | " + " | ".join(names) + " | NAMS 95% interval |", "|---|" + "---|" * (len(names) + 1)]
    for key in keys:
        low, high = result["nams_intervals"][key]
        cells = " | ".join(f"{methods[m][key]:.3f}" for m in names)
        lines.append(f"| {key.replace('_', ' ')} | {cells} | [{low:.3f}, {high:.3f}] |")
    trained = [v for k, v in result["training"]["seconds"].items() if k.startswith("train")]
    lines += ["", f"NAMS search: {methods['nams_adjoint']['seconds_per_target']:.3f} s per target group; "
              + (f"training: {sum(trained) / 60:.1f} min on this machine." if trained else
                 "the models came from the cache (trained by an earlier run).")]
    return "\n".join(lines) + "\n"

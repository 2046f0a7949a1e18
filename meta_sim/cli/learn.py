"""`meta-sim dataset | train | infer | eval`: the torch pipeline and the paper's experiments."""

from __future__ import annotations

from pathlib import Path

import click

from ..core.errors import MetaSimError
from ..core.fileio import made_folder
from ..experiments.splits import ALL_SPLIT_NAMES, get_split, single_seed
from ..sim.space_names import builtin_spaces
from .base import ARCHITECTURE_NAMES, _Bars, _torch_threads, main


def _dataset_options(command):
    for decorator in reversed([
        click.option("--designs", type=int, default=None, help="training designs [default: 600; paper: 1700]"),
        click.option("--tiles", type=int, default=None, help="tiles per design [default: 2; paper: 9]"),
        click.option("--paper-scale", is_flag=True, help="the paper's scale: 1,700 designs x 9 tiles"),
        click.option("--profile", type=click.Choice(["fast", "balanced", "paper"]), default=None,
                     help="a recommended training set (see `make bench-tradeoff`); --designs/--tiles override it"),
        click.option("--dataset-seed", type=int, default=1, show_default=True, help="design sampling and city seed"),
        click.option("--cities", type=int, default=8, show_default=True, help="cities the designs are spread over"),
        click.option("--preset", default="fast", show_default=True, help="render preset of the training tiles"),
        click.option("--space", default="rooftops-v1", show_default=True,
                     help=f"design space: a JSON file or one meta-sim ships ({', '.join(builtin_spaces())})"),
        click.option("--tile-px", type=int, default=384, show_default=True, help="training tile size in pixels"),
        click.option("--gsd", type=float, default=0.3, show_default=True, help="training tiles' metres per pixel"),
        click.option("--extractor", default="colour-texture", show_default=True,
                     help="features: colour-texture, torchscript:FILE, export:FILE or torchvision:NAME"),
        click.option("--weights", type=click.Path(path_type=Path), default=None,
                     help="weights file for a torchvision backbone"),
        click.option("--views", type=click.Choice(["1", "2", "4", "8"]), default="8", show_default=True,
                     help="augmentation views per tile (rotations x flip) averaged into a design's features"),
        click.option("--max-epochs", type=int, default=None, help="training epochs at most (early stopping)"),
        click.option("--architecture", type=click.Choice(list(ARCHITECTURE_NAMES)), default="additive",
                     show_default=True,
                     help="NAMS networks: paper (joint E, D, P), factorised (E and D per design parameter) or "
                          "additive (factorised, P a sum over parameters)"),
        click.option("--hidden", default=None,
                     help="hidden layer sizes of each network, e.g. 1024,2048 (default: the architecture's, "
                          "1024,2048 for paper, 512,1024 for the factorised ones)"),
        click.option("--roof-colour/--no-roof-colour", default=True, show_default=True,
                     help="add colour histograms of the likely roof pixels to the features (counted on the "
                          "training tiles' labels; see `make bench-nams` for what they change)"),
        click.option("--roof-finder", type=click.Choice(["segmenter", "segmenter-jitter", "colour"]),
                     default="segmenter", show_default=True,
                     help="what finds the roofs whose colours are counted: a small net learnt on the training "
                          "tiles' labels (segmenter; segmenter-jitter: trained with the whole scene's colours, "
                          "exposure, blur and noise jittered, for real imagery) or a pixel's colour alone (colour)"),
        click.option("--roof-weight-power", type=click.FloatRange(min=0.0, min_open=True), default=4.0,
                     show_default=True,
                     help="a pixel counts p(roof kind) to this power in its kind's colour histogram: higher "
                          "keeps only the pixels the roof finder is sure of (see `make bench-ablations`)"),
        click.option("--roof-score-cone/--no-roof-score-cone", default=True, show_default=True,
                     help="also count the roof colours in the E1/E2 score's own colour cone, at full "
                          "resolution (see `make bench-ablations`, row nams_exhaustive_no_score_cone)"),
        click.option("--roof-finder-steps", type=int, default=None,
                     help="training steps of the segmenter roof finder (default 3000; fewer learn it faster: see "
                          "`make bench-ablations`, row nams_exhaustive_roof_finder_steps_1000)"),
        click.option("--cache", type=click.Path(path_type=Path), default=None,
                     help="cache folder (default: $META_SIM_CACHE or ~/.cache/meta-sim)"),
    ]):
        command = decorator(command)
    return command


def _configs(o):
    from ..pipeline.dataset import DatasetConfig
    from ..pipeline.workflow import ModelSettings

    if o["profile"] and o["paper_scale"]:
        raise MetaSimError("give --profile or --paper-scale, not both")
    if o["profile"]:
        from ..pipeline.profiles import get_profile

        base = get_profile(o["profile"]).dataset
    else:
        base = DatasetConfig.paper() if o["paper_scale"] else DatasetConfig()
    overrides = {k: v for k, v in (("designs", o["designs"]), ("tiles", o["tiles"])) if v is not None}
    dataset = DatasetConfig(**{**base.__dict__, **overrides, "seed": o["dataset_seed"], "cities": o["cities"],
                               "preset": o["preset"], "tile_px": o["tile_px"], "pixel_size_m": o["gsd"],
                               "space": o["space"]})
    nams = {}
    if o["hidden"]:
        try:
            nams["hidden"] = [int(x) for x in o["hidden"].split(",")]
        except ValueError:
            raise MetaSimError("--hidden takes comma-separated integers, e.g. 1024,2048") from None
    train = {"max_epochs": o["max_epochs"]} if o["max_epochs"] is not None else {}
    settings = ModelSettings(extractor=o["extractor"], weights=str(o["weights"]) if o["weights"] else None,
                             views=int(o["views"]), nams=nams, train=train, architecture=o["architecture"],
                             roof_colour=o["roof_colour"], roof_finder=o["roof_finder"],
                             roof_weight_power=o["roof_weight_power"], roof_score_cone=o["roof_score_cone"],
                             roof_finder_steps=o["roof_finder_steps"])
    return dataset.check(), settings.check()


@main.command("dataset")
@_dataset_options
@_torch_threads
def dataset_command(**o):
    """Render a training set of uniformly sampled designs and cache its features (resumable)."""
    from ..pipeline.workflow import dataset_dir, prepare_features

    dataset, settings = _configs(o)
    bars = _Bars()
    features, seconds, rendered = prepare_features(dataset, settings, o["cache"], bars)
    bars.close()
    click.echo(f"{len(features.names)} designs x {dataset.tiles} tiles ({rendered} rendered now), features "
               f"{tuple(features.features.shape)} in {dataset_dir(dataset, o['cache'])} "
               f"(render {seconds['render']:.0f} s, features {seconds['features']:.0f} s)")


@main.command("train")
@_dataset_options
@click.option("--out", type=click.Path(path_type=Path), required=True, help="folder for nams.pt and dr.pt")
@_torch_threads
def train_command(out, **o):
    """Train NAMS (and the DR baseline) on the training set; builds the set first if needed."""
    import shutil

    from ..pipeline.workflow import ensure_models

    dataset, settings = _configs(o)
    with made_folder(out):  # before hours of training, not after
        bars = _Bars()
        models = ensure_models(dataset, settings, o["cache"], bars)
        bars.close()
        shutil.copy2(models.nams_path, out / "nams.pt")
        shutil.copy2(models.dr_path, out / "dr.pt")
    click.echo(f"wrote {out / 'nams.pt'} ({settings.architecture} NAMS) and {out / 'dr.pt'} "
               + ", ".join(f"{k} {v:.0f} s" for k, v in models.seconds.items()))


def _search_options(command):
    for decorator in reversed([
        click.option("-M", "--starts", "M", type=int, default=1000, show_default=True, help="adjoint: random starts"),
        click.option("-k", type=float, default=3.0, show_default=True, help="adjoint: starts within +-k sigma"),
        click.option("-S", "--keep", "S", type=int, default=50, show_default=True, help="best results voting"),
        click.option("--iterations", type=int, default=200, show_default=True, help="adjoint: Adam steps"),
        click.option("--lr", type=float, default=0.01, show_default=True, help="adjoint: Adam learning rate"),
        click.option("-r", "--rejection", "r", type=float, default=0.0, show_default=True,
                     help="diversify with rejection rate (paper: 0.25 on real imagery)"),
    ]):
        command = decorator(command)
    return command


@main.command("infer")
@click.argument("target_dir", metavar="TARGET_DIR[:METRES]")
@click.option("--model", type=click.Path(path_type=Path), required=True, help="NAMS checkpoint (nams.pt)")
@click.option("--out", type=click.Path(path_type=Path), required=True, help="folder for presets and report")
@click.option("--overwrite", is_flag=True, help="replace the outputs of an earlier run in --out (as a whole)")
@click.option("--group-size", type=int, default=9, show_default=True, help="target tiles per inferred design")
@click.option("--gsd", type=float, default=None,
              help="metres per pixel of the targets that nothing else states (TARGET_DIR:METRES, GeoTIFF/EXR "
                   "metadata, world files, a pixel_size.txt in TARGET_DIR); default: the model's, with a warning")
@click.option("--views", type=click.Choice(["1", "2", "4", "8"]), default=None,
              help="augmentation views per tile (default: as trained)")
@click.option("--weights", type=click.Path(path_type=Path), default=None, help="backbone weights, if needed")
@click.option("--seed", type=int, default=0, show_default=True, help="search seed")
@click.option("--search", "method", type=click.Choice(["auto", "adjoint", "exhaustive"]), default="auto",
              show_default=True, help="exhaustive evaluates every design; adjoint is the paper's search")
@click.option("--profile", type=click.Choice(["fast", "balanced", "paper"]), default=None,
              help="recommended search settings (fast/balanced: exhaustive; paper: adjoint M=1000, 200 "
                   "iterations, 8 views); options given explicitly win")
@click.option("--population-near", "near", type=int, default=0, show_default=True,
              help="population.json's designs to render from: each group's N best-ranked designs of the search "
                   "(the spread of what the search could not tell apart) instead of its one answer (0)")
@_search_options
@click.pass_context
@_torch_threads
def infer_command(ctx, target_dir, model, out, overwrite, group_size, gsd, views, weights, seed, method, profile,
                  near, M, k, S, iterations, lr, r):
    """Infer rooftop designs for a folder of target images (TARGET_DIR:METRES states their metres per pixel);
    write presets and a report."""
    from ..pipeline.infer import InferSettings, infer
    from ..sim.pixelsize import ImageFolder

    if profile:
        from ..pipeline.profiles import get_profile

        chosen = get_profile(profile)
        given = {name for name in ctx.params
                 if ctx.get_parameter_source(name) is not click.core.ParameterSource.DEFAULT}
        method = method if "method" in given else chosen.method
        M = M if "M" in given else chosen.M
        iterations = iterations if "iterations" in given else chosen.iterations
        views = views if "views" in given else str(chosen.views)
        group_size = group_size if "group_size" in given else chosen.group_size
    settings = InferSettings(group_size=group_size, method=method, M=M, k=k, S=S, iterations=iterations, lr=lr,
                             r=r, seed=seed, gsd=gsd, views=int(views) if views else None,
                             weights=str(weights) if weights else None, near=near)
    bars = _Bars()
    try:
        with made_folder(out.parent):
            report = infer(ImageFolder.parse(target_dir), model, out, settings, bars, overwrite=overwrite,
                           warn=lambda line: click.echo(line, err=True))
    finally:
        bars.close()
    for s in report["skipped"]:
        click.echo(f"skipped {s['path']}: {s['reason']}", err=True)
    click.echo((out / "report.md").read_text())
    for kind, ends in report["groups_outside_roof_pixels_range"].items():
        for end, count in ends.items():
            if count:
                click.echo(f"warning: {count} of {report['group_count']} groups have {end} {kind}-roof evidence, "
                           f"outside the model's training cities; their inferred {kind} roofs are unreliable "
                           "(report.md)", err=True)
    click.echo(f"{report['group_count']} presets in {out / 'presets'}, population in {out / 'population.json'}")


@main.group("eval")
def eval_group():
    """The paper's experiments: design recovery (e1, e2) and the task model (task e1|e2|e3)."""


def _design_eval(experiment: str, summary: str):
    @click.option("--out", type=click.Path(path_type=Path), required=True, help="folder for results and nams.pt")
    @click.option("--targets", type=int, default=20, show_default=True, help="target groups (per target seed)")
    @click.option("--target-tiles", type=int, default=9, show_default=True,
                  help="tiles per target group (the paper's groups have 9)")
    @click.option("--seed", type=int, default=1, show_default=True,
                  help="target seed (and the searches'); E2 then draws from heldout-v1")
    @click.option("--split", "split_name", type=click.Choice(list(ALL_SPLIT_NAMES)), default=None,
                  help="the targets of a split instead of --seed: validation (choices may be made on it; E2 "
                       "with heldout-v5), test (report only; E2 with heldout-v2) or check (report only, no "
                       "bench runs it; E2 with heldout-v3), --targets groups of each of its seeds")
    @click.option("--ms2/--no-ms2", default=True, show_default=True,
                  help="run the MS2 baseline (computes and caches features of every training tile once)")
    @click.option("--sbi/--no-sbi", default=True, show_default=True,
                  help="run the sbi baseline (neural ratio estimation; discrete spaces; trains and caches it once)")
    @_dataset_options
    @_search_options
    @click.pass_context
    @_torch_threads
    def command(ctx, out, targets, target_tiles, seed, split_name, ms2, sbi, M, k, S, iterations, lr, r, **o):
        from ..experiments.evaluate import EvalSettings, results_markdown, run_eval

        if split_name and ctx.get_parameter_source("seed") is not click.core.ParameterSource.DEFAULT:
            raise MetaSimError("give --split or --seed, not both: a split has its own target seeds")
        dataset, settings = _configs(o)
        split = get_split(experiment, split_name) if split_name else single_seed(experiment, seed)
        eval_settings = EvalSettings(targets=targets, tiles=target_tiles, seed=seed, split=split, ms2=ms2, sbi=sbi,
                                     M=M, k=k, S=S, iterations=iterations, lr=lr, r=r)
        eval_settings.check()
        with made_folder(out):
            bars = _Bars()
            results = run_eval(experiment, out, dataset, settings, eval_settings, o["cache"], bars)
            bars.close()
        click.echo(results_markdown(results))
        if split.touches_test:
            click.echo(f"These targets are the {split.report_split} split's: report these figures; choose nothing "
                       "by them (choose on --split validation).")
        click.echo(f"results, sheet.png and the checkpoint nams.pt are in {out}"
                   + (" with breakdown.md and breakdown.png: where NAMS's top-10 misses come from"
                      if experiment == "e2" else ""))

    command.__doc__ = summary
    eval_group.command(experiment)(command)


_design_eval("e1", "E1 (bank designs, unseen cities): top-1/top-10 of every method.")
_design_eval("e2", "E2 (held-out textures, the design gap): top-1/top-10 of every method.")


@eval_group.command("task")
@click.argument("experiments", nargs=-1, required=True, type=click.Choice(["e1", "e2", "e3"]))
@click.option("--out", type=click.Path(path_type=Path), required=True,
              help="folder for task.json, task.md and the predictions PNGs")
@click.option("--sim-only/--no-sim-only", default=False, show_default=True,
              help="also the sim-only transfer: rendered-only training on each real domain")
@click.option("--quick", is_flag=True, help="a few-minute smoke run (tiny models and sets; not a measurement)")
@click.option("--seeds", default="0,1,2", show_default=True, help="segmenter training seeds (at least 3 to report)")
@click.option("--steps", type=int, default=None, help="segmenter training steps [default: 500]")
@click.option("--realdata", type=click.Path(path_type=Path), default=None,
              help="the shared real domains (default: ../shared/realdata beside the repository)")
@_dataset_options
@_torch_threads
def eval_task_command(experiments, out, sim_only, quick, seeds, steps, realdata, **o):
    """The task model per augmentation strategy (none, uniform, DR, MS2, NAMS, GT): IoU on the targets."""
    from dataclasses import replace

    from ..experiments.task_eval import TaskEvalSettings, quick_models, run_task_eval, task_markdown

    dataset, settings = _configs(o)
    task_settings = TaskEvalSettings.quick() if quick else TaskEvalSettings()
    try:
        task_settings = replace(task_settings, seeds=tuple(int(x) for x in seeds.split(",")))
    except ValueError:
        raise MetaSimError(f"--seeds takes comma-separated integers, not {seeds!r}") from None
    if steps is not None:
        task_settings = replace(task_settings, train=replace(task_settings.train, steps=steps))
    if quick:
        dataset, settings = quick_models(dataset, settings)
    task_settings.check()
    from ..experiments.realdomains import REALDATA, require

    realdata = require(realdata or REALDATA)
    bars = _Bars()
    try:
        with made_folder(out):
            results = run_task_eval(list(dict.fromkeys(experiments)), out, dataset, settings, task_settings,
                                    o["cache"], realdata, sim_only, bars)
    finally:
        bars.close()
    click.echo(task_markdown(results))
    click.echo(f"task.json, task.md and the predictions PNGs are in {out}")


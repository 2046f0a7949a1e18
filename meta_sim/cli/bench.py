"""`meta-sim bench`: the benchmarks behind docs/benchmarks.md."""

from __future__ import annotations

from pathlib import Path

import click

from ..core.errors import MetaSimError
from ..experiments.publish import DOCS, publish, publish_section
from ..sim.space_names import builtin_spaces
from .base import _Bars, _torch_threads, main

README = Path("README.md")


def _docs_option(command):
    return click.option("--docs/--no-docs", default=True, show_default=True,
                        help=f"also replace this benchmark's table in {DOCS}")(command)


def _publish(result: dict, out: Path, table: str, section: str, docs: bool, *more: Path) -> None:
    written = publish(result, out, table, section, DOCS if docs else None)
    click.echo(table)
    click.echo("wrote " + ", ".join(str(p) for p in [*written, *more]))


def _with_bars(run, **kwargs):
    """``run(bars=..., **kwargs)`` with a progress bar per stage, the bars closed however it ends."""
    bars = _Bars()
    try:
        return run(bars=bars, **kwargs)
    finally:
        bars.close()


@main.group()
def bench():
    """Measure speed; results go to benchmarks/*.json."""


@bench.command("render")
@_docs_option
@click.option("--out", type=click.Path(path_type=Path), default=Path("benchmarks/render.json"), show_default=True)
@click.option("--designs", type=int, default=4, show_default=True, help="designs rendered per preset")
@click.option("--tiles", type=int, default=9, show_default=True, help="tiles per design")
@click.option("--repeats", type=int, default=3, show_default=True, help="runs per preset; medians are reported")
@click.option("--presets", default="fast,balanced,quality", show_default=True, help="comma-separated presets")
def bench_render(out, docs, designs, tiles, repeats, presets):
    """Seconds per tile per preset (render + label pass + EXR write), city build and city layout times."""
    from ..experiments.bench import bench_render as run
    from ..experiments.bench import format_render_table

    result = run(designs=designs, tiles=tiles, repeats=repeats, presets=presets.split(","))
    _publish(result, out, format_render_table(result), "render", docs)


@bench.command("exposure")
@_docs_option
@click.option("--out", type=click.Path(path_type=Path), default=Path("benchmarks/exposure.json"), show_default=True)
@click.option("--designs", type=int, default=100, show_default=True,
              help="the training set's first designs rendered with both presets")
@click.option("--tiles", type=int, default=2, show_default=True, help="tiles per design")
def bench_exposure_command(out, docs, designs, tiles):
    """The fast preset's exposure: flat roofs' brightness, path traced over rasterised, on training renders."""
    from ..experiments.exposure import bench_exposure, format_exposure_table

    if designs < 1 or tiles < 1:
        raise MetaSimError("--designs and --tiles must be at least 1")
    result = _with_bars(bench_exposure, designs=designs, tiles=tiles)
    _publish(result, out, format_exposure_table(result), "exposure", docs)


@bench.command("nams")
@_docs_option
@click.option("--out", type=click.Path(path_type=Path), default=Path("benchmarks/nams.json"), show_default=True)
@click.option("--targets", type=int, default=100, show_default=True,
              help="target groups per target seed of each split (3 seeds each: 300 groups per split and experiment)")
@click.option("--adjoint-targets", type=int, default=20, show_default=True,
              help="target groups for the (slow) neural-adjoint search, spread over the seeds")
@click.option("--cache", type=click.Path(path_type=Path), default=None, help="cache folder")
@_torch_threads
def bench_nams_command(out, docs, targets, adjoint_targets, cache):
    """Training, feature and search time, and E1/E2 accuracy per method and search setting (default scale), on
    the test split with 95% intervals and on the validation split beside it."""
    for name, value in (("--targets", targets), ("--adjoint-targets", adjoint_targets)):
        if value < 1:
            raise MetaSimError(f"{name} must be at least 1, not {value}")
    from ..experiments.bench import bench_nams, format_nams_table

    result = _with_bars(bench_nams, targets=targets, adjoint_targets=adjoint_targets, root=cache)
    _publish(result, out, format_nams_table(result), "nams", docs)


@bench.command("appearance")
@_docs_option
@click.option("--out", type=click.Path(path_type=Path), default=None,
              help="[default: benchmarks/appearance.json, or appearance-SPACE.json for another --space]")
@click.option("--targets", type=int, default=100, show_default=True, help="target groups")
@click.option("--pictures", type=click.Path(path_type=Path), default=None,
              help="folder for sheet.png (targets beside their inferred designs) [default: benchmarks/appearance, "
                   "or benchmarks/appearance/SPACE]")
@click.option("--space", default="overhead-v1", show_default=True,
              help=f"a design space meta-sim ships with appearance parameters ({', '.join(builtin_spaces())})")
@click.option("--cache", type=click.Path(path_type=Path), default=None, help="cache folder")
@_torch_threads
def bench_appearance_command(out, docs, targets, pictures, space, cache):
    """E1 in overhead-v1 (or --space): how well NAMS infers a target's look (ground, vegetation, sun, sensor,
    city style)."""
    from ..experiments.bench import APPEARANCE_SPACE, bench_appearance, format_appearance_table

    if space not in builtin_spaces():
        raise MetaSimError(f"--space must be a built-in design space ({', '.join(builtin_spaces())}), not {space!r}")
    other = space != APPEARANCE_SPACE
    out = out or Path(f"benchmarks/appearance-{space}.json" if other else "benchmarks/appearance.json")
    pictures = pictures or Path("benchmarks/appearance") / (space if other else "")
    bars = _Bars()
    result = bench_appearance(targets=targets, root=cache, bars=bars, out=pictures, space=space)
    bars.close()
    _publish(result, out, format_appearance_table(result), f"appearance-{space}" if other else "appearance", docs,
             Path(pictures) / "sheet.png")


@bench.command("stability")
@_docs_option
@click.option("--out", type=click.Path(path_type=Path), default=Path("benchmarks/stability.json"), show_default=True)
@click.option("--scratch", type=click.Path(path_type=Path), default=None,
              help="folder for the run's tiny models, targets and outputs (default: a temporary one)")
@_torch_threads
def bench_stability_command(out, docs, scratch):
    """The extreme cases (constant, black, white, HDR and NaN targets; one-tile groups; M=1, S=M, k=0, r=0 and 1;
    a one-choice space; zero-variance features; bfloat16) end to end on tiny models made in the run: what each
    ended in. Exits 2 after writing if any ended in neither a finite preset nor a clear error."""
    from ..experiments.stability import bench_stability, check, format_stability_table

    bars = _Bars()
    try:
        result = bench_stability(scratch, bars)
    finally:
        bars.close()
    _publish(result, out, format_stability_table(result), "stability", docs)
    check(result)


def _on_bench_nams_targets(out: str):
    """The options of a bench scored on bench-nams' targets: --docs, --out (default ``out``), --targets, --cache."""
    def decorate(command):
        for option in (click.option("--cache", type=click.Path(path_type=Path), default=None, help="cache folder"),
                       click.option("--targets", type=int, default=100, show_default=True,
                                    help="target groups per target seed of each split (as bench-nams)"),
                       click.option("--out", type=click.Path(path_type=Path), default=Path(out), show_default=True),
                       _docs_option):
            command = option(command)
        return command
    return decorate


@bench.command("adjoint")
@_on_bench_nams_targets("benchmarks/adjoint.json")
@click.option("--adjoint-targets", type=int, default=20, show_default=True,
              help="target groups per split and experiment, spread over the seeds")
@_torch_threads
def bench_adjoint_command(out, docs, targets, cache, adjoint_targets):
    """E1/E2 accuracy and search time of the neural-adjoint search from the paper's setting (1000 starts x 200
    steps) down, beside the exhaustive search, on bench-nams' test and validation targets; the fastest setting
    that keeps E1 is chosen on validation."""
    if adjoint_targets < 1:
        raise MetaSimError(f"--adjoint-targets must be at least 1, not {adjoint_targets}")
    from ..experiments.bench import bench_adjoint, format_adjoint_table

    result = _with_bars(bench_adjoint, targets=targets, adjoint_targets=adjoint_targets, root=cache)
    _publish(result, out, format_adjoint_table(result), "adjoint", docs)


@bench.command("ablations")
@_on_bench_nams_targets("benchmarks/ablations.json")
@_torch_threads
def bench_ablations_command(out, docs, targets, cache):
    """E1/E2 of the default model beside its variants (the other NAMS architectures, the roof-colour ablations),
    each trained on the same training set, on bench-nams' test and validation targets with 95% intervals."""
    from ..experiments.bench import bench_ablations, format_ablations_table

    result = _with_bars(bench_ablations, targets=targets, root=cache)
    _publish(result, out, format_ablations_table(result), "ablations", docs)


@bench.command("reference")
@_on_bench_nams_targets("benchmarks/reference.json")
def bench_reference_command(out, docs, targets, cache):
    """E1/E2 of the roof-colour reference on the test and validation splits: how far the renders' roof colours
    (found with the roof labels) agree with the swatch similarity that scores every method."""
    from ..experiments.reference import bench_reference, format_reference_table

    result = _with_bars(bench_reference, targets=targets, root=cache)
    _publish(result, out, format_reference_table(result), "reference", docs)


@bench.command("objective")
@_on_bench_nams_targets("benchmarks/objective.json")
def bench_objective_command(out, docs, targets, cache):
    """How the search compares the roof-colour histograms (exponent, blur): a grid scored on the validation
    split of E1 and E2, the best chosen there, and the default and the chosen one scored on test."""
    from ..experiments.objective import bench_objective, format_objective_table

    result = _with_bars(bench_objective, targets=targets, root=cache)
    _publish(result, out, format_objective_table(result), "objective", docs)


@bench.command("tradeoff")
@_docs_option
@click.option("--out", type=click.Path(path_type=Path), default=Path("benchmarks/tradeoff.json"), show_default=True)
@click.option("--plot", type=click.Path(path_type=Path), default=Path("benchmarks/tradeoff.png"), show_default=True)
@click.option("--targets", type=int, default=100, show_default=True,
              help="E1 target groups of 9 tiles per seed of each split, validation and test (as bench-nams)")
@click.option("--adjoint-targets", type=int, default=20, show_default=True,
              help="target groups of each split for the (slow) neural-adjoint settings")
@click.option("--presets", default="fast,balanced", show_default=True, help="render presets to compare")
@click.option("--profiles", default="fast,balanced,paper", show_default=True,
              help="profiles measured end to end (paper renders 15,300 tiles)")
@click.option("--training-sets", default=None,
              help="training sets compared, DESIGNSxTILES,... (default: 150x4,300x2,300x4,600x2,600x4,1700x9)")
@click.option("--merge", is_flag=True,
              help="add this run's points to those of --out (same targets; the rows it did not measure again are "
                   "kept): the study measured in parts")
@click.option("--cache", type=click.Path(path_type=Path), default=None, help="cache folder")
@_torch_threads
def bench_tradeoff_command(out, docs, plot, targets, adjoint_targets, presets, profiles, training_sets, merge, cache):
    """E1 accuracy against time for every knob that costs time, and the fast/balanced/paper profiles, on the
    test split (reported) and the validation split (where the profiles are chosen) beside it. Hours on 2 CPUs:
    measure it in parts with --training-sets, --presets, --profiles and --merge."""
    from ..core.extras import require
    from ..experiments.tradeoff import (
        bench_tradeoff,
        format_profiles_table,
        format_tradeoff_table,
        merge_results,
        parse_training_sets,
        plot_tradeoff,
        read_tradeoff,
    )
    from ..pipeline.profiles import get_profile

    names = [p for p in profiles.split(",") if p]
    for name in names:
        get_profile(name)
    sets = parse_training_sets(training_sets)
    earlier = read_tradeoff(out) if merge else None  # before hours of measuring, not after
    require("matplotlib", "the trade-off plot")
    bars = _Bars()
    result = bench_tradeoff(targets=targets, adjoint_targets=adjoint_targets, root=cache,
                            presets=[p for p in presets.split(",") if p], profiles=names, training_sets=sets,
                            bars=bars)
    bars.close()
    if earlier is not None:
        result = merge_results(earlier, result)
    plot_tradeoff(result, plot)
    _publish(result, out, format_tradeoff_table(result), "tradeoff", docs, plot)
    if docs:  # the profiles' measured rows in the README too
        click.echo(f"wrote {publish_section(README, 'profiles', format_profiles_table(result))}")


@bench.command("farm")
@_docs_option
@click.option("--out", type=click.Path(path_type=Path), default=Path("benchmarks/farm.json"), show_default=True)
@click.option("--designs", type=int, default=16, show_default=True, help="tasks of the job (one design each)")
@click.option("--tiles", type=int, default=4, show_default=True, help="tiles per task")
def bench_farm_command(out, docs, designs, tiles):
    """Tiles per second and peak memory per worker: 1 and 2 local workers, and a Dask LocalCluster."""
    from ..experiments.farm_bench import bench_farm, format_farm_table

    result = bench_farm(designs=designs, tiles=tiles)
    _publish(result, out, format_farm_table(result), "farm", docs)


@bench.command("infer")
@_docs_option
@click.option("--out", type=click.Path(path_type=Path), default=Path("benchmarks/infer.json"), show_default=True)
@click.option("--model", type=click.Path(path_type=Path), default=None,
              help="NAMS checkpoint (default: the cached default model, trained first if missing)")
@click.option("--sizes", default="180,1440,11520", show_default=True, help="images per folder, comma-separated")
@click.option("--big-px", type=int, default=16000, show_default=True, help="side of the one large image (0: none)")
@click.option("--realdata", type=click.Path(path_type=Path), default=None,
              help="the shared real tiles (default: ../shared/realdata beside the repository)")
@click.option("--cache", type=click.Path(path_type=Path), default=None, help="cache folder")
@_torch_threads
def bench_infer_command(out, docs, model, sizes, big_px, realdata, cache):
    """Peak memory and throughput of `meta-sim infer` on growing folders of real tiles and one huge image."""
    from ..experiments.infer_bench import REALDATA, bench_infer, format_infer_table

    try:
        counts = tuple(int(s) for s in sizes.split(",") if s.strip())
    except ValueError:
        raise MetaSimError(f"--sizes must be whole numbers separated by commas, not {sizes!r}") from None
    if not counts or min(counts) < 1 or big_px < 0:
        raise MetaSimError("--sizes must be positive and --big-px at least 0")
    if model is None:
        from ..pipeline.dataset import DatasetConfig
        from ..pipeline.workflow import ModelSettings, ensure_models

        bars = _Bars()
        model = ensure_models(DatasetConfig(), ModelSettings(), cache, bars).nams_path
        bars.close()
    result = bench_infer(Path(model), counts, big_px, realdata or REALDATA)
    _publish(result, out, format_infer_table(result), "infer", docs)


def _task_bench_options(pictures: str, pictures_help: str):
    """The options `bench task` and `bench realism` share."""

    def decorate(command):
        for decorator in reversed([
            _docs_option,
            click.option("--out", type=click.Path(path_type=Path), default=Path(f"benchmarks/{pictures}.json"),
                         show_default=True),
            click.option("--pictures", type=click.Path(path_type=Path), default=Path(f"benchmarks/{pictures}"),
                         show_default=True, help=pictures_help),
            click.option("--quick", is_flag=True,
                         help="a few-minute smoke run with tiny models (not a measurement; no docs)"),
            click.option("--realdata", type=click.Path(path_type=Path), default=None,
                         help="the shared real domains (default: ../shared/realdata beside the repository)"),
            click.option("--cache", type=click.Path(path_type=Path), default=None, help="cache folder"),
            _torch_threads,
        ]):
            command = decorator(command)
        return command

    return decorate


def _task_configs(quick: bool):
    """(dataset, models, task settings) of a task benchmark: the defaults, or the quick run's."""
    from ..experiments.task_eval import TaskEvalSettings, quick_models
    from ..pipeline.dataset import DatasetConfig
    from ..pipeline.workflow import ModelSettings

    if quick:
        return (*quick_models(DatasetConfig(), ModelSettings()), TaskEvalSettings.quick())
    return DatasetConfig(), ModelSettings(), TaskEvalSettings()


@bench.command("task")
@_task_bench_options("task", "folder for each experiment's predictions PNG")
def bench_task_command(out, docs, pictures, quick, realdata, cache):
    """The task model (building IoU) for E1, E2 and E3 per augmentation strategy, and the sim-only
    transfer on each real domain, beside the paper's U-Net."""
    from ..experiments.task_eval import run_task_eval, task_markdown

    dataset, models, settings = _task_configs(quick)
    bars = _Bars()
    try:
        result = run_task_eval(["e1", "e2", "e3"], pictures, dataset, models, settings, cache, realdata, True, bars,
                               write=False)
    finally:
        bars.close()
    _publish(result, out, task_markdown(result), "task", docs and not quick)


@bench.command("roof-finder")
@click.option("--out", type=click.Path(path_type=Path), default=Path("benchmarks/roof_finder.json"), show_default=True)
@_docs_option
@click.option("--spaces", default=",".join(("rooftops-v1", "overhead-v2")), show_default=True,
              help="comma-separated design spaces whose models' roof finders to measure")
@click.option("--finders", default="segmenter", show_default=True,
              help="comma-separated roof finders (segmenter, segmenter-jitter, colour): a model per space and finder")
@click.option("--realdata", type=click.Path(path_type=Path), default=None,
              help="the shared real domains (default: ../shared/realdata beside the repository)")
@click.option("--cache", type=click.Path(path_type=Path), default=None, help="cache folder")
@_torch_threads
def bench_roof_finder_command(out, docs, spaces, finders, realdata, cache):
    """How each model's roof finder reads real imagery: roof pixels it counts against the true building share
    and the training cities' range, and its building map against the masks, per real domain."""
    from ..experiments.finder_bench import bench_roof_finder, format_roof_finder_table

    bars = _Bars()
    try:
        result = bench_roof_finder([s.strip() for s in spaces.split(",") if s.strip()],
                                   [f.strip() for f in finders.split(",") if f.strip()], cache, realdata, bars)
    finally:
        bars.close()
    _publish(result, out, format_roof_finder_table(result), "roof-finder", docs)


@bench.command("sensor")
@click.option("--out", type=click.Path(path_type=Path), default=Path("benchmarks/sensor.json"), show_default=True)
@_docs_option
@click.option("--realdata", type=click.Path(path_type=Path), default=None,
              help="the shared real domains (default: ../shared/realdata beside the repository)")
@click.option("--cache", type=click.Path(path_type=Path), default=None, help="cache folder")
def bench_sensor_command(out, docs, realdata, cache):
    """Fit each named sensor's sharpness (blur, unsharp mask) to the fine detail of the real domains' adapt
    scenes it stands for, on renders of the richest built-in scene with no sensor."""
    from ..experiments.sensor_fit import bench_sensor, format_sensor_table

    result = _with_bars(bench_sensor, cache_dir=cache, realdata=realdata)
    _publish(result, out, format_sensor_table(result), "sensor", docs)


@bench.command("realism")
@_task_bench_options("realism", "folder for realism*.png (real scenes beside renders of their inferred designs)")
@click.option("--runs", default=None,
              help="comma-separated runs to (re)measure, e.g. overhead-v1, or another built-in design space "
                   "(e.g. overhead-v2) to add its run, or a space with +scene, +ground or +camera (overhead-v2+scene: "
                   "its segmenters trained on renders with that colour augmentation), and any of these with :uniform "
                   "(overhead-v2+scene:uniform: no NAMS model, the space's renders alone, from renders of uniform "
                   "designs), or with :near (overhead-towns-v3+scene:near: each domain's renders drawn from its "
                   "groups' best-ranked designs of the search, not one design per group), or with :dr (each group's "
                   "design from the DR baseline trained beside NAMS), or with :matched (each domain's renders "
                   "brought to the colour statistics of its adapt scenes), or with :critic (each domain's renders "
                   "drawn from the training designs a real-versus-rendered critic of its adapt scenes finds the most "
                   "real), or with :ownroofs (the uniform designs with each domain's own roofs, cut from its "
                   "labelled adapt scenes, painted on the renders' buildings: an upper bound of roof textures, never "
                   "a candidate for issue 18's choices), and any of these with :rSHARE "
                   "(overhead-towns-v4+scene:r0.5: that share of each domain's "
                   "cities drawn uniformly instead of from its inferred designs; 0.25 otherwise), and any of these "
                   "with :stepsN last (overhead-towns-v8:critic:r0.5:steps2000: every segmenter of the run trains "
                   "N steps instead of 500); their rows replace those in --out and the other rows stay (default: "
                   "every run)")
@click.option("--tables", is_flag=True,
              help="measure nothing: write the tables again from the results in --out (after a change to them)")
def bench_realism_command(out, docs, pictures, quick, realdata, cache, runs, tables):
    """How close renders are to each real domain: sim-only building IoU against the other real domains
    and the all-building answer, and a real-versus-rendered classifier's accuracy."""
    import json

    from ..experiments.task_eval import realism_markdown, run_realism

    if tables:
        if runs or quick:
            raise click.UsageError("--tables measures nothing: it takes neither --runs nor --quick")
        if not Path(out).is_file():
            raise click.UsageError(f"--tables: no results at {out}; measure them first")
        result = json.loads(Path(out).read_text())
        _publish(result, out, realism_markdown(result), "realism", docs)
        return
    dataset, models, settings = _task_configs(quick)
    only = {r.strip() for r in runs.split(",") if r.strip()} if runs else None
    bars = _Bars()
    try:
        result = run_realism(dataset, models, settings, pictures, cache, realdata, bars, only=only)
    finally:
        bars.close()
    if only and Path(out).is_file():  # the runs not measured now keep their rows (and their share of the time)
        earlier = json.loads(Path(out).read_text())
        runs = {**{k: v for k, v in earlier.get("runs", {}).items() if k not in result["runs"]}, **result["runs"]}
        models = {**earlier.get("nams_models", {}), **result["nams_models"]}
        result = {**earlier, **result, "runs": runs, "nams_models": models,
                  "seconds": result["seconds"] + float(earlier.get("seconds", 0.0))}
    _publish(result, out, realism_markdown(result), "realism", docs and not quick,
             *sorted(Path(pictures).glob("realism*.png")))

"""E1 and E2 of the paper on our simulator: can a method recover the rooftop design of targets?

* E1: synthetic targets whose design is in the bank, rendered in city seeds
  the training set never used, with designs drawn independently of the
  training set's, as the design behind real imagery would be. Some targets
  are a training design by chance; ``unseen`` scores only the others (see
  docs/design.md, "E1 targets and the design stream").
* E2: synthetic targets made with held-out textures (the design gap): the
  best a method can do is name the bank texture nearest to the truth.

Each experiment has a validation and a test split (``splits.py``): target
seeds and, for E2, the held-out set. Choices are made on validation; test is
only reported.

Methods, all in one harness: uniform sampling, direct regression (DR), MS2
(REINFORCE over a categorical design distribution with KDE feature
distributions, drawing simulations from the training set's tiles; see
``meta_sim/nams/ms2.py``), the sbi baseline (neural ratio estimation with
the ``sbi`` package, evaluated over every design; ``meta_sim/nams/nre.py``),
and NAMS with the neural-adjoint and the exhaustive search.

Scoring follows the paper (section 5.4): rank the bank's textures by the HSV
similarity to the true texture (``meta_sim/sim/textures/similarity.py``); a
prediction is a top-n hit when it is among the n nearest, with ties at the
n-th place shared fairly (``ranking.py``). In E1 the nearest texture is the
truth itself. The published scores are in docs/benchmarks.md
(`make bench-nams`).
"""

from __future__ import annotations

import hashlib
import json
import pickle
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from ..core.errors import MetaSimError
from ..core.fileio import write_text_atomic
from ..core.progress import Bars
from ..nams.search import SearchOptions
from ..render.jobs import Job
from ..sim.design import Continuous, DesignSpace
from .ranking import KIND_OF, rankings
from .splits import FIRST_HELDOUT, Split, single_seed

TARGET_CITY_SEED = 100_000  # training sets use small seeds: targets come from cities never trained on
# Designs are drawn from np.random.default_rng([seed, stream]). Training sets use stream 1
# (render.jobs.sample_designs): E1 targets once did too, and with the default seed of both they were the
# training set's first designs. Version 2 of the targets draws E1 from a stream of its own.
TARGET_DESIGN_STREAM = {"e1": 3, "e2": 2}
TARGETS_VERSION = 2
METRICS = ("flat_top1", "flat_top10", "sloped_top1", "sloped_top10")


def target_jobs(experiment: str, space: DesignSpace, heldout, n: int, seed: int) -> list[Job]:
    """``n`` target designs, each in its own unseen city."""
    if experiment not in TARGET_DESIGN_STREAM:
        raise MetaSimError(f"unknown experiment {experiment!r}; choose e1 or e2")
    rng = np.random.default_rng([seed, TARGET_DESIGN_STREAM[experiment]])
    if experiment == "e1":
        designs = space.sample(rng, n)
    else:  # held-out textures for the roofs; any other parameter drawn as in E1
        designs = []
        for _ in range(n):
            design = {}
            for param in space.parameters:
                if getattr(param, "texture_kind", None):
                    ids = heldout.ids(param.texture_kind)
                    design[param.name] = ids[int(rng.integers(len(ids)))]
            other = [p for p in space.parameters if p.name not in design]
            if other:
                sampled = replace(space, parameters=tuple(other)).sample(rng, 1)[0]
                design = {name: {**design, **sampled}[name] for name in space.names}
            designs.append(design)
    return [Job(design, TARGET_CITY_SEED + seed * 1000 + k, f"{experiment}-{k:04d}")
            for k, design in enumerate(designs)]


def score(predicted: dict, truth: dict, ranks: dict, space: DesignSpace | None = None) -> dict:
    """top-1 / top-10 hits (tie-aware, see ``ranking.Ranking.credit``) and the closeness (the predicted
    texture's similarity to the truth as a share of the nearest bank texture's, ``ranking.Ranking.closeness``)
    for each roof parameter the space has.

    With ``space``, its other parameters too: ``{name}_hit`` (1 for the true choice) for a categorical
    one, ``{name}_error`` (the absolute error as a fraction of the parameter's range) for a continuous one.
    """
    out = {}
    for param, kind in KIND_OF.items():
        if param not in truth:
            continue
        ranking = ranks[kind][truth[param]]
        out[f"{kind}_top1"] = ranking.credit(predicted[param], 1)
        out[f"{kind}_top10"] = ranking.credit(predicted[param], 10)
        out[f"{kind}_closeness"] = ranking.closeness(predicted[param])
    for param in (space.parameters if space else ()):
        if param.name in KIND_OF:
            continue
        if isinstance(param, Continuous):
            out[f"{param.name}_error"] = abs(float(predicted[param.name]) - float(truth[param.name])) / (
                param.high - param.low)
        else:
            out[f"{param.name}_hit"] = float(predicted[param.name] == truth[param.name])
    return out


def unseen_rows(rows: list[dict], jobs: list[Job], training_designs) -> list[dict]:
    """The score rows of the targets whose design is not one of the training set's."""
    return [row for row, job in zip(rows, jobs) if job.design not in training_designs]


def mean_scores(rows: list[dict]) -> dict:
    """The mean of each metric over score rows (``score``'s); {} for no rows."""
    return {key: float(np.mean([r[key] for r in rows])) for key in rows[0]} if rows else {}


def bootstrap_intervals(rows: list[dict], resamples: int = 2000, seed: int = 0,
                        clusters: dict[str, list] | None = None) -> dict:
    """Per metric of the score rows (one per target group): a 95% interval of its mean, resampling the
    rows with replacement (the same draws for every metric).

    ``clusters`` (roof kind -> a label per row, e.g. each group's true texture of that kind): a metric of that
    kind (``flat_top10``) resamples the labels instead, each drawn label bringing all its rows (a cluster
    bootstrap). E2's groups share a few held-out textures, and a texture's groups miss or hit together: what
    varies from one set of textures to the next is the textures, and resampling groups hides it."""
    means = bootstrap_means(rows, resamples, seed, clusters)
    return {key: [float(np.percentile(m, 2.5)), float(np.percentile(m, 97.5))] for key, m in means.items()}


def bootstrap_means(rows: list[dict], resamples: int = 2000, seed: int = 0,
                    clusters: dict[str, list] | None = None) -> dict[str, np.ndarray]:
    """Per metric of the score rows: its mean in each of ``resamples`` bootstrap resamples (``bootstrap_intervals``
    takes their percentiles). Metrics resampled alike share the draws, so resampled means of several metrics
    can be added up draw by draw."""
    rng = np.random.default_rng(seed)
    draws = rng.integers(0, len(rows), (resamples, len(rows)))
    by_kind = {}
    for kind, labels in (clusters or {}).items():
        if len(labels) != len(rows):
            raise ValueError(f"{len(labels)} {kind} cluster labels for {len(rows)} rows")
        names, index = np.unique(np.asarray(labels, dtype=object).astype(str), return_inverse=True)
        by_kind[kind] = (index, len(names), rng.integers(0, len(names), (resamples, len(names))))
    out = {}
    for key in rows[0]:
        values = np.array([r[key] for r in rows], dtype=np.float64)
        kind = key.split("_", 1)[0]
        if kind in by_kind:
            index, n, picks = by_kind[kind]
            sums, counts = np.bincount(index, values, n), np.bincount(index, minlength=n).astype(np.float64)
            out[key] = sums[picks].sum(axis=1) / counts[picks].sum(axis=1)
        else:
            out[key] = values[draws].mean(axis=1)
    return out


def texture_clusters(experiment: str, designs: list[dict]) -> dict[str, list] | None:
    """E2's cluster labels for ``bootstrap_intervals``: each target group's true texture per roof kind (from
    its true design). None for E1, whose targets are the bank's own textures (the set a user infers from, not
    a sample of it)."""
    if experiment != "e2":
        return None
    return {kind: [design[param] for design in designs] for param, kind in KIND_OF.items()
            if designs and param in designs[0]}


def results_markdown(results: dict) -> str:
    """``run_eval``'s results as Markdown tables: every method, then (E1) the targets the training
    set lacks."""
    experiment = results["experiment"].upper()
    split = f", {results['split']['name']}" if "split" in results else ""
    lines = [f"### {experiment}: rate of inferring one of the n nearest textures "
             f"({results['targets']} target groups of {results['tiles_per_target']} tiles{split}; "
             "95% intervals from resampling the " + ("held-out textures" if results["experiment"] == "e2" else "groups")
             + ")", "",
             "| method | flat top-1 | flat top-10 | sloped top-1 | sloped top-10 | s per target |",
             "|---|---|---|---|---|---|"]
    for name, m in results["methods"].items():
        cells = " | ".join(with_interval(m, k) if k in m else "-" for k in METRICS)
        lines.append(f"| {name} | {cells} | {m['seconds_per_target']:.4f} |")
    trained = {name: m["train_seconds"] for name, m in results["methods"].items() if "train_seconds" in m}
    if trained:
        lines += ["", "Training (when the cached model was trained): "
                  + ", ".join(f"{name} {seconds:.1f} s" for name, seconds in trained.items()) + "."]
    unseen = {name: m for name, m in results["methods"].items() if m.get("unseen")}
    if unseen:
        n = next(iter(unseen.values()))["unseen_targets"]
        lines += ["", f"Only the {n} targets whose design is not in the training set:", "",
                  "| method | flat top-1 | flat top-10 | sloped top-1 | sloped top-10 |", "|---|---|---|---|---|"]
        for name, m in unseen.items():
            lines.append(f"| {name} | " + " | ".join(f"{m['unseen'][k]:.3f}" for k in METRICS) + " |")
    others = [k for k in next(iter(results["methods"].values())) if k.endswith(("_hit", "_error"))]
    if others:
        lines += ["", "The space's other parameters: rate of inferring the true choice (categorical), and the mean "
                  "absolute error as a fraction of the parameter's range (continuous; uniform guessing: 1/3):", "",
                  "| method | " + " | ".join(k.replace("_hit", " hit").replace("_error", " error") for k in others)
                  + " |", "|---|" + "---|" * len(others)]
        for name, m in results["methods"].items():
            lines.append(f"| {name} | " + " | ".join(f"{m[k]:.3f}" if k in m else "-" for k in others) + " |")
    return "\n".join(lines) + "\n"


def with_interval(metrics: dict, key: str) -> str:
    """``metrics[key]`` with its 95% interval when ``metrics`` has one: ``0.811 [0.760, 0.860]``."""
    low_high = metrics.get("intervals", {}).get(key)
    return f"{metrics[key]:.3f}" + (f" [{low_high[0]:.3f}, {low_high[1]:.3f}]" if low_high else "")


def write_results(out: Path, results: dict) -> None:
    """Write ``results.json`` and ``results.md`` into the folder ``out``."""
    write_text_atomic(out / "results.json", json.dumps(results, indent=2) + "\n")
    write_text_atomic(out / "results.md", results_markdown(results))


def render_targets(experiment: str, n: int, tiles: int, seed: int, preset: str, root: Path,
                   tile_px: int = 384, pixel_size_m: float = 0.3, bars: Bars | None = None,
                   space: str = "rooftops-v1", heldout: str = FIRST_HELDOUT) -> tuple[list[Job], Path]:
    """Render (or reuse) the target groups of an experiment in design space ``space`` (E2's roofs from
    the held-out set ``heldout``); returns the jobs and their tile folder."""
    from ..render.jobs import RenderSettings
    from ..render.loop import render_jobs
    from ..sim.quality import get_preset
    from ..sim.textures import ensure_default_bank, ensure_heldout_bank

    space_name, space = space, DesignSpace.load(space)
    bank, held = ensure_default_bank(), ensure_heldout_bank(name=heldout)
    jobs = target_jobs(experiment, space, held, n, seed)
    name = f"{experiment}-v{TARGETS_VERSION}-n{n}-t{tiles}-s{seed}-{preset}-{tile_px}px-{pixel_size_m}m"
    if space_name != "rooftops-v1":  # the default space's targets keep the folders they had
        name += f"-{space.name}"
    if experiment == "e2" and heldout != FIRST_HELDOUT:  # as do those of the first held-out set
        name += f"-{heldout}"
    folder = Path(root) / "targets" / name
    settings = RenderSettings(space=space, banks=[bank, held], preset=get_preset(preset), out_dir=folder,
                              n_tiles=tiles, tile_px=tile_px, pixel_size_m=pixel_size_m)
    render_jobs(jobs, settings, bars(f"render {experiment} targets (seed {seed})", n * tiles) if bars else None)
    return jobs, folder


def render_split_targets(split: Split, n: int, tiles: int, preset: str, root: Path, tile_px: int = 384,
                         pixel_size_m: float = 0.3, bars: Bars | None = None,
                         space: str = "rooftops-v1") -> tuple[list[Job], list[Path]]:
    """``render_targets`` for each seed of ``split``, ``n`` groups each: the jobs, seed after seed, and
    each job's tile folder. MetaSimError when ``n`` groups per seed would share cities between seeds."""
    split.check(n)
    jobs, folders = [], []
    for seed in split.seeds:
        more, folder = render_targets(split.experiment, n, tiles, seed, preset, root, tile_px, pixel_size_m, bars,
                                      space, split.heldout or FIRST_HELDOUT)
        jobs += more
        folders += [folder] * len(more)
    return jobs, folders


@dataclass(frozen=True)
class EvalSettings(SearchOptions):
    """How `meta-sim eval` scores: the neural-adjoint search settings (``SearchOptions``; ``S`` also
    for the exhaustive vote), target groups (per target seed) and tiles per group, whether to run MS2
    and the sbi baseline, the seed of the searches and, without a ``split``, of the targets (E2 then
    uses ``heldout-v1``), the split whose target seeds and held-out set to use instead, the targets'
    render preset, and the rows of ``sheet.png``."""

    targets: int = 20
    tiles: int = 9  # per target group, as in the paper (and `meta-sim infer`'s default group size)
    ms2: bool = True  # run the MS2 baseline (needs the training set's per-tile features)
    sbi: bool = True  # run the sbi baseline in a discrete space (trains its classifier once per model)
    seed: int = 1
    split: Split | None = None
    preset: str | None = None  # default: the training set's render preset
    sheet_rows: int = 6

    def check(self, method: str = "auto") -> None:
        """MetaSimError for settings the evaluation would refuse, before anything is rendered."""
        super().check(method)
        for name, value in (("--targets", self.targets), ("--target-tiles", self.tiles)):
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise MetaSimError(f"{name} must be at least 1, not {value!r}")
        if self.split is not None:
            self.split.check(self.targets)
        if self.sbi:
            from ..core.extras import require

            require("sbi", "the sbi baseline (--no-sbi leaves it out)")

    def target_split(self, experiment: str) -> Split:
        """The targets of ``experiment``: the split, else the one seed ``seed`` with ``heldout-v1``."""
        if self.split is None:
            return single_seed(experiment, self.seed)
        if self.split.experiment != experiment:
            raise MetaSimError(f"the {self.split.name} split given is {self.split.experiment.upper()}'s, "
                               f"not {experiment.upper()}'s")
        return self.split


@dataclass
class EvalContext:
    """Everything the methods of one experiment are scored with."""

    experiment: str
    models: object  # workflow.Models
    nams: object  # nams.Checkpoint
    dr: object
    jobs: list
    folders: list  # each job's tile folder (one per target seed)
    tiles: int
    features: object  # (targets, F) tensor: each group's tiles x views averaged
    tile_features: object  # (targets, tiles, F) tensor: each tile's views averaged
    feature_seconds: float
    ranks: dict
    pool: object = None  # dataset.TileFeatures of the training set: MS2's pre-rendered simulations
    training_designs: list = ()  # the training set's designs: E1 also scores the targets it lacks
    split: Split | None = None  # where the targets come from
    sbi: object = None  # nams.Checkpoint of the sbi baseline's classifier (a discrete space, when asked for)

    def subset(self, indices) -> EvalContext:
        """The same context on the target groups ``indices`` only."""
        indices = list(indices)
        return replace(self, jobs=[self.jobs[i] for i in indices], folders=[self.folders[i] for i in indices],
                       features=self.features[indices], tile_features=self.tile_features[indices])


@dataclass
class Methods:
    """The trained models every method needs: NAMS and DR checkpoints, the feature extractor, (for
    MS2) the training set's per-tile features, and (for the sbi baseline) its checkpoint."""

    models: object  # workflow.Models
    nams: object  # nams.Checkpoint
    dr: object
    extractor: object
    pool: object = None
    sbi: object = None


def load_methods(dataset, models_settings, root: Path, ms2: bool = True, bars: Bars | None = None,
                 sbi: bool = False) -> Methods:
    """Build or reuse the training set and models under ``root``, with ``ms2`` the MS2 pool, and with
    ``sbi`` the sbi baseline when the space is discrete (its seconds join ``models.seconds``)."""
    from ..nams import load_checkpoint
    from ..pipeline.roofcolour import checkpoint_extractor
    from ..pipeline.workflow import ensure_models, ensure_nre

    models = ensure_models(dataset, models_settings, root, bars)
    nams, dr = load_checkpoint(models.nams_path, "nams"), load_checkpoint(models.dr_path, "dr")
    sbi_checkpoint = None
    if sbi and discrete(nams.space):
        path, seconds = ensure_nre(models, dataset, models_settings, bars)
        models.seconds.update(seconds)
        sbi_checkpoint = load_checkpoint(path, "sbi_nre")
    extractor = checkpoint_extractor(nams, Path(models_settings.weights) if models_settings.weights else None)
    pool = None
    if ms2:
        from ..pipeline.dataset import build_tile_features
        from ..pipeline.workflow import dataset_dir

        pool = build_tile_features(dataset_dir(dataset, root), dataset, extractor, models_settings.views,
                                   bars("MS2 pool: training tile features", dataset.designs) if bars else None)
    return Methods(models, nams, dr, extractor, pool, sbi_checkpoint)


def group_features(groups: list[list[np.ndarray]], extractor, views: int, label: str,
                   bars: Bars | None = None) -> tuple[object, list]:
    """Each group's features (the mean over its tiles x views) and each tile's (views averaged)."""
    import torch

    from ..pipeline.features import features_for_groups

    # Every tile x view weighs the same in a group's mean, so the mean of the tiles' features is the group's.
    singles = [[tile] for group in groups for tile in group]
    feats = features_for_groups(singles, extractor, views, progress=bars(label, len(singles)) if bars else None)
    per_group = list(torch.split(feats, [len(g) for g in groups]))
    return torch.stack([f.mean(dim=0) for f in per_group]), per_group


# Target groups read at a time: 32 groups of 9 tiles are 288 tiles of 384 x 384 (about 0.5 GB as float32), where a
# split's 2,700 at once held gigabytes and, one split after another, filled 24 GB. A multiple of the features'
# batch of 32 tiles, so the batches (and the features) are those of reading them all at once.
TARGET_GROUPS_READ = 32


def _target_tile_features(jobs, folders, tiles: int, extractor, views: int, label: str,
                          bars: Bars | None = None):
    """(groups, tiles, dim) each target group's first ``tiles`` tiles' features (views averaged), read
    ``TARGET_GROUPS_READ`` groups at a time."""
    import torch

    from ..pipeline.dataset import job_tiles
    from ..pipeline.features import features_for_groups
    from ..sim.imageio import read_image

    progress = bars(label, len(jobs) * tiles) if bars else None
    out = []
    for start in range(0, len(jobs), TARGET_GROUPS_READ):
        part = list(zip(jobs[start:start + TARGET_GROUPS_READ], folders[start:start + TARGET_GROUPS_READ]))
        singles = [[read_image(p)] for job, folder in part for p in job_tiles(folder, job.name, tiles)]
        feats = features_for_groups(singles, extractor, views, progress=progress)
        out.append(feats.reshape(len(part), tiles, -1))
    return torch.cat(out)


def target_features_path(root: Path, extractor_id: str, views: int, folders: list, tiles: int) -> Path:
    """Where the features of the first ``tiles`` tiles of each target folder by ``extractor_id`` over
    ``views`` views are kept: the extractor's id names its roof finder's weights, so a retrained finder
    never reads another's."""
    key = json.dumps([extractor_id, views, tiles, [Path(f).name for f in folders]])
    return Path(root) / "targets" / "features" / f"{hashlib.sha256(key.encode()).hexdigest()[:16]}.pt"


def stored_target_features(root: Path, extractor_id: str, views: int, folders: list, tiles: int) -> dict | None:
    """What ``store_target_features`` kept for these targets ("features" (groups, tiles, dim), "seconds"),
    or None: none kept, or a file that is unreadable or does not fit (computed again, never trusted)."""
    import torch

    try:
        stored = torch.load(target_features_path(root, extractor_id, views, folders, tiles), weights_only=True)
    except (OSError, RuntimeError, ValueError, EOFError, pickle.UnpicklingError):
        return None
    features = stored.get("features") if isinstance(stored, dict) else None
    ok = (stored is not None and stored.get("extractor") == extractor_id and isinstance(features, torch.Tensor)
          and features.ndim == 3 and tuple(features.shape[:2]) == (len(folders), tiles)
          and bool(torch.isfinite(features).all()) and isinstance(stored.get("seconds"), float))
    return stored if ok else None


def store_target_features(root: Path, extractor_id: str, views: int, folders: list, tiles: int, features,
                          seconds: float) -> dict:
    """Keep the target features (groups, tiles, dim) and the seconds they took (for the cost figures), so
    that the benches and evaluations after the first, interrupted or not, read them instead of the tiles."""
    import torch

    from ..core.fileio import atomic_path

    stored = {"extractor": extractor_id, "features": features.contiguous(), "seconds": float(seconds)}
    with atomic_path(target_features_path(root, extractor_id, views, folders, tiles)) as tmp:
        torch.save(stored, tmp)
    return stored


def prepare_eval(experiment: str, dataset, models_settings, settings: EvalSettings, root: Path,
                 bars: Bars | None = None, test_tiles: int = 0) -> EvalContext:
    """Build or reuse the training set and models; render the targets and compute their features.

    ``experiment`` is "e1" or "e2"; ``dataset`` a DatasetConfig and ``models_settings`` a
    ModelSettings (``pipeline.workflow``); training sets, models and targets are cached under
    ``root``. The targets are ``settings.targets`` groups of each seed of
    ``settings.target_split(experiment)``. With ``settings.ms2`` the training set's per-tile
    features are computed too (MS2's pool). ``test_tiles`` more tiles of each target are rendered
    after the ``settings.tiles`` the methods see (labelled test tiles for a task model; the features
    never use them). Returns the EvalContext every method is scored with. Raises MetaSimError for an
    unknown experiment or preset, a split of another experiment, a missing ``bpy`` while something
    is left to render, or what ``ensure_models`` raises.
    """
    import time

    from ..render.jobs import sample_designs
    from ..sim.textures import ensure_default_bank, ensure_heldout_bank

    split = settings.target_split(experiment)
    split.check(settings.targets)
    methods = load_methods(dataset, models_settings, root, settings.ms2, bars, settings.sbi)
    tiles = settings.tiles
    jobs, folders = render_split_targets(split, settings.targets, tiles + test_tiles,
                                         settings.preset or dataset.preset, root, dataset.tile_px,
                                         dataset.pixel_size_m, bars, dataset.space)
    views = models_settings.views
    stored = stored_target_features(root, methods.extractor.id, views, folders, tiles)
    if stored is None:
        started = time.perf_counter()
        per_group = _target_tile_features(jobs, folders, tiles, methods.extractor, views,
                                          f"{experiment} target features", bars)
        stored = store_target_features(root, methods.extractor.id, views, folders, tiles, per_group,
                                       time.perf_counter() - started)
    per_tile = stored["features"]
    features = per_tile.mean(dim=1)  # every tile x view weighs the same in a group's mean
    feature_seconds = stored["seconds"] / len(jobs)
    ranks = rankings(experiment, ensure_default_bank(), ensure_heldout_bank(name=split.heldout or FIRST_HELDOUT))
    training_designs = sample_designs(methods.nams.space, dataset.designs, dataset.seed) if experiment == "e1" else []
    return EvalContext(experiment, methods.models, methods.nams, methods.dr, jobs, folders, tiles, features,
                       per_tile, feature_seconds, ranks, methods.pool, training_designs, split,
                       methods.sbi)


def method_runs(ctx: EvalContext, seed: int, adjoint_settings: dict, S: int = 50, found: dict | None = None,
                bars: Bars | None = None) -> dict:
    """Method name -> a function returning one design per target (searches batched over targets). NAMS's
    searches also keep their ``SearchResult`` lists in ``found`` (by method name) when it is given; the
    neural-adjoint search shows its steps on ``bars`` (a "bars" in ``adjoint_settings`` wins)."""
    import torch

    from ..nams import adjoint_search, dr_predict, exhaustive_search, ms2_search, uniform_predict
    from ..nams.nre import nre_predict
    from ..pipeline.roofcolour import search_colour

    space, feats, n = ctx.nams.space, ctx.features, len(ctx.jobs)
    generator = torch.Generator().manual_seed(seed)
    norm = ctx.nams.feature_norm
    normed = norm.apply(feats)
    runs = {
        "uniform": lambda: uniform_predict(space, n, generator),
        "dr": lambda: [r.design for r in dr_predict(ctx.dr.model, ctx.dr.feature_norm.apply(feats), space)],
    }
    if ctx.pool is not None and discrete(space):
        # MS2 compares distributions of single tiles, in the space NAMS searches in (see nams/ms2.py).
        pool = norm.apply(ctx.pool.features.reshape(-1, ctx.pool.features.shape[-1]))
        pool_designs = ctx.pool.encoded.repeat_interleave(ctx.pool.features.shape[1], dim=0)
        runs["ms2"] = lambda: [r.design for r in ms2_search(
            pool, pool_designs, [norm.apply(t) for t in ctx.tile_features], space, generator=generator)]
    if ctx.sbi is not None:
        runs["sbi_nre"] = lambda: [r.design for r in nre_predict(ctx.sbi.model, ctx.sbi.feature_norm.apply(feats),
                                                                 space)]
    colour = search_colour(ctx.nams)
    found = {} if found is None else found

    def kept(method: str, results: list) -> list[dict]:
        found[method] = results
        return [r.design for r in results]

    runs["nams_adjoint"] = lambda: kept("nams_adjoint", adjoint_search(
        ctx.nams.model, normed, space, generator=generator, colour=colour, **{"bars": bars, **adjoint_settings}))
    if discrete(space):  # the exhaustive search enumerates every design
        runs["nams_exhaustive"] = lambda: kept("nams_exhaustive", exhaustive_search(ctx.nams.model, normed, space,
                                                                                    S=S, colour=colour))
    return runs


# The neural-adjoint setting (starts M, steps) the benchmarks use in spaces with continuous parameters, where
# NAMS is factorised over many parameters: each step costs several times the default space's, and the
# paper's 1,000 starts x 200 steps would take minutes per target group (bench-nams's (64, 100) row, on E1's
# validation split: docs/design.md, "Splits").
CONTINUOUS_SEARCH = {"M": 64, "iterations": 100}


def discrete(space: DesignSpace) -> bool:
    """Whether every parameter is categorical (what the exhaustive search and MS2 need)."""
    return not any(isinstance(p, Continuous) for p in space.parameters)


def best_nams_name(methods) -> str:
    """NAMS's best method among the names ``methods``: the exhaustive search where it ran (a discrete
    space), else the neural-adjoint."""
    return "nams_exhaustive" if "nams_exhaustive" in methods else "nams_adjoint"


def best_nams(predictions: dict) -> list:
    """NAMS's designs (``best_nams_name``'s) of method name -> designs."""
    return predictions[best_nams_name(predictions)]


def score_other_model(ctx: EvalContext, checkpoint, seed: int, S: int = 50) -> dict:
    """Score another NAMS checkpoint with the exhaustive search on ``ctx``'s targets and features.

    The checkpoint must use the same extractor as ``ctx``'s model or its
    leading part (a model trained without the roof-colour histograms): the
    features are cut to the dimensions it was trained on.
    """
    norm = checkpoint.feature_norm
    dim = norm.mean.shape[0] + norm.hist_dim
    if dim > ctx.features.shape[-1]:
        raise MetaSimError(f"the checkpoint was trained on {dim} feature dimensions; these targets have "
                           f"{ctx.features.shape[-1]}")
    other = replace(ctx, nams=checkpoint, features=ctx.features[:, :dim],
                    tile_features=ctx.tile_features[..., :dim], pool=None, sbi=None)
    metrics, _ = score_method(other, method_runs(other, seed, {}, S)["nams_exhaustive"])
    return {**metrics, "targets": len(ctx.jobs)}


def score_method(ctx: EvalContext, run) -> tuple[dict, list[dict]]:
    """Mean top-1/top-10 rates and seconds per target of one method, and ``intervals``: each rate's
    95% interval from resampling the target groups, in E2 the held-out textures (``bootstrap_intervals``,
    ``texture_clusters``).

    In E1 also ``unseen``: the rates over the targets whose design is not one
    of the training set's (``unseen_targets`` of them). A method that only
    recalls the designs it was trained on scores well overall and poorly there.
    """
    import time

    started = time.perf_counter()
    designs = run()
    seconds = (time.perf_counter() - started) / len(ctx.jobs)
    rows = [score(p, job.design, ctx.ranks, ctx.nams.space) for p, job in zip(designs, ctx.jobs)]
    metrics = {**mean_scores(rows), "seconds_per_target": seconds,
               "intervals": bootstrap_intervals(rows, clusters=texture_clusters(ctx.experiment,
                                                                                 [j.design for j in ctx.jobs]))}
    if ctx.training_designs:
        unseen = unseen_rows(rows, ctx.jobs, ctx.training_designs)
        metrics.update(unseen=mean_scores(unseen), unseen_targets=len(unseen))
    return metrics, designs


def run_eval(experiment: str, out: Path, dataset, models_settings, settings: EvalSettings = EvalSettings(),
             root: Path | None = None, bars: Bars | None = None) -> dict:
    """Build or reuse the training set and models, render targets, score every method.

    Arguments as for ``prepare_eval`` (``root`` defaults to the cache). Scores uniform, DR, MS2 (with
    ``settings.ms2``), the sbi baseline (with ``settings.sbi``, in a discrete space; its row also holds
    ``train_seconds``, its training time when it was trained) and NAMS with the adjoint and the
    exhaustive search, and writes into ``out``:
    ``results.json`` and ``results.md``, copies of ``nams.pt`` and ``dr.pt``, ``sheet.png``
    (the first ``settings.sheet_rows`` targets beside the same city rendered with NAMS's inferred
    design), and in E2 where NAMS's top-10 misses come from (``breakdown.write_breakdown``:
    ``breakdown.json``, ``breakdown.md``, ``breakdown.png``). Returns the results dict. Raises
    MetaSimError as ``prepare_eval`` does, or when the search settings are invalid.
    """
    import shutil

    from ..core.cache import cache_root
    from ..render.jobs import RenderSettings
    from ..sim.quality import get_preset
    from ..sim.textures import ensure_default_bank, ensure_heldout_bank
    from .breakdown import write_breakdown

    root = Path(root or cache_root())
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    ctx = prepare_eval(experiment, dataset, models_settings, settings, root, bars)
    adjoint = settings.search_options()
    methods, predictions = {}, {}
    for name, run in method_runs(ctx, settings.seed, adjoint, settings.S, bars=bars).items():
        methods[name], predictions[name] = score_method(ctx, run)
    if "sbi_nre" in methods:
        methods["sbi_nre"]["train_seconds"] = ctx.sbi.extra["seconds"]
    results = {"experiment": experiment, "split": ctx.split.to_dict(), "targets": len(ctx.jobs),
               "tiles_per_target": ctx.tiles,
               "feature_seconds_per_target": ctx.feature_seconds, "methods": methods,
               "adjoint": adjoint, "training": {"designs": dataset.designs, "tiles": dataset.tiles,
                                                "preset": dataset.preset, "seconds": ctx.models.seconds},
               "model_id": ctx.nams.model_id, "architecture": ctx.nams.model.config.architecture,
               "targets_detail": [{"name": j.name, "truth": j.design,
                                   "predicted": {m: predictions[m][i] for m in predictions}}
                                  for i, j in enumerate(ctx.jobs)]}
    write_results(out, results)
    shutil.copy2(ctx.models.nams_path, out / "nams.pt")
    shutil.copy2(ctx.models.dr_path, out / "dr.pt")
    banks = _banks()
    if experiment == "e2":
        heldout = ensure_heldout_bank(name=ctx.split.heldout or FIRST_HELDOUT)
        other_roof = rankings("e2", ensure_default_bank(), heldout, across=True)
        write_breakdown(out, results, best_nams_name(predictions), ctx.ranks, other_roof,
                        lambda texture_id: texture_swatch(banks, texture_id))
    comparison_sheet(out / "sheet.png", ctx.jobs[:settings.sheet_rows], ctx.folders, best_nams(predictions),
                     RenderSettings(space=ctx.nams.space, banks=banks,
                                    preset=get_preset(settings.preset or dataset.preset),
                                    out_dir=root / "targets" / "inferred", n_tiles=ctx.tiles,
                                    tile_px=dataset.tile_px, pixel_size_m=dataset.pixel_size_m))
    return results


def _banks() -> list:
    from ..sim.textures import ensure_default_bank, ensure_heldout_banks

    return [ensure_default_bank(), *ensure_heldout_banks()]


def texture_swatch(banks: list, texture_id: str) -> np.ndarray:
    """The uint8 RGB image of ``texture_id`` from the first of ``banks`` that has it."""
    return next(b for b in banks if b.contains(texture_id)).load_image(texture_id)


def comparison_sheet(path: Path, jobs: list[Job], target_folders: list[Path], predicted: list[dict],
                     settings) -> None:
    """Each target's first tile beside the same city rendered with the inferred design, and the textures."""
    from ..pipeline.dataset import job_tiles
    from ..render.loop import render_jobs
    from ..sim.imageio import read_image
    from ..sim.textures.pngio import write_png
    from ..sim.textures.sheet import render_sheet

    space, banks, folder, tiles = settings.space, settings.banks, settings.out_dir, settings.n_tiles
    # Named by city too: the jobs of two target seeds share names, and the inferred renders one folder.
    inferred = [Job(design, job.city_seed, f"{job.name}-{job.city_seed}-inferred")
                for job, design in zip(jobs, predicted)]
    render_jobs(inferred, settings)

    def srgb8(path):
        return np.floor(read_image(path) * 255 + 0.5).astype(np.uint8)

    rows = []
    for job, guess, target_folder in zip(jobs, inferred, target_folders):
        row = [("TARGET", srgb8(job_tiles(target_folder, job.name, tiles)[0])),
               ("INFERRED", srgb8(job_tiles(folder, guess.name, tiles)[0]))]
        for param in [n for n in space.names if n in KIND_OF]:
            kind = KIND_OF[param][0].upper()
            row += [(f"{kind} TRUE", texture_swatch(banks, job.design[param])),
                    (f"{kind} NAMS", texture_swatch(banks, guess.design[param]))]
        rows.append(row)
    write_png(path, render_sheet(rows, 160, len(rows[0])))

"""What each knob that costs time buys in accuracy (`meta-sim bench tradeoff`, `make bench-tradeoff`).

Every point is measured on both of E1's splits (bank designs in cities never trained on; ``splits.py``):
the validation split, on which the profiles and the defaults are chosen, and the test split, which only
reports. Per split: top-1 and top-10 for flat and sloped roofs; and two costs, the same for both:

* ``seconds_per_group``: inference, per target group: features of its tiles
  (x views) plus the search, timed over the groups of both splits;
* ``one_off_seconds``: before any inference, once: rendering the training
  set (tiles x the render preset's seconds per tile from ``make
  bench-render``), learning its roof segmenter, its features and training NAMS.

Knobs, each varied alone from the default (``DatasetConfig()``, "fast"
renders, target groups of 9 tiles, exhaustive search):

* ``tiles per target group``: 1, 2, 4, 9;
* ``search``, ``architecture``, ``roof colour``, ``roof finder``, ``roof weight power``: the exhaustive
  search, DR, MS2 and the sbi baseline, taken from ``make bench-nams`` (``benchmarks/nams.json``), the
  neural-adjoint search at several (M, iterations), the paper's (1000, 200) first, from ``make
  bench-adjoint`` (``benchmarks/adjoint.json``), and the other NAMS architectures and the roof-colour
  ablations, from ``make bench-ablations`` (``benchmarks/ablations.json``); all on the same model and E1
  targets, split for split, with this bench's feature time per tile added;
* ``views``: the default extractor is invariant to the 8 dihedral views, so
  8 views give the features of 1 at the cost of 1 (checked, not assumed:
  the bench compares the vectors); a backbone pays 8x;
* ``training set``: designs x tiles per design;
* ``roof finder steps``, ``training epochs``: the roof segmenter learnt in fewer steps and NAMS trained for
  fewer epochs, from ``make bench-ablations``, their one-off cost with the variant's training times;
* ``render preset``: training set and targets both rendered with it.

``PROFILES`` names three recommended combinations -- fast, balanced and
paper-faithful -- and the bench measures each end to end.

The whole study takes longer than a working session on 2 CPUs (the balanced preset's renders and the paper
profile's 15,300 tiles), so it can be measured in parts: each run measures the default model's points and the
training sets, presets and profiles it is given, and ``merge_results`` adds them to an earlier run's on the
same targets. Every measured point names the weights of its model (``weights_id``): a training set trained
again in a later part must give the same weights, or the merge refuses.
"""

from __future__ import annotations

import datetime
import hashlib
import io
import json
import math
import re
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

from ..core.errors import MetaSimError
from ..core.extras import require
from ..core.fileio import write_bytes_atomic
from ..core.progress import Bars
from ..pipeline.dataset import DatasetConfig
from ..pipeline.profiles import PROFILES
from .splits import SPLIT_NAMES, get_split, spread

GROUP_TILES = (1, 2, 4, 9)
TRAINING_SETS = ((150, 4), (300, 2), (300, 4), (600, 2), (600, 4), (1700, 9))
RENDER_PRESETS = ("fast", "balanced")
METRICS = ("flat_top1", "flat_top10", "sloped_top1", "sloped_top10")
# Validation: every choice (the profiles and the defaults) is made on it; test: only reported.
SPLITS = tuple(get_split("e1", name) for name in SPLIT_NAMES)
REPORTED = "test"
# Plotted against the one-off cost; the others per group.
ONE_OFF_KNOBS = ("training set", "render preset", "roof finder steps", "training epochs")
# The table's and the plot's order of the knobs (a merged result's points are put back in it).
KNOB_ORDER = ("tiles per target group", "search", "architecture", "roof colour", "roof finder",
              "roof weight power", "roof finder steps", "training epochs", "training set", "render preset", "profile")


def weights_id(model) -> str:
    """The first 12 hex digits of the sha256 of a model's tensors (names, shapes, dtypes and values): equal for
    two trainings exactly when they learnt the same weights (a checkpoint's ``model_id`` also covers its
    training time, which differs every run)."""
    import torch

    digest = hashlib.sha256()
    for name, tensor in sorted(model.state_dict().items()):
        tensor = tensor.detach().cpu().contiguous()
        digest.update(f"{name}:{tuple(tensor.shape)}:{tensor.dtype};".encode())
        digest.update(tensor.reshape(-1).view(torch.uint8).numpy().tobytes())
    return digest.hexdigest()[:12]


@dataclass
class Point:
    """One row of the trade-off: a knob's setting, its E1 metrics and number of targets per split (split
    name -> ...; a split a source lacks is absent), inference seconds per target group, one-off seconds, and
    anything else worth keeping in the JSON."""

    knob: str
    setting: str
    metrics: dict
    seconds_per_group: float
    one_off_seconds: float
    targets: dict
    detail: dict = field(default_factory=dict)


def _render_seconds_per_tile(preset: str, render_bench: Path) -> float:
    try:
        return float(json.loads(render_bench.read_text())["presets"][preset]["seconds_per_tile"])
    except (OSError, ValueError, KeyError) as exc:
        raise MetaSimError(f"no '{preset}' figure in {render_bench} ({exc}); run `make bench-render` first") from None


class _Experiment:
    """One training set and model, and per split its E1 targets rendered with its preset and their
    per-tile features."""

    def __init__(self, dataset: DatasetConfig, views: int, targets: int, root: Path,
                 render_bench: Path, bars: Bars | None = None):
        import torch

        from ..nams import load_checkpoint
        from ..pipeline.dataset import job_tiles
        from ..pipeline.features import features_for_groups
        from ..pipeline.roofcolour import checkpoint_extractor, roof_finder_seconds, search_colour
        from ..pipeline.workflow import ModelSettings, dataset_dir, ensure_models
        from ..render.jobs import sample_designs
        from ..sim.design import DesignSpace
        from ..sim.imageio import read_image
        from ..sim.textures import ensure_default_bank, ensure_heldout_bank
        from .evaluate import rankings, render_split_targets, store_target_features, stored_target_features

        self.dataset, self.views = dataset, views
        # E1 targets whose design the training set lacks are also scored alone ("unseen").
        self.training_designs = sample_designs(DesignSpace.load(dataset.space), dataset.designs, dataset.seed)
        models = ensure_models(dataset, ModelSettings(views=views), root, bars)
        self.nams = load_checkpoint(models.nams_path, "nams")
        self.weights = weights_id(self.nams.model)
        self.colour = search_colour(self.nams)
        self.per_seed = targets
        extractor = checkpoint_extractor(self.nams)
        tiles = max(GROUP_TILES)
        self.targets, seconds, featurised = {}, 0.0, 0
        for split in SPLITS:
            jobs, folders = render_split_targets(split, targets, tiles, dataset.preset, root, dataset.tile_px,
                                                 dataset.pixel_size_m, bars)
            stored = stored_target_features(root, extractor.id, 1, folders, tiles)
            if stored is None:
                features, split_seconds = [], 0.0
                for start in range(0, len(jobs), targets):  # a seed's tiles at a time: a split's would fill memory
                    groups = [[read_image(p)] for job, folder in zip(jobs[start:start + targets],
                                                                     folders[start:start + targets])
                              for p in job_tiles(folder, job.name, tiles)]
                    started = time.perf_counter()
                    features.append(features_for_groups(groups, extractor, 1))
                    split_seconds += time.perf_counter() - started
                stored = store_target_features(root, extractor.id, 1, folders, tiles,
                                               torch.cat(features).reshape(len(jobs), tiles, -1), split_seconds)
            seconds, featurised = seconds + stored["seconds"], featurised + len(jobs) * tiles
            self.targets[split.name] = (split, jobs, stored["features"])
        self.feature_seconds_per_tile = seconds / featurised
        self.ranks = rankings("e1", ensure_default_bank(), ensure_heldout_bank())
        feature_total = self.feature_seconds_per_tile * dataset.designs * dataset.tiles
        train = float(self.nams.extra.get("seconds", 0.0))
        settings = ModelSettings(views=views)
        self.finder_seconds = roof_finder_seconds(dataset_dir(dataset, root), settings.roof_finder,
                                                  settings.seed) or 0.0
        self.one_off = (_render_seconds_per_tile(dataset.preset, render_bench) * dataset.designs * dataset.tiles
                        + feature_total + self.finder_seconds + train)
        self.train_seconds = train

    def run(self, knob: str, setting: str, group_tiles: int = 9, method: str = "exhaustive",
            adjoint: dict | None = None, targets: int | None = None) -> Point:
        """One point: every split's targets (``targets`` groups of each, spread over its seeds: the
        adjoint's few) searched with ``method``; the search time is over the groups of all splits."""
        import torch

        from ..nams import adjoint_search, exhaustive_search
        from .evaluate import mean_scores, score, unseen_rows

        metrics, counts, search_seconds = {}, {}, 0.0
        for name, (split, all_jobs, tile_features) in self.targets.items():
            chosen = spread(len(split.seeds), self.per_seed, targets or len(all_jobs))
            jobs = [all_jobs[i] for i in chosen]
            normed = self.nams.feature_norm.apply(tile_features[chosen, :group_tiles].mean(dim=1))
            started = time.perf_counter()
            if method == "exhaustive":
                results = exhaustive_search(self.nams.model, normed, self.nams.space, colour=self.colour)
            else:  # the searches' random starts seeded as bench-nams's: by the split's first target seed
                results = adjoint_search(self.nams.model, normed, self.nams.space, colour=self.colour,
                                         generator=torch.Generator().manual_seed(split.seeds[0]),
                                         **{"S": min(50, adjoint["M"]), **adjoint})
            search_seconds += time.perf_counter() - started
            rows = [score(r.design, job.design, self.ranks) for r, job in zip(results, jobs)]
            unseen = unseen_rows(rows, jobs, self.training_designs)
            metrics[name] = {**mean_scores(rows), "unseen_targets": len(unseen),
                             **{f"unseen_{k}": v for k, v in mean_scores(unseen).items()}}
            counts[name] = len(jobs)
        search_seconds /= sum(counts.values())
        return Point(knob, setting, metrics,
                     round(search_seconds + group_tiles * self.feature_seconds_per_tile, 5),
                     round(self.one_off, 1), counts,
                     {"search_seconds_per_group": round(search_seconds, 5),
                      "feature_seconds_per_tile": round(self.feature_seconds_per_tile, 5),
                      "train_seconds": round(self.train_seconds, 1),
                      "dataset": asdict(self.dataset), "views": self.views, "weights": self.weights,
                      "measured_on": datetime.datetime.now(datetime.timezone.utc).date().isoformat()})


def _views_check() -> dict:
    """The default extractor's features of 1 and 8 views of one tile, every view computed, and the cost."""
    import numpy as np

    from ..pipeline.features import ColourTexture, features_for_groups, time_extractor

    extractor = ColourTexture()
    tile = np.random.default_rng(0).random((384, 384, 3), dtype=np.float32)
    one, eight = (features_for_groups([[tile]], _AllViews(extractor), n)[0] for n in (1, 8))
    return {"max_abs_difference_1_vs_8_views": float((one - eight).abs().max()),
            "seconds_per_9_tiles_1_view": round(time_extractor(extractor, 384, 9, 1), 4),
            "seconds_per_9_tiles_8_views_if_not_invariant": round(time_extractor(_AllViews(extractor), 384, 9, 8), 4)}


class _AllViews:
    """The same extractor, without the claim of invariance: every view is computed."""

    dihedral_invariant = False

    def __init__(self, inner):
        self.inner, self.id, self.dim = inner, inner.id, inner.dim

    def __call__(self, batch):
        return self.inner(batch)


def read_nams_rows(nams_bench: Path, per_seed: int, make: str = "bench-nams") -> dict:
    """The E1 rows of ``make bench-nams`` (or of ``make MAKE``, on the same targets) per split (split name ->
    method name -> row), checked to be on this bench's targets: ``per_seed`` groups of 9 tiles per seed of
    each split. A split the file lacks is left out (its figures are missing, never another split's);
    MetaSimError without the validation split's, for a file from before the splits, or for other targets."""
    try:
        bench = json.loads(nams_bench.read_text())
    except (OSError, ValueError) as exc:
        raise MetaSimError(f"cannot read {nams_bench} ({exc}); run `make {make}` first") from None
    if "splits" not in bench:
        raise MetaSimError(f"{nams_bench} predates the validation and test splits (its E1 rows are target seed 1's "
                           f"alone): run `make {make}` again")
    if bench.get("tiles_per_target") != max(GROUP_TILES):
        raise MetaSimError(f"{nams_bench} was measured on groups of {bench.get('tiles_per_target')} tiles, "
                           f"not {max(GROUP_TILES)}: run `make {make}` again")
    rows = {}
    for split in SPLITS:
        part = bench["splits"].get(split.name)
        if part is None:
            continue
        try:
            rows[split.name], seeds = part["experiments"]["e1"], part["settings"]["e1"]["seeds"]
        except (KeyError, TypeError) as exc:
            raise MetaSimError(f"no E1 {split.name} rows in {nams_bench} ({exc}); run `make {make}` "
                               "again") from None
        if (seeds, bench.get("targets_per_seed")) != (list(split.seeds), per_seed):
            raise MetaSimError(f"{nams_bench} was measured on {bench.get('targets_per_seed')} target groups of "
                               f"{split.name} seeds {seeds}, not {per_seed} of {list(split.seeds)}: run "
                               f"`make {make}` again with as many --targets")
    if "validation" not in rows:
        raise MetaSimError(f"no E1 validation rows in {nams_bench}, on which the choices are made; run "
                           f"`make {make}` again")
    return rows


# bench-ablations's variants of the default model (rows nams_exhaustive_NAME), each a knob of its own.
_VARIANTS = {"no_roof_colour": ("roof colour", "none"), "no_score_cone": ("roof colour", "no score cone"),
             "colour_roof_finder": ("roof finder", "colour"),
             "roof_weight_power_1": ("roof weight power", "1")}
_TRAINING_VARIANTS = {"roof_finder_steps": "roof finder steps", "max_epochs": "training epochs"}
_TRAINING_ROW = re.compile(r"(roof_finder_steps|max_epochs)_(\d+)")  # a variant that only trains for less


def _nams_knob(name: str) -> tuple[str, str]:
    """The knob and setting of a bench-nams or bench-ablations row: a search method or setting, another
    architecture, or a variant of the roof colours."""
    from ..nams.model import ARCHITECTURES

    adjoint = re.fullmatch(r"nams_adjoint_M(\d+)_it(\d+)", name)
    if adjoint:
        return "search", f"adjoint M={adjoint[1]}, {adjoint[2]} it"
    if name == "nams_exhaustive":
        return "search", "exhaustive"
    variant = name.removeprefix("nams_exhaustive_")
    training = _TRAINING_ROW.fullmatch(variant)
    if training:
        return _TRAINING_VARIANTS[training[1]], training[2]
    if variant in _VARIANTS:
        return _VARIANTS[variant]
    if variant in ARCHITECTURES:
        return "architecture", variant
    return "search", name


def ablation_one_offs(ablations_bench: Path, base: _Experiment) -> dict:
    """Per bench-ablations row (``nams_exhaustive_NAME``) whose training cost differs from the default's: the
    default's one-off cost with NAMS's training and the roof segmenter's learning replaced by the variant's
    (the times bench-ablations kept; a variant without its own segmenter time learns the default's)."""
    bench = json.loads(Path(ablations_bench).read_text())
    train, finders = bench.get("train_seconds", {}), bench.get("roof_segmenter_seconds", {})
    out = {}
    for name in {*train, *finders}:
        if not _TRAINING_ROW.fullmatch(name):
            continue
        nams = train.get(name, base.train_seconds)
        finder = finders.get(name, base.finder_seconds)
        out[f"nams_exhaustive_{name}"] = base.one_off - base.train_seconds - base.finder_seconds + nams + finder
    return out


def _search_points(rows: dict, base: _Experiment, source: str = "bench-nams",
                   skip: tuple[str, ...] = ("uniform",), one_offs: dict | None = None) -> list[Point]:
    """E1 rows of ``source`` (``read_nams_rows``) as points but those named in ``skip``, every split's beside the
    others: search time (over the groups of all splits) plus 9 tiles' features of this bench; the one-off cost
    the default's, or the row's own in ``one_offs`` (name -> seconds)."""
    features = max(GROUP_TILES) * base.feature_seconds_per_tile
    points = []
    for name in rows["validation"]:
        if name in skip:
            continue
        per_split = {split: split_rows[name] for split, split_rows in rows.items() if name in split_rows}
        metrics = {split: {**{k: row[k] for k in METRICS},
                           **({"unseen_targets": row["unseen_targets"],
                               **{f"unseen_{k}": v for k, v in row["unseen"].items()}} if row.get("unseen") else {})}
                   for split, row in per_split.items()}
        targets = {split: int(row["targets"]) for split, row in per_split.items()}
        search = sum(row["seconds_per_target"] * targets[split] for split, row in per_split.items()) / sum(
            targets.values())
        one_off = (one_offs or {}).get(name, base.one_off)
        points.append(Point(*_nams_knob(name), metrics, round(search + features, 5), round(one_off, 1), targets,
                            {"search_seconds_per_group": round(search, 5), "from": f"{source} row {name}"}))
    return points


def bench_tradeoff(targets: int = 100, adjoint_targets: int = 20, root: Path | None = None,
                   render_bench: Path = Path("benchmarks/render.json"), nams_bench: Path = Path("benchmarks/nams.json"),
                   adjoint_bench: Path = Path("benchmarks/adjoint.json"),
                   ablations_bench: Path = Path("benchmarks/ablations.json"), presets=RENDER_PRESETS,
                   training_sets=TRAINING_SETS, profiles=tuple(PROFILES), bars: Bars | None = None) -> dict:
    """Measure every knob alone, then every profile end to end, on ``targets`` groups of each seed of E1's
    validation and test splits (the adjoint search on ``adjoint_targets`` of each split); returns a
    JSON-able dict. A training set met twice (the default is a setting of several knobs) is featurised once."""
    from ..core.cache import cache_root

    root = Path(root or cache_root())
    nams_rows = read_nams_rows(nams_bench, targets)  # before hours of work, not after
    adjoint_rows = read_nams_rows(adjoint_bench, targets, "bench-adjoint")
    ablation_rows = read_nams_rows(ablations_bench, targets, "bench-ablations")
    experiments: dict = {}

    def experiment(dataset: DatasetConfig, views: int = 8) -> _Experiment:
        if (dataset, views) not in experiments:
            experiments[dataset, views] = _Experiment(dataset, views, targets, root, render_bench, bars)
        return experiments[dataset, views]

    base = experiment(DatasetConfig())
    points = [base.run("tiles per target group", str(g), group_tiles=g) for g in GROUP_TILES]
    points += _search_points(nams_rows, base)
    # Rows bench-nams has too (its exhaustive search, its adjoint setting) are taken from it, on all its groups.
    points += _search_points(adjoint_rows, base, "bench-adjoint", skip=tuple(nams_rows["validation"]))
    points += _search_points(ablation_rows, base, "bench-ablations", skip=("nams_exhaustive",),
                             one_offs=ablation_one_offs(ablations_bench, base))
    points += [experiment(DatasetConfig(designs=d, tiles=t)).run("training set", f"{d} x {t}")
               for d, t in training_sets]
    points += [experiment(DatasetConfig(preset=preset)).run("render preset", preset) for preset in presets]
    for name in profiles:
        profile = PROFILES[name]
        n = adjoint_targets if profile.method == "adjoint" else None  # None: every target group
        points.append(experiment(profile.dataset, profile.views).run(
            "profile", name, profile.group_size, profile.method, profile.search_options(), targets=n))
    import torch

    return {"experiment": "e1", "splits": {s.name: s.to_dict() for s in SPLITS}, "reported": REPORTED,
            "targets_per_seed": targets, "adjoint_targets": adjoint_targets,
            "tiles_per_target_group_default": max(GROUP_TILES),
            "views": _views_check(), "points": [asdict(p) for p in points],
            "profiles": {name: {**asdict(PROFILES[name]), "dataset": asdict(PROFILES[name].dataset)}
                         for name in profiles},
            "machine": {"torch_threads": torch.get_num_threads()}}


def parse_training_sets(text: str | None) -> tuple[tuple[int, int], ...]:
    """``--training-sets``: "DESIGNSxTILES,..." (None: ``TRAINING_SETS``; "": none), each a positive whole
    number of designs and of tiles per design; MetaSimError naming a malformed one."""
    if text is None:
        return TRAINING_SETS
    sets = []
    for item in (part.strip() for part in text.split(",")):
        if not item:
            continue
        match = re.fullmatch(r"([1-9]\d{0,5})x([1-9]\d{0,2})", item)
        if match is None:
            raise MetaSimError(f"a training set is DESIGNSxTILES (say 600x2), not {item!r}")
        sets.append((int(match[1]), int(match[2])))
    return tuple(dict.fromkeys(sets))


def read_tradeoff(path: Path) -> dict:
    """An earlier ``bench tradeoff`` result to merge into (``--merge``); MetaSimError if it cannot be read."""
    try:
        result = json.loads(Path(path).read_text())
    except (OSError, ValueError) as exc:
        raise MetaSimError(f"cannot read the earlier trade-off result {path} ({exc}); run without --merge") from None
    if not isinstance(result, dict) or not isinstance(result.get("points"), list):
        raise MetaSimError(f"{path} is not a trade-off result; run without --merge")
    return result


# What two parts of the study must share to be one table.
_SHARED = ("experiment", "splits", "reported", "targets_per_seed", "adjoint_targets", "tiles_per_target_group_default")


def _knob_rank(point: dict) -> tuple:
    """A point's place in the table: its knob's in ``KNOB_ORDER``, a training set's rows by designs x tiles."""
    knob = point["knob"]
    rank = KNOB_ORDER.index(knob) if knob in KNOB_ORDER else len(KNOB_ORDER)
    sizes = re.fullmatch(r"(\d+) x (\d+)", point["setting"]) if knob == "training set" else None
    return (rank, (int(sizes[1]) * int(sizes[2]), int(sizes[1])) if sizes else (0, 0))


def merge_results(old: dict, new: dict) -> dict:
    """``new`` (a run of part of the study) with the points of ``old`` it did not measure again. Both must be
    on the same targets (splits, groups per seed, the adjoint's groups); a point of ``old`` whose training set
    (and views) ``new`` trained again must have been measured with the same weights, or the two parts are not
    one model's table: MetaSimError, as for other targets or an ``old`` from before the splits."""
    if "splits" not in old:
        raise MetaSimError("the earlier trade-off result predates the validation and test splits; measure the "
                           "whole study again (without --merge)")
    differ = [key for key in _SHARED if old.get(key) != new.get(key)]
    if differ:
        raise MetaSimError(f"the earlier trade-off result was measured on other targets ({', '.join(differ)} "
                           "differ); measure the whole study again (without --merge)")
    def model(detail: dict) -> str:  # which training set (and views) a point's model learnt from
        return json.dumps([detail["dataset"], detail.get("views")], sort_keys=True)

    models = {model(p["detail"]): p["detail"]["weights"] for p in new["points"] if "weights" in p.get("detail", {})}
    measured = {(p["knob"], p["setting"]) for p in new["points"]}
    kept = []
    for point in old["points"]:
        if (point["knob"], point["setting"]) in measured:
            continue
        detail = point.get("detail", {})
        if "weights" in detail:
            again = models.get(model(detail))
            if again is not None and again != detail["weights"]:
                raise MetaSimError(f"the training set of row '{point['knob']} {point['setting']}' was trained again "
                                   f"and learnt other weights ({again}, not {detail['weights']}): the parts are "
                                   "not one model's; measure the whole study again (without --merge)")
        elif "from" in detail:
            continue  # another bench's row: every run reads those files again
        else:
            raise MetaSimError(f"row '{point['knob']} {point['setting']}' of the earlier trade-off result does not "
                               "name its model's weights (it predates measuring in parts); measure the whole "
                               "study again (without --merge)")
        kept.append(point)
    return {**new, "points": sorted([*kept, *new["points"]], key=_knob_rank)}


def measured_dates(result: dict) -> list[str]:
    """The days (UTC) on which a result's own points were measured, in order."""
    return sorted({p["detail"]["measured_on"] for p in result["points"] if "measured_on" in p.get("detail", {})})


def accuracy(metrics: dict) -> float:
    """The plot's single accuracy figure: mean of flat and sloped top-1."""
    return (metrics["flat_top1"] + metrics["sloped_top1"]) / 2


def _by_split(result: dict) -> tuple[tuple[str, ...], list[dict]]:
    """The splits a result holds, the reported one first, and its points with metrics and targets per split.
    A result from before the test split was measured holds one: the validation split, or target seed 1 alone
    for one from before the splits."""
    if "splits" in result:
        return tuple(sorted(result["splits"], key=lambda name: name != result["reported"])), result["points"]
    name = "validation" if "split" in result else "seed 1"
    return (name,), [{**p, "metrics": {name: p["metrics"]}, "targets": {name: p["targets"]}}
                     for p in result["points"]]


def format_tradeoff_table(result: dict) -> str:
    """The trade-off's result as the Markdown table of docs/benchmarks.md: per point the test split's row and
    the validation split's beside it ("-" where a source lacks the split), the splits note and the views note.
    Reads results from before the test split too."""
    splits, points = _by_split(result)
    lines = ["| knob | setting | split | flat top-1 | flat top-10 | sloped top-1 | sloped top-10 | s per group | "
             "one-off min | targets | top-1 flat / sloped, unseen designs |", "|---" * 11 + "|"]
    for p in points:
        for split in splits:
            m = p["metrics"].get(split)
            if m is None:
                cells, targets, unseen = " | ".join("-" for _ in METRICS), "-", "-"
            else:
                cells, targets = " | ".join(f"{m[k]:.2f}" for k in METRICS), p["targets"][split]
                unseen = (f"{m['unseen_flat_top1']:.2f} / {m['unseen_sloped_top1']:.2f} ({m['unseen_targets']})"
                          if "unseen_flat_top1" in m else "-")
            lines.append(f"| {p['knob']} | {p['setting']} | {split} | {cells} | {p['seconds_per_group']:.3f} | "
                         f"{p['one_off_seconds'] / 60:.1f} | {targets} | {unseen} |")
    if "splits" in result:
        described = " and ".join(f"its {name} split (seeds {', '.join(map(str, result['splits'][name]['seeds']))})"
                                 for name in splits)
        note = (f"E1 on {described}, {result['targets_per_seed']} target groups of "
                f"{result['tiles_per_target_group_default']} tiles per seed, the neural-adjoint rows on "
                f"{result['adjoint_targets']} of each split's. The {result['reported']} rows report; the profiles "
                "and defaults are chosen on the validation rows only.")
        dates = measured_dates(result)
        if len(dates) > 1:
            note += (f" Measured in parts (`--merge`, each training set's weights checked to be the same in every "
                     f"part) on {', '.join(dates)}.")
    elif "split" in result:
        note = (f"E1 on its validation split alone (seeds {', '.join(map(str, result['split']['seeds']))}), "
                "measured before the test split was.")
    else:
        note = "E1 on target seed 1 alone, measured before the splits existed."
    v = result["views"]
    lines += ["", note, "", f"Views: the default extractor's features of 1 and 8 dihedral views differ by at most "
              f"{v['max_abs_difference_1_vs_8_views']:.1e}, so it computes one "
              f"({v['seconds_per_9_tiles_1_view']:.3f} s "
              f"per 9 tiles; {v['seconds_per_9_tiles_8_views_if_not_invariant']:.3f} s if all 8 were computed, "
              "as a backbone must)."]
    return "\n".join(lines)


def format_profiles_table(result: dict, names=tuple(PROFILES)) -> str:
    """The README's table of what each profile measured in a trade-off result: E1 top-1 and top-10 on the
    reported split, top-1 on validation beside them, inference and one-off cost ("-" for a profile the result
    lacks)."""
    splits, points = _by_split(result)
    reported, other = splits[0], splits[1] if len(splits) > 1 else None
    rows = {p["setting"]: p for p in points if p["knob"] == "profile"}
    lines = [f"| profile | E1 top-1 flat / sloped, {reported} | top-10, {reported} | top-1, {other or '-'} | "
             "s per target group | one-off min | targets |", "|---" * 7 + "|"]
    for name in names:
        p = rows.get(name)
        if p is None:
            lines.append(f"| {name} | not measured yet | - | - | - | - | - |")
            continue

        def pair(split, k, p=p):
            m = p["metrics"].get(split)
            return "-" if m is None else f"{m[f'flat_{k}']:.3f} / {m[f'sloped_{k}']:.3f}"

        lines.append(f"| {name} | {pair(reported, 'top1')} | {pair(reported, 'top10')} | "
                     f"{pair(other, 'top1') if other else '-'} | {p['seconds_per_group']:.3f} | "
                     f"{p['one_off_seconds'] / 60:.1f} | {p['targets'].get(reported, '-')} |")
    return "\n".join(lines)


LABEL_GID = "tradeoff-label"  # the gid of the plot's point labels
_LABELS = {"tiles per target group": "group of {}", "training set": "set {}", "render preset": "{} renders",
           "profile": "profile {}", "architecture": "{} architecture", "roof finder": "{} roof finder",
           "roof colour": "roof colour: {}", "roof weight power": "roof weight power {}",
           "roof finder steps": "segmenter {} steps", "training epochs": "at most {} epochs"}
_MARKERS = "os^Dv<>pXhP"
_RING_POINTS = 8  # the step between rings of candidate label places, in points
_DIRECTIONS = tuple(math.radians(a) for a in (0, 30, -30, 60, -60, 90, -90, 120, -120, 150, -150, 180))
_PAD_PX = 2


def tradeoff_figure(result: dict):
    """The trade-off plot as a matplotlib figure: test accuracy against seconds per target group (left, log)
    and against the one-off cost (right), the profiles on both, every point labelled (``_place_labels``)."""
    require("matplotlib", "the trade-off plot")
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib import pyplot as plt

    splits, points = _by_split(result)
    if REPORTED not in splits:
        raise MetaSimError(f"this trade-off result has no {REPORTED} figures to plot; run `make bench-tradeoff` again")
    shown = [p for p in points if REPORTED in p["metrics"]]
    fig, (left, right) = plt.subplots(1, 2, figsize=(13, 6), dpi=110)
    left.set_xscale("log")
    labels = []
    for i, knob in enumerate(dict.fromkeys(p["knob"] for p in shown)):
        mine = [p for p in shown if p["knob"] == knob]
        ys = [accuracy(p["metrics"][REPORTED]) for p in mine]
        for axis in (left, right) if knob == "profile" else (right if knob in ONE_OFF_KNOBS else left,):
            xs = [p["one_off_seconds"] / 60 if axis is right else p["seconds_per_group"] for p in mine]
            size = 160 if knob == "profile" else 45  # points squared
            axis.scatter(xs, ys, marker="*" if knob == "profile" else _MARKERS[i % len(_MARKERS)], s=size,
                         color=f"C{i % 10}", label=knob, zorder=3)
            labels += [(axis, x, y, math.sqrt(size) / 2, _LABELS.get(knob, "{}").format(p["setting"]))
                       for x, y, p in zip(xs, ys, mine)]
    left.set_xlabel("seconds per target group (features + search), log scale")
    right.set_xlabel("one-off minutes (render + features + training)")
    for axis in (left, right):
        axis.set_ylabel(f"E1 {REPORTED} top-1, mean of flat and sloped")
        axis.grid(True, alpha=0.3)
    handles = {label: handle for axis in (left, right) for handle, label in zip(*axis.get_legend_handles_labels())}
    legend = fig.legend(handles.values(), handles.keys(), loc="lower center", ncol=min(len(handles), 6), fontsize=8)
    missing = len(points) - len(shown)
    title = fig.suptitle(f"meta-sim: E1 accuracy on the {REPORTED} split bought by time\n"
                         f"{result['targets_per_seed']} target groups per seed, the adjoint on "
                         f"{result['adjoint_targets']} per split; the profiles are chosen on the validation split"
                         + (f"; rows without {REPORTED} figures, not drawn: {missing}" if missing else ""), fontsize=10)
    fig.tight_layout(rect=(0, 0.08, 1, 1))
    for axis in (left, right):  # fixed before the labels are placed: they are placed in display space
        axis.set_xlim(axis.get_xlim())
        axis.set_ylim(axis.get_ylim())
    _place_labels(fig, labels, [legend, title])
    return fig


def _overlaps(box, others) -> bool:
    return any(box.x0 < o.x1 + _PAD_PX and o.x0 < box.x1 + _PAD_PX and box.y0 < o.y1 + _PAD_PX
               and o.y0 < box.y1 + _PAD_PX for o in others)


def _place_labels(fig, labels, fixed) -> None:
    """Write each (axis, x, y, marker half-side in points, text) label beside its point: at the first free
    place on rings of growing radius around it, free meaning its box overlaps no label placed before, no
    point and none of the ``fixed`` artists (legend, title); inside its axes while the rings fit in them,
    then outside every axes. The rings grow without bound and the obstacles are finitely many, so every
    label gets a place. A label anywhere but right beside its point is joined to it by a line."""
    from matplotlib.lines import Line2D
    from matplotlib.transforms import Bbox

    fig.canvas.draw()
    renderer = fig.canvas.get_renderer()
    px_per_point = fig.dpi / 72
    obstacles = []
    for axis, x, y, half, _ in labels:
        (px, py), half = axis.transData.transform((x, y)), half * px_per_point
        obstacles.append(Bbox.from_extents(px - half, py - half, px + half, py + half))
    obstacles += [artist.get_window_extent(renderer) for artist in fixed]
    panels = [axis.get_tightbbox(renderer) for axis in fig.axes]
    for axis, x, y, _, text in labels:
        frame = axis.get_window_extent(renderer)
        inside = math.hypot(frame.width, frame.height) / px_per_point
        artist = axis.text(x, y, text, fontsize=7, gid=LABEL_GID, zorder=4)
        radius, place = 0, None
        while place is None:
            radius += _RING_POINTS
            place = _free_place(artist, axis, fig, renderer, radius, obstacles,
                                None if radius <= inside else panels, frame)
        box, direction = place
        obstacles.append(box)
        if (radius, direction) != (_RING_POINTS, 0):
            dx, dy = artist.get_transform().transform((x, y)) - axis.transData.transform((x, y))
            end = axis.transData.inverted().transform(axis.transData.transform((x, y)) + (dx, dy))
            axis.add_line(Line2D([x, end[0]], [y, end[1]], lw=0.6, color="0.4", zorder=2, clip_on=False))


def _free_place(artist, axis, fig, renderer, radius: float, obstacles: list, panels: list | None, frame):
    """Try ``artist`` in each direction on the ring of ``radius`` points: (its window box, the direction's
    index) at the first place that overlaps no obstacle and lies inside ``frame`` (with ``panels`` None) or
    outside every one of ``panels``; None when the ring has no such place."""
    from matplotlib.transforms import offset_copy

    for index, angle in enumerate(_DIRECTIONS):
        dx, dy = radius * math.cos(angle), radius * math.sin(angle)
        artist.set_transform(offset_copy(axis.transData, fig, dx, dy, units="points"))
        artist.set_horizontalalignment("left" if dx > 0.25 * radius else "right" if dx < -0.25 * radius
                                       else "center")
        artist.set_verticalalignment("bottom" if dy > 0.25 * radius else "top" if dy < -0.25 * radius
                                     else "center")
        box = artist.get_window_extent(renderer)
        within = (frame.x0 <= box.x0 and box.x1 <= frame.x1 and frame.y0 <= box.y0 and box.y1 <= frame.y1
                  if panels is None else not _overlaps(box, panels))
        if within and not _overlaps(box, obstacles):
            return box, index
    return None


def plot_tradeoff(result: dict, path: Path) -> Path:
    """``tradeoff_figure`` written to ``path`` as a PNG (cropped to what was drawn: a label may sit
    outside the axes)."""
    fig = tradeoff_figure(result)
    from matplotlib import pyplot as plt

    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=fig.dpi, bbox_inches="tight")
    plt.close(fig)
    return write_bytes_atomic(path, buffer.getvalue())

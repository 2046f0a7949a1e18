"""What each knob that costs time buys in accuracy (`meta-sim bench tradeoff`, `make bench-tradeoff`).

Every point is measured on E1's validation split (bank designs in cities
never trained on; ``splits.py``), since the profiles are chosen on it: top-1
and top-10 for flat and sloped roofs, and two costs:

* ``seconds_per_group``: inference, per target group: features of its tiles
  (x views) plus the search;
* ``one_off_seconds``: before any inference, once: rendering the training
  set (tiles x the render preset's seconds per tile from ``make
  bench-render``), its features and training NAMS.

Knobs, each varied alone from the default (``DatasetConfig()``, "fast"
renders, target groups of 9 tiles, exhaustive search):

* ``tiles per target group``: 1, 2, 4, 9;
* ``search``: exhaustive, and the neural-adjoint search at several (M,
  iterations), the paper's (1000, 200) first, plus DR and MS2: taken from
  ``make bench-nams`` (``benchmarks/nams.json``, the same model and E1
  validation targets), with this bench's feature time per tile added;
* ``views``: the default extractor is invariant to the 8 dihedral views, so
  8 views give the features of 1 at the cost of 1 (checked, not assumed:
  the bench compares the vectors); a backbone pays 8x;
* ``training set``: designs x tiles per design;
* ``render preset``: training set and targets both rendered with it.

``PROFILES`` names three recommended combinations -- fast, balanced and
paper-faithful -- and the bench measures each end to end.
"""

from __future__ import annotations

import io
import json
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

from ..core.errors import MetaSimError
from ..core.extras import require
from ..core.fileio import write_bytes_atomic
from ..core.progress import Bars
from ..pipeline.dataset import DatasetConfig
from ..pipeline.profiles import PROFILES
from .splits import get_split, spread

GROUP_TILES = (1, 2, 4, 9)
TRAINING_SETS = ((150, 4), (300, 2), (300, 4), (600, 2), (600, 4), (1700, 9))
RENDER_PRESETS = ("fast", "balanced")
METRICS = ("flat_top1", "flat_top10", "sloped_top1", "sloped_top10")
SPLIT = get_split("e1", "validation")  # the profiles and defaults are choices: made on validation only


@dataclass
class Point:
    """One row of the trade-off: a knob's setting, its E1 metrics, inference seconds per target group,
    one-off seconds, the number of targets, and anything else worth keeping in the JSON."""

    knob: str
    setting: str
    metrics: dict
    seconds_per_group: float
    one_off_seconds: float
    targets: int
    detail: dict = field(default_factory=dict)


def _render_seconds_per_tile(preset: str, render_bench: Path) -> float:
    try:
        return float(json.loads(render_bench.read_text())["presets"][preset]["seconds_per_tile"])
    except (OSError, ValueError, KeyError) as exc:
        raise MetaSimError(f"no '{preset}' figure in {render_bench} ({exc}); run `make bench-render` first") from None


class _Experiment:
    """One training set and model, E1 targets rendered with its preset, per-tile target features."""

    def __init__(self, dataset: DatasetConfig, views: int, targets: int, root: Path,
                 render_bench: Path, bars: Bars | None = None):
        from ..nams import load_checkpoint
        from ..pipeline.dataset import job_tiles
        from ..pipeline.features import features_for_groups
        from ..pipeline.roofcolour import checkpoint_extractor
        from ..pipeline.workflow import ModelSettings, ensure_models
        from ..render.jobs import sample_designs
        from ..sim.design import DesignSpace
        from ..sim.imageio import read_image
        from ..sim.textures import ensure_default_bank, ensure_heldout_bank
        from .evaluate import rankings, render_split_targets

        self.dataset = dataset
        # E1 targets whose design the training set lacks are also scored alone ("unseen").
        self.training_designs = sample_designs(DesignSpace.load(dataset.space), dataset.designs, dataset.seed)
        models = ensure_models(dataset, ModelSettings(views=views), root, bars)
        self.nams = load_checkpoint(models.nams_path, "nams")
        self.seeds, self.per_seed = len(SPLIT.seeds), targets
        self.jobs, folders = render_split_targets(SPLIT, targets, max(GROUP_TILES), dataset.preset, root,
                                                  dataset.tile_px, dataset.pixel_size_m, bars)
        extractor = checkpoint_extractor(self.nams)
        tiles = [[read_image(p)] for job, folder in zip(self.jobs, folders)
                 for p in job_tiles(folder, job.name, max(GROUP_TILES))]
        started = time.perf_counter()
        self.tile_features = features_for_groups(tiles, extractor, 1).reshape(len(self.jobs), max(GROUP_TILES), -1)
        self.feature_seconds_per_tile = (time.perf_counter() - started) / len(tiles)
        self.ranks = rankings("e1", ensure_default_bank(), ensure_heldout_bank())
        feature_total = self.feature_seconds_per_tile * dataset.designs * dataset.tiles
        train = float(self.nams.extra.get("seconds", 0.0))
        self.one_off = (_render_seconds_per_tile(dataset.preset, render_bench) * dataset.designs * dataset.tiles
                        + feature_total + train)
        self.train_seconds = train

    def run(self, knob: str, setting: str, group_tiles: int = 9, method: str = "exhaustive",
            adjoint: dict | None = None, targets: int | None = None, seed: int = 1) -> Point:
        import torch

        from ..nams import adjoint_search, exhaustive_search
        from .evaluate import mean_scores, score, unseen_rows

        chosen = spread(self.seeds, self.per_seed, targets or len(self.jobs))  # the adjoint's few: every seed's
        n, jobs = len(chosen), [self.jobs[i] for i in chosen]
        feats = self.tile_features[chosen, :group_tiles].mean(dim=1)
        normed = self.nams.feature_norm.apply(feats)
        started = time.perf_counter()
        if method == "exhaustive":
            results = exhaustive_search(self.nams.model, normed, self.nams.space)
        else:
            results = adjoint_search(self.nams.model, normed, self.nams.space,
                                     generator=torch.Generator().manual_seed(seed),
                                     **{"S": min(50, adjoint["M"]), **adjoint})
        search_seconds = (time.perf_counter() - started) / n
        rows = [score(r.design, job.design, self.ranks) for r, job in zip(results, jobs)]
        unseen = unseen_rows(rows, jobs, self.training_designs)
        metrics = {**mean_scores(rows), "unseen_targets": len(unseen),
                   **{f"unseen_{k}": v for k, v in mean_scores(unseen).items()}}
        return Point(knob, setting, metrics,
                     round(search_seconds + group_tiles * self.feature_seconds_per_tile, 5),
                     round(self.one_off, 1), n,
                     {"search_seconds_per_group": round(search_seconds, 5),
                      "feature_seconds_per_tile": round(self.feature_seconds_per_tile, 5),
                      "train_seconds": round(self.train_seconds, 1),
                      "dataset": asdict(self.dataset)})


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


def _search_points(nams_bench: Path, base: _Experiment) -> list[Point]:
    """The search methods' E1 validation rows of ``make bench-nams`` as points: search time plus 9 tiles'
    features."""
    try:
        bench = json.loads(nams_bench.read_text())
        rows = bench["splits"]["validation"]["experiments"]["e1"]
        seeds = bench["splits"]["validation"]["settings"]["e1"]["seeds"]
    except (OSError, ValueError, KeyError) as exc:
        raise MetaSimError(f"no E1 validation rows in {nams_bench} ({exc}); run `make bench-nams` first") from None
    if (seeds, bench.get("targets_per_seed")) != (list(SPLIT.seeds), base.per_seed):
        raise MetaSimError(f"{nams_bench} was measured on {bench.get('targets_per_seed')} target groups of seeds "
                           f"{seeds}, not {base.per_seed} of {list(SPLIT.seeds)}: run `make bench-nams` again "
                           "with as many --targets")
    if bench.get("tiles_per_target") != max(GROUP_TILES):
        raise MetaSimError(f"{nams_bench} was measured on groups of {bench.get('tiles_per_target')} tiles, "
                           f"not {max(GROUP_TILES)}: run `make bench-nams` again")
    features = max(GROUP_TILES) * base.feature_seconds_per_tile
    points = []
    for name, row in rows.items():
        if name == "uniform":
            continue
        setting = name.replace("nams_adjoint_M", "adjoint M=").replace("_it", ", ") + (" it" if "_it" in name else "")
        setting = setting.replace("nams_exhaustive", "exhaustive")
        unseen = ({"unseen_targets": row["unseen_targets"], **{f"unseen_{k}": v for k, v in row["unseen"].items()}}
                  if row.get("unseen") else {})
        points.append(Point("search", setting, {**{k: row[k] for k in METRICS}, **unseen},
                            round(row["seconds_per_target"] + features, 5), round(base.one_off, 1),
                            int(row["targets"]),
                            {"search_seconds_per_group": row["seconds_per_target"], "from": str(nams_bench)}))
    return points


def bench_tradeoff(targets: int = 100, adjoint_targets: int = 20, root: Path | None = None,
                   render_bench: Path = Path("benchmarks/render.json"),
                   nams_bench: Path = Path("benchmarks/nams.json"), presets=RENDER_PRESETS,
                   training_sets=TRAINING_SETS, profiles=tuple(PROFILES), bars: Bars | None = None) -> dict:
    """Measure every knob alone, then every profile end to end, on ``targets`` groups of each seed of E1's
    validation split (the adjoint search on ``adjoint_targets`` of them); returns a JSON-able dict."""
    from ..core.cache import cache_root

    root = Path(root or cache_root())
    points: list[Point] = []
    base = _Experiment(DatasetConfig(), 8, targets, root, render_bench, bars)
    for g in GROUP_TILES:
        points.append(base.run("tiles per target group", str(g), group_tiles=g))
    points += _search_points(nams_bench, base)
    for designs, tiles in training_sets:
        experiment = _Experiment(DatasetConfig(designs=designs, tiles=tiles), 8, targets, root, render_bench, bars)
        points.append(experiment.run("training set", f"{designs} x {tiles}"))
    for preset in presets:
        experiment = _Experiment(DatasetConfig(preset=preset), 8, targets, root, render_bench, bars)
        points.append(experiment.run("render preset", preset))
    for name in profiles:
        profile = PROFILES[name]
        experiment = _Experiment(profile.dataset, profile.views, targets, root, render_bench, bars)
        n = adjoint_targets if profile.method == "adjoint" else targets
        points.append(experiment.run("profile", name, profile.group_size, profile.method,
                                     profile.search_options(), targets=n))
    import torch

    return {"experiment": "e1", "split": SPLIT.to_dict(), "targets_per_seed": targets,
            "targets": len(base.jobs), "adjoint_targets": adjoint_targets,
            "tiles_per_target_group_default": max(GROUP_TILES),
            "views": _views_check(), "points": [asdict(p) for p in points],
            "profiles": {name: {**asdict(PROFILES[name]), "dataset": asdict(PROFILES[name].dataset)}
                         for name in profiles},
            "machine": {"torch_threads": torch.get_num_threads()}}


def accuracy(metrics: dict) -> float:
    """The plot's single accuracy figure: mean of flat and sloped top-1."""
    return (metrics["flat_top1"] + metrics["sloped_top1"]) / 2


def format_tradeoff_table(result: dict) -> str:
    """The trade-off's result as the Markdown table of docs/benchmarks.md, with the views note."""
    lines = ["| knob | setting | flat top-1 | flat top-10 | sloped top-1 | sloped top-10 | s per group | "
             "one-off min | targets | top-1 flat / sloped, unseen designs |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for p in result["points"]:
        m = p["metrics"]
        unseen = (f"{m['unseen_flat_top1']:.2f} / {m['unseen_sloped_top1']:.2f} ({m['unseen_targets']})"
                  if "unseen_flat_top1" in m else "-")
        lines.append(f"| {p['knob']} | {p['setting']} | " + " | ".join(f"{m[k]:.2f}" for k in METRICS)
                     + f" | {p['seconds_per_group']:.3f} | {p['one_off_seconds'] / 60:.1f} | {p['targets']} "
                     f"| {unseen} |")
    v = result["views"]
    lines += ["", f"Views: the default extractor's features of 1 and 8 dihedral views differ by at most "
              f"{v['max_abs_difference_1_vs_8_views']:.1e}, so it computes one "
              f"({v['seconds_per_9_tiles_1_view']:.3f} s "
              f"per 9 tiles; {v['seconds_per_9_tiles_8_views_if_not_invariant']:.3f} s if all 8 were computed, "
              "as a backbone must)."]
    return "\n".join(lines)


def plot_tradeoff(result: dict, path: Path) -> Path:
    """Two panels: accuracy against seconds per target group, and against the one-off cost."""
    require("matplotlib", "the trade-off plot")
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib import pyplot as plt

    fig, (left, right) = plt.subplots(1, 2, figsize=(12, 4.8), dpi=110)
    left.set_xscale("log")
    placed: dict = {left: [], right: []}

    def label(axis, x, y, text):
        """Annotate, moving the text down a line while it would sit on an earlier label."""
        px, py = axis.transData.transform((x, y))
        shift = 0
        while any(abs(px - qx) < 60 and abs(py - shift - qy) < 9 for qx, qy in placed[axis]):
            shift += 9
        placed[axis].append((px, py - shift))
        axis.annotate(text, (x, y), textcoords="offset points", xytext=(5, 4 - shift * 72 / fig.dpi), fontsize=7)

    markers = {"tiles per target group": "o", "search": "s", "training set": "^", "render preset": "D",
               "profile": "*"}
    for knob, marker in markers.items():
        points = [p for p in result["points"] if p["knob"] == knob]
        if not points:
            continue
        axis = left if knob in ("tiles per target group", "search") else right
        xs = [p["seconds_per_group"] if axis is left else p["one_off_seconds"] / 60 for p in points]
        ys = [accuracy(p["metrics"]) for p in points]
        size = 160 if knob == "profile" else 50
        axis.scatter(xs, ys, marker=marker, s=size, label=knob, zorder=3)
        for x, y, p in zip(xs, ys, points):
            label(axis, x, y, p["setting"])
        if knob == "profile":  # profiles go on both panels
            lx = [p["seconds_per_group"] for p in points]
            left.scatter(lx, ys, marker=marker, s=size, label=knob, zorder=3)
            for x, y, p in zip(lx, ys, points):
                label(left, x, y, p["setting"])
    left.set_xlabel("seconds per target group (features + search), log scale")
    right.set_xlabel("one-off minutes (render + features + training)")
    for axis in (left, right):
        axis.set_ylabel("E1 top-1, mean of flat and sloped")
        axis.grid(True, alpha=0.3)
        axis.legend(fontsize=8, loc="lower right")
    fig.suptitle(f"meta-sim: accuracy bought by time (E1 validation, {result['targets']} target groups; "
                 f"adjoint on {result['adjoint_targets']})")
    fig.tight_layout()
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png")
    plt.close(fig)
    return write_bytes_atomic(path, buffer.getvalue())

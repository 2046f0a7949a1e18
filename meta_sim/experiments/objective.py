"""How the search compares the roof-colour histograms, chosen on validation and reported on test.

The exhaustive search ranks designs by ``rest ** (1 - exponent) * colour ** exponent``, where ``colour`` is the
error over the roof-colour histograms plus ``weight`` times the error over the histograms blurred by a
Gaussian of ``sigma`` bins (``nams.ColourComparison``, ``pipeline.roofcolour.colour_comparison``). Which
histograms there are is the other half of the choice: the default model's (with the histograms in the score's
own colour cone, ``ModelSettings.roof_score_cone``) and the same model without those (the stretched cone's
alone). This bench scores a grid of both on the default training set (the one bench-nams scores) and its
targets:

* on the validation split of E1 and E2, every setting of the grid;
* the setting with the best mean of the four figures issue 20 sets targets on (E1 top-1 and E2 top-10, flat
  and sloped) is chosen, the default (``pipeline.roofcolour.SEARCH_COLOUR`` on the default model, itself
  this bench's choice) winning ties;
* on the test split only the default, the chosen setting, the plain comparison (exponent 0.5, no blur) and
  that on the model without the score cone (the default before 2026-12-02) are scored, for the report.

``make bench-objective`` writes ``benchmarks/objective.json`` and its table in docs/benchmarks.md.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from pathlib import Path

from ..core.progress import Bars
from ..pipeline.roofcolour import SEARCH_COLOUR
from .evaluate import bootstrap_intervals, mean_scores, score
from .splits import get_split

EXPONENTS = (0.25, 0.3, 0.35, 0.5)
SIGMAS = (1.0, 1.5, 2.0)  # bins of the 8 x 8 x 8 cone
WEIGHTS = (1.0, 10.0, 30.0, 100.0)
CRITERION = ("e1", "flat_top1"), ("e1", "sloped_top1"), ("e2", "flat_top10"), ("e2", "sloped_top10")
SHOWN = ("flat_top1", "flat_top10", "flat_closeness", "sloped_top1", "sloped_top10", "sloped_closeness")


@dataclass(frozen=True)
class Setting:
    """One colour comparison: the colour error's exponent, and the blur's sigma (bins) and weight (0: none);
    and the model's histograms: with the score's cone or without."""

    exponent: float = 0.5
    sigma: float = 0.0
    weight: float = 0.0
    score_cone: bool = True

    @property
    def name(self) -> str:
        blur = f", blur {self.sigma:g} bins x {self.weight:g}" if self.weight else ", no blur"
        return f"exponent {self.exponent:g}{blur}" + ("" if self.score_cone else ", no score cone")

    def comparison(self, blocks: tuple[int, ...] = (488,)):
        """The ``nams.ColourComparison`` for a model with the roof-colour histograms ``blocks``."""
        from ..pipeline.roofcolour import colour_comparison

        return colour_comparison(self.exponent, self.sigma, self.weight, blocks)


DEFAULT = Setting(*SEARCH_COLOUR)  # the search's default (pipeline.roofcolour.search_colour) on the default model
PLAIN = Setting()  # the plain geometric mean
WITHOUT_SCORE_CONE = Setting(score_cone=False)  # the default before the score cone and the blur


def grid(exponents=EXPONENTS, sigmas=SIGMAS, weights=WEIGHTS) -> list[Setting]:
    """The default first, then for each model (with the score cone, then without) every exponent without
    blur and with every blur."""
    settings = [DEFAULT]
    for cone in (True, False):
        settings += [Setting(e, score_cone=cone) for e in exponents]
        settings += [Setting(e, s, w, cone) for e in exponents for s in sigmas for w in weights]
    return [s for k, s in enumerate(settings) if s not in settings[:k]]


def criterion(metrics: dict) -> float:
    """The mean of E1 top-1 and E2 top-10, flat and sloped (``metrics``: experiment -> mean scores)."""
    return sum(metrics[e][k] for e, k in CRITERION) / len(CRITERION)


def choose(rows: list[dict]) -> dict:
    """The validation row with the best criterion; the first (the default) wins ties."""
    best = max(r["criterion"] for r in rows)
    return next(r for r in rows if r["criterion"] == best)


def _targets(split_name: str, targets: int, root: Path, bars: Bars | None, cones=(True, False)) -> dict:
    """Per model (with the score cone or without, ``cones``), per experiment of ``split_name``: the model's
    checkpoint, normalised target features, the targets' true designs and the rankings that score them."""
    from dataclasses import replace

    from ..pipeline.dataset import DatasetConfig
    from ..pipeline.workflow import ModelSettings
    from .evaluate import EvalSettings, prepare_eval

    out = {}
    for cone in cones:
        models = replace(ModelSettings(), roof_score_cone=cone)
        out[cone] = {}
        for experiment in ("e1", "e2"):
            settings = EvalSettings(targets=targets, ms2=False, sbi=False, split=get_split(experiment, split_name))
            ctx = prepare_eval(experiment, DatasetConfig(), models, settings, root, bars)
            out[cone][experiment] = (ctx.nams, ctx.nams.feature_norm.apply(ctx.features),
                                     [j.design for j in ctx.jobs], ctx.ranks)
    return out


def _score(setting: Setting, data: dict, intervals: bool = False) -> dict:
    """Per experiment: the mean scores of the exhaustive search with ``setting`` (with 95% intervals)."""
    from ..nams import exhaustive_search

    out, comparisons = {}, {}  # one blur per histogram layout (the experiments share the default model's)
    for experiment, (ckpt, normed, truth, ranks) in data[setting.score_cone].items():
        blocks = ckpt.feature_norm.hist_blocks
        if blocks not in comparisons:
            comparisons[blocks] = setting.comparison(blocks)
        found = exhaustive_search(ckpt.model, normed, ckpt.space, colour=comparisons[blocks])
        rows = [score(r.design, t, ranks, ckpt.space) for r, t in zip(found, truth)]
        out[experiment] = {k: round(v, 4) for k, v in mean_scores(rows).items()}
        if intervals:
            out[experiment]["intervals"] = {k: [round(a, 4), round(b, 4)]
                                            for k, (a, b) in bootstrap_intervals(rows).items()}
        out[experiment]["targets"] = len(rows)
    return out


def bench_objective(targets: int = 100, root: Path | None = None, settings: list[Setting] | None = None,
                    bars: Bars | None = None) -> dict:
    """Score ``settings`` (default ``grid()``) on the validation split of E1 and E2 (``targets`` groups per
    seed), choose one there, and score the default and the chosen one on the test split."""
    from ..core.cache import cache_root

    root = Path(root or cache_root())
    settings = settings or grid()
    validation = _targets("validation", targets, root, bars)
    update = bars("colour comparisons (validation)", len(settings)) if bars else None
    rows = []
    for setting in settings:
        metrics = _score(setting, validation)
        rows.append({"setting": asdict(setting), "name": setting.name, "metrics": metrics,
                     "criterion": round(criterion(metrics), 4)})
        if update:
            update(1)
    chosen = choose(rows)
    test = _targets("test", targets, root, bars)
    reported = {}
    named = {r["name"]: r for r in rows}
    for label, row in (("default", rows[0]), ("chosen", chosen), ("plain comparison", named[PLAIN.name]),
                       ("without score cone", named[WITHOUT_SCORE_CONE.name])):
        setting = Setting(**row["setting"])
        metrics = _score(setting, test, intervals=True)
        reported[label] = {"setting": row["setting"], "name": setting.name, "metrics": metrics,
                           "criterion": round(criterion(metrics), 4)}
    return {"criterion": [f"{e} {k}" for e, k in CRITERION], "targets_per_seed": targets,
            "validation": rows, "chosen": chosen["setting"], "test": reported,
            "splits": {name: {e: get_split(e, name).to_dict() for e in ("e1", "e2")}
                       for name in ("validation", "test")}}


def format_objective_table(result: dict, best: int = 5) -> str:
    """The bench's Markdown table: the default and the chosen setting on test and validation, then the best
    ``best`` validation rows."""
    head = ("| setting | split | E1 flat top-1 | E1 sloped top-1 | E2 flat top-10 | E2 sloped top-10 | "
            "E2 flat closeness | E2 sloped closeness | mean of the four |")
    lines = [head, "|" + "---|" * 9]

    def cells(metrics: dict, with_intervals: bool) -> str:
        out = []
        for e, k in (("e1", "flat_top1"), ("e1", "sloped_top1"), ("e2", "flat_top10"), ("e2", "sloped_top10"),
                     ("e2", "flat_closeness"), ("e2", "sloped_closeness")):
            value = f"{metrics[e][k]:.3f}"
            if with_intervals and k in metrics[e].get("intervals", {}):
                low, high = metrics[e]["intervals"][k]
                value += f" [{low:.3f}, {high:.3f}]"
            out.append(value)
        return " | ".join(out)

    by_name = {r["name"]: r for r in result["validation"]}
    for label in ("default", "chosen", "plain comparison", "without score cone"):
        row = result["test"].get(label)  # a result from before the score cone lacks the last two
        if row is None:
            continue
        lines.append(f"| {label}: {row['name']} | test | {cells(row['metrics'], True)} | {row['criterion']:.3f} |")
        valid = by_name[row["name"]]
        lines.append(f"| {label}: {row['name']} | validation | {cells(valid['metrics'], False)} | "
                     f"{valid['criterion']:.3f} |")
    ranked = sorted(result["validation"], key=lambda r: -r["criterion"])[:best]
    for i, row in enumerate(ranked, 1):
        lines.append(f"| validation #{i}: {row['name']} | validation | {cells(row['metrics'], False)} | "
                     f"{row['criterion']:.3f} |")
    seeds = result["splits"]
    lines += ["", f"{result['targets_per_seed']} target groups per seed: validation E1 seeds "
              f"{', '.join(map(str, seeds['validation']['e1']['seeds']))} and E2 on "
              f"`{seeds['validation']['e2']['heldout']}`; test seeds "
              f"{', '.join(map(str, seeds['test']['e1']['seeds']))} "
              f"and E2 on `{seeds['test']['e2']['heldout']}` (95% intervals over the groups). "
              f"{len(result['validation'])} settings scored on validation; the test split scores only the default, "
              f"the chosen one, the plain comparison (exponent 0.5, no blur) and that on the model without the "
              f"score cone (the default before 2026-12-02)."]
    return "\n".join(lines)

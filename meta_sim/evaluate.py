"""E1 and E2 of the paper on our simulator: can a method recover the rooftop design of targets?

* E1: synthetic targets whose design is in the bank, rendered in city seeds
  the training set never used.
* E2: synthetic targets made with held-out textures (the design gap): the
  best a method can do is name the bank texture nearest to the truth.

Scoring follows the paper (section 5.4): rank the bank's textures by the HSV
similarity to the true texture (``meta_sim/textures/similarity.py``); a
prediction is a top-n hit when it is among the n nearest. In E1 the nearest
texture is the truth itself.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from .design import DesignSpace
from .errors import MetaSimError
from .render import Job

TARGET_CITY_SEED = 100_000  # training sets use small seeds: targets come from cities never trained on
KIND_OF = {"flat_roof": "flat", "sloped_roof": "sloped"}
METRICS = ("flat_top1", "flat_top10", "sloped_top1", "sloped_top10")


def target_jobs(experiment: str, space: DesignSpace, heldout, n: int, seed: int) -> list[Job]:
    """``n`` target designs, each in its own unseen city."""
    rng = np.random.default_rng([seed, 2 if experiment == "e2" else 1])
    if experiment == "e1":
        designs = space.sample(rng, n)
    elif experiment == "e2":
        designs = []
        for _ in range(n):
            design = {}
            for param in space.parameters:
                ids = heldout.ids(param.texture_kind)
                design[param.name] = ids[int(rng.integers(len(ids)))]
            designs.append(design)
    else:
        raise MetaSimError(f"unknown experiment {experiment!r}; choose e1 or e2")
    return [Job(design, TARGET_CITY_SEED + seed * 1000 + k, f"{experiment}-{k:04d}")
            for k, design in enumerate(designs)]


def rankings(experiment: str, bank, heldout) -> dict:
    """Per roof kind: true texture id -> bank ids of that kind, nearest first."""
    from .textures import SIMILARITY_FILE, SIMILARITY_TO_DEFAULT_FILE, load_similarity, rank_by_similarity

    sim = load_similarity(Path(heldout.root if experiment == "e2" else bank.root) /
                          (SIMILARITY_TO_DEFAULT_FILE if experiment == "e2" else SIMILARITY_FILE))
    truth_bank = heldout if experiment == "e2" else bank
    return {kind: {t: rank_by_similarity(t, bank.ids(kind), sim) for t in truth_bank.ids(kind)}
            for kind in ("flat", "sloped")}


def score(predicted: dict, truth: dict, ranks: dict) -> dict:
    """top-1 / top-10 hits for each roof parameter the space has."""
    out = {}
    for param, kind in KIND_OF.items():
        if param not in truth:
            continue
        order = ranks[kind][truth[param]]
        out[f"{kind}_top1"] = float(predicted[param] in order[:1])
        out[f"{kind}_top10"] = float(predicted[param] in order[:10])
    return out


def mean_scores(rows: list[dict]) -> dict:
    return {key: float(np.mean([r[key] for r in rows])) for key in rows[0]} if rows else {}


def results_markdown(results: dict) -> str:
    experiment = results["experiment"].upper()
    lines = [f"### {experiment}: rate of inferring one of the n nearest textures "
             f"({results['targets']} target groups of {results['tiles_per_target']} tiles)", "",
             "| method | flat top-1 | flat top-10 | sloped top-1 | sloped top-10 | s per target |",
             "|---|---|---|---|---|---|"]
    for name, m in results["methods"].items():
        cells = " | ".join(f"{m[k]:.3f}" if k in m else "-" for k in METRICS)
        lines.append(f"| {name} | {cells} | {m['seconds_per_target']:.4f} |")
    return "\n".join(lines) + "\n"


def write_results(out: Path, results: dict) -> None:
    out.mkdir(parents=True, exist_ok=True)
    for name, text in (("results.json", json.dumps(results, indent=2) + "\n"),
                       ("results.md", results_markdown(results))):
        tmp = out / f".{name}.tmp"
        tmp.write_text(text)
        tmp.replace(out / name)

"""`meta-sim bench roof-finder`: how each model's roof finder reads real imagery.

On a real target the inferred roof textures are the colours of the pixels the
model's roof finder (learnt on renders) counts as roofs. This benchmark puts
that finder on every shared real domain's labelled scenes, the ``adapt`` ones
(validation: a finder setting may be chosen here) and the ``test`` ones (report
only), and compares what it counts with the building masks
(``pipeline.roofcolour.finder_agreement``), beside the range of roof pixels
the model's training cities span, which `meta-sim infer` holds each target
group against. One training set per design space: the default space's as
`meta-sim infer`'s default model is trained on, and the realism spaces' as
bench-realism trains them (twice the designs). The finder and the training
features are all it needs: no model is trained.
"""

from __future__ import annotations

import time
from dataclasses import replace
from pathlib import Path

from ..core.progress import Bars
from . import realdomains

DEFAULT_SPACES = ("rooftops-v1", "overhead-v2")
DEFAULT_FINDERS = ("segmenter",)


def finder_on_scenes(extractor, scenes: list, pixel_size_m: float) -> dict:
    """``roofcolour.finder_agreement`` on real scenes brought to the training tiles' ``pixel_size_m``."""
    from ..pipeline.roofcolour import finder_agreement

    pairs = [realdomains.at_pixel_size(scene, pixel_size_m) for scene in scenes]
    return finder_agreement(extractor, [i for i, _ in pairs], [m for _, m in pairs])


def bench_roof_finder(spaces=DEFAULT_SPACES, finders=DEFAULT_FINDERS, root: Path | None = None,
                      realdata: Path | None = None, bars: Bars | None = None) -> dict:
    """Per design space of ``spaces`` and roof finder of ``finders`` (``roofcolour.ROOF_FINDERS``), the
    row "space" (the default finder) or "space finder": the model's id, the training cities' roof-pixel
    range (``roofcolour.training_evidence``) and, per real domain, the finder on its validation and test
    scenes. Renders the training set and learns the finder when the cache lacks them. MetaSimError for an
    unknown space or finder, or missing real data."""
    from ..pipeline.dataset import DatasetConfig
    from ..pipeline.roofcolour import stored_extractor, training_evidence
    from ..pipeline.workflow import ModelSettings, dataset_dir, prepare_features

    started = time.perf_counter()
    realdata = realdomains.require(Path(realdata or realdomains.REALDATA))
    default = DatasetConfig()
    result = {"spaces": {}}
    for space, finder in [(space, finder) for space in spaces for finder in finders]:
        settings = replace(ModelSettings(), roof_finder=finder).check()
        dataset = replace(default, space=space)
        if space != default.space:  # as bench-realism trains the other spaces' models
            dataset = replace(dataset, designs=2 * default.designs)
        features = prepare_features(dataset, settings, root, bars).features
        extractor = stored_extractor(settings.extractor, features.roof_likelihood)
        domains = {}
        for domain in realdomains.DOMAINS:
            adapt, test = realdomains.split(realdomains.scenes(domain, realdata))
            domains[domain] = {"validation": finder_on_scenes(extractor, adapt, dataset.pixel_size_m),
                               "test": finder_on_scenes(extractor, test, dataset.pixel_size_m)}
        name = space if finder == ModelSettings().roof_finder else f"{space} {finder}"
        result["spaces"][name] = {
            "training_set": dataset_dir(dataset, root).name, "designs": dataset.designs, "roof_finder": finder,
            "extractor": features.extractor_id,
            "training": training_evidence(features.features, features.hist_blocks), "domains": domains}
    result["seconds"] = round(time.perf_counter() - started, 1)
    return result


def format_roof_finder_table(result: dict) -> str:
    """``bench_roof_finder``'s result as Markdown."""
    lines = ["Each training set's roof finder on the real domains' labelled scenes, validation (`adapt`) / test: the "
             "share of pixels it counts as flat and as sloped roofs (each by its weight, as the features count "
             "them; in brackets the range all but 10% of the model's training cities span), the true building "
             "share, and its building map (p(flat) + p(sloped) above 0.5) against the building masks, %.", "",
             "| space | training set | domain | flat roof pixels | sloped roof pixels | building share | IoU "
             "| precision | recall |", "|---|---|---|---|---|---|---|---|---|"]
    for space, row in result["spaces"].items():
        training = row["training"] or {}
        spans = {kind: f" [{100 * training[kind]['low']:.1f}-{100 * training[kind]['high']:.1f}]"
                 if kind in training else "" for kind in ("flat", "sloped")}
        for domain, split in row["domains"].items():
            v, t = split["validation"], split["test"]
            cells = [f"{100 * v['roof_pixels'][k]:.1f} / {100 * t['roof_pixels'][k]:.1f}{spans[k]}"
                     for k in ("flat", "sloped")]
            cells += [f"{100 * v[k]:.1f} / {100 * t[k]:.1f}" for k in ("building_share", "iou", "precision", "recall")]
            lines.append(f"| {space} | `{row['training_set']}` | {domain} | " + " | ".join(cells) + " |")
    lines += ["", f"{result['seconds'] / 60:.0f} min of wall time (finders learnt in the run included)."]
    return "\n".join(lines) + "\n"

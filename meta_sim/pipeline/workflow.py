"""Training set -> features -> NAMS and DR checkpoints (and the sbi baseline's), cached by what went in.

`meta-sim train`, `meta-sim eval` and `make demo` share this path. A cached
model is reused only when the dataset configuration, the extractor, the view
count and the training settings are all unchanged.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import NamedTuple

import torch

from ..core.cache import cache_root
from ..core.errors import MetaSimError
from ..core.locks import locked
from ..core.progress import Bars
from ..nams.model import DEFAULT_ARCHITECTURE, architecture_options
from .dataset import DatasetConfig, FeatureSet, build_features, render_training_set

# Bumped when training changes in a way no setting shows (e.g. how features are normalised).
MODEL_CODE_VERSION = 2


@dataclass(frozen=True)
class ModelSettings:
    """Everything besides the training set that decides the cached models: the NAMS architecture,
    the feature extractor spec (``features.make_extractor``) and a backbone's weights file, the
    dihedral views per tile, NAMSConfig and TrainConfig overrides, the seed, and the roof-colour
    features' settings. An unknown architecture, option or value raises MetaSimError when the
    settings are used (``key``, ``train_models``)."""

    architecture: str = DEFAULT_ARCHITECTURE  # a name from nams.ARCHITECTURES
    extractor: str = "colour-texture"
    weights: str | None = None
    views: int = 8
    nams: dict = field(default_factory=dict)  # NAMSConfig overrides (hidden sizes, z_dim, loss weights)
    train: dict = field(default_factory=dict)  # TrainConfig overrides
    seed: int = 0
    # The next four were chosen on E1/E2's validation split (bench-ablations's rows; docs/design.md,
    # "Splits"). Add the roof-colour histograms to the features (meta_sim.pipeline.roofcolour); needs the
    # tiles' labels.
    roof_colour: bool = True
    # What finds the roofs they count: roofcolour.ROOF_FINDERS (the learnt segmenter, or colour alone).
    roof_finder: str = "segmenter"
    # A pixel counts p(roof kind) ** roof_weight_power in that kind's histogram (1: the plain probability).
    roof_weight_power: float = 4.0
    # Also the roof pixels' histograms in the E1/E2 score's own colour cone (roofcolour.RoofColourExtractor).
    roof_score_cone: bool = True
    # The segmenter roof finder's training steps (None: roofsegment.STEPS); the trade study's knob for its cost.
    roof_finder_steps: int | None = None

    def check(self) -> "ModelSettings":
        """These settings, or MetaSimError for any that training would refuse (checked before any work)."""
        import math

        from ..nams import NAMSConfig, TrainConfig
        from .features import VIEW_COUNTS
        from .roofcolour import ROOF_FINDERS

        hidden = architecture_options(self.architecture, ())["hidden"]
        NAMSConfig.from_dict({"design_dim": 1, "feature_dim": 1, "hidden": hidden, **self.nams})
        TrainConfig.from_dict({"seed": self.seed, **self.train})
        if self.views not in VIEW_COUNTS:
            raise MetaSimError(f"--views must be one of {', '.join(map(str, VIEW_COUNTS))}, not {self.views}")
        if self.roof_finder not in ROOF_FINDERS:
            raise MetaSimError(f"unknown roof finder {self.roof_finder!r}; choose one of {', '.join(ROOF_FINDERS)}")
        if not (math.isfinite(self.roof_weight_power) and 0 < self.roof_weight_power <= 64):
            raise MetaSimError(f"--roof-weight-power must be above 0 and at most 64, not {self.roof_weight_power}")
        steps = self.roof_finder_steps
        if steps is not None and (isinstance(steps, bool) or not isinstance(steps, int) or not 1 <= steps <= 1_000_000):
            raise MetaSimError(f"--roof-finder-steps must be a whole number from 1 to 1000000, not {steps!r}")
        if steps is not None and not self.roof_finder.startswith("segmenter"):
            raise MetaSimError(f"--roof-finder-steps sets the segmenter's training; the {self.roof_finder!r} roof "
                               "finder has no steps")
        return self

    def key(self, dataset: DatasetConfig, extractor_id: str, generation: int = 0) -> str:
        """Names the cached models: every input, with the training and model defaults resolved, so
        that a change of a default (not only of an override) trains afresh, and the training set's tile
        ``generation`` (``tiles_generation``) when its tiles were ever rendered again."""
        from ..nams import NAMSConfig, TrainConfig

        hidden = architecture_options(self.architecture, ())["hidden"]  # an unknown name: an error here
        nams = NAMSConfig.from_dict({"design_dim": 1, "feature_dim": 1, "hidden": hidden, **self.nams}).to_dict()
        # The architecture names blocks and predictor (filled in from the design space when training);
        # keys without them stay those of the models cached before architectures existed.
        for name in ("blocks", "predictor", "colour_dims"):
            if name not in self.nams:
                del nams[name]
        train = TrainConfig.from_dict({"seed": self.seed, **self.train}).to_dict()
        inputs = {"dataset": dataset.identity(), "extractor": extractor_id, "views": self.views,
                  "nams": nams, "train": train, "seed": self.seed, "code": MODEL_CODE_VERSION}
        if generation:  # tiles rendered again under the same key: models of the older tiles are stale
            inputs["tiles_generation"] = int(generation)
        if self.architecture != "paper":  # models cached before the choice existed are the paper's
            inputs["architecture"] = self.architecture
        if self.roof_colour:  # models without it keep the keys they had before it existed
            from .roofcolour import VERSION

            inputs["roof_colour"] = VERSION
        blob = json.dumps(inputs, sort_keys=True)
        return hashlib.sha256(blob.encode()).hexdigest()[:12]


class Prepared(NamedTuple):
    """A training set's features, the seconds spent on them ("render", "features") and how many of
    its tiles this call rendered (0 when another run had rendered them all)."""

    features: FeatureSet
    seconds: dict
    tiles_rendered: int


@dataclass
class Models:
    """What ``ensure_models`` returns: the NAMS and DR checkpoint paths, the training set's features,
    and the seconds spent on each stage this time ("train_*" only when the models were trained)."""

    nams_path: Path
    dr_path: Path
    features: FeatureSet
    seconds: dict


def dataset_dir(config: DatasetConfig, root: Path | None = None) -> Path:
    """The folder of the training set ``config`` describes: ``datasets/<config.key()>`` under ``root``
    (default: the cache, ``core.cache.cache_root``). Nothing is created."""
    return Path(root or cache_root()) / "datasets" / config.key()


GENERATION_FILE = "tiles-generation"


def tiles_generation(folder: Path) -> int:
    """How many times a training set's tiles were rendered again after something had been derived from them
    (0 for a set rendered once): the models' key takes it (``ModelSettings.key``)."""
    try:
        return int((Path(folder) / GENERATION_FILE).read_text().strip())
    except (FileNotFoundError, ValueError):
        return 0


def drop_derived(folder: Path) -> int:
    """After tiles of the training set in ``folder`` were (re)rendered: delete what was derived from the tiles
    before (the features, per design and per tile, and the roof finders: every ``*.pt`` beside ``tiles/``) and
    count one more tile generation, so neither they nor models trained on them are taken for the new tiles'.
    A set whose tiles are rendered while nothing was derived yet (a first run, or one stopped while rendering)
    keeps its generation. A named sensor or scene whose look changed renders its tiles again under the same
    key (their headers no longer match); so does a space file reused under an old name. Returns the generation."""
    from ..core.fileio import write_text_atomic

    folder = Path(folder)
    derived = sorted(folder.glob("*.pt"))
    generation = tiles_generation(folder)
    if not derived:
        return generation
    for path in derived:
        path.unlink(missing_ok=True)
    generation += 1
    write_text_atomic(folder / GENERATION_FILE, f"{generation}\n")
    return generation


def prepare_features(config: DatasetConfig, settings: ModelSettings, root: Path | None = None,
                     bars: Bars | None = None) -> tuple[FeatureSet, dict]:
    """Render what is missing of the training set and compute what is missing of its features.

    With ``settings.roof_colour`` the roof finder is learnt first (once per training set) and the
    features end in its roof-colour histograms. Returns them as ``Prepared``; ``bars`` makes a
    progress bar per stage. Another process preparing the same set holds its lock until it is done.
    Raises MetaSimError for an unknown space, preset, extractor or roof finder, a missing ``bpy``
    while tiles are missing, or an unreadable tile.
    """

    folder = dataset_dir(config, root)
    with locked(folder):  # another process preparing the same set: wait for it, then find its work done
        return _prepare_features(folder, config, settings, bars)


def render_tiles(folder: Path, config: DatasetConfig, bars: Bars | None = None) -> int:
    """Render (or finish) the training set's tiles in ``folder``/tiles; when any tile was written, the files
    derived from older tiles are dropped (``drop_derived``). Returns how many tiles this call wrote."""
    _, summary = render_training_set(folder, config,
                                     bars("render training set", config.designs * config.tiles) if bars else None)
    if summary.written:
        drop_derived(folder)
    return summary.written


def _prepare_features(folder: Path, config: DatasetConfig, settings: ModelSettings,
                      bars: Bars | None) -> tuple[FeatureSet, dict]:
    from .features import make_extractor

    seconds = {}
    started = time.perf_counter()
    written = render_tiles(folder, config, bars)
    seconds["render"] = time.perf_counter() - started
    extractor = make_extractor(settings.extractor, Path(settings.weights) if settings.weights else None)
    started = time.perf_counter()
    if settings.roof_colour:
        from .dataset import training_tiles
        from .roofcolour import RoofColourExtractor, ensure_roof_finder

        paths = training_tiles(folder, config)
        if settings.roof_finder.startswith("segmenter"):
            from .roofsegment import STEPS

            progress = bars("roof segmenter", settings.roof_finder_steps or STEPS) if bars else None
        else:
            progress = bars("roof colours", len(paths)) if bars else None
        finder = ensure_roof_finder(folder, paths, settings.roof_finder, settings.seed, progress,
                                    settings.roof_finder_steps)
        extractor = RoofColourExtractor(extractor, finder,
                                        settings.roof_weight_power, settings.roof_score_cone)
    features = build_features(folder, config, extractor, settings.views,
                              bars("features", config.designs) if bars else None)
    seconds["features"] = time.perf_counter() - started
    return Prepared(features, seconds, written)


def train_models(features: FeatureSet, out_dir: Path, settings: ModelSettings, dataset: DatasetConfig,
                 bars: Bars | None = None, kinds: tuple[str, ...] = ("nams", "dr")) -> dict:
    """Train NAMS and the DR baseline (``kinds``: those of them) on a feature set; write ``nams.pt`` and
    ``dr.pt`` into ``out_dir`` and return the seconds each took ("train_nams", "train_dr"). Each model is
    seeded on its own, so one trained alone is the one trained beside the other.

    ``dataset`` is recorded in the checkpoints (tile size and pixel size are what inference cuts
    targets to). Raises MetaSimError for an unknown architecture or an invalid NAMS or training
    option, or when training fails (see ``nams.train.train_nams``).
    """
    from ..nams import NAMSConfig, TrainConfig, save_checkpoint, train_dr, train_nams

    torch.manual_seed(settings.seed)
    train_config = TrainConfig.from_dict({"seed": settings.seed, **settings.train})
    architecture = architecture_options(settings.architecture, features.space.widths())
    nams_config = NAMSConfig.from_dict({"design_dim": features.encoded.shape[1],
                                        "feature_dim": features.features.shape[1], **architecture, **settings.nams})
    seconds = {}
    out_dir = Path(out_dir)
    # DR keeps per-feature standardisation: whitening is there for the search's metric, and DR
    # has no search (it is the paper's baseline as the paper trained it; its E1/E2 rows come from `make bench-nams`).
    jobs = (("nams", train_nams, nams_config, train_config),
            ("dr", train_dr, None, dataclasses.replace(train_config, whiten=0)))
    for kind, trainer, config, trainer_config in jobs:
        if kind not in kinds:
            continue
        update = bars(f"train {kind}", train_config.max_epochs) if bars else None
        started = time.perf_counter()
        fit = trainer(features.encoded, features.features, config, trainer_config,
                      (lambda report, update=update: update(1)) if update else None, features.hist_blocks)
        seconds[f"train_{kind}"] = time.perf_counter() - started
        extra = {"designs": len(features.names), "views": features.views,
                 "extractor_spec": settings.extractor, "seconds": seconds[f"train_{kind}"],
                 "tile_px": dataset.tile_px, "pixel_size_m": dataset.pixel_size_m, "dataset": asdict(dataset)}
        if features.roof_likelihood is not None:
            from .roofcolour import training_evidence

            extra["roof_likelihood"] = features.roof_likelihood
            extra["roof_evidence"] = training_evidence(features.features, features.hist_blocks)
        save_checkpoint(out_dir / f"{kind}.pt", kind, fit.model, fit.model.config, features.space.to_dict(),
                        fit.norm, features.extractor_id, extra=extra, history=fit.history)
    return seconds


def ensure_models(config: DatasetConfig, settings: ModelSettings, root: Path | None = None,
                  bars: Bars | None = None) -> Models:
    """The cached NAMS and DR checkpoints for these inputs, trained first if they are missing.

    Renders and computes features as ``prepare_features`` does, then looks in ``models/<key>``
    under ``root`` (default: the cache) for checkpoints keyed by every input
    (``ModelSettings.key``); one that is missing or unreadable is trained again (``train_models``), so a run
    stopped between the two keeps the one it finished. Returns their paths, the features and the seconds spent. Raises
    MetaSimError as ``prepare_features`` and ``train_models`` do.
    """
    from ..nams import load_checkpoint

    features, seconds, _ = prepare_features(config, settings, root, bars)
    generation = tiles_generation(dataset_dir(config, root))
    folder = Path(root or cache_root()) / "models" / settings.key(config, features.extractor_id, generation)
    paths = {kind: folder / f"{kind}.pt" for kind in ("nams", "dr")}
    with locked(folder):
        missing = []
        for kind, path in paths.items():
            try:
                load_checkpoint(path, kind)
            except MetaSimError:
                missing.append(kind)
        if missing:
            seconds.update(train_models(features, folder, settings, config, bars, kinds=tuple(missing)))
    return Models(paths["nams"], paths["dr"], features, seconds)


# Bumped when the sbi baseline's training changes in a way its settings do not show.
NRE_CODE_VERSION = 1


def nre_settings(settings: ModelSettings) -> tuple[dict, object]:
    """The sbi baseline's classifier options (without the sizes, which the features decide) and its
    ``NRETrainConfig``: the defaults of ``nams.nre``, seeded by ``settings.seed``."""
    from ..nams.nre import NREConfig, NRETrainConfig

    classifier = {k: v for k, v in NREConfig(design_dim=1, feature_dim=1).to_dict().items()
                  if k not in ("design_dim", "feature_dim")}
    return classifier, NRETrainConfig(seed=settings.seed)


def train_nre_checkpoint(features: FeatureSet, nams, path: Path, settings: ModelSettings,
                         dataset: DatasetConfig, bars: Bars | None = None) -> float:
    """Train the sbi baseline on a training set's features, normalised by the NAMS checkpoint ``nams``
    (the features NAMS searches in), and write its checkpoint to ``path``; returns the seconds training
    took; ``bars`` makes a progress bar of its epochs. Raises MetaSimError as ``nams.nre.train_nre`` does."""
    from ..nams import save_checkpoint
    from ..nams.nre import KIND, NREConfig, train_nre

    classifier, train_config = nre_settings(settings)
    normed = nams.feature_norm.apply(features.features)
    fit = train_nre(features.encoded, normed, features.space,
                    NREConfig(design_dim=features.encoded.shape[1], feature_dim=normed.shape[1], **classifier),
                    train_config, bars(f"train {KIND}", train_config.max_epochs) if bars else None)
    seconds = fit.history["seconds"]
    extra = {"designs": len(features.names), "views": features.views, "extractor_spec": settings.extractor,
             "seconds": seconds, "tile_px": dataset.tile_px, "pixel_size_m": dataset.pixel_size_m,
             "dataset": asdict(dataset), "nams_model_id": nams.model_id}
    save_checkpoint(path, fit.model.kind, fit.model, fit.model.config, features.space.to_dict(), nams.feature_norm,
                    features.extractor_id, extra=extra, history=fit.history)
    return seconds


def ensure_nre(models: Models, dataset: DatasetConfig, settings: ModelSettings,
               bars: Bars | None = None) -> tuple[Path, dict]:
    """The cached sbi baseline for the models ``ensure_models`` returned, trained first if it is missing
    or unreadable (``train_nre_checkpoint``).

    It lies beside them, named by its own settings and code version, so it is keyed by every input
    theirs is (the training set, the extractor, the NAMS normalisation it reuses) and by its own.
    Returns its path and the seconds spent ("train_sbi_nre" only when it was trained now). Raises
    MetaSimError for a design space the baseline cannot enumerate, without the ``sbi`` package, or as
    training does.
    """
    from ..nams import load_checkpoint
    from ..nams.nre import KIND, check_space

    nams = load_checkpoint(models.nams_path, "nams")
    check_space(nams.space)
    classifier, train_config = nre_settings(settings)
    blob = json.dumps({"classifier": classifier, "train": train_config.to_dict(), "code": NRE_CODE_VERSION},
                      sort_keys=True)
    path = models.nams_path.parent / f"{KIND}-{hashlib.sha256(blob.encode()).hexdigest()[:8]}.pt"
    with locked(path.parent):
        try:
            load_checkpoint(path, KIND)
            return path, {}
        except MetaSimError:
            return path, {f"train_{KIND}": train_nre_checkpoint(models.features, nams, path, settings, dataset, bars)}

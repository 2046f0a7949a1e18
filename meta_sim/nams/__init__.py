"""The torch side of NAMS: networks (``model``), training and checkpoints (``train``,
``checkpoint``), design inference (``search``), and the MS2 and sbi baselines (``ms2``, ``nre``).
Never imports bpy."""

from .checkpoint import Checkpoint, load_checkpoint, model_id, save_checkpoint
from .model import (
    ARCHITECTURES,
    DEFAULT_ARCHITECTURE,
    NAMS,
    DirectRegression,
    DRConfig,
    NAMSConfig,
    architecture_options,
    build_model,
)
from .ms2 import MS2Config, ms2_search
from .norm import FeatureNorm
from .nre import NREConfig, NRETrainConfig, RatioClassifier, nre_predict, train_nre
from .search import (
    PLAIN_COLOUR,
    ColourComparison,
    RoofMatch,
    SearchResult,
    adjoint_search,
    design_losses,
    design_table,
    dr_predict,
    exhaustive_search,
    near_designs,
    search,
    time_search,
    uniform_predict,
)
from .train import EpochReport, Fit, TrainConfig, train_dr, train_nams

__all__ = [
    "ARCHITECTURES", "DEFAULT_ARCHITECTURE", "architecture_options", "Checkpoint", "ColourComparison", "DRConfig",
    "DirectRegression", "EpochReport", "FeatureNorm", "Fit", "MS2Config", "NAMS", "NAMSConfig", "NREConfig",
    "NRETrainConfig", "PLAIN_COLOUR", "RatioClassifier", "RoofMatch", "SearchResult", "TrainConfig", "adjoint_search",
    "build_model",
    "design_losses", "design_table", "dr_predict", "exhaustive_search", "load_checkpoint", "model_id", "ms2_search",
    "near_designs", "nre_predict", "save_checkpoint", "search", "time_search", "train_dr", "train_nams", "train_nre",
    "uniform_predict",
]

"""The torch side of NAMS: networks (``model``), training and checkpoints (``train``,
``checkpoint``), and design inference (``search``). Never imports bpy."""

from .checkpoint import Checkpoint, load_checkpoint, model_id, save_checkpoint
from .model import DirectRegression, DRConfig, NAMS, NAMSConfig, build_model
from .train import EpochReport, FeatureNorm, Fit, TrainConfig, train_dr, train_nams

__all__ = [
    "Checkpoint", "DRConfig", "DirectRegression", "EpochReport", "FeatureNorm", "Fit", "NAMS", "NAMSConfig",
    "TrainConfig", "build_model", "load_checkpoint", "model_id", "save_checkpoint", "train_dr", "train_nams",
]

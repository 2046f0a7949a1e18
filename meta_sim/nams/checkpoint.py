"""The checkpoint file: the one reader and writer of trained NAMS / DR models.

A checkpoint is ``torch.save`` of a dict holding only tensors and plain Python
values, so it loads with ``torch.load(path, weights_only=True)`` (no pickled
code is ever executed):

    format          "meta-sim-checkpoint"
    format_version  2
    kind            "nams", "dr" or "sbi_nre" (the sbi baseline's ratio classifier, ``nre``)
    model_config    NAMSConfig / DRConfig / NREConfig as a dict
    state_dict      the model's tensors (NAMS: also the buffers z_mean, z_std,
                    feature_scale)
    space           the design space (DesignSpace.to_dict())
    feature_norm    FeatureNorm.to_dict() (mean, std, and any whitening and
                    histogram blocks)
    extractor_id    which feature extractor made the training features
    history         training history (plain values)
    extra           anything else the caller wants kept (plain values)
    digest          sha256 over all of the above: a flipped byte in a tensor
                    would otherwise load silently

Files are written to a temporary file beside the target and moved into place,
so a reader never sees half a checkpoint. The ``model_id`` of a checkpoint is
the first 12 hex digits of the sha256 of its bytes (presets cite it).
"""

from __future__ import annotations

import hashlib
import io
import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Mapping

import torch

from ..core.errors import MetaSimError
from ..core.fileio import write_bytes_atomic
from ..sim.design import DesignSpace
from .model import MODELS, NAMS, DirectRegression, build_model
from .norm import FeatureNorm
from .nre import KIND as NRE_KIND
from .nre import NREConfig, RatioClassifier

# Every kind a checkpoint holds: the networks of model.py, and the sbi baseline's classifier.
KINDS = (*MODELS, NRE_KIND)

FORMAT = "meta-sim-checkpoint"
FORMAT_VERSION = 2


@dataclass
class Checkpoint:
    """A loaded, verified checkpoint (``load_checkpoint``): the model in eval mode, the design space and
    feature normalisation it was trained with, and ``model_id``, which presets cite."""

    kind: str
    model: NAMS | DirectRegression | RatioClassifier
    space: DesignSpace
    feature_norm: FeatureNorm
    extractor_id: str
    history: dict
    extra: dict
    model_id: str


def save_checkpoint(path: str | Path, kind: str, model: NAMS | DirectRegression | RatioClassifier, config,
                    space_dict: Mapping, feature_norm: FeatureNorm, extractor_id: str, extra: Mapping | None = None,
                    history: Mapping | None = None) -> str:
    """Write a checkpoint atomically and return its model_id.

    ``config`` is the model's config (dataclass or dict) and must be the one
    the model was built with; ``extra`` and ``history`` hold plain values only.
    """
    if kind not in KINDS or getattr(model, "kind", None) != kind:
        raise ValueError(f"kind {kind!r} does not match the model ({type(model).__name__})")
    config_dict = config.to_dict() if hasattr(config, "to_dict") else dict(config)
    if config_dict != model.config.to_dict():
        raise ValueError("config is not the config the model was built with")
    space = DesignSpace.from_dict(space_dict)
    if space.dim != model.config.design_dim:
        raise ValueError(f"the space encodes to {space.dim} values; the model has design_dim "
                         f"{model.config.design_dim}")
    payload = {
        "format": FORMAT,
        "format_version": FORMAT_VERSION,
        "kind": kind,
        "model_config": config_dict,
        "state_dict": {name: t.detach().cpu().clone() for name, t in model.state_dict().items()},
        "space": space.to_dict(),
        "feature_norm": feature_norm.to_dict(),
        "extractor_id": str(extractor_id),
        "history": _plain(dict(history or {}), "history"),
        "extra": _plain(dict(extra or {}), "extra"),
    }
    payload["digest"] = _digest(payload)
    buffer = io.BytesIO()
    torch.save(payload, buffer)
    data = buffer.getvalue()
    write_bytes_atomic(path, data)
    return _model_id(data)


def load_checkpoint(path: str | Path, kind: str | None = None) -> Checkpoint:
    """Read and verify a checkpoint; the model comes back in eval mode.

    ``kind`` ("nams", "dr" or "sbi_nre"), when given, must match the file. An "sbi_nre" checkpoint
    needs the ``sbi`` package (MetaSimError naming the extra without it).
    """
    path = Path(path)
    try:
        data = path.read_bytes()
    except FileNotFoundError:
        raise MetaSimError(f"checkpoint {path} not found; train one first (or check the path)") from None
    except OSError as exc:
        raise MetaSimError(f"cannot read checkpoint {path}: {exc.strerror or exc}") from None
    try:
        payload = torch.load(io.BytesIO(data), map_location="cpu", weights_only=True)
    except Exception as exc:  # torch raises many types for a damaged zip / pickle; all mean "corrupt"
        raise MetaSimError(f"{path} is not a readable meta-sim checkpoint (corrupt or not a checkpoint: "
                           f"{type(exc).__name__})") from None
    if not isinstance(payload, dict) or payload.get("format") != FORMAT:
        raise MetaSimError(f"{path} is not a meta-sim checkpoint")
    version = payload.get("format_version")
    if version != FORMAT_VERSION:
        raise MetaSimError(f"{path} has checkpoint format version {version!r}; this meta-sim reads version "
                           f"{FORMAT_VERSION} (retrain, or use the meta-sim release that wrote it)")
    if payload.get("digest") != _digest({k: v for k, v in payload.items() if k != "digest"}):
        raise MetaSimError(f"{path} is corrupt (its contents do not match their checksum); retrain or "
                           f"copy it again")
    found = payload.get("kind")
    if kind is not None and found != kind:
        raise MetaSimError(f"{path} is a {found!r} checkpoint; this needs a {kind!r} checkpoint")
    try:
        model = _build(found, payload["model_config"])
        model.load_state_dict(payload["state_dict"])
    except _DAMAGED as exc:
        raise MetaSimError(f"{path}: the model does not match its config ({type(exc).__name__})") from None
    model.eval()
    space = DesignSpace.from_dict(payload["space"])
    if space.dim != model.config.design_dim:
        raise MetaSimError(f"{path}: its design space does not match its model")
    if getattr(model.config, "blocks", ()) and list(model.config.blocks) != space.widths():
        raise MetaSimError(f"{path}: its model's parameter blocks do not match its design space")
    try:
        norm = FeatureNorm.from_dict(payload["feature_norm"])
    except _DAMAGED as exc:
        raise MetaSimError(f"{path}: its feature normalisation is damaged ({type(exc).__name__})") from None
    _check_metadata(path, payload)
    feature_dim = model.config.feature_dim
    if norm.dim != feature_dim:
        raise MetaSimError(f"{path}: its feature normalisation does not match its model")
    return Checkpoint(kind=found, model=model, space=space, feature_norm=norm,
                      extractor_id=payload["extractor_id"], history=payload["history"],
                      extra=payload["extra"], model_id=_model_id(data))


def _build(kind, config) -> NAMS | DirectRegression | RatioClassifier:
    if kind == NRE_KIND:
        return RatioClassifier(NREConfig.from_dict(config))
    return build_model(kind, config)


# What a damaged (but checksummed) structure raises while it is rebuilt: all mean "not usable".
_DAMAGED = (KeyError, RuntimeError, TypeError, ValueError, AttributeError, IndexError, OverflowError)
# Settings inference reads from ``extra``: (check, what a valid value is).
_EXTRA = {"tile_px": (lambda v: isinstance(v, int) and not isinstance(v, bool) and 16 <= v <= 8192, "16..8192 px"),
          "pixel_size_m": (lambda v: isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
                           and 0 < v < 1e5, "a positive number of metres"),
          "views": (lambda v: v in (1, 2, 4, 8) and not isinstance(v, bool), "1, 2, 4 or 8")}


def _check_metadata(path: Path, payload: dict) -> None:
    if not isinstance(payload.get("extractor_id"), str):
        raise MetaSimError(f"{path}: its extractor id is damaged; retrain")
    for name in ("history", "extra"):
        if not isinstance(payload.get(name), dict):
            raise MetaSimError(f"{path}: its {name} is damaged; retrain")
    for key, (valid, what) in _EXTRA.items():
        if key in payload["extra"] and not valid(payload["extra"][key]):
            raise MetaSimError(f"{path}: extra.{key} must be {what}, not {payload['extra'][key]!r}")


def model_id(path: str | Path) -> str:
    """The model_id of a checkpoint file, without loading it."""
    try:
        return _model_id(Path(path).read_bytes())
    except FileNotFoundError:
        raise MetaSimError(f"checkpoint {path} not found") from None


def _model_id(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()[:12]


_PLAIN = (str, int, float, bool, type(None))


def _plain(value, where: str):
    """``value`` if it holds only what ``weights_only`` loading accepts; else a TypeError naming the path."""
    if isinstance(value, _PLAIN) or isinstance(value, torch.Tensor):
        return value
    if isinstance(value, (list, tuple)):
        return [_plain(v, f"{where}[{i}]") for i, v in enumerate(value)]
    if isinstance(value, Mapping):
        if not all(isinstance(k, str) for k in value):
            raise TypeError(f"{where}: checkpoint dict keys must be strings")
        return {k: _plain(v, f"{where}.{k}") for k, v in value.items()}
    raise TypeError(f"{where}: {type(value).__name__} cannot go into a checkpoint (plain values and tensors only)")


def _digest(payload: Mapping) -> str:
    h = hashlib.sha256()
    _feed(h, payload)
    return h.hexdigest()


def _feed(h, value) -> None:
    """Hash a nested value canonically: dict keys sorted, tensors by dtype, shape and bytes."""
    if isinstance(value, torch.Tensor):
        t = value.detach().cpu().contiguous().reshape(-1)
        h.update(f"T{t.dtype}{tuple(value.shape)}".encode())
        h.update(t.view(torch.uint8).numpy().tobytes())
    elif isinstance(value, Mapping):
        h.update(b"{")
        for key in sorted(value):
            h.update(json.dumps(key).encode())
            _feed(h, value[key])
        h.update(b"}")
    elif isinstance(value, (list, tuple)):
        h.update(b"[")
        for item in value:
            _feed(h, item)
        h.update(b"]")
    else:
        h.update(json.dumps(value).encode())

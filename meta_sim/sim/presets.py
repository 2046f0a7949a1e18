"""Design presets: what `meta-sim infer` writes and the Blender add-on reads.

A preset is JSON data, never code. Two kinds:

* ``group``: the design inferred for one group of target images::

    {"format": "meta-sim-design-preset", "version": 1, "kind": "group",
     "name": "kampala-000", "design_space": "rooftops-v1",
     "design": {"flat_roof": "flat-gravel-light", "sloped_roof": "sloped-clay-red"},
     "vote_shares": {"flat_roof": {"flat-gravel-light": 0.62, ...}, ...},
     "search": {"method": "adjoint", "loss": 0.41, ...},
     "source_images": ["a.png", ...], "model_id": "3f2a9c0d1e2b"}

* ``population``: the distribution of the designs inferred for all groups
  (``distribution``: parameter -> choice -> share, and ``designs``: each
  distinct design with its count), to sample the next dataset from.

Pure Python: no torch, no bpy.
"""

from __future__ import annotations

import json
import math
import os
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Mapping

from ..core.errors import MetaSimError
from ..core.fileio import write_text_atomic
from .design import DesignSpace

FORMAT = "meta-sim-design-preset"
VERSION = 1
KINDS = ("group", "population")
ROOF_KINDS = ("flat", "sloped")  # the roof evidence a group preset may record


@dataclass
class DesignPreset:
    kind: str
    name: str
    design_space: str
    design: dict
    vote_shares: dict = field(default_factory=dict)
    search: dict = field(default_factory=dict)
    source_images: list = field(default_factory=list)
    model_id: str = ""
    distribution: dict = field(default_factory=dict)  # population only
    designs: list = field(default_factory=list)  # population only: [{"design": ..., "count": n}]

    def confidence(self, parameter: str) -> float:
        """The vote share of the chosen value of ``parameter`` (1.0 when no votes were recorded)."""
        shares = self.vote_shares.get(parameter) or self.distribution.get(parameter) or {}
        return float(shares.get(str(self.design.get(parameter)), 1.0 if not shares else 0.0))

    def roof_evidence(self) -> dict:
        """Roof kind -> ``{"share", "range", "outside"}`` from a group preset's search: the share of the
        group's pixels the roof finder counted as roofs of that kind (``roof_pixels_<kind>``), the range
        the model's training cities span but for a few at either end (``roof_pixels_low_<kind>`` and
        ``roof_pixels_high_<kind>``; None when the model did not record one), and "low" or "high" when
        the share is outside it (else None). Empty when the preset records no roof evidence; values that
        are not shares in [0, 1] are left out."""
        out = {}
        for kind in ROOF_KINDS:
            share = self.search.get(f"roof_pixels_{kind}")
            if not _share(share):
                continue
            low, high = (self.search.get(f"roof_pixels_{end}_{kind}") for end in ("low", "high"))
            span = (float(low), float(high)) if _share(low) and _share(high) and low <= high else None
            outside = None if span is None else "low" if share < span[0] else "high" if share > span[1] else None
            out[kind] = {"share": float(share), "range": span, "outside": outside}
        return out

    def common_folder(self) -> str | None:
        """The folder the preset's images share ('' for bare file names); None when none is recorded or
        absolute and relative paths are mixed."""
        images = [str(p) for p in self.source_images]
        if not images:
            return None
        try:
            return os.path.commonpath(images) if len(images) > 1 else os.path.dirname(images[0])
        except ValueError:  # absolute and relative paths mixed
            return None

    def target(self) -> str:
        """Where the preset's images came from: how many, and their common folder."""
        images = self.source_images
        if not images:
            return "no target images recorded"
        common = self.common_folder()
        common = "several folders" if common is None else common
        return f"{len(images)} image{'s' if len(images) != 1 else ''} in {common or '.'}"

    def to_dict(self) -> dict:
        out = {"format": FORMAT, "version": VERSION, "kind": self.kind, "name": self.name,
               "design_space": self.design_space, "design": self.design,
               "vote_shares": self.vote_shares, "search": self.search,
               "source_images": [str(p) for p in self.source_images], "model_id": self.model_id}
        if self.kind == "population":
            out["distribution"] = self.distribution
            out["designs"] = self.designs
        return out

    @classmethod
    def from_dict(cls, data, space: DesignSpace | None = None, extra: Mapping | None = None) -> "DesignPreset":
        """Validate a preset read from disk; ``space`` checks every id against the design space."""
        if not isinstance(data, Mapping) or data.get("format") != FORMAT:
            raise MetaSimError(f"not a meta-sim design preset (expected \"format\": \"{FORMAT}\")")
        version = data.get("version")
        if not isinstance(version, int) or version < 1:
            raise MetaSimError(f"preset version {version!r} is not valid")
        if version > VERSION:
            raise MetaSimError(f"preset version {version} is newer than this meta-sim reads ({VERSION}); "
                               "update meta-sim")
        kind = data.get("kind")
        if kind not in KINDS:
            raise MetaSimError(f"preset kind {kind!r} must be one of {', '.join(KINDS)}")
        design = data.get("design")
        if not isinstance(design, Mapping) or not design:
            raise MetaSimError("preset has no design")
        preset = cls(kind=kind, name=_text(data, "name"), design_space=_text(data, "design_space"),
                     design=_design(design, "design"), vote_shares=_shares(data, "vote_shares"),
                     search=_plain_mapping(data, "search"), source_images=_source_images(data),
                     model_id=_text(data, "model_id"), distribution=_shares(data, "distribution"),
                     designs=_designs(data))
        if space is not None:
            try:
                preset.design = space.validate(preset.design, extra)
            except MetaSimError as exc:
                raise MetaSimError(f"preset {preset.name!r} does not fit design space {space.name!r}: {exc}") from None
        return preset


MAX_TEXT = 1000
MAX_ITEMS = 100_000


def _mapping(data: Mapping, key: str) -> dict:
    value = data.get(key) or {}
    if not isinstance(value, Mapping):
        raise MetaSimError(f"preset field {key!r} must be an object")
    return dict(value)


def _text(data: Mapping, key: str) -> str:
    value = data.get(key, "")
    if not isinstance(value, str) or len(value) > MAX_TEXT:
        raise MetaSimError(f"preset field {key!r} must be a string of at most {MAX_TEXT} characters")
    return value


def _scalar(value, where: str):
    """A design value: an id (string) or a finite number."""
    if isinstance(value, str) and len(value) <= MAX_TEXT:
        return value
    if isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value):
        return value
    raise MetaSimError(f"preset field {where} must be an id or a finite number, not {value!r}")


def _design(value, where: str) -> dict:
    if not isinstance(value, Mapping) or not value:
        raise MetaSimError(f"preset field {where} must be a non-empty object")
    return {str(k): _scalar(v, f"{where}.{k}") for k, v in value.items()}


def _shares(data: Mapping, key: str) -> dict:
    """parameter -> choice -> share in [0, 1]."""
    out = {}
    for param, shares in _mapping(data, key).items():
        if not isinstance(shares, Mapping):
            raise MetaSimError(f"preset field {key}.{param} must map choices to shares")
        for choice, share in shares.items():
            if isinstance(share, bool) or not isinstance(share, (int, float)) or not 0 <= share <= 1:
                raise MetaSimError(f"preset field {key}.{param}.{choice} must be a share in [0, 1], not {share!r}")
        out[str(param)] = {str(c): float(s) for c, s in shares.items()}
    return out


def _plain_mapping(data: Mapping, key: str) -> dict:
    """An object of strings, finite numbers, booleans and None (the search's settings and loss)."""
    out = _mapping(data, key)
    for name, value in out.items():
        if not (value is None or isinstance(value, (str, bool)) or
                (isinstance(value, (int, float)) and math.isfinite(value))):
            raise MetaSimError(f"preset field {key}.{name} must be a string, a finite number or null")
    return out


def _share(value) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and 0 <= value <= 1


def _source_images(data: Mapping) -> list:
    value = data.get("source_images") or []
    if not isinstance(value, list) or len(value) > MAX_ITEMS or not all(
            isinstance(p, str) and 0 < len(p) <= MAX_TEXT for p in value):
        raise MetaSimError("preset field 'source_images' must be a list of paths")
    return list(value)


def _designs(data: Mapping) -> list:
    value = data.get("designs") or []
    if not isinstance(value, list) or len(value) > MAX_ITEMS:
        raise MetaSimError("preset field 'designs' must be a list")
    out = []
    for index, entry in enumerate(value):
        count = entry.get("count") if isinstance(entry, Mapping) else None
        if isinstance(count, bool) or not isinstance(count, int) or count < 1:
            raise MetaSimError(f"preset field designs[{index}] must hold a design and a count of at least 1")
        out.append({"design": _design(entry.get("design"), f"designs[{index}].design"), "count": count})
    return out


def save_preset(path: str | Path, preset: DesignPreset) -> Path:
    """Write atomically (temporary file, then rename)."""
    return write_text_atomic(path, json.dumps(preset.to_dict(), indent=2) + "\n")


def load_preset(path: str | Path, space: DesignSpace | None = None, extra: Mapping | None = None) -> DesignPreset:
    path = Path(path)
    try:
        data = json.loads(path.read_text())
    except FileNotFoundError:
        raise MetaSimError(f"preset {path} does not exist") from None
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise MetaSimError(f"preset {path} is not valid JSON ({exc})") from None
    try:
        return DesignPreset.from_dict(data, space, extra)
    except MetaSimError as exc:
        raise MetaSimError(f"{path}: {exc}") from None


def population(presets: list[DesignPreset], space: DesignSpace, name: str, model_id: str = "",
               near: list[dict] | None = None, near_per_group: int = 0) -> DesignPreset:
    """The distribution of the groups' designs; its own design is the most common value per parameter.
    Its ``designs`` (what `render --population` samples) are the groups' designs, or with ``near`` those
    designs instead (each group's ``near_per_group`` best-ranked designs of the search, ``nams.near_designs``)."""
    if not presets:
        raise MetaSimError("a population needs at least one group preset")
    if near is not None and not near:
        raise MetaSimError("a population drawn from near designs needs at least one")
    distribution, design = {}, {}
    for param in space.names:
        counts = Counter(str(p.design[param]) for p in presets)
        distribution[param] = {value: n / len(presets) for value, n in counts.most_common()}
        design[param] = next(p.design[param] for p in presets if str(p.design[param]) == counts.most_common(1)[0][0])
    combos = Counter(json.dumps(d, sort_keys=True) for d in (near if near is not None else
                                                            [p.design for p in presets]))
    return DesignPreset(kind="population", name=name, design_space=space.name, design=design,
                        vote_shares=distribution, distribution=distribution,
                        designs=[{"design": json.loads(k), "count": n} for k, n in combos.most_common()],
                        source_images=sorted({s for p in presets for s in p.source_images}),
                        model_id=model_id, search={"groups": len(presets),
                                                   **({"near": near_per_group} if near is not None else {})})

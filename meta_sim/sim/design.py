"""The design space: which scene parameters a design sets, and their values.

A design space is declared in a versioned JSON file (see ``meta_sim/sim/spaces``):

    {"format": "meta-sim-design-space", "version": 1, "name": "rooftops",
     "parameters": [
        {"name": "flat_roof", "type": "categorical", "texture_kind": "flat",
         "choices": ["flat-gravel-light", ...]},
        {"name": "building_density", "type": "continuous", "low": 0.3, "high": 0.9,
         "layout_field": "building_density"}],
     "layout": {"sloped_share": 0.0}}

A categorical parameter with ``texture_kind`` sets the material of every roof
of that kind; its ``choices`` may be ``{"all": KIND}``, KIND its ``texture_kind``:
every texture of that kind in the default bank, in the bank's manifest order
(``textures.procedural.recipes(KIND)``: known without building the bank or bpy).
Loading expands it, so ``to_dict`` always lists the ids. A parameter with
``layout_field`` sets that field of the city layout (a number, or a categorical
choice such as a city style); a parameter with ``appearance`` sets a field of
``sim.appearance`` (ground cover, sensor, greenness, sun elevation, brightness,
roof jitter, ground albedo). ``layout`` holds fixed layout overrides the scene
needs (a space without sloped roofs builds none).

A space may extend a shipped one and declare only its differences:

    {"format": "meta-sim-design-space", "version": 1, "name": "my-towns",
     "extends": "overhead-v2",
     "remove": ["style"],
     "parameters": [
        {"name": "building_density", "type": "continuous", "low": 0.05, "high": 1.0,
         "layout_field": "building_density"},
        {"name": "open_share", "type": "continuous", "low": 0.0, "high": 0.3,
         "layout_field": "open_share", "after": "building_density"}],
     "layout": {"style": "dense", "roof_furniture": null}}

- ``extends`` names a space meta-sim ships (``builtin_spaces()``), never a path; the base
  may extend another, at most ``MAX_EXTENDS`` steps deep, and no space may come back in its
  own chain. The result is the base's parameters and layout with these changes, in order:
- ``remove`` drops the base's parameters of those names (each must exist in the base).
- each entry of ``parameters`` is a whole parameter: one of the base's name replaces it
  where it stands, a new name goes at the end; ``"after": NAME`` places it right after
  NAME instead (a parameter of the base or one placed before it in this list).
- ``layout`` is merged key by key: a value replaces the base's or adds a key at the end,
  ``null`` drops the base's key.
- ``name`` is this space's own (never inherited); ``format`` and ``version`` are required
  as in any space. ``remove`` and ``"after"`` need ``extends``.

Every key is checked: an unknown key, a name to remove or place after that the base lacks,
or a parameter given twice is one MetaSimError saying what to fix.

A design is a plain ``dict``: parameter name -> choice id (categorical) or
float (continuous). Encoding concatenates a one-hot block per categorical
parameter and one value in [0, 1] per continuous parameter, in declaration
order: the default space encodes to the paper's 40 + 44 = 84-D vector.

Pure Python and numpy: imported by the add-on, the renderer and the torch side.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Iterable, Mapping

import numpy as np

from ..core.errors import MetaSimError
from ..core.names import MAX_NAME, safe_name
from .appearance import check_field
from .space_names import DEFAULT_SPACE, SPACES_DIR, builtin_spaces
from .textures.procedural import KINDS, recipes

FORMAT = "meta-sim-design-space"
VERSION = 1
MAX_EXTENDS = 4  # a space, its base, ... : a chain of at most this many "extends"
_SPACE_KEYS = ("format", "version", "name", "extends", "remove", "parameters", "layout")
_PARAMETER_KEYS = {
    "categorical": ("name", "type", "choices", "texture_kind", "layout_field", "appearance"),
    "continuous": ("name", "type", "low", "high", "layout_field", "appearance"),
}


@dataclass(frozen=True)
class Categorical:
    name: str
    choices: tuple[str, ...]
    texture_kind: str | None = None
    layout_field: str | None = None  # the layout field set to the choice (a city style)
    appearance: str | None = None  # the appearance field set to the choice (sim.appearance)

    @property
    def width(self) -> int:
        return len(self.choices)

    def resolve(self, value, extra: Iterable[str] = ()) -> str:
        """A choice id from an id or a 0-based index (int or digit string).

        ``extra`` ids are accepted as well (held-out textures may be rendered,
        though they cannot be encoded).
        """
        if isinstance(value, (int, np.integer)) or (isinstance(value, str) and value.isascii() and value.isdigit()):
            index = int(value)
            if not 0 <= index < len(self.choices):
                raise MetaSimError(
                    f"{self.name}: index {index} is out of range; use 0..{len(self.choices) - 1} "
                    f"or a choice id such as {self.choices[0]!r}")
            return self.choices[index]
        if isinstance(value, str) and (value in self.choices or value in set(extra)):
            return value
        raise MetaSimError(
            f"{self.name}: unknown choice {value!r}; use a 0-based index or one of "
            f"{_preview(self.choices)} (`meta-sim textures list` shows all)")

    def to_dict(self) -> dict:
        out = {"name": self.name, "type": "categorical", "choices": list(self.choices)}
        for key in ("texture_kind", "layout_field", "appearance"):
            if getattr(self, key):
                out[key] = getattr(self, key)
        return out


@dataclass(frozen=True)
class Continuous:
    name: str
    low: float
    high: float
    layout_field: str | None = None
    appearance: str | None = None  # the appearance field set to the value (sim.appearance)

    @property
    def width(self) -> int:
        return 1

    def resolve(self, value, extra: Iterable[str] = ()) -> float:
        try:
            number = float(value)
        except (TypeError, ValueError):
            raise MetaSimError(f"{self.name}: {value!r} is not a number") from None
        if not (self.low <= number <= self.high):
            raise MetaSimError(
                f"{self.name}: {number} is out of range [{self.low}, {self.high}]")
        return number

    def to_dict(self) -> dict:
        out = {"name": self.name, "type": "continuous", "low": self.low, "high": self.high}
        for key in ("layout_field", "appearance"):
            if getattr(self, key):
                out[key] = getattr(self, key)
        return out


Parameter = Categorical | Continuous


def _finite(value, what: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise MetaSimError(f"{what} must be a finite number, not {value!r}")
    return float(value)


def _bindings(raw: Mapping, name: str) -> tuple[str | None, str | None]:
    """A parameter's layout_field and appearance field names (None when absent), checked to be identifiers."""
    out = []
    for key in ("layout_field", "appearance"):
        value = raw.get(key)
        if value is not None and (not isinstance(value, str) or not value.isidentifier()):
            raise MetaSimError(f"{name}: {key} must be a field name, not {value!r}")
        out.append(value)
    return out[0], out[1]


def _listed(keys) -> str:
    return ", ".join(f'"{k}"' for k in keys)


def _header(data) -> None:
    """MetaSimError unless ``data`` is a design-space declaration of this version with known keys only."""
    if not isinstance(data, Mapping) or data.get("format") != FORMAT:
        raise MetaSimError(f"not a design-space file (expected \"format\": \"{FORMAT}\")")
    version = data.get("version")
    if version != VERSION:
        raise MetaSimError(
            f"design-space version {version!r} is not supported (this meta-sim reads {VERSION})")
    unknown = [str(k) for k in data if k not in _SPACE_KEYS]
    if unknown:
        raise MetaSimError(f"unknown design-space key(s) {_listed(unknown)}; a space has {_listed(_SPACE_KEYS)}")


def _raw_parameters(data: Mapping, where: str = "") -> list[Mapping]:
    """The ``parameters`` list of a declaration, each an object with an identifier ``name``."""
    raws = data.get("parameters", [])
    if not isinstance(raws, list):
        raise MetaSimError(f"{where}design-space \"parameters\" must be a list")
    for raw in raws:
        if not isinstance(raw, Mapping):
            raise MetaSimError(f"{where}a design-space parameter must be an object, not {raw!r}")
        name = raw.get("name")
        if not isinstance(name, str) or not name.isidentifier() or len(name) > MAX_NAME:
            raise MetaSimError(f"{where}design-space parameter name {name!r} must be an identifier")
    return raws


def _read(path: Path) -> dict:
    try:
        return json.loads(path.read_text())
    except json.JSONDecodeError as exc:
        raise MetaSimError(f"{path}: not valid JSON ({exc})") from None


def _declaration(data, chain: tuple[str, ...] = ()) -> dict:
    """``data`` with its ``extends`` resolved (see the module docstring): a declaration without
    ``extends``, ``remove`` or ``"after"``. ``chain`` holds the bases already being resolved."""
    _header(data)
    raws = _raw_parameters(data)
    base_name = data.get("extends")
    if base_name is None:
        if "remove" in data or any("after" in raw for raw in raws):
            raise MetaSimError("\"remove\" and \"after\" change a base space: add \"extends\": "
                               "the name of a shipped space, or drop them")
        return dict(data)
    shipped = builtin_spaces()
    if not isinstance(base_name, str) or base_name not in shipped:
        raise MetaSimError(f"\"extends\": {base_name!r} is not a space meta-sim ships; extend one of: "
                           f"{', '.join(shipped)}")
    if base_name in chain:
        raise MetaSimError(f"design spaces extend each other in a cycle: {' -> '.join(chain + (base_name,))}; "
                           "make one of them declare its parameters")
    if len(chain) >= MAX_EXTENDS:
        raise MetaSimError(f"design space {base_name!r} is more than {MAX_EXTENDS} \"extends\" deep "
                           f"({' -> '.join(chain)}); extend a space nearer the top")
    base = _declaration(_read(SPACES_DIR / f"{base_name}.json"), chain + (base_name,))
    return _extended(base, data, raws)


def _extended(base: Mapping, data: Mapping, raws: list[Mapping]) -> dict:
    """The base declaration with the changes ``data`` declares (``raws``: its parameters)."""
    where = f"extending {data['extends']!r}: "
    merged = [dict(raw) for raw in _raw_parameters(base)]
    remove = data.get("remove", [])
    if not isinstance(remove, list) or not all(isinstance(n, str) for n in remove):
        raise MetaSimError(f"{where}\"remove\" must be a list of parameter names")
    given = [raw["name"] for raw in raws]
    for name in remove:
        if name not in (p["name"] for p in merged):
            raise MetaSimError(f"{where}cannot remove {name!r}: the base has {', '.join(p['name'] for p in merged)}")
        if name in given:
            raise MetaSimError(f"{where}{name!r} is both removed and declared; drop it from \"remove\"")
        merged = [p for p in merged if p["name"] != name]
    if len(set(given)) != len(given):
        raise MetaSimError(f"{where}each parameter may be declared once")
    for raw in raws:
        entry = {k: v for k, v in raw.items() if k != "after"}
        names = [p["name"] for p in merged]
        at = names.index(entry["name"]) if entry["name"] in names else None
        if "after" not in raw:
            if at is None:
                merged.append(entry)
            else:
                merged[at] = entry
            continue
        if at is not None:
            del merged[at], names[at]
        if raw["after"] not in names:
            raise MetaSimError(f"{where}{entry['name']}: \"after\" must name a parameter of the space, "
                               f"one of {', '.join(names)}; not {raw['after']!r}")
        merged.insert(names.index(raw["after"]) + 1, entry)
    layout = data.get("layout", {})
    if not isinstance(layout, Mapping):
        raise MetaSimError(f"{where}design-space \"layout\" must be an object")
    out_layout = dict(base.get("layout", {}))
    for key, value in layout.items():
        if value is not None:
            out_layout[key] = value
        elif key in out_layout:
            del out_layout[key]
        else:
            raise MetaSimError(f"{where}layout {key!r}: null drops a key of the base's layout, which has none")
    out = {k: data[k] for k in ("format", "version", "name") if k in data}
    return {**out, "parameters": merged, "layout": out_layout}


def _bank_ids(spec: Mapping, texture_kind: str | None, name: str) -> tuple[str, ...]:
    """The ids ``{"all": KIND}`` stands for: every texture of that kind in the default bank, in its
    manifest order (the recipes' order, so nothing is built)."""
    if set(spec) != {"all"} or spec["all"] not in KINDS:
        forms = " or ".join(json.dumps({"all": kind}) for kind in KINDS)
        raise MetaSimError(f"{name}: choices must be a list of ids or {forms}, not {json.dumps(spec)[:80]}")
    if spec["all"] != texture_kind:
        kind = json.dumps(spec["all"])
        raise MetaSimError(f"{name}: choices {{\"all\": {kind}}} need \"texture_kind\": {kind}")
    return tuple(r.id for r in recipes(spec["all"]))


def _draw(p: Parameter, rng, size: int | None = None):
    """One value of ``p`` drawn uniformly from ``rng`` (a list of ``size`` values when size is given)."""
    if isinstance(p, Categorical):
        picks = rng.integers(len(p.choices), size=size)
        return p.choices[int(picks)] if size is None else [p.choices[int(i)] for i in picks]
    values = rng.uniform(p.low, p.high, size=size)
    return float(values) if size is None else [float(v) for v in values]


def _check_layout_value(key, value) -> None:
    """A fixed layout override is a field name with a finite number, true/false, a short name or a mapping of
    short names to finite numbers (a city style mix); anything else (NaN, a list, a nested object) is refused
    here, before it reaches the layout or a file. The layout checks what the values mean."""
    if not isinstance(key, str) or not key.isidentifier() or len(key) > MAX_NAME:
        raise MetaSimError(f"design-space layout key {key!r} must be a field name")
    if isinstance(value, Mapping):
        if not all(isinstance(k, str) and len(k) <= MAX_NAME and _is_finite_number(v) for k, v in value.items()):
            raise MetaSimError(f"design-space layout {key}: a mapping must give each name a finite number")
    elif isinstance(value, str):
        if len(value) > MAX_NAME:
            raise MetaSimError(f"design-space layout {key}: a name of at most {MAX_NAME} characters")
    elif not _is_finite_number(value):
        raise MetaSimError(f"design-space layout {key}: {value!r} must be a finite number, true/false or a name")


def _is_finite_number(value) -> bool:
    """True for true/false, whole numbers and finite floats."""
    return isinstance(value, (bool, int)) or isinstance(value, float) and math.isfinite(value)


def _preview(choices: tuple[str, ...], n: int = 3) -> str:
    shown = ", ".join(repr(c) for c in choices[:n])
    return shown + (", ..." if len(choices) > n else "")


@dataclass(frozen=True)
class DesignSpace:
    name: str
    parameters: tuple[Parameter, ...]
    layout: Mapping[str, float] = field(default_factory=dict)
    version: int = VERSION

    # --- declaration -------------------------------------------------------
    @classmethod
    def from_dict(cls, data: Mapping) -> "DesignSpace":
        """A space from its declaration (see the module docstring), ``extends`` and ``{"all": KIND}`` resolved."""
        data = _declaration(data)
        params: list[Parameter] = []
        for raw in _raw_parameters(data):
            name, kind = raw["name"], raw.get("type")
            if not isinstance(kind, str) or kind not in _PARAMETER_KEYS:
                raise MetaSimError(f"{name}: type must be 'categorical' or 'continuous', not {kind!r}")
            unknown = [str(k) for k in raw if k not in _PARAMETER_KEYS[kind]]
            if unknown:
                raise MetaSimError(f"{name}: unknown key(s) {_listed(unknown)}; a {kind} parameter has "
                                   f"{_listed(_PARAMETER_KEYS[kind])}")
            if kind == "categorical":
                texture_kind = raw.get("texture_kind")
                if texture_kind not in (None, *KINDS):
                    raise MetaSimError(f"{name}: texture_kind must be \"flat\" or \"sloped\", not {texture_kind!r}")
                choices = raw.get("choices") or ()
                if isinstance(choices, Mapping):
                    choices = _bank_ids(choices, texture_kind, name)
                if not isinstance(choices, (list, tuple)) or not choices or len(set(map(str, choices))) != len(choices):
                    raise MetaSimError(f"{name}: choices must be a non-empty list of unique ids")
                choices = tuple(safe_name(c, f"{name}: choice") for c in choices)
                field, look = _bindings(raw, name)
                if look is not None:
                    check_field(look, True, name, choices)
                if sum(x is not None for x in (texture_kind, field, look)) > 1:
                    raise MetaSimError(f"{name}: set at most one of texture_kind, layout_field and appearance")
                params.append(Categorical(name, choices, texture_kind, field, look))
            else:
                low, high = (_finite(raw.get(key), f"{name}: {key}") for key in ("low", "high"))
                if not low < high:
                    raise MetaSimError(f"{name}: low ({low}) must be below high ({high})")
                field, look = _bindings(raw, name)
                if look is not None:
                    check_field(look, False, name, low=low, high=high)
                if field is not None and look is not None:
                    raise MetaSimError(f"{name}: set layout_field or appearance, not both")
                params.append(Continuous(name, low, high, field, look))
        if not params:
            raise MetaSimError("a design space needs at least one parameter")
        if len({p.name for p in params}) != len(params):
            raise MetaSimError("design-space parameter names must be unique")
        kinds = [p.texture_kind for p in params if isinstance(p, Categorical) and p.texture_kind]
        if len(set(kinds)) != len(kinds):
            raise MetaSimError("at most one parameter may set each roof kind's material")
        for what in ("layout_field", "appearance"):
            bound = [getattr(p, what) for p in params if getattr(p, what)]
            if len(set(bound)) != len(bound):
                raise MetaSimError(f"at most one parameter may set each {what.replace('_', ' ')}")
        space_name, layout = data.get("name", "unnamed"), data.get("layout", {})
        if not isinstance(space_name, str) or not space_name or len(space_name) > MAX_NAME:
            raise MetaSimError(f"design-space name must be a short non-empty string, not {space_name!r}")
        if not isinstance(layout, Mapping):
            raise MetaSimError("design-space \"layout\" must be an object")
        for key, value in layout.items():
            _check_layout_value(key, value)
        return cls(space_name, tuple(params), dict(layout))

    def to_dict(self) -> dict:
        return {"format": FORMAT, "version": self.version, "name": self.name,
                "parameters": [p.to_dict() for p in self.parameters],
                "layout": dict(self.layout)}

    @classmethod
    def load(cls, path_or_name: str | Path = DEFAULT_SPACE) -> "DesignSpace":
        """Load a space from a JSON file, or a built-in one by name."""
        path = Path(path_or_name)
        if not path.suffix:
            path = SPACES_DIR / f"{path_or_name}.json"
        try:
            data = _read(path)
        except FileNotFoundError:
            raise MetaSimError(f"design space {str(path_or_name)!r} not found; "
                               f"give a JSON file or one of: {', '.join(builtin_spaces())}") from None
        return cls.from_dict(data)

    @classmethod
    def for_textures(cls, name: str, flat_ids, sloped_ids) -> "DesignSpace":
        """The rooftop space of a texture bank: one parameter per roof kind the bank has.

        A bank without sloped textures gives a flat-only space whose cities build no sloped roofs.
        """
        params = [Categorical(n, tuple(ids), kind) for n, ids, kind in
                  (("flat_roof", flat_ids, "flat"), ("sloped_roof", sloped_ids, "sloped")) if ids]
        if not params:
            raise MetaSimError(f"texture bank {name!r} has no flat or sloped textures")
        layout = {} if sloped_ids else {"sloped_share": 0.0}
        return cls(name, tuple(params), layout)

    # --- lookup ------------------------------------------------------------
    @property
    def names(self) -> tuple[str, ...]:
        return tuple(p.name for p in self.parameters)

    @property
    def dim(self) -> int:
        return sum(p.width for p in self.parameters)

    def parameter(self, name: str) -> Parameter:
        for p in self.parameters:
            if p.name == name:
                return p
        raise MetaSimError(f"unknown design parameter {name!r}; this space has {', '.join(self.names)}")

    def texture_parameter(self, kind: str) -> Categorical | None:
        for p in self.parameters:
            if isinstance(p, Categorical) and p.texture_kind == kind:
                return p
        return None

    def blocks(self) -> list[tuple[Parameter, slice]]:
        """Each parameter with its slice of the encoded vector."""
        out, start = [], 0
        for p in self.parameters:
            out.append((p, slice(start, start + p.width)))
            start += p.width
        return out

    # --- designs -----------------------------------------------------------
    def widths(self) -> list[int]:
        """Each parameter's width in the encoded vector, in order."""
        return [p.width for p in self.parameters]

    def validate(self, design: Mapping, extra: Mapping[str, Iterable[str]] | None = None) -> dict:
        """A complete, canonical design (choice ids, floats), or MetaSimError."""
        extra = extra or {}
        unknown = set(design) - set(self.names)
        if unknown:
            raise MetaSimError(f"unknown design parameter(s) {', '.join(sorted(unknown))}; "
                               f"this space has {', '.join(self.names)}")
        missing = [n for n in self.names if n not in design]
        if missing:
            raise MetaSimError(f"design is missing {', '.join(missing)}")
        return {p.name: p.resolve(design[p.name], extra.get(p.name, ())) for p in self.parameters}

    def parse(self, text: str, extra: Mapping[str, Iterable[str]] | None = None) -> dict:
        """Parse ``flat_roof=3,sloped_roof=sloped-clay-red`` into a design."""
        design = {}
        for item in filter(None, (s.strip() for s in text.split(","))):
            name, sep, value = item.partition("=")
            if not sep or not value.strip():
                raise MetaSimError(f"bad design item {item!r}: write name=value, e.g. flat_roof=3")
            if name.strip() in design:
                raise MetaSimError(f"design parameter {name.strip()!r} is given twice")
            design[name.strip()] = value.strip()
        return self.validate(design, extra)

    def sample(self, rng: np.random.Generator, n: int, order: str = "design") -> list[dict]:
        """``n`` designs drawn uniformly: every uniform design of meta-sim comes from here.

        ``rng`` is a ``numpy.random.Generator``, or anything with its ``integers(high, size)`` and
        ``uniform(low, high, size)`` (``nams.search.TorchDraws`` draws them from a ``torch.Generator``).
        ``order`` lays out the stream, and each order keeps the designs its callers have always had:
        "design" draws one design's values after another, so design k depends only on the generator
        state (a larger set extends a smaller); "parameter" draws each parameter's ``n`` values at once
        (``nams.uniform_predict``, the paper's Uniform baseline).
        """
        if order == "design":
            return [{p.name: _draw(p, rng) for p in self.parameters} for _ in range(n)]
        if order == "parameter":
            columns = [_draw(p, rng, n) for p in self.parameters]
            return [{p.name: column[k] for p, column in zip(self.parameters, columns)} for k in range(n)]
        raise MetaSimError(f"sample order must be 'design' or 'parameter', not {order!r}")

    def encode(self, design: Mapping) -> np.ndarray:
        design = self.validate(design)
        vec = np.zeros(self.dim, dtype=np.float32)
        for p, sl in self.blocks():
            if isinstance(p, Categorical):
                vec[sl.start + p.choices.index(design[p.name])] = 1.0
            else:
                vec[sl.start] = (design[p.name] - p.low) / (p.high - p.low)
        return vec

    def decode(self, vec) -> dict:
        """The design nearest to a vector: argmax per categorical block, clipped values."""
        vec = np.asarray(vec, dtype=np.float64).reshape(-1)
        if vec.shape[0] != self.dim:
            raise MetaSimError(f"design vector has {vec.shape[0]} entries; this space needs {self.dim}")
        if not np.all(np.isfinite(vec)):
            raise MetaSimError("design vector contains NaN or Inf")
        design = {}
        for p, sl in self.blocks():
            if isinstance(p, Categorical):
                design[p.name] = p.choices[int(np.argmax(vec[sl]))]
            else:
                design[p.name] = float(p.low + np.clip(vec[sl.start], 0.0, 1.0) * (p.high - p.low))
        return design

    def format(self, design: Mapping) -> str:
        """The inverse of ``parse``: ``flat_roof=<id>,sloped_roof=<id>``."""
        return ",".join(f"{n}={design[n]}" for n in self.names)

    def scene_version(self) -> dict:
        """``layout.scene_version`` of the cities this space can render: ``{"scene": N}`` when its fixed
        layout asks for roof furniture or a style, or a parameter sets the style; else {}."""
        from .layout import scene_version

        styled = any(p.layout_field == "style" for p in self.parameters)
        return scene_version({**self.layout, **({"style": "styled"} if styled else {})})

    def layout_overrides(self, design: Mapping) -> dict:
        """Fixed layout overrides plus the design's layout-bound values."""
        out = dict(self.layout)
        for p in self.parameters:
            if p.layout_field:
                out[p.layout_field] = float(design[p.name]) if isinstance(p, Continuous) else design[p.name]
        return out


def diversify(space: DesignSpace, rng: np.random.Generator, n: int, r: float, base: Callable[[int], dict],
              coins_first: bool = False) -> list[tuple[dict, bool]]:
    """Diversify with rejection (the paper's, section 4): design k is ``base(k)``, replaced with
    probability ``r`` by a uniform design of ``space``; each design with whether it was replaced.

    ``rng`` is as for ``DesignSpace.sample`` (with ``random(size)`` besides); ``base`` may draw from it.
    ``coins_first`` lays out the stream, and each layout keeps the designs its callers have always had:
    False draws, for each design in turn, its coin, its base and its replacement, so the first k designs
    do not depend on n (``render.jobs.sample_population``); True draws the n coins at once first, and
    nothing at all when r is 0 (the searches' answers, ``nams.search``).
    """
    if coins_first and r == 0.0:
        return [(base(k), False) for k in range(n)]
    coins = list(rng.random(n)) if coins_first else None
    out = []
    for k in range(n):
        replaced = bool((coins[k] if coins_first else rng.random()) < r)
        design = base(k)
        out.append((space.sample(rng, 1)[0] if replaced else design, replaced))
    return out

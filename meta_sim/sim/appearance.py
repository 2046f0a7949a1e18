"""How a city looks beyond its roofs: ground cover and its albedo, vegetation colour, sun and shadows,
brightness, roof variation and sensor.

Each of these can be set for a whole render (``meta-sim render --ground mixed --sensor drone ...``)
or declared as a parameter of a design space, so NAMS infers it for a target like a roof material::

    {"name": "ground", "type": "categorical", "appearance": "ground", "choices": ["plain", "arid"]}
    {"name": "greenness", "type": "continuous", "appearance": "greenness", "low": 0.0, "high": 1.0}

A design's value overrides the render's setting for that design only. ``FIELDS`` lists what a space
may declare: categorical fields with their allowed choices, continuous ones with the range their
values must stay inside. Pure Python and numpy: the add-on, the renderer and the torch side import it.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Mapping

import numpy as np

from ..core.errors import MetaSimError
from .ground import COVERS, DIRT, MIXES
from .jitter import LUMA, roof_jitter, roof_paint
from .sensor import SENSORS, Sensor, get_sensor

# categorical field -> the choices it allows; continuous field -> (lowest, highest) value
CATEGORICAL_FIELDS = {"ground": tuple(MIXES), "sensor": tuple(SENSORS)}
CONTINUOUS_FIELDS = {"roof_jitter": (0.0, 1.0), "greenness": (0.0, 1.0), "sun_elevation_deg": (15.0, 85.0),
                     "brightness": (0.25, 4.0), "ground_albedo": (0.2, 2.0), "roof_paint": (0.0, 1.0),
                     "shadow_depth": (0.0, 0.95), "view_height_m": (30.0, 10_000.0), "ground_grain": (0.0, 1.0),
                     "road_dust": (0.0, 1.0), "soil_redness": (0.0, 1.0), "saturation": (0.5, 2.0)}
FIELDS = (*CATEGORICAL_FIELDS, *CONTINUOUS_FIELDS)

# Vegetation colours (linear RGB) at greenness 1 (lush, after rain) and 0 (dry season, dormant grass).
LUSH = {"lawn": (0.11, 0.20, 0.06), "tree": (0.04, 0.12, 0.03)}
DRY = {"lawn": (0.34, 0.29, 0.17), "tree": (0.12, 0.13, 0.06)}
TREE_COLOUR = (0.05, 0.13, 0.035)  # small trees' leaves when greenness is not set
# The bare ground's colours (linear RGB) at soil redness 1: the iron-rich red-orange earth (laterite) of the
# tropics, as in Kampala's yards and unpaved lanes, redder than `ground.COVERS`' soil.
LATERITE = {"soil": (0.45, 0.24, 0.13), "sand": (0.55, 0.36, 0.22), "dirt": (0.40, 0.22, 0.12)}


@dataclass(frozen=True)
class Appearance:
    """Everything of a render's look that is not a roof texture or the layout.

    ``greenness``, ``sun_elevation_deg`` and ``ground_albedo`` are None when not set: today's lawn and
    tree colours, a sun elevation drawn from the city seed, and today's ground. ``brightness`` scales the
    rendered light before the sensor sees it (real images of one place differ in brightness by camera
    settings and haze); ``ground_albedo`` scales the reflectance of the bare ground only, in the scene
    (``ground_colours``), so the ground can be darker or brighter than the roofs; ``roof_paint`` is the
    share of buildings whose roof is painted in place of its texture (``sim.jitter.roof_paint``);
    ``shadow_depth`` the share of a flat surface's light a shadow takes away, None for the presets' own
    (``sim.quality.SHADOW_DEPTH`` in the fast preset, ``cycles_light`` in the path-traced ones);
    ``view_height_m`` the height of a perspective camera over each tile's centre (a drone's photo: walls show
    and roofs lean out from the centre, the more the taller and the farther), None for today's orthographic
    nadir view; ``ground_grain`` the strength of the bare ground's fine texture (``sim.ground.grain_field``),
    None for today's smooth covers; ``road_dust`` how far the roads' and tracks' colour moves towards dust
    (``sim.surfaces.dusty``), None for today's; ``soil_redness`` how far the bare soil, sand and dirt tracks
    move towards red laterite (`LATERITE`, ``ground_colours``), None for today's; ``saturation`` the colour
    saturation of the finished render around its luminance (a camera's or its processing's vividness: 1 as
    rendered, 0 grey), None for 1.
    """

    sensor: Sensor = Sensor()
    roof_jitter: float = 0.0
    ground: str = "plain"
    greenness: float | None = None
    sun_elevation_deg: float | None = None
    brightness: float = 1.0
    ground_albedo: float | None = None
    roof_paint: float = 0.0
    shadow_depth: float | None = None
    view_height_m: float | None = None
    ground_grain: float | None = None
    road_dust: float | None = None
    soil_redness: float | None = None
    saturation: float | None = None

    def with_design(self, space, design: Mapping) -> "Appearance":
        """This appearance with the values ``design`` gives to the space's appearance parameters."""
        changes = {}
        for param in space.parameters:
            target = getattr(param, "appearance", None)
            if target == "sensor":
                changes["sensor"] = get_sensor(str(design[param.name]))
            elif target is not None:
                changes[target] = design[param.name] if target == "ground" else float(design[param.name])
        return replace(self, **changes) if changes else self

    def scene_key(self) -> tuple:
        """What the Blender scene of a city depends on (the rest is applied to finished renders)."""
        return (self.ground, self.greenness, self.sun_elevation_deg, self.ground_albedo, self.shadow_depth,
                self.view_height_m, self.ground_grain, self.road_dust, self.soil_redness)

    def header(self) -> dict:
        """The fields that differ from a plain render, for a tile's header (empty for a plain one)."""
        out = {}
        if self.sensor.active:
            out["sensor"] = self.sensor.to_dict()
        if self.roof_jitter:
            out["roof_jitter"] = self.roof_jitter
        if self.ground != "plain":
            out["ground"] = self.ground
        if self.greenness is not None:
            out["greenness"] = self.greenness
        if self.sun_elevation_deg is not None:
            out["sun_elevation_deg"] = self.sun_elevation_deg
        if self.brightness != 1.0:
            out["brightness"] = self.brightness
        if self.ground_albedo is not None:
            out["ground_albedo"] = self.ground_albedo
        if self.roof_paint:
            out["roof_paint"] = self.roof_paint
        if self.shadow_depth is not None:
            out["shadow_depth"] = self.shadow_depth
        if self.view_height_m is not None:
            out["view_height_m"] = self.view_height_m
        if self.ground_grain is not None:
            out["ground_grain"] = self.ground_grain
        if self.road_dust is not None:
            out["road_dust"] = self.road_dust
        if self.soil_redness is not None:
            out["soil_redness"] = self.soil_redness
        if self.saturation is not None:
            out["saturation"] = self.saturation
        return out

    def apply(self, rgb: np.ndarray, instance: np.ndarray, roof_class: np.ndarray, city_seed: int,
              seed, preset=None) -> np.ndarray:
        """A finished linear render as this appearance shows it: a share of the roofs painted, roofs varied
        per building, the light scaled by the brightness and its colours by the saturation, then seen through
        the sensor (its noise seeded by ``seed``), whose own tone curve replaces that of the render ``preset`` (a
        ``RenderPreset``; None: no curve)."""
        image = roof_paint(rgb, instance, roof_class, city_seed, self.roof_paint)
        image = roof_jitter(image, instance, roof_class, city_seed, self.roof_jitter)
        if self.brightness != 1.0:
            image = image * np.float32(self.brightness)
        if self.saturation is not None and self.saturation != 1.0:
            image = saturate(image, self.saturation)
        if self.sensor.active or preset is None:
            return self.sensor.apply(image, seed)
        return preset.tone_map(image)


def check_field(target, categorical: bool, where: str, choices=(), low: float = 0.0, high: float = 1.0) -> str:
    """Validate a design-space parameter bound to appearance field ``target``: a known field of the
    parameter's type whose choices (or range) the field allows. Returns the field's name."""
    fields = CATEGORICAL_FIELDS if categorical else CONTINUOUS_FIELDS
    if target not in fields:
        kind = "categorical" if categorical else "continuous"
        raise MetaSimError(f"{where}: appearance must name a {kind} appearance field ({', '.join(fields)}), "
                           f"not {target!r}")
    if categorical:
        unknown = [c for c in choices if c not in fields[target]]
        if unknown:
            raise MetaSimError(f"{where}: {target} has no choice {unknown[0]!r}; "
                               f"choose from {', '.join(fields[target])}")
    else:
        lo, hi = fields[target]
        if low < lo or high > hi:
            raise MetaSimError(f"{where}: {target} must stay within [{lo:g}, {hi:g}], not [{low:g}, {high:g}]")
    return target


def vegetation_colour(kind: str, greenness: float | None, default) -> tuple:
    """The linear colour of ``kind`` ("lawn" or "tree") at ``greenness``; ``default`` when None."""
    if greenness is None:
        return tuple(default)
    g = float(np.clip(greenness, 0.0, 1.0))
    return tuple(float(d + g * (lush - d)) for d, lush in zip(DRY[kind], LUSH[kind]))


def foliage_tint(greenness: float | None) -> tuple | None:
    """Per-channel factors that take the foliage atlas (real trees and shrubs, ``surfaces.foliage_atlas``)
    from its own greens to ``greenness`` as the small trees' colour goes from `TREE_COLOUR` to
    ``vegetation_colour("tree", greenness)``; None (the atlas as it is) when greenness is not set."""
    if greenness is None:
        return None
    return tuple(t / d for t, d in zip(vegetation_colour("tree", greenness, TREE_COLOUR), TREE_COLOUR))


def saturate(rgb: np.ndarray, saturation: float) -> np.ndarray:
    """A linear RGB image (..., 3) with its colours' distance from their luminance (Rec. 709) times
    ``saturation``, clipped at 0; the luminance of every pixel that stays non-negative is kept."""
    rgb = np.asarray(rgb, np.float32)
    luma = rgb @ LUMA
    return np.clip(luma[..., None] + np.float32(saturation) * (rgb - luma[..., None]), 0.0, None).astype(np.float32)



def ground_colours(greenness: float | None, albedo: float | None, soil_redness: float | None = None) -> dict:
    """The linear colour of each surface of the bare ground: every cover of ``ground.COVERS`` (the lawn at
    ``greenness``, see ``vegetation_colour``) and "dirt", the unpaved tracks' earth, as ground-like as the
    covers; with ``soil_redness`` (0 to 1) the soil, sand and dirt that far towards `LATERITE`. ``albedo``
    multiplies them all (clipped at 1, as a reflectance is); None leaves them as they are. Roofs, walls,
    asphalt, pavings, yards, pools, cars and vegetation are not ground."""
    colours = {**COVERS, "lawn": vegetation_colour("lawn", greenness, COVERS["lawn"]), "dirt": DIRT}
    if soil_redness is not None:
        t = float(np.clip(soil_redness, 0.0, 1.0))
        colours.update({name: tuple(c + t * (red - c) for c, red in zip(colours[name], LATERITE[name]))
                        for name in LATERITE})
    if albedo is None:
        return {name: tuple(colour) for name, colour in colours.items()}
    return {name: tuple(float(min(1.0, c * float(albedo))) for c in colour) for name, colour in colours.items()}

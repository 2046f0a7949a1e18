"""Render quality presets: what each costs is measured by `make bench-render` (docs/benchmarks.md).

Pure data, shared by the renderer, the CLI and the add-on.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..core.errors import MetaSimError
from .sensor import tone_curve


@dataclass(frozen=True)
class RenderPreset:
    """A render quality setting: the engine, its samples, bounces, denoising, anti-aliasing and
    shadows, and the exposure that brings its renders to the brightness of the others."""

    name: str
    engine: str  # 'BLENDER_WORKBENCH' (rasterised) or 'CYCLES' (path traced)
    description: str
    samples: int = 1
    bounces: int = 0
    denoise: bool = False
    antialiasing: str = "FXAA"  # Workbench only
    shadows: bool = True
    # Linear gain on the rendered RGB, so that every preset renders a scene at one brightness.
    exposure: float = 1.0
    # The tone curve a render ends with, (knee, ceiling) of ``sensor.tone_curve``; None: none (bright
    # surfaces clip at white when the tile is shown or read as 8 bits).
    tone: tuple[float, float] | None = None

    def to_dict(self) -> dict:
        """The settings as plain values (recorded in tile metadata)."""
        return {"name": self.name, "engine": self.engine, "samples": self.samples,
                "bounces": self.bounces, "denoise": self.denoise,
                "antialiasing": self.antialiasing, "shadows": self.shadows, "exposure": self.exposure,
                **({"tone": list(self.tone)} if self.tone else {})}

    def cache_fields(self) -> dict:
        """What, beyond the preset's name, tells its renders apart from those cached before presets
        had the setting: the exposure when it is not 1 and the tone curve when there is one (tiles,
        training sets and models key on them)."""
        return {**({} if self.exposure == 1.0 else {"exposure": self.exposure}),
                **({"tone": list(self.tone)} if self.tone else {})}

    def tone_map(self, rgb: np.ndarray) -> np.ndarray:
        """A finished linear render through the preset's tone curve (unchanged without one)."""
        return rgb if self.tone is None else tone_curve(rgb, *self.tone)


# Workbench's studio light renders a surface far darker than the path-traced presets' sun and sky do,
# so fast renders are scaled up to their brightness: a model trained on one preset then meets
# targets at the brightness it learnt. `make bench-exposure` measures it: the median ratio of flat-roof
# brightness, balanced over fast at exposure 1, on training renders, no E1/E2 target (docs/design.md, "The fast
# preset's exposure"); `tests/render/render_test.py` checks that the two presets' roofs agree within a third.
# 6.0 before the shadows were cast from the sun's direction (SHADOW_SHIFT), when most cities' flat surfaces
# were shadowed at about half their light.
FAST_EXPOSURE = 3.3

# Every preset ends with a tone curve that does not clip: the identity up to a linear 0.6 (display
# 0.80), then a shoulder towards 0.95 (display 0.977, an 8-bit 249), so a white roof keeps its texture
# instead of clipping flat, and everything darker than the knee renders as before. Under the fast
# preset's exposure and the path-traced sun, white roofs render at a linear 1.0-1.8; without the curve
# most of their pixels clip (docs/design.md, "A tone curve in every preset").
TONE = (0.6, 0.95)


# A city of the richer scene (``layout.LayoutParams.richer_scene``) is lit in the fast preset by a studio light of
# its own instead of Workbench's: its sun (a directional light from the city's sun direction, in world space)
# and the sky (an even ambient light), so a sloped roof shows a sunlit and a shaded side as from the air,
# where the studio light, fixed to the camera, lit every roof alike from one side. The two are scaled so that
# a flat surface is as bright as under the studio light, whatever the sun's elevation (a camera's automatic
# exposure): FAST_EXPOSURE still brings it to the path-traced presets' brightness. SKY_SHARE is the sky's
# share of the light on a flat surface: clear-sky diffuse light is some 10-25% of the total at these
# elevations; not fitted to any target (docs/design.md, "The sun in the fast preset").
SKY_SHARE = 0.2
# Blender facts, measured by tests/render/render_test.py on a flat plane: a flat surface's brightness per unit
# albedo under Workbench's default studio light seen from above, and Workbench's diffuse response to a
# studio light of unit colour at normal incidence.
STUDIO_FLAT = 0.4216
WORKBENCH_DIFFUSE = 0.931


# Workbench's shadows from the sun: a surface is shadowed where the sun's light is blocked (cast shadows)
# or where it faces away from the sun, with a hard edge at grazing light (shift 0, focus 1), so that a surface
# the sun lights keeps the studio light's brightness at any elevation. Workbench's defaults (shift 0.1, focus
# 0) also darken lit surfaces by a ramp over the sun's angle: a flat roof at 30 degrees came out at 0.68 of
# its lit brightness. Measured by tests/render/render_test.py.
SHADOW_SHIFT = 0.0
SHADOW_FOCUS = 1.0


# How deep a shadow is: the share of a flat surface's light that a shadow takes away. Workbench's shadow
# intensity in the fast preset, used for every city unless a design declares its own (``shadow_depth``, an
# appearance field). Real shadows under a clear sky keep only the sky's light, some 10-25% of the total;
# a declared depth also sets the path-traced presets' sun and sky (``cycles_light``).
SHADOW_DEPTH = 0.55
# The path-traced presets' sun (irradiance, W/m^2) and sky (strength of the world's colour).
SUN_ENERGY = 4.0
SKY_STRENGTH = 0.8
SKY_COLOUR = (0.45, 0.5, 0.6)


def cycles_light(elevation: float, shadow_depth: float | None = None) -> tuple[float, float]:
    """``(sun energy, sky strength)`` of the path-traced presets for a sun at ``elevation`` (radians):
    today's sun and sky when ``shadow_depth`` is None, else the two rescaled so that the sky's share of the
    light on a flat surface is ``1 - shadow_depth`` (what a cast shadow keeps) while their sum, the lit
    surface's brightness, stays as it was. A diffuse surface under a sky of radiance L receives L (in units
    of its albedo), under a sun of irradiance E at elevation e it receives E sin(e) / pi."""
    if not 0.0 < elevation <= math.pi / 2:
        raise MetaSimError(f"the sun's elevation must be above the horizon, not {math.degrees(elevation):g} degrees")
    if shadow_depth is None:
        return SUN_ENERGY, SKY_STRENGTH
    if not 0.0 <= shadow_depth < 1.0:
        raise MetaSimError(f"a shadow's depth must be at least 0 and below 1, not {shadow_depth!r}")
    sky = SKY_STRENGTH * sum(SKY_COLOUR) / 3
    sun = SUN_ENERGY * math.sin(elevation) / math.pi
    total = sky + sun
    return shadow_depth * total * math.pi / math.sin(elevation), SKY_STRENGTH * (1.0 - shadow_depth) * total / sky


def workbench_direction(elevation: float, azimuth: float) -> tuple[float, float, float]:
    """The direction towards a sun at ``elevation`` and ``azimuth`` (radians; azimuth 0 is a sun in the south,
    the scene's convention) in Workbench's light frame, where y is up and z points south: world (x, y, z) is
    (x, z, -y). Both a studio light's directions and the shadows' ``light_direction`` are given in it; the
    world vector given as it is would put the sun below the horizon for most azimuths, shadowing every flat
    surface."""
    to_sun = (math.cos(elevation) * math.sin(azimuth), -math.cos(elevation) * math.cos(azimuth), math.sin(elevation))
    return to_sun[0], to_sun[2], -to_sun[1]


def sun_studio_light(elevation: float, azimuth: float) -> str:
    """The text of a Workbench studio light (a ``.sl`` file) of a sun at ``elevation`` and ``azimuth``
    (radians; ``workbench_direction``) and the sky, for world-space lighting."""
    if not 0.0 < elevation <= math.pi / 2:
        raise MetaSimError(f"the sun's elevation must be above the horizon, not {math.degrees(elevation):g} degrees")
    vec = workbench_direction(elevation, azimuth)
    sun = (1.0 - SKY_SHARE) * STUDIO_FLAT / (WORKBENCH_DIFFUSE * math.sin(elevation))
    sky = SKY_SHARE * STUDIO_FLAT
    lines = ["version 1", *(f"light_ambient.{c} {sky:.6f}" for c in "xyz")]
    for i in range(4):  # a studio light has four; the sun is the first, the others are off
        on = i == 0
        lines += [f"light[{i}].flag {int(on)}", f"light[{i}].smooth 0.000000",
                  *(f"light[{i}].col.{c} {sun if on else 0.0:.6f}" for c in "xyz"),
                  *(f"light[{i}].spec.{c} 0.000000" for c in "xyz"),
                  *(f"light[{i}].vec.{c} {v:.6f}" for c, v in zip("xyz", vec if on else (0.0, 1.0, 0.0)))]
    return "\n".join(lines) + "\n"


PRESETS = {p.name: p for p in (
    RenderPreset("fast", "BLENDER_WORKBENCH",
                 "rasterised (Workbench): textures, studio light, sun-direction shadows, FXAA",
                 exposure=FAST_EXPOSURE, tone=TONE),
    RenderPreset("balanced", "CYCLES",
                 "path traced (Cycles): 4 samples, 2 diffuse bounces, sun and sky", samples=4, bounces=2, tone=TONE),
    RenderPreset("quality", "CYCLES",
                 "path traced (Cycles): 8 samples, 3 diffuse bounces, sun and sky", samples=8, bounces=3, tone=TONE),
)}


def get_preset(name: str) -> RenderPreset:
    """The render preset called ``name``; MetaSimError listing the presets for an unknown one."""
    try:
        return PRESETS[name]
    except KeyError:
        raise MetaSimError(f"unknown render preset {name!r}; choose one of {', '.join(PRESETS)}") from None

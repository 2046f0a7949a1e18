"""Render quality presets: what each costs is measured by `make bench-render` (docs/benchmarks.md).

Pure data, shared by the renderer, the CLI and the add-on.
"""

from __future__ import annotations

from dataclasses import dataclass

from ..core.errors import MetaSimError


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

    def to_dict(self) -> dict:
        """The settings as plain values (recorded in tile metadata)."""
        return {"name": self.name, "engine": self.engine, "samples": self.samples,
                "bounces": self.bounces, "denoise": self.denoise,
                "antialiasing": self.antialiasing, "shadows": self.shadows, "exposure": self.exposure}

    def cache_fields(self) -> dict:
        """What, beyond the preset's name, tells its renders apart from those cached before presets
        had the setting: the exposure when it is not 1 (tiles, training sets and models key on it)."""
        return {} if self.exposure == 1.0 else {"exposure": self.exposure}


# Workbench's studio light renders a surface far darker than the path-traced presets' sun and sky do,
# so fast renders are scaled up to their brightness: a model trained on one preset then meets
# targets at the brightness it learnt. How the value was chosen is in docs/design.md ("The fast
# preset's exposure"); `tests/render/render_test.py` checks that the two presets' roofs agree within a third.
FAST_EXPOSURE = 6.0


PRESETS = {p.name: p for p in (
    RenderPreset("fast", "BLENDER_WORKBENCH",
                 "rasterised (Workbench): textures, studio light, sun-direction shadows, FXAA",
                 exposure=FAST_EXPOSURE),
    RenderPreset("balanced", "CYCLES",
                 "path traced (Cycles): 4 samples, 2 diffuse bounces, sun and sky", samples=4, bounces=2),
    RenderPreset("quality", "CYCLES",
                 "path traced (Cycles): 16 samples, 3 diffuse bounces, sun and sky", samples=16, bounces=3),
)}


def get_preset(name: str) -> RenderPreset:
    """The render preset called ``name``; MetaSimError listing the presets for an unknown one."""
    try:
        return PRESETS[name]
    except KeyError:
        raise MetaSimError(f"unknown render preset {name!r}; choose one of {', '.join(PRESETS)}") from None

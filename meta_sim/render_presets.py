"""Render quality presets: what each costs is measured by `make bench-render`.

Pure data, shared by the renderer, the CLI and the add-on.
"""

from __future__ import annotations

from dataclasses import dataclass

from .errors import MetaSimError


@dataclass(frozen=True)
class RenderPreset:
    name: str
    engine: str  # 'BLENDER_WORKBENCH' (rasterised) or 'CYCLES' (path traced)
    description: str
    samples: int = 1
    bounces: int = 0
    denoise: bool = False
    antialiasing: str = "FXAA"  # Workbench only
    shadows: bool = True

    def to_dict(self) -> dict:
        return {"name": self.name, "engine": self.engine, "samples": self.samples,
                "bounces": self.bounces, "denoise": self.denoise,
                "antialiasing": self.antialiasing, "shadows": self.shadows}


PRESETS = {p.name: p for p in (
    RenderPreset("fast", "BLENDER_WORKBENCH",
                 "rasterised (Workbench): textures, studio light, sun-direction shadows, FXAA"),
    RenderPreset("balanced", "CYCLES",
                 "path traced (Cycles): 4 samples, 2 diffuse bounces, sun and sky", samples=4, bounces=2),
    RenderPreset("quality", "CYCLES",
                 "path traced (Cycles): 16 samples, 3 diffuse bounces, sun and sky", samples=16, bounces=3),
)}


def get_preset(name: str) -> RenderPreset:
    try:
        return PRESETS[name]
    except KeyError:
        raise MetaSimError(f"unknown render preset {name!r}; choose one of {', '.join(PRESETS)}") from None

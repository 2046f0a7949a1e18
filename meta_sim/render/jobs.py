"""What a render is asked to do: jobs (one design in one city), their settings, tile names,
the metadata a finished tile carries, and ``designs.json`` beside the tiles. No bpy here."""

from __future__ import annotations

import hashlib
import json
from collections import defaultdict
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..core.fileio import write_text_atomic
from ..core.locks import locked
from ..core.names import safe_name
from ..sim import tiles
from ..sim.appearance import Appearance
from ..sim.design import DesignSpace, diversify
from ..sim.layout import scene_version
from ..sim.quality import RenderPreset
from ..sim.sensor import Sensor

READABLE_NAME = 120  # characters of a single design's choices in its tiles' names


@dataclass(frozen=True)
class Job:
    """One design to render in one city: tiles ``{name}_t{j:02d}.exr``.

    ``design`` maps each parameter of the space to its choice, ``city_seed`` picks the city layout,
    ``name`` the tiles' file stem. ``tiles`` restricts the job to some tile indices (a farm task);
    None means all of them.
    """

    design: dict
    city_seed: int
    name: str
    tiles: tuple | None = None

    def tile_indices(self, n_tiles: int) -> tuple:
        """The tile indices this job renders out of ``n_tiles`` per design."""
        return tuple(range(n_tiles)) if self.tiles is None else tuple(self.tiles)


@dataclass
class RenderSettings:
    """What every job of a render shares: the design space, the texture banks, the render quality
    preset, the output folder, tiles per design, tile size in pixels and metres per pixel, and
    whether to write PNG previews beside the EXR tiles."""

    space: DesignSpace
    banks: list  # TextureBank objects; a texture id is looked up in each in turn
    preset: RenderPreset
    out_dir: Path
    n_tiles: int = 9
    tile_px: int = 384
    pixel_size_m: float = 0.3
    preview: bool = False
    sensor: Sensor = Sensor()  # "none" by default: the render as it is
    roof_jitter: float = 0.0  # per-building roof variation (sim.jitter); 0: none
    ground: str = "plain"  # ground cover mix (sim.ground); plain: one lawn
    style: str = "suburban"  # city style mix (sim.layout.parse_style); suburban: the street grid

    def appearance(self, job: "Job") -> Appearance:
        """How ``job``'s tiles look: this render's sensor, roof jitter and ground, with whatever the
        job's design sets through the space's appearance parameters."""
        return Appearance(self.sensor, self.roof_jitter, self.ground).with_design(self.space, job.design)

    def header(self, job: "Job") -> dict:
        """What a tile header of ``job`` records beyond a plain render: its look, the city style and the
        roof furniture's density (so tiles rendered before a space had furniture are never taken for its) and,
        for a city of the richer scene, its version (``layout.scene_version``)."""
        overrides = self.space.layout_overrides(job.design)
        furniture = overrides.get("roof_furniture", 0.0)
        return {**self.appearance(job).header(), **({"style": self.style} if self.style != "suburban" else {}),
                **({"roof_furniture": furniture} if furniture else {}),
                **scene_version({"style": self.style, **overrides})}

    @property
    def tile_m(self) -> float:
        """A tile's side on the ground, in metres."""
        return self.tile_px * self.pixel_size_m


@dataclass
class RenderSummary:
    """What ``render_jobs`` did: tiles written and skipped (already valid), cities built, seconds
    per stage ("layout", "build", "labels", "render", "write") and the paths written."""

    written: int = 0
    skipped: int = 0
    cities: int = 0
    seconds: dict = field(default_factory=lambda: defaultdict(float))
    paths: list = field(default_factory=list)


def tile_path(out_dir: Path, job: Job, index: int) -> Path:
    """Tile ``index`` of ``job`` in ``out_dir``: ``{name}_tNN.exr``. MetaSimError when the job's name
    (from a design's ids or a farm manifest) would not make a safe file name inside ``out_dir``."""
    return Path(out_dir) / safe_name(f"{job.name}_t{index:02d}.exr", "tile file name")


def expected_meta(settings: RenderSettings, job: Job, index: int) -> dict:
    """The metadata a valid tile of ``job`` carries (``tiles.is_valid_tile`` compares it)."""
    return {"design": job.design, "design_space": settings.space.name, "city_seed": job.city_seed,
            "tile_index": index, "tile_size_px": [settings.tile_px, settings.tile_px],
            "pixel_size_m": settings.pixel_size_m, "preset": settings.preset.name,
            "format_version": tiles.TILE_FORMAT_VERSION, **settings.preset.cache_fields(),
            **settings.header(job)}


def design_jobs(space: DesignSpace, designs: list[dict], seed: int, cities: int) -> list[Job]:
    """Jobs for a training set: design k is rendered in city ``seed + k % cities``."""
    return [Job(design, seed + k % cities, f"d{k:05d}") for k, design in enumerate(designs)]


def single_job(space: DesignSpace, design: dict, seed: int) -> Job:
    """The job for one given design in city ``seed``, named after its choices and the seed; a name too long
    for a file (a rich space's many values) keeps its start and gains a digest of the whole design."""
    name = "+".join(str(design[n]) for n in space.names)
    if len(name) > READABLE_NAME:
        digest = hashlib.sha256(json.dumps(design, sort_keys=True).encode()).hexdigest()[:12]
        name = f"{name[:READABLE_NAME]}+{digest}"
    return Job(design, seed, f"{name}_s{seed}")


def sample_designs(space: DesignSpace, n: int, seed: int) -> list[dict]:
    """``n`` uniform designs; the first k do not depend on n (a larger set extends a smaller)."""
    return space.sample(np.random.default_rng([seed, 1]), n)


def sample_population(space: DesignSpace, designs: list[dict], counts: list[int], n: int, r: float,
                      seed: int) -> list[dict]:
    """``n`` designs drawn from a population (``designs`` with their ``counts``), each replaced by a
    uniform design with probability ``r`` (the paper's diversify-with-rejection); the first k do not
    depend on n."""
    rng = np.random.default_rng([seed, 2])
    shares = np.asarray(counts, dtype=np.float64) / float(sum(counts))
    drawn = diversify(space, rng, n, r, lambda _: dict(designs[int(rng.choice(len(designs), p=shares))]))
    return [design for design, _ in drawn]


def write_job_manifest(out_dir: Path, jobs: list[Job], settings: RenderSettings) -> Path:
    """``designs.json`` beside the tiles: every job rendered into the folder, with its design,
    city seed, settings and tile names (jobs already listed by an earlier run are kept)."""
    path = Path(out_dir) / "designs.json"
    with locked(path):  # two renders into one folder must not lose each other's entries
        entries = {}
        if path.is_file():
            try:
                entries = {e["name"]: e for e in json.loads(path.read_text()).get("jobs", [])}
            except (ValueError, KeyError, TypeError, AttributeError):
                entries = {}  # a damaged manifest is rebuilt from this run
        for job in jobs:
            entries[job.name] = {"name": job.name, "design": job.design, "city_seed": job.city_seed,
                                 "design_space": settings.space.name, "preset": settings.preset.name,
                                 "tile_px": settings.tile_px, "pixel_size_m": settings.pixel_size_m,
                                 "tiles": [tile_path(out_dir, job, j).name for j in range(settings.n_tiles)]}
        data = {"format": "meta-sim-render-job", "version": 1, "jobs": [entries[k] for k in sorted(entries)]}
        return write_text_atomic(path, json.dumps(data, indent=1) + "\n")

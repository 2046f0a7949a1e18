"""Job manifests: the tasks of a render job, planned once and run anywhere.

A manifest is one versioned JSON file. It holds the render settings shared by
all tasks (design space, texture bank, preset, tile size, pixel size, tiles
per design) and the tasks; a task is one design in one city, with its tile
indices and output file names. A task's name is a hash of its content, so
its outputs are a pure function of what it renders and planning twice gives
the same file, byte for byte.

Tiles go to ``out_dir``, stored relative to the manifest when it lies inside
the manifest's folder, so a job on shared storage reads the same from any
mount point. Pure Python: Blender's own Python loads manifests (farm shards).
"""

from __future__ import annotations

import hashlib
import json
import re
from dataclasses import dataclass, field, replace
from pathlib import Path

from ..core.errors import MetaSimError
from ..core.fileio import abandoned, write_text_atomic
from ..core.names import safe_name
from ..core.progress import Bars

FORMAT = "meta-sim-farm-job"
VERSION = 1
TASK_KEYS = ("name", "design", "city_seed", "tiles", "outputs")


def _is_int(value) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


@dataclass(frozen=True)
class Task:
    """One design in one city: tiles ``outputs[k]`` for tile indices ``tiles[k]``."""

    name: str
    design: dict
    city_seed: int
    tiles: tuple
    outputs: tuple

    def to_dict(self) -> dict:
        """The task as the manifest's JSON holds it."""
        return {"name": self.name, "design": self.design, "city_seed": self.city_seed,
                "tiles": list(self.tiles), "outputs": list(self.outputs)}

    @classmethod
    def from_dict(cls, data) -> "Task":
        """A task from the manifest's JSON; MetaSimError when a key is missing or of the wrong type
        (``Manifest.from_dict`` checks the task against its content)."""
        if not isinstance(data, dict) or any(k not in data for k in TASK_KEYS):
            raise MetaSimError(f"a manifest task needs the keys {', '.join(TASK_KEYS)}")
        name = safe_name(data["name"], "manifest task name")
        design, seed, tiles, outputs = data["design"], data["city_seed"], data["tiles"], data["outputs"]
        if not isinstance(design, dict) or not all(isinstance(v, (str, int, float)) for v in design.values()):
            raise MetaSimError(f"task {name}: design must be an object of ids and numbers")
        if not _is_int(seed) or not isinstance(tiles, list) or not all(_is_int(j) for j in tiles):
            raise MetaSimError(f"task {name}: city_seed and tiles must be whole numbers")
        if not isinstance(outputs, list) or not all(isinstance(p, str) for p in outputs):
            raise MetaSimError(f"task {name}: outputs must be a list of file names")
        return cls(name, dict(design), seed, tuple(tiles), tuple(outputs))


@dataclass(frozen=True)
class Manifest:
    """A render job: the settings every task shares, the tiles' folder and the tasks (``plan``
    makes one, ``save`` and ``load`` write and read it)."""

    space: dict  # the design space, as DesignSpace.to_dict()
    bank: str | None  # texture bank folder; None: the default bank of each machine's cache
    preset: str
    n_tiles: int
    tile_px: int
    pixel_size_m: float
    out_dir: Path  # absolute in memory
    tasks: tuple = field(default_factory=tuple)
    # What the renders look like beyond the preset (sim.sensor, sim.jitter, sim.ground, the city style of
    # sim.layout); defaults: as rendered before they existed.
    appearance: dict = field(default_factory=lambda: dict(DEFAULT_APPEARANCE))

    @property
    def n_outputs(self) -> int:
        """Tiles over all tasks."""
        return sum(len(t.tiles) for t in self.tasks)

    def to_dict(self, relative_to: Path | None = None) -> dict:
        """The manifest's JSON; ``out_dir`` is written relative to ``relative_to`` when it lies inside it."""
        out_dir = Path(self.out_dir)
        if relative_to is not None and out_dir.is_relative_to(relative_to):
            out_dir = out_dir.relative_to(relative_to)
        return {"format": FORMAT, "version": VERSION, "space": self.space, "bank": self.bank,
                "preset": self.preset, "n_tiles": self.n_tiles, "tile_px": self.tile_px,
                "pixel_size_m": self.pixel_size_m, "out_dir": str(out_dir), "appearance": dict(self.appearance),
                "tasks": [t.to_dict() for t in self.tasks]}

    @classmethod
    def from_dict(cls, data, base: Path) -> "Manifest":
        """A manifest from its JSON, a relative ``out_dir`` resolved against ``base``; MetaSimError for
        another format or version or a damaged file."""
        if not isinstance(data, dict) or data.get("format") != FORMAT:
            raise MetaSimError(f"not a meta-sim job manifest (expected \"format\": \"{FORMAT}\"); "
                               "write one with `meta-sim jobs plan`")
        if data.get("version") != VERSION:
            raise MetaSimError(f"job manifest version {data.get('version')!r} is not supported "
                               f"(this meta-sim reads {VERSION}); plan the job again")
        try:
            manifest = cls(space=dict(data["space"]), bank=data["bank"], preset=str(data["preset"]),
                           n_tiles=int(data["n_tiles"]), tile_px=int(data["tile_px"]),
                           pixel_size_m=float(data["pixel_size_m"]), out_dir=Path(base) / data["out_dir"],
                           tasks=tuple(Task.from_dict(t) for t in data["tasks"]),
                           appearance=check_appearance(data.get("appearance", DEFAULT_APPEARANCE)))
        except (KeyError, TypeError, ValueError) as exc:
            raise MetaSimError(f"damaged job manifest ({exc!r}); plan the job again") from None
        manifest.check_tasks()
        return manifest

    def check_tasks(self) -> None:
        """Every task is what its name says: the name is the hash of its design, city and the shared
        settings, its tiles lie in 0..n_tiles-1 and its outputs are its tiles' file names. A manifest
        edited by hand (or by someone hostile) cannot send a tile anywhere else; MetaSimError if not."""
        shared, order = self.shared_settings(), self.parameter_order()
        for task in self.tasks:
            if task.name != task_name(task.design, task.city_seed, shared, order):
                raise MetaSimError(f"manifest task {task.name} does not match its design, city and settings "
                                   "(edited by hand?); plan the job again")
            if len(set(task.tiles)) != len(task.tiles) or not all(0 <= j < self.n_tiles for j in task.tiles):
                raise MetaSimError(f"task {task.name}: tile indices must be distinct and in 0..{self.n_tiles - 1}")
            if list(task.outputs) != [f"{task.name}_t{j:02d}.exr" for j in task.tiles]:
                raise MetaSimError(f"task {task.name}: outputs must be its tiles' file names; plan the job again")

    def shared_settings(self) -> dict:
        """What every task's pixels depend on besides its design and city (part of each task's name)."""
        return shared_settings(self.space.get("name"), self.preset, self.n_tiles, self.tile_px, self.pixel_size_m,
                               self.appearance)

    def parameter_order(self) -> tuple:
        """The space's parameter names in declaration order (task names read the design in this order)."""
        parameters = self.space.get("parameters")
        if not isinstance(parameters, list):
            return ()
        return tuple(p["name"] for p in parameters if isinstance(p, dict) and isinstance(p.get("name"), str))

    def subset(self, tasks) -> "Manifest":
        """The same job with only ``tasks``."""
        return replace(self, tasks=tuple(tasks))

    def shard(self, index: int, count: int) -> "Manifest":
        """The ``index``-th of ``count`` shards: every count-th task, so shards are balanced."""
        if not (count >= 1 and 0 <= index < count):
            raise MetaSimError(f"shard {index}/{count}: write i/n with 0 <= i < n, e.g. 0/4")
        return self.subset(self.tasks[index::count])


DEFAULT_APPEARANCE = {"sensor": "none", "roof_jitter": 0.0, "ground": "plain", "style": "suburban"}


def check_appearance(appearance) -> dict:
    """A manifest's appearance settings, each checked; MetaSimError for an unknown key or value."""
    from ..sim.ground import get_mix
    from ..sim.jitter import check_strength
    from ..sim.layout import parse_style, style_text
    from ..sim.sensor import get_sensor

    if not isinstance(appearance, dict) or set(appearance) - set(DEFAULT_APPEARANCE):
        raise MetaSimError(f"manifest appearance must hold only {', '.join(DEFAULT_APPEARANCE)}; plan the job again")
    out = {**DEFAULT_APPEARANCE, **appearance}
    get_sensor(out["sensor"])
    get_mix(out["ground"])
    out["roof_jitter"] = check_strength(out["roof_jitter"])
    out["style"] = style_text(parse_style(out["style"]))
    return out


def shared_settings(space: str, preset: str, n_tiles: int, tile_px: int, pixel_size_m: float,
                    appearance: dict) -> dict:
    """What every task's pixels depend on besides its design and city (part of each task's name); the
    appearance only where it differs from the default, so jobs planned before it keep their names."""
    changed = {k: v for k, v in appearance.items() if v != DEFAULT_APPEARANCE[k]}
    return {"space": space, "preset": preset, "n_tiles": n_tiles, "tile_px": tile_px, "pixel_size_m": pixel_size_m,
            **changed}


def parse_shard(text: str) -> tuple[int, int]:
    """``"i/n"`` -> (i, n); MetaSimError when ``text`` is not of that form (``Manifest.shard`` checks
    the range)."""
    match = re.fullmatch(r"\s*(\d+)\s*/\s*(\d+)\s*", text or "")
    if not match:
        raise MetaSimError(f"--shard {text!r}: write i/n, e.g. 0/4 for the first of four shards")
    return int(match[1]), int(match[2])


def task_name(design: dict, city_seed: int, settings: dict, order: tuple = ()) -> str:
    """Readable design values plus a hash of everything that decides the task's pixels.

    The values are read in the space's declaration order (``order``; names it lacks follow, sorted), never
    in the dict's own: a manifest is saved with sorted keys, and the name must survive the round trip."""
    content = json.dumps({"design": design, "city_seed": city_seed, **settings}, sort_keys=True)
    digest = hashlib.sha256(content.encode()).hexdigest()[:12]
    names = [n for n in order if n in design] + sorted(set(design) - set(order))
    readable = re.sub(r"[^A-Za-z0-9.+-]", "_", "+".join(str(design[n]) for n in names))[:80]
    return f"{readable}_s{city_seed}_{digest}"


def plan(options: dict, out_dir: Path, bars: Bars | None = None) -> Manifest:
    """A manifest from the render options of `meta-sim render` (``--design`` or ``--random-designs``).

    Designs are validated and the banks built here (via the worker's own planning, ``bars`` showing
    each bank it builds), so a planned job fails on bad input now rather than on the farm. Duplicate
    tasks (a random design drawn twice for one city) are planned once.
    """
    from ..render.jobs import tile_path
    from ..render.plan import plan as plan_render

    jobs, settings = plan_render({**options, "out": out_dir, "preview": False}, bars)
    appearance = {"sensor": settings.sensor.name, "roof_jitter": settings.roof_jitter, "ground": settings.ground,
                  "style": settings.style}
    shared = shared_settings(settings.space.name, settings.preset.name, settings.n_tiles, settings.tile_px,
                             settings.pixel_size_m, appearance)
    tasks = {}
    for job in jobs:
        name = task_name(job.design, job.city_seed, shared, settings.space.names)
        indices = job.tile_indices(settings.n_tiles)
        outputs = tuple(tile_path(Path(), replace(job, name=name), j).name for j in indices)
        tasks.setdefault(name, Task(name, job.design, job.city_seed, indices, outputs))
    bank = options.get("bank")
    return Manifest(space=settings.space.to_dict(), bank=str(Path(bank).resolve()) if bank else None,
                    preset=settings.preset.name, n_tiles=settings.n_tiles, tile_px=settings.tile_px,
                    pixel_size_m=settings.pixel_size_m, out_dir=Path(out_dir).resolve(),
                    tasks=tuple(tasks.values()), appearance=appearance)


def default_out_dir(manifest_path: Path) -> Path:
    """Tiles of ``job.json`` go to ``job-tiles/`` beside it."""
    path = Path(manifest_path)
    return path.with_name(f"{path.stem}-tiles")


def save(manifest: Manifest, path: Path) -> Path:
    """Write atomically (a reader sees the old manifest or the new one)."""
    path = Path(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        data = manifest.to_dict(relative_to=path.parent.resolve())
        write_text_atomic(path, json.dumps(data, indent=1, sort_keys=True) + "\n")
    except OSError as exc:
        raise MetaSimError(f"cannot write the manifest {path}: {exc.strerror}; choose another --out") from None
    return path


def load(path: Path) -> Manifest:
    """Read the manifest at ``path``; MetaSimError when it is missing, unreadable or not a manifest
    this meta-sim reads."""
    path = Path(path)
    try:
        data = json.loads(path.read_text())
    except FileNotFoundError:
        raise MetaSimError(f"job manifest {path} not found; write one with `meta-sim jobs plan`") from None
    except (OSError, ValueError) as exc:
        raise MetaSimError(f"{path}: not a readable job manifest ({exc}); plan the job again") from None
    return Manifest.from_dict(data, path.parent.resolve())


def render_setup(manifest: Manifest, with_banks: bool = True):
    """(jobs, RenderSettings) for the manifest's tasks. Without banks the settings serve only
    to check tiles (their expected metadata), which needs no texture images."""
    from ..render.jobs import Job, RenderSettings
    from ..sim.design import DesignSpace
    from ..sim.quality import get_preset
    from ..sim.sensor import get_sensor

    banks = []
    if with_banks:
        from ..sim.textures import ensure_default_bank, ensure_heldout_banks, load_bank

        named = [value for task in manifest.tasks for value in task.design.values() if isinstance(value, str)]
        banks = [load_bank(manifest.bank) if manifest.bank else ensure_default_bank(), *ensure_heldout_banks(ids=named)]
    settings = RenderSettings(space=DesignSpace.from_dict(manifest.space), banks=banks,
                              preset=get_preset(manifest.preset), out_dir=Path(manifest.out_dir),
                              n_tiles=manifest.n_tiles, tile_px=manifest.tile_px,
                              pixel_size_m=manifest.pixel_size_m, sensor=get_sensor(manifest.appearance["sensor"]),
                              roof_jitter=manifest.appearance["roof_jitter"], ground=manifest.appearance["ground"],
                              style=manifest.appearance["style"])
    jobs = [Job(t.design, t.city_seed, t.name, t.tiles) for t in manifest.tasks]
    return jobs, settings


DONE, MISSING, CORRUPT = "done", "missing", "corrupt"


@dataclass
class Status:
    """Each task's tile states (done / missing / corrupt) and leftover temporary files."""

    states: dict  # task name -> list of (path, state)
    temporaries: list

    def count(self, state: str) -> int:
        """Tiles in ``state`` over all tasks."""
        return sum(1 for tiles in self.states.values() for _, state_ in tiles if state_ == state)

    @property
    def complete_tasks(self) -> set:
        """Names of the tasks whose tiles are all done."""
        return {name for name, tiles in self.states.items() if all(s == DONE for _, s in tiles)}

    def paths(self, state: str) -> list:
        """Paths of the tiles in ``state``."""
        return [path for tiles in self.states.values() for path, s in tiles if s == state]


def check(manifest: Manifest, threads: int = 8) -> Status:
    """Validate every output as the worker does (readable EXR, channels, size, metadata).

    Tiles are read in threads: OpenImageIO decodes without holding the GIL.
    """
    from concurrent.futures import ThreadPoolExecutor

    from ..render.jobs import expected_meta, tile_path
    from ..sim import tiles

    jobs, settings = render_setup(manifest, with_banks=False)
    items = [(job, j, tile_path(settings.out_dir, job, j)) for job in jobs for j in job.tiles]

    def state(item):
        job, j, path = item
        if not path.is_file():
            return MISSING
        return DONE if tiles.is_valid_tile(path, expected_meta(settings, job, j)) else CORRUPT

    with ThreadPoolExecutor(threads) as pool:
        found = list(pool.map(state, items))
    states = {job.name: [] for job in jobs}
    for (job, _, path), s in zip(items, found):
        states[job.name].append((path, s))
    return Status(states, temporaries(manifest))


def temporaries(manifest: Manifest, abandoned_only: bool = False) -> list[Path]:
    """Temporary tiles of the manifest's tasks (``.NAME_tNN.tmp*.exr``, never read as tiles): all of
    them, or only those whose writer is gone (``core.fileio.abandoned``), which are safe to delete
    while other workers may still be writing theirs."""
    out_dir = Path(manifest.out_dir)
    if not out_dir.is_dir():
        return []
    names = {t.name for t in manifest.tasks}
    pattern = re.compile(r"\.(.+)_t\d+\.tmp[\w-]+\.exr")
    found = (p for p in out_dir.glob(".*.tmp*.exr") if (m := pattern.fullmatch(p.name)) and m[1] in names)
    return sorted(p for p in found if not abandoned_only or abandoned(p))

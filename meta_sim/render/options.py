"""The render options, declared once as data.

Blender's own Python has neither click nor tqdm: a worker reads these options with argparse, the
click CLI builds its ``render`` command from the same table, and the add-on writes them into the
command lines of an exported render job.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from ..sim.space_names import builtin_spaces


@dataclass(frozen=True)
class Option:
    """One render option: its command-line flag, value type, default, help text, and whether it is
    an on/off flag that takes no value."""

    flag: str
    type: type
    default: object
    help: str
    is_flag: bool = False

    @property
    def dest(self) -> str:
        """The option's key in a parsed options dict (``--tile-px`` -> ``tile_px``)."""
        return self.flag.lstrip("-").replace("-", "_")


RENDER_OPTIONS = (
    Option("--design", str, None, "design to render, e.g. flat_roof=3,sloped_roof=sloped-clay-red "
           "(0-based index or texture id; held-out texture ids are accepted)"),
    Option("--random-designs", int, None, "render N uniformly sampled designs (a training set) instead"),
    Option("--population", Path, None, "render --images designs sampled from a population preset (the "
           "population.json of `meta-sim infer`) instead"),
    Option("--images", int, 100, "with --population: designs to sample (each rendered as --tiles tiles)"),
    Option("-r", float, 0.25, "with --population: diversify with rejection, the probability that a sampled "
           "design is replaced by a uniform one (the paper uses 0.25 on real imagery)"),
    Option("--seed", int, 1, "city seed (random designs: also the design sampling seed)"),
    Option("--cities", int, 8, "random or sampled designs: design k is rendered in city seed + (k mod CITIES)"),
    Option("--tiles", int, 9, "tiles per design (a near-square grid of adjacent tiles)"),
    Option("--preset", str, "fast", "render quality preset: fast (Workbench), balanced or quality (Cycles)"),
    Option("--sensor", str, "none", "camera after the render: none, drone, drone-v2 (sharper: fitted to real "
           "drone imagery by make bench-sensor) or satellite (colour balance, haze, blur, sharpening, a tone "
           "curve that does not clip, noise, JPEG; see meta_sim/sim/sensor.py)"),
    Option("--ground", str, "plain", "ground cover: plain (one lawn), suburban, mixed or arid (patches of lawn, "
           "dry grass, soil, sand, gravel, pavement; see meta_sim/sim/ground.py)"),
    Option("--style", str, "suburban", "city style: suburban (a street grid), dense (a packed informal town), "
           "downtown, industrial, or a mix such as dense=0.7,suburban=0.3 (see meta_sim/sim/layout.py)"),
    Option("--roof-jitter", float, 0.0, "per-building roof variation, 0 (none) to 1: brightness, tint and "
           "weathering drawn per building (see meta_sim/sim/jitter.py)"),
    Option("--out", Path, None, "output folder for the EXR tiles (created if missing)"),
    Option("--bank", Path, None, "texture bank folder (default: the built-in bank, built on first use)"),
    Option("--space", str, None, f"design space: a JSON file or one meta-sim ships ({', '.join(builtin_spaces())}; "
           "default: rooftops-v1; with --bank, one parameter per roof kind of that bank; with --population, the "
           "space it was inferred in)"),
    Option("--tile-px", int, 384, "tile width and height in pixels"),
    Option("--gsd", float, 0.3, "ground sampling distance: metres per pixel"),
    Option("--preview", bool, False, "also write an RGB PNG and a colour-coded label PNG per tile", True),
)

"""Where the shipped design spaces lie and their names, standard library only: the render options' help
(read by Blender's Python and argparse) and the CLI list them from here, never by hand."""

from __future__ import annotations

from pathlib import Path

SPACES_DIR = Path(__file__).parent / "spaces"
DEFAULT_SPACE = "rooftops-v1"


def builtin_spaces() -> list[str]:
    """The names of the shipped design spaces (``DesignSpace.load`` takes them by name), sorted."""
    return sorted(p.stem for p in SPACES_DIR.glob("*.json"))

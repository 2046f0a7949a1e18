"""Build the Blender extension zip with Blender's own validator and builder (`make addon`).

    python jobs/build_addon.py [--out dist]

The builder ships inside the bpy wheel (``bpy/<version>/scripts/addons_core/bl_pkg/cli/blender_ext.py``),
the same one ``blender --command extension build`` runs; no Blender binary is needed. It packs the
files the top-level ``blender_manifest.toml`` lists under ``[build] paths``.
"""

import argparse
import importlib.util
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def blender_ext() -> Path:
    """blender_ext.py of the installed bpy module (found without importing bpy)."""
    spec = importlib.util.find_spec("bpy")
    if spec is None or not spec.submodule_search_locations:
        sys.exit("error: the bpy module is not installed; run `make setup`")
    found = sorted(Path(spec.submodule_search_locations[0]).glob("*/scripts/addons_core/bl_pkg/cli/blender_ext.py"))
    if not found:
        sys.exit("error: this bpy has no blender_ext.py (Blender 4.2 or newer is needed)")
    return found[-1]


def run(*args: str) -> None:
    code = subprocess.call([sys.executable, str(blender_ext()), *args])
    if code:
        sys.exit(code)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=ROOT / "dist", help="output folder for the zip")
    args = parser.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    run("validate", str(ROOT))
    run("build", "--source-dir", str(ROOT), "--output-dir", str(args.out.resolve()))


if __name__ == "__main__":
    main()

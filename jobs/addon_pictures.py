"""The README's add-on picture: a preview tile before and after applying an inferred design preset.

    python jobs/addon_pictures.py --presets out/demo/infer/presets --out blender_addon/docs/before-after.png

Drives the built extension headless (the bpy module), as an artist would in the panel: generate a
city, render a preview tile, load the presets `meta-sim infer` wrote, apply the first, preview again.
"""

import argparse
import os
import subprocess
import sys
import tempfile
import zipfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--presets", type=Path, required=True, help="a folder of presets from meta-sim infer")
    parser.add_argument("--out", type=Path, required=True, help="PNG to write")
    parser.add_argument("--seed", type=int, default=4242, help="city seed")
    args = parser.parse_args()

    import bpy  # isort: skip (first: it puts Blender's script modules, addon_utils among them, on the path)
    import addon_utils  # isort: skip

    from meta_sim.sim.imageio import read_rgb8
    from meta_sim.sim.textures.pngio import write_png
    from meta_sim.sim.textures.sheet import render_sheet

    with tempfile.TemporaryDirectory() as tmp:
        subprocess.run([sys.executable, str(ROOT / "jobs" / "build_addon.py"), "--out", tmp], check=True,
                       capture_output=True)
        repo = Path(tmp) / "repo"
        with zipfile.ZipFile(next(Path(tmp).glob("meta_sim-*.zip"))) as archive:
            archive.extractall(repo / "meta_sim")
        os.environ.setdefault("BLENDER_USER_RESOURCES", str(Path(tmp) / "user"))
        bpy.context.preferences.extensions.repos.new(name="pictures", module="pictures", custom_directory=str(repo),
                                                     source="USER")
        addon_utils.enable("bl_ext.pictures.meta_sim", default_set=True)
        settings = bpy.context.scene.meta_sim
        settings.seed, settings.city_tiles, settings.tile_px, settings.gsd = args.seed, 1, 384, 0.3
        settings.render_preset = "fast"
        bpy.ops.meta_sim.load_bank()
        bpy.ops.meta_sim.generate_city()
        shots = []
        bpy.ops.meta_sim.render_preview()
        shots.append(("BEFORE: " + settings.flat_roof[5:] + " + " + settings.sloped_roof[7:],
                      read_rgb8(bpy.data.images["Meta-Sim Preview"].filepath)))
        settings.presets_folder = str(args.presets.resolve())
        bpy.ops.meta_sim.load_presets()
        settings.presets_index = next(i for i, r in enumerate(settings.presets) if not r.error and r.flat)
        bpy.ops.meta_sim.apply_preset()
        bpy.ops.meta_sim.render_preview()
        shots.append(("AFTER: " + settings.flat_roof[5:] + " + " + settings.sloped_roof[7:],
                      read_rgb8(bpy.data.images["Meta-Sim Preview"].filepath)))
        labels = read_rgb8(bpy.data.images["Meta-Sim Preview Labels"].filepath)
        shots.append(("LABELS", labels))
        args.out.parent.mkdir(parents=True, exist_ok=True)
        write_png(args.out, render_sheet([shots], 384, 3))
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

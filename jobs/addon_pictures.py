"""The README's add-on pictures: a preview tile before and after applying an inferred design preset, the
previews of a design asset library, and real target tiles beside a city wearing the design inferred for them.

    python jobs/addon_pictures.py --presets out/demo/infer/presets --out blender_addon/docs/before-after.png
    python jobs/addon_pictures.py --assets [--presets FOLDER] --out blender_addon/docs/asset-previews.png
    python jobs/addon_pictures.py --real ../shared/realdata/banepa/images:0.13 --out blender_addon/docs/real-target.png

Drives the built extension headless (the bpy module), as an artist would in the panel. Before/after:
generate a city, render a preview tile, load the presets `meta-sim infer` wrote, apply the first,
preview again. ``--assets``: load a presets folder (without ``--presets``: the designs of
``EXAMPLE_DESIGNS``, each saved with Save Design Preset, and their population), Build Asset Library,
and lay the assets' previews, as the library file holds them, side by side with their names.
``--real DIR:METRES``: train a small NAMS model in ``REAL_SPACE`` (minutes, in a temporary folder), run
`meta-sim infer` on the first ``REAL_TILES`` images of DIR, apply the group's preset in Blender (the scene
switches to its space) and render the city's tiles at the targets' ground size. The real images are only
read; only the picture is written.
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

# (preset name, flat roof, sloped roof): the demo's two designs and three more, for --assets without --presets
EXAMPLE_DESIGNS = (
    ("demo-hidden", "flat-gravel-dark", "sloped-seam-green"),
    ("demo-city", "flat-membrane-white-tpo", "sloped-clay-terracotta"),
    ("sedum-slate", "flat-green-sedum", "sloped-slate-grey"),
    ("metal-shingle", "flat-metal-deck-galvanised", "sloped-shingle-charcoal"),
    ("tar-corrugated", "flat-tar-gravel", "sloped-corrugated-rusty"),
)
REAL_SPACE = "overhead-towns-v5"  # the space the README recommends for real towns
REAL_TILES = 4
# The small model of --real: designs x one tile of 128 px at 0.5 m, colours of likely roofs found by colour alone.
REAL_TRAINING = ("--designs", "64", "--tiles", "1", "--tile-px", "128", "--gsd", "0.5", "--views", "1",
                 "--roof-finder", "colour", "--max-epochs", "40")
REAL_SEARCH = ("-M", "64", "--iterations", "100")  # the demo's adjoint search, not the paper's 1000 x 200
THUMB = 128  # px of a tile in the --real picture: the PNG stays small


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--presets", type=Path, help="a folder of presets from meta-sim infer")
    parser.add_argument("--assets", action="store_true", help="the asset previews instead of before/after")
    parser.add_argument("--real", help="DIR:METRES: real target tiles and the city of the design inferred for them")
    parser.add_argument("--out", type=Path, required=True, help="PNG to write")
    parser.add_argument("--seed", type=int, default=4242, help="city seed")
    args = parser.parse_args()
    if args.presets is None and not args.assets and not args.real:
        parser.error("--presets is needed for the before/after picture")

    import bpy  # isort: skip (first: it puts Blender's script modules, addon_utils among them, on the path)
    import addon_utils  # isort: skip

    from meta_sim.sim.textures.pngio import write_png

    with tempfile.TemporaryDirectory() as tmp:
        if args.real:
            real = infer_real(args.real, Path(tmp))
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
        if args.real:
            picture = real_and_rendered(settings, *real)
        elif args.assets:
            picture = asset_previews(settings, args.presets or _example_presets(settings, Path(tmp) / "presets"))
        else:
            picture = before_after(settings, args.presets)
        args.out.parent.mkdir(parents=True, exist_ok=True)
        write_png(args.out, picture)
    print(f"wrote {args.out}")
    return 0


def before_after(settings, presets: Path):
    import bpy

    from meta_sim.sim.imageio import read_rgb8
    from meta_sim.sim.textures.sheet import render_sheet

    shots = []
    bpy.ops.meta_sim.render_preview()
    shots.append(("BEFORE: " + _roofs(settings), read_rgb8(bpy.data.images["Meta-Sim Preview"].filepath)))
    settings.presets_folder = str(presets.resolve())
    bpy.ops.meta_sim.load_presets()
    settings.presets_index = next(i for i, r in enumerate(settings.presets) if not r.error and r.flat)
    bpy.ops.meta_sim.apply_preset()
    bpy.ops.meta_sim.render_preview()
    shots.append(("AFTER: " + _roofs(settings), read_rgb8(bpy.data.images["Meta-Sim Preview"].filepath)))
    labels = read_rgb8(bpy.data.images["Meta-Sim Preview Labels"].filepath)
    shots.append(("LABELS", labels))
    return render_sheet([shots], 384, 3)


def _roofs(settings) -> str:
    """The design's roofs, short: ``gravel-dark + seam-green``."""
    return " + ".join(settings.design[name].text.split("-", 1)[1] for name in ("flat_roof", "sloped_roof"))


def infer_real(target: str, tmp: Path) -> tuple[list[Path], Path, float]:
    """`meta-sim infer` with a small model trained here on the first ``REAL_TILES`` images of ``DIR:METRES``
    (linked into ``tmp``, never copied elsewhere); the images, the infer output and their pixel size."""
    folder, _, metres = target.rpartition(":")
    images = sorted(Path(folder).glob("*.png"))[:REAL_TILES]
    if not metres or len(images) < REAL_TILES:
        sys.exit(f"error: --real wants DIR:METRES with at least {REAL_TILES} PNG images in DIR")
    targets = tmp / "targets"
    targets.mkdir()
    for path in images:
        (targets / path.name).symlink_to(path.resolve())
    cli = [sys.executable, "-m", "meta_sim.cli"]
    subprocess.run([*cli, "train", "--space", REAL_SPACE, *REAL_TRAINING, "--cache", str(tmp / "cache"),
                    "--out", str(tmp / "model")], check=True)
    subprocess.run([*cli, "infer", f"{targets}:{metres}", "--model", str(tmp / "model" / "nams.pt"),
                    "--out", str(tmp / "infer"), "--group-size", str(REAL_TILES), *REAL_SEARCH], check=True)
    return images, tmp / "infer", float(metres)


def real_and_rendered(settings, images: list[Path], inferred: Path, metres: float):
    """The real tiles in a row; below, the city's tiles wearing the inferred group design (applied from its
    preset, which switches the scene to its space), each covering a real tile's ground."""
    import bpy

    from meta_sim.sim.imageio import read_rgb8
    from meta_sim.sim.textures.sheet import render_sheet

    real = [read_rgb8(path) for path in images]
    settings.presets_folder = str(inferred.resolve())
    bpy.ops.meta_sim.load_presets()
    settings.presets_index = next(i for i, r in enumerate(settings.presets) if not r.error and r.kind == "group")
    settings.city_tiles, settings.tile_px = len(images), 256
    settings.gsd = real[0].shape[1] * metres / settings.tile_px  # a tile covers a real tile's ground
    bpy.ops.meta_sim.apply_preset()
    bpy.ops.meta_sim.generate_city()
    rendered = []
    for tile in range(len(images)):
        settings.preview_tile = tile
        bpy.ops.meta_sim.render_preview()
        rendered.append((f"BLENDER TILE {tile}",
                         read_rgb8(bpy.data.images["Meta-Sim Preview"].filepath)))
    return render_sheet([[(f"REAL {path.stem[-6:]}", rgb) for path, rgb in zip(images, real)], rendered], THUMB,
                        len(images))


def _example_presets(settings, folder: Path) -> Path:
    """``EXAMPLE_DESIGNS`` saved from the panel (Save Design Preset), and the population of them."""
    import bpy

    from meta_sim.sim.design import DesignSpace
    from meta_sim.sim.presets import load_preset, population, save_preset

    for name, flat, sloped in EXAMPLE_DESIGNS:
        settings.design["flat_roof"].choice, settings.design["sloped_roof"].choice = flat, sloped
        bpy.ops.meta_sim.save_preset(filepath=str(folder / f"{name}.json"))
    groups = [load_preset(folder / f"{name}.json") for name, _, _ in EXAMPLE_DESIGNS]
    save_preset(folder / "population.json", population(groups, DesignSpace.load(), "examples-population"))
    return folder


def asset_previews(settings, presets: Path):
    """Build Asset Library on ``presets``; the previews the library file holds, named, in one row."""
    import bpy
    import numpy as np

    from meta_sim.sim import design_assets
    from meta_sim.sim.textures.sheet import render_sheet

    settings.presets_folder = str(presets.resolve())
    bpy.ops.meta_sim.build_assets()
    shots = []
    with bpy.data.temp_data() as data:
        blend = presets / design_assets.LIBRARY_DIR / design_assets.BLEND_FILE
        with data.libraries.load(str(blend), assets_only=True) as (source, target):
            target.scenes = source.scenes
        for scene in sorted(target.scenes, key=lambda s: (s.asset_data.get("kind") == "population", s.name)):
            width, height = scene.preview.image_size
            rgba = np.asarray(scene.preview.image_pixels_float[:], dtype=np.float32).reshape(height, width, 4)
            shots.append((scene.name, np.round(rgba[::-1, :, :3] * 255).astype(np.uint8)))
    return render_sheet([shots], design_assets.PREVIEW_PX, len(shots))


if __name__ == "__main__":
    sys.exit(main())

"""The roof-colour reference (meta_sim.reference) on tiles written here, without Blender."""

import numpy as np

from meta_sim import tiles
from meta_sim.reference import nearest, roof_histograms
from meta_sim.textures import hsv_cone_histogram


def _tile(path, colours: dict, size: int = 16):
    """A tile whose left half is a flat roof and right half a sloped roof, of the given linear colours."""
    rgb = np.zeros((size, size, 3), np.float32)
    roof_class = np.zeros((size, size), np.uint32)
    for column, (kind, roof) in enumerate((("flat", 1), ("sloped", 2))):
        if kind in colours:
            rgb[:, column * size // 2:(column + 1) * size // 2] = colours[kind]
            roof_class[:, column * size // 2:(column + 1) * size // 2] = roof
    meta = tiles.tile_metadata(design={"flat_roof": "a"}, space="s", city_seed=1, tile_index=0, origin_m=(0, 0),
                               size_px=(size, size), pixel_size_m=0.3, preset="fast")
    tiles.write_tile(path, rgb, (roof_class > 0).astype(np.uint32), roof_class, meta)
    return path


def test_roof_histograms_count_each_roof_kind_in_the_score_definition(tmp_path):
    red, grey = (0.6, 0.05, 0.05), (0.2, 0.2, 0.2)
    counts = roof_histograms([_tile(tmp_path / "a.exr", {"flat": red, "sloped": grey}),
                              _tile(tmp_path / "b.exr", {"flat": red})])
    assert counts["flat"].sum() == 2 * 128 and counts["sloped"].sum() == 128
    from meta_sim.imageio import linear_to_srgb

    srgb8 = np.round(linear_to_srgb(np.array([[red]])) * 255).astype(np.uint8)
    np.testing.assert_allclose(counts["flat"] / counts["flat"].sum(), hsv_cone_histogram(srgb8))


def test_nearest_picks_the_most_similar_colours_and_none_without_pixels(tmp_path):
    references = {}
    for name, colour in (("red", (0.6, 0.05, 0.05)), ("green", (0.05, 0.5, 0.05)), ("grey", (0.2, 0.2, 0.2))):
        counts = roof_histograms([_tile(tmp_path / f"{name}.exr", {"flat": colour})])["flat"]
        references[name] = counts / counts.sum()
    target = roof_histograms([_tile(tmp_path / "t.exr", {"flat": (0.55, 0.06, 0.04), "sloped": (0.1, 0.1, 0.1)})])
    assert nearest(target["flat"], references) == "red"
    assert nearest(np.zeros(512), references) is None

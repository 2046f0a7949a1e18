"""The roof-colour reference (meta_sim.reference) on tiles written here, without Blender."""

import numpy as np
import torch

from meta_sim.experiments.reference import nearest, roof_histograms
from meta_sim.sim import tiles
from meta_sim.sim.design import DesignSpace
from meta_sim.sim.imageio import linear_to_srgb
from meta_sim.sim.textures import hsv_cone_histogram


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
    assert set(counts) == {"labels"}
    labels = counts["labels"]
    assert labels["flat"].sum() == 2 * 128 and labels["sloped"].sum() == 128
    srgb8 = np.round(linear_to_srgb(np.array([[red]])) * 255).astype(np.uint8)
    np.testing.assert_allclose(labels["flat"] / labels["flat"].sum(), hsv_cone_histogram(srgb8))


class _LeftIsFlat:
    """A roof finder: the left half of every tile flat roof with probability 0.5, the rest nothing."""

    def weights(self, level1):
        out = torch.zeros(level1.shape[0], 2, *level1.shape[-2:])
        out[:, 0, :, :level1.shape[-1] // 2] = 0.5
        return out


def test_the_finder_row_counts_each_pixel_by_the_finders_probability_to_the_power(tmp_path):
    red, grey = (0.6, 0.05, 0.05), (0.2, 0.2, 0.2)
    counts = roof_histograms([_tile(tmp_path / "a.exr", {"flat": red, "sloped": grey})], (_LeftIsFlat(), 2.0))
    np.testing.assert_allclose(counts["finder"]["flat"], 0.25 * counts["labels"]["flat"])  # 0.5 ** 2 per pixel
    assert counts["finder"]["sloped"].sum() == 0.0 and counts["labels"]["sloped"].sum() == 128


def test_nearest_picks_the_most_similar_colours_and_none_without_pixels(tmp_path):
    references = {}
    for name, colour in (("red", (0.6, 0.05, 0.05)), ("green", (0.05, 0.5, 0.05)), ("grey", (0.2, 0.2, 0.2))):
        counts = roof_histograms([_tile(tmp_path / f"{name}.exr", {"flat": colour})])["labels"]["flat"]
        references[name] = counts / counts.sum()
    target = roof_histograms([_tile(tmp_path / "t.exr", {"flat": (0.55, 0.06, 0.04), "sloped": (0.1, 0.1, 0.1)})])[
        "labels"]
    assert nearest(target["flat"], references) == "red"
    assert nearest(np.zeros(512), references) is None


def test_bench_reference_on_a_small_rendered_training_set(bank, heldout_bank, tmp_path):
    """The whole benchmark on real renders: a few designs at a quarter of the pixels."""
    from meta_sim.experiments.reference import bench_reference, format_reference_table
    from meta_sim.pipeline.dataset import DatasetConfig
    from meta_sim.render.jobs import sample_designs

    dataset = DatasetConfig(designs=6, tiles=1, cities=1, tile_px=96, pixel_size_m=1.2)
    result = bench_reference(targets=2, tiles=2, root=tmp_path, dataset=dataset)
    designs = sample_designs(DesignSpace.load(), 6, dataset.seed)
    # every texture of the training set with a roof of its kind in view has a reference histogram
    for kind, param in (("flat", "flat_roof"), ("sloped", "sloped_roof")):
        assert 1 <= result["bank_textures_seen"][kind] <= len({d[param] for d in designs})
    for split, seeds in (("validation", [1, 2, 7]), ("test", [21, 22, 23])):
        for experiment in ("e1", "e2"):
            for name in ("roof_colour_reference", "roof_finder_reference"):
                row = result["splits"][split]["experiments"][experiment][name]
                assert row["targets"] == 6 and row["seeds"] == seeds
                assert all(0.0 <= row[f"{kind}_top{n}"] <= 1.0 for kind in ("flat", "sloped") for n in (1, 10))
        assert result["splits"][split]["experiments"]["e2"]["roof_colour_reference"]["heldout"] == (
            "heldout-v2" if split == "test" else "heldout-v5")
    table = format_reference_table(result)
    assert table.count("\n") == 9 and "| E2 | test | labels |" in table and "| E2 | test | finder |" in table
    assert result["roof_finder"] == {"finder": "segmenter", "weight_power": 4.0}

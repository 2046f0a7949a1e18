"""`meta-sim export`: PNG pairs and COCO polygons that give back the tiles' labels, written whole or not at all."""

import json
from collections import deque

import numpy as np
import pytest
from click.testing import CliRunner
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from pycocotools import mask as mask_utils
from pycocotools.coco import COCO

from meta_sim.cli import main as cli
from meta_sim.core.errors import MetaSimError
from meta_sim.pipeline.export import export_tiles, mask_polygons
from meta_sim.sim import tiles
from meta_sim.sim.imageio import read_rgb8
from meta_sim.sim.preview import to_srgb8

HOLED = 2  # the instance of the first tile with a hole in it


def _labels() -> tuple[np.ndarray, np.ndarray]:
    """A 32 x 32 tile's instances: an L, a rectangle with a hole, one building in two parts, one at the
    tile's corner, one whose two pixels touch only at a corner; roof class 1 for odd ids, 2 for even."""
    instance = np.zeros((32, 32), np.uint32)
    instance[2:11, 2:6] = 1
    instance[8:11, 2:13] = 1
    instance[14:25, 2:15] = HOLED
    instance[18:21, 6:10] = 0
    instance[2:6, 20:25] = 3
    instance[8:11, 20:24] = 3
    instance[26:32, 20:32] = 4
    instance[13, 20] = instance[14, 21] = 5
    return instance, np.where(instance > 0, 2 - instance % 2, 0).astype(np.uint32)


def _tiles(folder):
    """Three tiles: the shapes of ``_labels``, one rectangle, and no building at all."""
    folder.mkdir()
    rng = np.random.default_rng(0)
    shapes, _ = _labels()
    rectangle = np.zeros((32, 32), np.uint32)
    rectangle[5:9, 7:20] = 7
    for k, instance in enumerate([shapes, rectangle, np.zeros((32, 32), np.uint32)]):
        roof = np.where(instance > 0, 2 - instance % 2, 0).astype(np.uint32)
        meta = tiles.tile_metadata(design={"flat_roof": f"f{k}"}, space="toy", city_seed=10 + k, tile_index=k,
                                   origin_m=(0, 0), size_px=(32, 32), pixel_size_m=0.3, preset="fast")
        rgb = (rng.random((32, 32, 3)) * 1.2).astype(np.float32)  # some values above 1: clipped
        tiles.write_tile(folder / f"d{k:05d}_t00.exr", rgb, instance, roof, meta)
    (folder / ".hidden.exr").write_bytes(b"not a tile")  # dot-files are left out
    return folder


def _filled(mask: np.ndarray) -> np.ndarray:
    """``mask`` with its holes filled: what the outside cannot reach through 8-connected background."""
    outside = np.pad(~mask, 1, constant_values=True)
    reached = np.zeros_like(outside)
    reached[0, 0] = True
    queue = deque([(0, 0)])
    while queue:
        y, x = queue.popleft()
        for dy, dx in ((-1, -1), (-1, 0), (-1, 1), (0, -1), (0, 1), (1, -1), (1, 0), (1, 1)):
            a, b = y + dy, x + dx
            if 0 <= a < outside.shape[0] and 0 <= b < outside.shape[1] and outside[a, b] and not reached[a, b]:
                reached[a, b] = True
                queue.append((a, b))
    return ~reached[1:-1, 1:-1]


def _no_collinear_points(polygon: list) -> bool:
    points = np.array(polygon).reshape(-1, 2)
    steps = np.roll(points, -1, axis=0) - points
    after = np.roll(steps, -1, axis=0)
    return bool(np.all(steps[:, 0] * after[:, 1] != steps[:, 1] * after[:, 0]))


def test_coco_polygons_give_back_each_instance(tmp_path):
    source = _tiles(tmp_path / "tiles")
    summary = export_tiles(source, tmp_path / "coco", "coco")
    assert summary["tiles"] == 3 and summary["annotations"] == 6
    coco = COCO(str(tmp_path / "coco" / "annotations.json"))
    assert [c["name"] for c in coco.loadCats(coco.getCatIds())] == ["building"]
    assert [coco.imgs[i]["file_name"] for i in sorted(coco.imgs)] == [f"d{k:05d}_t00.png" for k in range(3)]
    assert coco.imgs[2]["city_seed"] == 11 and coco.imgs[2]["design"] == {"flat_roof": "f1"}
    assert coco.getAnnIds(imgIds=[3]) == []
    for image_id, path in zip(sorted(coco.imgs), sorted(source.glob("d*.exr"))):
        tile = tiles.read_tile(path)
        assert np.array_equal(read_rgb8(tmp_path / "coco" / "images" / coco.imgs[image_id]["file_name"]),
                              to_srgb8(tile.rgb))
        for ann in coco.loadAnns(coco.getAnnIds(imgIds=[image_id])):
            label = int(np.median(tile.instance[coco.annToMask(ann) > 0]))
            truth = tile.instance == label
            drawn = coco.annToMask(ann) > 0
            assert (drawn & truth).sum() / (drawn | truth).sum() >= 0.9
            assert np.array_equal(drawn, truth) or (label == HOLED and np.array_equal(drawn, _filled(truth)))
            assert ann["area"] == truth.sum() and ann["iscrowd"] == 0 and ann["category_id"] == 1
            rows, cols = np.nonzero(truth)
            assert ann["bbox"] == [cols.min(), rows.min(), np.ptp(cols) + 1, np.ptp(rows) + 1]
            assert ann["roof_class"] == 2 - label % 2
            assert all(len(p) >= 6 and _no_collinear_points(p) for p in ann["segmentation"])
    parts = {a["id"]: len(a["segmentation"]) for a in coco.loadAnns(coco.getAnnIds(imgIds=[1]))}
    assert sorted(parts.values()) == [1, 1, 1, 2, 2]  # building 3 in two parts, building 5's pixels apart


def test_png_pairs_match_the_tiles(tmp_path):
    source = _tiles(tmp_path / "tiles")
    export_tiles(source, tmp_path / "png")
    manifest = json.loads((tmp_path / "png" / "manifest.json").read_text())
    assert manifest["format_version"] == 1 and [t["name"] for t in manifest["tiles"]] == ["d00000_t00", "d00001_t00",
                                                                                          "d00002_t00"]
    for entry, path in zip(manifest["tiles"], sorted(source.glob("d*.exr"))):
        tile = tiles.read_tile(path)
        assert entry["design"] == tile.meta["design"] and entry["city_seed"] == tile.meta["city_seed"]
        assert entry["tile_index"] == tile.meta["tile_index"] and entry["pixel_size_m"] == 0.3
        assert np.array_equal(read_rgb8(tmp_path / "png" / entry["image"]), to_srgb8(tile.rgb))
        assert np.array_equal(read_rgb8(tmp_path / "png" / entry["mask"])[..., 0], (tile.instance > 0) * 255)
        assert np.array_equal(read_rgb8(tmp_path / "png" / entry["roof_class"])[..., 0], tile.roof_class)


@settings(max_examples=150, deadline=None)
@given(arrays(np.uint32, st.tuples(st.integers(1, 12), st.integers(1, 12)), elements=st.integers(0, 3)))
def test_polygons_rasterise_to_the_labels_with_holes_filled(labels):
    polygons = mask_polygons(labels)
    assert set(polygons) == set(np.unique(labels[labels > 0]).tolist())
    for label, parts in polygons.items():
        assert all(_no_collinear_points(p) for p in parts)
        rle = mask_utils.merge(mask_utils.frPyObjects(parts, *labels.shape))
        assert np.array_equal(mask_utils.decode(rle) > 0, _filled(labels == label))


def test_bad_inputs_fail_with_one_line_and_leave_out_as_it_was(tmp_path):
    source = _tiles(tmp_path / "tiles")
    out = tmp_path / "out"
    out.mkdir()
    (out / "keep.txt").write_text("earlier")
    with pytest.raises(MetaSimError, match="not a folder"):
        export_tiles(tmp_path / "missing", tmp_path / "new")
    (tmp_path / "empty").mkdir()
    with pytest.raises(MetaSimError, match="no rendered tiles"):
        export_tiles(tmp_path / "empty", tmp_path / "new")
    with pytest.raises(MetaSimError, match="--overwrite"):
        export_tiles(source, out, "coco")
    with pytest.raises(MetaSimError, match="format"):
        export_tiles(source, tmp_path / "new", "tiff")
    with pytest.raises(MetaSimError, match="replace the tiles"):
        export_tiles(source, tmp_path, overwrite=True)
    (source / "z broken.exr").write_bytes(b"x")
    with pytest.raises(MetaSimError, match="not a safe name"):
        export_tiles(source, out, overwrite=True)
    (source / "z broken.exr").unlink()
    (tmp_path / "empty" / "broken.exr").write_bytes(b"x")
    with pytest.raises(MetaSimError, match="no readable tiles .*broken.exr"):  # found after the attempt to read it
        export_tiles(tmp_path / "empty", out, overwrite=True)
    assert [p.name for p in out.iterdir()] == ["keep.txt"] and not (tmp_path / "new").exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["empty", "out", "tiles"]  # no temporary folder left
    export_tiles(source, out, overwrite=True)
    assert sorted(p.name for p in out.iterdir()) == ["images", "manifest.json", "masks", "roof_class"]


def test_an_unreadable_tile_is_listed_and_the_rest_exported(tmp_path):
    source = _tiles(tmp_path / "tiles")
    (source / "d00001_t00.exr").write_bytes((source / "d00001_t00.exr").read_bytes()[:300])  # truncated
    for fmt in ("png", "coco"):
        result = CliRunner().invoke(cli, ["export", str(source), "--format", fmt, "--out", str(tmp_path / fmt)])
        assert result.exit_code == 1 and "Traceback" not in result.output, result.output
        assert f"2 tiles exported as {fmt}" in result.output
        assert f"skipped {source / 'd00001_t00.exr'}: " in result.output
        assert result.output.strip().splitlines()[-1].startswith("error: 1 unreadable tiles left out")
        assert sorted(p.name for p in (tmp_path / fmt / "images").iterdir()) == ["d00000_t00.png", "d00002_t00.png"]
    coco = json.loads((tmp_path / "coco" / "annotations.json").read_text())
    assert [image["id"] for image in coco["images"]] == [1, 2]
    assert {a["image_id"] for a in coco["annotations"]} == {1}  # the third tile has no building


def test_cli(tmp_path):
    source = _tiles(tmp_path / "tiles")
    run = CliRunner().invoke
    result = run(cli, ["export", str(source), "--format", "coco", "--out", str(tmp_path / "coco")])
    assert result.exit_code == 0 and "3 tiles exported as coco, 6 building annotations" in result.output
    for args, message in ((["--out", str(tmp_path / "coco")], "--overwrite"),
                          (["--format", "tiff", "--out", str(tmp_path / "x")], "Invalid value for '--format'")):
        result = run(cli, ["export", str(source), *args])
        assert result.exit_code == 2 and message in result.output and "Traceback" not in result.output
    result = run(cli, ["export", str(tmp_path / "missing"), "--out", str(tmp_path / "x")])
    assert result.exit_code == 2 and result.output.startswith("error: ") and result.output.count("\n") == 1
    assert run(cli, ["export", str(source), "--out", str(tmp_path / "coco"), "--overwrite"]).exit_code == 0
    assert sorted(p.name for p in (tmp_path / "coco").iterdir()) == ["images", "manifest.json", "masks", "roof_class"]
